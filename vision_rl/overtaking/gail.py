"""`train-baseline --algo gail`: Generative Adversarial Imitation Learning with an off-policy learner.

A discriminator ``D(o, a)`` (the paper's 2 x 256 MLP, one logit) learns by logistic regression to tell the
demonstrations' (observation, action) pairs (label 1) from the learner's (label 0, drawn from its replay buffer).
The learner is online SAC (:mod:`.online`) whose reward is the discriminator's log-odds ``log D - log(1 - D)`` (its
logit, clipped to +-``REWARD_CLIP``), recomputed with the current discriminator whenever a batch is sampled
(:class:`GAILReplayBuffer`), so no stored reward goes stale. The discriminator takes ``gail_disc_updates`` steps
every ``gail_disc_every_steps`` transitions (:class:`GAILCompanion`, which rides along the learner). Why not the
``imitation`` library: docs/notes/overtaking.md, "baselines.py".
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from stable_baselines3.common.buffers import ReplayBuffer
from torch import nn

from vision_rl.files import first_line
from vision_rl.overtaking.baseline_run import HIDDEN_UNITS, BaselineError, TrainBaselineConfig
from vision_rl.overtaking.demos import OBS_DIM, Demos, load_demos_for
from vision_rl.training.sac import next_multiple

#: The discriminator's logit (the learner's reward) is clipped to this, so one confident pair cannot dominate.
REWARD_CLIP = 10.0


class Discriminator(nn.Module):
    """``D(o, a)``: a logit that the (observation, scaled action) pair is the expert's; MLP 2 x 256 ReLU."""

    def __init__(self, obs_dim: int = OBS_DIM, action_dim: int = 2, hidden_units: tuple[int, ...] = HIDDEN_UNITS):
        super().__init__()
        layers: list[nn.Module] = []
        width = obs_dim + action_dim
        for units in hidden_units:
            layers += [nn.Linear(width, units), nn.ReLU()]
            width = units
        layers.append(nn.Linear(width, 1))
        self.net = nn.Sequential(*layers)

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([obs, action], dim=-1)).squeeze(-1)

    def reward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """The learner's reward: the log-odds ``log D - log(1 - D)`` (the logit), clipped to +-REWARD_CLIP."""
        with torch.no_grad():
            return self(obs, action).clamp(-REWARD_CLIP, REWARD_CLIP)


def discriminator_step(
    disc: Discriminator,
    optimizer: torch.optim.Optimizer,
    expert_obs: torch.Tensor,
    expert_act: torch.Tensor,
    learner_obs: torch.Tensor,
    learner_act: torch.Tensor,
) -> dict[str, float]:
    """One logistic-regression step: expert pairs labelled 1, learner pairs 0; returns loss and accuracies."""
    logits_e, logits_l = disc(expert_obs, expert_act), disc(learner_obs, learner_act)
    loss = nn.functional.binary_cross_entropy_with_logits(logits_e, torch.ones_like(logits_e)) + (
        nn.functional.binary_cross_entropy_with_logits(logits_l, torch.zeros_like(logits_l))
    )
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    return {
        "disc_loss": float(loss.detach()),
        "disc_acc_expert": float((logits_e > 0).float().mean()),
        "disc_acc_learner": float((logits_l < 0).float().mean()),
    }


class GAILReplayBuffer(ReplayBuffer):
    """A replay buffer whose sampled rewards are the discriminator's current log-odds of (observation, action)
    (``discriminator`` set after construction; without one, the stored rewards)."""

    discriminator: Discriminator | None = None

    def _get_samples(self, batch_inds, env=None):
        samples = super()._get_samples(batch_inds, env)
        if self.discriminator is None:
            return samples
        reward = self.discriminator.reward(samples.observations, samples.actions).reshape(-1, 1)
        return samples._replace(rewards=reward.to(samples.rewards.dtype))


class GAILUpdater:
    """The discriminator, its optimiser and its updates: expert pairs against pairs drawn from the learner's
    replay buffer (both with actions in the policy's [-1, 1] units, as SB3 stores them).

    Args:
        expert_obs, expert_actions_scaled: (N, obs_dim) and (N, action_dim) demonstration pairs.
        batch, updates, learning_rate: pairs of each kind per step, steps per :meth:`update`, Adam step size.
        seed: of the discriminator's weights and of the pairs drawn.
        hidden_units: the discriminator's MLP.
    """

    def __init__(
        self,
        expert_obs: np.ndarray,
        expert_actions_scaled: np.ndarray,
        *,
        batch: int,
        updates: int,
        learning_rate: float,
        seed: int,
        device: str = "cpu",
        hidden_units: tuple[int, ...] = HIDDEN_UNITS,
    ) -> None:
        self.batch, self.updates, self.device = batch, updates, device
        torch.manual_seed(seed)
        self.disc = Discriminator(expert_obs.shape[1], expert_actions_scaled.shape[1], hidden_units).to(device)
        self.optimizer = torch.optim.Adam(self.disc.parameters(), lr=learning_rate)
        self.expert_obs = torch.as_tensor(expert_obs, dtype=torch.float32, device=device)
        self.expert_act = torch.as_tensor(expert_actions_scaled, dtype=torch.float32, device=device)
        self.rng = np.random.default_rng(seed + 7)
        self.last: dict[str, float] = {}

    def update(self, buffer: ReplayBuffer) -> dict[str, float]:
        rows = buffer.buffer_size if buffer.full else buffer.pos
        if rows == 0:
            return {}
        batch = self.batch
        for _ in range(self.updates):
            e = torch.as_tensor(self.rng.integers(0, len(self.expert_obs), batch), device=self.device)
            r, k = self.rng.integers(0, rows, batch), self.rng.integers(0, buffer.n_envs, batch)
            lo = torch.as_tensor(buffer.observations[r, k], dtype=torch.float32, device=self.device)
            la = torch.as_tensor(buffer.actions[r, k], dtype=torch.float32, device=self.device)
            self.last = discriminator_step(self.disc, self.optimizer, self.expert_obs[e], self.expert_act[e], lo, la)
        return self.last

    def state(self) -> dict[str, Any]:
        return {"discriminator": self.disc.state_dict(), "discriminator_optimizer": self.optimizer.state_dict()}

    def restore(self, state: dict[str, Any], source: str) -> None:
        try:
            self.disc.load_state_dict(state["discriminator"])
            self.optimizer.load_state_dict(state["discriminator_optimizer"])
        except (KeyError, RuntimeError, ValueError) as exc:
            raise BaselineError(f"{source}: no discriminator that fits this gail run: {first_line(exc)}") from None


class GAILCompanion:
    """gail's part of an online SAC run (:func:`.online.train_online`): the demonstrations (their checksum is a
    setting of the run folder), the replay buffer whose rewards are the discriminator's, the discriminator's
    updates on the learner's steps, its figures in each evaluation and its state in the agent file."""

    replay_buffer_class = GAILReplayBuffer

    def __init__(self, cfg: TrainBaselineConfig) -> None:
        self.cfg = cfg
        self.demos: Demos = load_demos_for(cfg.demos, cfg.racing.track, cfg.racing.car)
        self.updater: GAILUpdater | None = None
        self.next_update: int | None = None

    def attach(self, model, device: str) -> None:
        """The discriminator, made once the learner is (its actions in the policy's [-1, 1] units)."""
        cfg = self.cfg
        scaled = model.policy.scale_action(self.demos.expert_actions.astype(np.float64))
        self.updater = GAILUpdater(
            self.demos.observations,
            scaled,
            batch=cfg.gail_disc_batch,
            updates=cfg.gail_disc_updates,
            learning_rate=cfg.gail_disc_lr,
            seed=cfg.seed,
            device=device,
        )
        model.replay_buffer.discriminator = self.updater.disc

    def begin(self, start_steps: int) -> None:
        """The session starts at ``start_steps``: the next update is at the following multiple."""
        self.next_update = next_multiple(start_steps, self.cfg.gail_disc_every_steps)

    def on_step(self, num_timesteps: int, model) -> None:
        """Before the learner's evaluations and saves of this step: the discriminator's updates when due."""
        if self.next_update is not None and num_timesteps >= self.next_update:
            self._updater().update(model.replay_buffer)
            self.next_update = next_multiple(num_timesteps, self.cfg.gail_disc_every_steps)

    def figures(self) -> dict[str, float]:
        """The last discriminator step's loss and accuracies, for metrics.jsonl."""
        return self._updater().last

    def state(self) -> dict[str, Any]:
        return self._updater().state()

    def restore(self, state: dict[str, Any], source: str) -> None:
        self._updater().restore(state, source)

    def _updater(self) -> GAILUpdater:
        assert self.updater is not None, "attach() first"
        return self.updater


__all__ = [
    "REWARD_CLIP",
    "Discriminator",
    "GAILCompanion",
    "GAILReplayBuffer",
    "GAILUpdater",
    "discriminator_step",
]
