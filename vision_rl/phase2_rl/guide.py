"""Demonstrations of the built-in AI in an off-policy learner's replay buffer (not in the papers).

SAC on the papers' reward learned, on expressway, never to brake: the state and vision policies keep the throttle on
into the slow corners and let the outer wall take the speed, at up to 159 km/h, whatever the wall penalty's weight
or form. Braking early enough is a long run of actions that exploration around a full-throttle policy does not
find; the AI's laps show it. Its transitions go into the buffer before the first update, rewarded by the
environment's own reward, and optionally the actor clones them. Measured over 3 training seeds each, neither
stopped the hits (docs/results/state-expressway-hatchback-clean); both stay as options for further study.
"""

from __future__ import annotations

import numpy as np


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
            infos = [{**info, "TimeLimit.truncated": True} if not done else info
                     for info, done in zip(infos, dones, strict=True)]  # fmt: skip
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

        def train(self, gradient_steps: int, batch_size: int = 64) -> None:
            super().train(gradient_steps, batch_size)
            if self.bc_weight > 0:
                self.clone(gradient_steps, batch_size, self.bc_weight)

        def clone(self, gradient_steps: int, batch_size: int, weight: float = 1.0) -> None:
            """``gradient_steps`` actor steps on ``weight * |mean action - the AI's action|^2`` (none without guided
            rows in the buffer)."""
            rows = min(self.demo_rows, self.replay_buffer.size())
            if rows == 0:
                return
            buffer = self.replay_buffer
            for _ in range(gradient_steps):
                # torch's generator, which SB3 seeds with the run's seed, so a run repeats.
                row = torch.randint(0, rows, (batch_size,)).numpy()
                env = torch.randint(0, buffer.n_envs, (batch_size,)).numpy()
                obs = torch.as_tensor(buffer.observations[row, env], device=self.device)
                target = torch.as_tensor(buffer.actions[row, env], device=self.device)
                loss = weight * torch.mean((self.actor(obs, deterministic=True) - target) ** 2)
                self.actor.optimizer.zero_grad()
                loss.backward()
                self.actor.optimizer.step()
            self.logger.record("train/bc_loss", loss.item())

    return GuidedSAC
