"""Demonstrations of the built-in AI in an off-policy learner's replay buffer (not in the papers).

SAC on the papers' reward learned, on expressway, never to brake: the state and vision policies keep the throttle on
into the slow corners and let the outer wall take the speed, at up to 159 km/h, whatever the wall penalty's weight
or form. Braking early enough is a long run of actions that exploration around a full-throttle policy does not
find; the AI's laps show it. Its transitions go into the buffer before the first update, rewarded by the
environment's own reward, and optionally the actor clones them. Measured over 3 training seeds each, neither
stopped the hits. What did (with a throttle cut after each hit) is the AI labelling the states the policy itself
visits and the actor cloning those labels beside SAC's update (:func:`start_labels`): 0.02-0.48 s of wall contact
per lap over 3 seeds (docs/results/state-expressway-hatchback-clean).
"""

from __future__ import annotations

import numpy as np

#: The labelling AI's skill: its fastest (2:08.655 on expressway, 1.6 % above the limit, clean), so that cloning it
#: pulls towards braking where it must, not towards the default skill's 10 % margin.
LABEL_SKILL = 1.0


def add_guided_transitions(model, venv, n_transitions: int) -> int:
    """Drive every ego of ``venv`` (a :class:`vision_rl.envs.sb3.RacingSB3VecEnv` with vector observations) by the
    built-in AI and add at least ``n_transitions`` of its transitions to ``model``'s replay buffer, as
    Stable-Baselines3's own collection would add them (the true last observation of an ended episode, time limits
    marked as truncations). Returns how many were added; ``venv`` is left mid-episode, so a learner resets it before
    collecting its own."""
    obs = venv.reset()
    added = 0
    while added < n_transitions:
        next_obs, reward, dones, infos, actions = venv.guided_step()
        last_obs = next_obs.copy()
        for g, info in enumerate(infos):
            if "terminal_observation" in info:
                last_obs[g] = info["terminal_observation"]
        if added + len(reward) >= n_transitions:
            # The learner resets the world after this step: every guided episode ends here, cut short (so an n-step
            # return does not run on into the learner's first episode).
            infos = [
                {**info, "TimeLimit.truncated": True} if not done else info
                for info, done in zip(infos, dones, strict=True)
            ]
            dones = np.ones_like(dones)
        scaled = model.policy.scale_action(actions.astype(np.float32))
        model.replay_buffer.add(obs, last_obs, scaled, reward, dones, infos)
        obs = next_obs
        added += len(reward)
    return added


def guided_sac_class():
    """:class:`stable_baselines3.SAC` with a behaviour-cloning step on the guided transitions after each update
    (imported on first use: SB3 imports torch).

    SAC's critic values an action by what the current policy does after it, so the AI's braking in the buffer does
    not make braking worth more to a policy that accelerates into the wall on the next step (the ``--guide-steps``
    probes in docs/results/state-expressway-hatchback-clean). After each SAC update the actor takes one gradient step on
    ``bc_weight * |mean action - the AI's action|^2`` over a batch of the first ``demo_rows`` buffer rows (where
    :func:`add_guided_transitions` put them), as DDPG from demonstrations adds a cloning loss to its actor's."""
    import torch
    from stable_baselines3 import SAC

    class GuidedSAC(SAC):
        demo_rows: int = 0
        """Buffer rows (vector steps) from the start that hold the AI's transitions."""
        bc_weight: float = 0.0
        label_weight: float = 0.0
        """Weight of a cloning step on the AI's labels of the states the policy visits (0: none)."""
        label_skill: float | None = None
        """The labelling AI's skill (None: no labels); samplers in other processes label with it too."""
        label_steer_weight: float = 1.0
        """Weight of the steering column in the labels' cloning loss, the pedal's being 1 (0: the pedal alone)."""
        label_fade_steps: int = 0
        """Environment steps before ``label_end_steps`` over which the labels' weight falls linearly to 0 (0: none)."""
        label_end_steps: int = 0

        def label_weight_now(self) -> float:
            """The labels' weight at this step: ``label_weight``, faded towards the end when asked."""
            if self.label_fade_steps <= 0:
                return self.label_weight
            left = (self.label_end_steps - self.num_timesteps) / self.label_fade_steps
            return self.label_weight * min(1.0, max(0.0, left))

        def train(self, gradient_steps: int, batch_size: int = 64) -> None:
            super().train(gradient_steps, batch_size)
            if self.bc_weight > 0:
                self.clone(gradient_steps, batch_size, self.bc_weight)
            label_weight = self.label_weight_now()
            if label_weight > 0:
                self.clone(gradient_steps, batch_size, label_weight, labels=True)
            if self.label_fade_steps > 0:
                self.logger.record("train/label_weight", label_weight)

        def _store_transition(self, replay_buffer, buffer_action, new_obs, reward, dones, infos) -> None:
            if getattr(replay_buffer, "ai_labels", None) is not None:  # the row SB3 is about to write
                none = np.full(2, np.nan)
                labels = np.stack([info.get("ai_action", none) for info in infos])
                replay_buffer.ai_labels[replay_buffer.pos] = self.policy.scale_action(labels)
            super()._store_transition(replay_buffer, buffer_action, new_obs, reward, dones, infos)

        def clone(self, gradient_steps: int, batch_size: int, weight: float = 1.0, labels: bool = False) -> None:
            """``gradient_steps`` actor steps on ``weight * |mean action - the AI's action|^2`` over the guided rows
            (none without them), or with ``labels`` over every row the AI labelled, its steering column weighted by
            ``label_steer_weight``."""
            buffer = self.replay_buffer
            rows = buffer.size() if labels else min(self.demo_rows, buffer.size())
            if rows == 0 or (labels and getattr(buffer, "ai_labels", None) is None):
                return
            loss = None
            columns = torch.tensor([self.label_steer_weight if labels else 1.0, 1.0], device=self.device)
            for _ in range(gradient_steps):
                # torch's generator, which SB3 seeds with the run's seed, so a run repeats.
                row = torch.randint(0, rows, (batch_size,)).numpy()
                env = torch.randint(0, buffer.n_envs, (batch_size,)).numpy()
                actions = buffer.ai_labels[row, env] if labels else buffer.actions[row, env]
                keep = np.isfinite(actions[:, 0])
                if not keep.any():
                    continue
                obs = torch.as_tensor(buffer.observations[row[keep], env[keep]], device=self.device)
                target = torch.as_tensor(actions[keep], device=self.device)
                loss = weight * torch.mean(columns * (self.actor(obs, deterministic=True) - target) ** 2)
                self.actor.optimizer.zero_grad()
                loss.backward()
                self.actor.optimizer.step()
            if loss is not None:
                self.logger.record("train/label_loss" if labels else "train/bc_loss", loss.item())

    return GuidedSAC


def start_labels(
    model,
    venv,
    weight: float,
    skill: float = LABEL_SKILL,
    fade_steps: int = 0,
    end_steps: int = 0,
    steer_weight: float = 1.0,
) -> None:
    """From the next transition on, ``venv``'s built-in AI at ``skill`` labels every state the policy visits with
    the action it would take there, the labels go beside the transitions into ``model`` (a ``GuidedSAC``), and the
    actor takes a cloning step of ``weight`` on a batch of them after each SAC update: DAgger's labels (Ross et al.
    2011, https://arxiv.org/abs/1011.0686) as a regulariser of the actor, on the policy's own states rather than
    the AI's, so the critic sees where braking leads (not in the papers). The labels are an array of the buffer,
    ``ai_labels`` (rows, envs, 2), NaN where a row has none, saved and restored with it. With ``fade_steps`` the
    weight falls linearly to 0 over the ``fade_steps`` environment steps before ``end_steps``, so that SAC alone
    refines the lap the labels taught to brake on. ``steer_weight`` weighs the steering column of the cloning loss
    (0: the actor clones the AI's pedal alone; both columns are labelled and saved either way)."""
    buffer = model.replay_buffer
    buffer.ai_labels = np.full((buffer.buffer_size, buffer.n_envs, 2), np.nan, dtype=np.float32)
    model.label_weight, model.label_skill, model.label_steer_weight = weight, skill, steer_weight
    model.label_fade_steps, model.label_end_steps = fade_steps, end_steps
    venv.core.label_with_ai(skill)
