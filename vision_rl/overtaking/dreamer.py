"""A Dreamer-style world-model agent: the Table III PlaNet row (``train-baseline --algo dreamer``).

PlaNet plans every action with the cross-entropy method in its learned latent space, far beyond a 2-core CPU for 20
cars; its successor Dreamer keeps the same world model and replaces the planner with an actor and a value trained on
the model's imagined trajectories, so acting is one forward pass. This module is that successor, sized like the
paper's other baselines (2 x 256 MLPs) on the same 96-D observation, with its replay and its protocol driver; its
training is :mod:`.dreamer_train`. The parts and the numbers: docs/notes/overtaking.md, "dreamer.py".

Sequences are stored per car (:class:`SequenceReplay`) in Dreamer's convention: row ``t`` holds observation
``o_t``, the action ``a_{t-1}`` that led to it, the reward received on arriving, whether the episode continues from
it, and whether it starts an episode (the model's state is reset there).
"""

from __future__ import annotations

import contextlib
import copy
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import nn
from torch.distributions import Independent, Normal, TanhTransform, TransformedDistribution, kl_divergence

from vision_rl.envs.core import RacingConfig
from vision_rl.envs.racing_env import action_space
from vision_rl.evaluation.protocol import DRIVER_BATCH_CARS
from vision_rl.overtaking.config import OBSERVATION
from vision_rl.training.artifact import PolicyDriver, PolicySpec


@dataclass(frozen=True)
class DreamerRecipe:
    """Sizes and step sizes of the world model, actor and value (Dreamer's defaults where they fit a CPU)."""

    hidden_units: tuple[int, ...] = (256, 256)
    """Every MLP's hidden layers (the overtaking paper's network for every method, Sec. IV-B)."""
    deter_units: int = 256
    """Units of the deterministic recurrent state h (Dreamer: 200)."""
    stoch_units: int = 32
    """Units of the stochastic state z (Dreamer: 30)."""
    batch_sequences: int = 16
    """Sequences per world-model update (Dreamer: 50)."""
    sequence_steps: int = 32
    """Control steps per sequence (Dreamer: 50)."""
    imagine_steps: int = 15
    """Imagination horizon of the actor and value updates, control steps (Dreamer: 15)."""
    imagine_starts: int = 128
    """Posterior states of the batch the imagined rollouts start from, drawn at random (Dreamer: all of them,
    here 512; imagining from all took 4x the world model's update time on one core)."""
    gamma: float = 0.99
    """Discount per control step."""
    lambda_: float = 0.95
    """Lambda of the lambda-returns."""
    free_nats: float = 3.0
    """The KL term's floor, nats (Dreamer: 3)."""
    model_lr: float = 6e-4
    """World model's Adam step size (Dreamer: 6e-4)."""
    actor_lr: float = 8e-5
    """Actor's Adam step size (Dreamer: 8e-5)."""
    value_lr: float = 8e-5
    """Value's Adam step size (Dreamer: 8e-5)."""
    grad_clip: float = 100.0
    """Gradient norm clip of every update (Dreamer: 100)."""
    explore_std: float = 0.3
    """Std of the exploration noise on actions in [-1, 1] (Dreamer: 0.3)."""
    value_target_tau: float = 0.01
    """Step of the slow value copy that the lambda-returns bootstrap from, per update (DreamerV2's slow critic,
    arXiv:2010.02193 Sec. 2: without it a value that bootstraps on itself ran away on a toy task)."""


def mlp(inputs: int, hidden: tuple[int, ...], outputs: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    width = inputs
    for units in hidden:
        layers += [nn.Linear(width, units), nn.ELU()]
        width = units
    layers.append(nn.Linear(width, outputs))
    return nn.Sequential(*layers)


def _gaussian(params: torch.Tensor) -> Normal:
    mean, raw_std = params.chunk(2, dim=-1)
    return Normal(mean, nn.functional.softplus(raw_std) + 0.1)  # Dreamer's floor keeps the KL finite


class LatentState(NamedTuple):
    """The RSSM's state of N cars: deterministic ``h`` (N, deter) and stochastic ``z`` (N, stoch)."""

    h: torch.Tensor
    z: torch.Tensor

    def feature(self) -> torch.Tensor:
        return torch.cat([self.h, self.z], dim=-1)


class SequenceBatch(NamedTuple):
    """B sequences of L rows, in :class:`SequenceReplay`'s convention, as float32 tensors."""

    observations: torch.Tensor  # (B, L, obs_dim)
    prev_actions: torch.Tensor  # (B, L, action_dim)
    rewards: torch.Tensor  # (B, L)
    continues: torch.Tensor  # (B, L)
    is_first: torch.Tensor  # (B, L)


class WorldModel(nn.Module):
    """Encoder, RSSM and the observation, reward and continuation heads."""

    def __init__(self, obs_dim: int, action_dim: int, recipe: DreamerRecipe) -> None:
        super().__init__()
        hidden, deter, stoch = recipe.hidden_units, recipe.deter_units, recipe.stoch_units
        self.deter_units, self.stoch_units = deter, stoch
        self.encoder = mlp(obs_dim, hidden[:-1], hidden[-1])
        self.pre_gru = nn.Sequential(nn.Linear(stoch + action_dim, deter), nn.ELU())
        self.gru = nn.GRUCell(deter, deter)
        self.prior_net = mlp(deter, hidden[:1], 2 * stoch)
        self.posterior_net = mlp(deter + hidden[-1], hidden[:1], 2 * stoch)
        feature = deter + stoch
        self.decoder = mlp(feature, hidden, obs_dim)
        self.reward_head = mlp(feature, hidden, 1)
        self.continue_head = mlp(feature, hidden, 1)

    def initial(self, n: int) -> LatentState:
        p = next(self.parameters())
        return LatentState(p.new_zeros(n, self.deter_units), p.new_zeros(n, self.stoch_units))

    def imagine_step(self, state: LatentState, action: torch.Tensor) -> tuple[torch.Tensor, Normal]:
        """The next ``h`` and the prior over the next ``z`` after ``action``."""
        h = self.gru(self.pre_gru(torch.cat([state.z, action], dim=-1)), state.h)
        return h, _gaussian(self.prior_net(h))

    def observe_step(
        self,
        state: LatentState,
        prev_action: torch.Tensor,
        embed: torch.Tensor,
        is_first: torch.Tensor,
        sample: bool = True,
    ) -> tuple[LatentState, Normal, Normal]:
        """Filter one observation: the state (reset where ``is_first``; ``z`` drawn from the posterior, or its mean
        when not ``sample``), its prior and its posterior."""
        keep = (1.0 - is_first).unsqueeze(-1)
        state = LatentState(state.h * keep, state.z * keep)
        h, prior = self.imagine_step(state, prev_action * keep)
        posterior = _gaussian(self.posterior_net(torch.cat([h, embed], dim=-1)))
        return LatentState(h, posterior.rsample() if sample else posterior.mean), prior, posterior

    def loss(self, batch: SequenceBatch, free_nats: float) -> tuple[torch.Tensor, LatentState, dict[str, float]]:
        """The world-model loss of a batch, the posterior states (B*L rows) and the loss's terms."""
        n_seq, length = batch.rewards.shape
        embed = self.encoder(batch.observations)
        state = self.initial(n_seq)
        hs, zs, kls = [], [], []
        for t in range(length):
            state, prior, posterior = self.observe_step(
                state, batch.prev_actions[:, t], embed[:, t], batch.is_first[:, t]
            )
            hs.append(state.h)
            zs.append(state.z)
            kls.append(kl_divergence(posterior, prior).sum(-1))
        states = LatentState(torch.stack(hs, 1), torch.stack(zs, 1))
        feature = states.feature()
        observation_nll = 0.5 * ((self.decoder(feature) - batch.observations) ** 2).sum(-1).mean()
        reward_nll = 0.5 * ((self.reward_head(feature).squeeze(-1) - batch.rewards) ** 2).mean()
        continue_nll = nn.functional.binary_cross_entropy_with_logits(
            self.continue_head(feature).squeeze(-1), batch.continues
        )
        kl = torch.stack(kls, 1).mean()
        loss = observation_nll + reward_nll + continue_nll + torch.clamp(kl, min=free_nats)
        terms = {
            "observation_nll": float(observation_nll.detach()),
            "reward_nll": float(reward_nll.detach()),
            "continue_nll": float(continue_nll.detach()),
            "kl": float(kl.detach()),
        }
        flat = LatentState(states.h.reshape(n_seq * length, -1), states.z.reshape(n_seq * length, -1))
        return loss, flat, terms


class Actor(nn.Module):
    """A tanh-transformed diagonal Gaussian over actions in [-1, 1] (Dreamer's parameterisation)."""

    #: Dreamer's initial std 5 before the tanh and its floor 1e-4.
    RAW_INIT_STD = math.log(math.exp(5.0) - 1.0)
    MIN_STD = 1e-4

    def __init__(self, feature_units: int, action_dim: int, hidden: tuple[int, ...]) -> None:
        super().__init__()
        self.net = mlp(feature_units, hidden, 2 * action_dim)

    def _mean_std(self, feature: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mean, raw_std = self.net(feature).chunk(2, dim=-1)
        return 5.0 * torch.tanh(mean / 5.0), nn.functional.softplus(raw_std + self.RAW_INIT_STD) + self.MIN_STD

    def distribution(self, feature: torch.Tensor) -> TransformedDistribution:
        mean, std = self._mean_std(feature)
        return TransformedDistribution(Independent(Normal(mean, std), 1), TanhTransform(cache_size=1))

    def mode(self, feature: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self._mean_std(feature)[0])


def lambda_returns(
    rewards: torch.Tensor, values: torch.Tensor, discounts: torch.Tensor, lambda_: float
) -> torch.Tensor:
    """Lambda-returns of an imagined rollout (Dreamer's Eq. 6), time first.

    ``rewards`` and ``discounts`` (H, N) are those on arriving at states 1..H; ``values`` (H + 1, N) those of
    states 0..H. Returns R_0..R_{H-1} with R_t = r_t + d_t ((1 - lambda) v_{t+1} + lambda R_{t+1}) and R_H = v_H.
    """
    horizon = rewards.shape[0]
    returns = []
    last = values[horizon]
    for t in reversed(range(horizon)):
        last = rewards[t] + discounts[t] * ((1.0 - lambda_) * values[t + 1] + lambda_ * last)
        returns.append(last)
    return torch.stack(returns[::-1])


@contextlib.contextmanager
def frozen(*modules: nn.Module) -> Iterator[None]:
    """Gradients flow through ``modules`` but none is stored for their parameters."""
    params = [p for m in modules for p in m.parameters()]
    flags = [p.requires_grad for p in params]
    for p in params:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p, flag in zip(params, flags, strict=True):
            p.requires_grad_(flag)


class DreamerAgent:
    """World model, actor and value with their optimisers; :meth:`update` trains all three on a batch,
    :meth:`act` drives N cars from their recurrent states."""

    def __init__(self, obs_dim: int, action_dim: int, recipe: DreamerRecipe, seed: int = 0, device: str = "cpu"):
        torch.manual_seed(seed)
        self.recipe, self.device = recipe, torch.device(device)
        self.obs_dim, self.action_dim = obs_dim, action_dim
        self.world_model = WorldModel(obs_dim, action_dim, recipe).to(self.device)
        feature = recipe.deter_units + recipe.stoch_units
        self.actor = Actor(feature, action_dim, recipe.hidden_units).to(self.device)
        self.value = mlp(feature, recipe.hidden_units, 1).to(self.device)
        self.value_target = copy.deepcopy(self.value).requires_grad_(False)
        self.optimizers = {
            "world_model": torch.optim.Adam(self.world_model.parameters(), lr=recipe.model_lr, eps=1e-4),
            "actor": torch.optim.Adam(self.actor.parameters(), lr=recipe.actor_lr, eps=1e-4),
            "value": torch.optim.Adam(self.value.parameters(), lr=recipe.value_lr, eps=1e-4),
        }
        self.noise = torch.Generator(device="cpu").manual_seed(seed + 1)
        self.n_updates = 0

    def _step(self, name: str, module: nn.Module, loss: torch.Tensor) -> None:
        optimizer = self.optimizers[name]
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(module.parameters(), self.recipe.grad_clip)
        optimizer.step()

    def update(self, batch: SequenceBatch) -> dict[str, float]:
        """One update of the world model, then the actor and the value on rollouts imagined from its posteriors."""
        r = self.recipe
        model_loss, posteriors, terms = self.world_model.loss(batch, r.free_nats)
        self._step("world_model", self.world_model, model_loss)

        with frozen(self.world_model):
            starts = torch.randperm(len(posteriors.h), generator=self.noise)[: r.imagine_starts].to(self.device)
            state = LatentState(posteriors.h[starts].detach(), posteriors.z[starts].detach())
            features = [state.feature()]
            for _ in range(r.imagine_steps):
                action = self.actor.distribution(features[-1].detach()).rsample()
                h, prior = self.world_model.imagine_step(state, action)
                state = LatentState(h, prior.rsample())
                features.append(state.feature())
            feature = torch.stack(features)  # (H + 1, N, F)
            rewards = self.world_model.reward_head(feature[1:]).squeeze(-1)
            discounts = r.gamma * torch.sigmoid(self.world_model.continue_head(feature[1:]).squeeze(-1))
            returns = lambda_returns(rewards, self.value_target(feature).squeeze(-1), discounts, r.lambda_)
            # A state's weight: its discount from the start, the chance (under the model) that the episode reached it.
            weights = torch.cumprod(torch.cat([torch.ones_like(discounts[:1]), discounts[:-1]]), 0).detach()
            actor_loss = -(weights * returns).mean()
        self._step("actor", self.actor, actor_loss)

        value_loss = 0.5 * (weights * (self.value(feature[:-1].detach()).squeeze(-1) - returns.detach()) ** 2).mean()
        self._step("value", self.value, value_loss)
        with torch.no_grad():
            for target, source in zip(self.value_target.parameters(), self.value.parameters(), strict=True):
                target.lerp_(source, r.value_target_tau)
        self.n_updates += 1
        return {
            **terms,
            "model_loss": float(model_loss.detach()),
            "actor_loss": float(actor_loss.detach()),
            "value_loss": float(value_loss.detach()),
            "imagined_return": float(returns[0].mean().detach()),
        }

    def initial(self, n: int) -> tuple[LatentState, torch.Tensor]:
        """The recurrent state and the previous action (zeros) of ``n`` cars before their first observation."""
        return self.world_model.initial(n), torch.zeros(n, self.action_dim, device=self.device)

    @torch.no_grad()
    def act(
        self, carry: tuple[LatentState, torch.Tensor], observations: np.ndarray, is_first: np.ndarray, explore: bool
    ) -> tuple[np.ndarray, tuple[LatentState, torch.Tensor]]:
        """Actions (N, action_dim) in [-1, 1] for N cars' observations, and their new recurrent carry. ``is_first``
        marks cars whose observation starts an episode (their state restarts). ``explore``: sampled states and
        actions plus Gaussian noise, clipped; otherwise the posterior's mean and the actor's mode (deterministic)."""
        state, prev_action = carry
        obs = torch.as_tensor(observations, dtype=torch.float32, device=self.device)
        first = torch.as_tensor(is_first, dtype=torch.float32, device=self.device)
        state, _, _ = self.world_model.observe_step(state, prev_action, self.world_model.encoder(obs), first, explore)
        feature = state.feature()
        if explore:
            action = self.actor.distribution(feature).sample()
            noise = torch.randn(action.shape, generator=self.noise) * self.recipe.explore_std
            action = torch.clamp(action + noise.to(self.device), -1.0, 1.0)
        else:
            action = self.actor.mode(feature)
        return action.cpu().numpy().astype(np.float64), (state, action.float())

    def state_dict(self) -> dict[str, Any]:
        return {
            "world_model": self.world_model.state_dict(),
            "actor": self.actor.state_dict(),
            "value": self.value.state_dict(),
            "value_target": self.value_target.state_dict(),
            "optimizers": {k: o.state_dict() for k, o in self.optimizers.items()},
        }

    def load_state_dict(self, state: dict[str, Any], optimizers: bool = True) -> None:
        """Load weights (and optimisers); raises KeyError/RuntimeError on weights of another shape."""
        self.world_model.load_state_dict(state["world_model"])
        self.actor.load_state_dict(state["actor"])
        self.value.load_state_dict(state["value"])
        self.value_target.load_state_dict(state["value_target"])
        if optimizers:
            for name, optimizer in self.optimizers.items():
                optimizer.load_state_dict(state["optimizers"][name])


class SequenceReplay:
    """Rows of every car's experience in time order, one column per car, each a ring of ``capacity_per_car``
    rows (preallocated). A row is (o_t, a_{t-1}, r_t, continue_t, is_first_t); see the module's docstring."""

    ARRAYS = ("observations", "prev_actions", "rewards", "continues", "is_first")

    def __init__(self, capacity_per_car: int, n_cars: int, obs_dim: int, action_dim: int) -> None:
        if capacity_per_car < 2:
            raise ValueError(f"a sequence replay needs at least 2 rows per car, got {capacity_per_car}")
        self.capacity, self.n_cars = int(capacity_per_car), int(n_cars)
        self.observations = np.zeros((capacity_per_car, n_cars, obs_dim), dtype=np.float32)
        self.prev_actions = np.zeros((capacity_per_car, n_cars, action_dim), dtype=np.float32)
        self.rewards = np.zeros((capacity_per_car, n_cars), dtype=np.float32)
        self.continues = np.zeros((capacity_per_car, n_cars), dtype=np.float32)
        self.is_first = np.zeros((capacity_per_car, n_cars), dtype=np.float32)
        # Rows ever written per car: the next goes at written % capacity.
        self.written = np.zeros(n_cars, dtype=np.int64)

    @property
    def filled(self) -> np.ndarray:
        return np.minimum(self.written, self.capacity)

    def add(
        self,
        cars: np.ndarray,
        observations: np.ndarray,
        prev_actions: np.ndarray,
        rewards: np.ndarray,
        continues: np.ndarray,
        is_first: np.ndarray,
    ) -> None:
        """Append one row to each of ``cars`` (distinct car indices)."""
        cars = np.asarray(cars, dtype=np.int64)
        rows = self.written[cars] % self.capacity
        self.observations[rows, cars] = observations
        self.prev_actions[rows, cars] = prev_actions
        self.rewards[rows, cars] = rewards
        self.continues[rows, cars] = continues
        self.is_first[rows, cars] = is_first
        self.written[cars] += 1

    def can_sample(self, length: int) -> bool:
        return bool((self.filled >= length).any())

    def sample(
        self, rng: np.random.Generator, batch: int, length: int, device: str | torch.device = "cpu"
    ) -> SequenceBatch:
        """``batch`` sequences of ``length`` consecutive rows, each from one car, uniformly over their starts."""
        filled = self.filled
        eligible = np.flatnonzero(filled >= length)
        if len(eligible) == 0:
            raise ValueError(f"no car has {length} rows yet")
        starts_per_car = (filled - length + 1)[eligible]
        cars = rng.choice(eligible, size=batch, p=starts_per_car / starts_per_car.sum())
        oldest = self.written[cars] - filled[cars]
        start = oldest + rng.integers(0, filled[cars] - length + 1)
        rows = (start[:, None] + np.arange(length)[None, :]) % self.capacity
        cols = cars[:, None]

        def take(array: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(array[rows, cols], device=device)

        return SequenceBatch(*(take(getattr(self, name)) for name in self.ARRAYS))

    def arrays(self) -> dict[str, np.ndarray]:
        """The filled rows of every car, oldest first: each array (max filled, n_cars, ...), with ``written``."""
        n = int(self.filled.max()) if self.n_cars else 0
        start = self.written - self.filled
        rows = (start[None, :] + np.arange(n)[:, None]) % self.capacity
        cols = np.arange(self.n_cars)[None, :]
        out = {name: getattr(self, name)[rows, cols] for name in self.ARRAYS}
        out["written"] = self.written.copy()
        return out

    def restore(self, arrays: dict[str, np.ndarray]) -> int:
        """Fill a fresh replay from :meth:`arrays`; returns the rows restored over all cars. Raises ValueError on
        arrays of another shape."""
        written = np.asarray(arrays["written"], dtype=np.int64)
        if written.shape != (self.n_cars,):
            raise ValueError(f"rows of {written.shape[0] if written.ndim else 0} cars, this replay has {self.n_cars}")
        n = len(arrays["observations"])
        if n > self.capacity:
            raise ValueError(f"{n} rows per car, more than this replay's capacity {self.capacity}")
        filled = np.minimum(written, n)
        for name in self.ARRAYS:
            values, target = arrays[name], getattr(self, name)
            if values.shape[1:] != target.shape[1:] or len(values) != n:
                raise ValueError(f"{name} has shape {values.shape[1:]} per row, this replay {target.shape[1:]}")
            target[:n] = values
        # Rows were written oldest first from index 0: continue each car after its last one.
        self.written = filled.copy()
        return int(filled.sum())


# ------------------------------------------------------------------------------------------------- driving


def to_env_units(actions: np.ndarray) -> np.ndarray:
    """Actions in [-1, 1] to the environment's ``[steer rad, omega]``."""
    space = action_space()
    return space.low + 0.5 * (np.clip(actions, -1.0, 1.0) + 1.0) * (space.high - space.low)


def to_model_units(actions: np.ndarray) -> np.ndarray:
    """The environment's ``[steer rad, omega]`` to the agent's [-1, 1]: the inverse of :func:`to_env_units`."""
    space = action_space()
    return np.clip(2.0 * (np.asarray(actions, dtype=np.float64) - space.low) / (space.high - space.low) - 1.0, -1, 1)


class DreamerDriver(PolicyDriver):
    """A Dreamer agent as a protocol driver: its recurrent state restarts with every protocol run.

    :class:`PolicyDriver` calls ``_predict`` once per batch of ``DRIVER_BATCH_CARS`` cars, in order, every control
    step; each batch keeps its own recurrent state, so a start drives the same beside any number of others."""

    def __init__(self, agent: DreamerAgent, config: RacingConfig, normalizer, identity: dict[str, Any]) -> None:
        super().__init__(self._predict, OBSERVATION, normalizer, None, config, identity)
        self.agent = agent

    def reset(self, world, car_ids: np.ndarray) -> None:
        super().reset(world, car_ids)
        n_batches = -(-len(car_ids) // DRIVER_BATCH_CARS)
        self.carries = [self.agent.initial(DRIVER_BATCH_CARS) for _ in range(n_batches)]
        self.calls = 0

    def _predict(self, obs: np.ndarray) -> np.ndarray:
        i = self.calls % len(self.carries)
        first = np.full(len(obs), float(self.calls < len(self.carries)))  # each batch's first step restarts its state
        action, self.carries[i] = self.agent.act(self.carries[i], obs, first, explore=False)
        self.calls += 1
        return to_env_units(action)


@dataclass
class LoadedDreamer:
    """A trained Dreamer agent ready to drive (as :class:`~.artifact.LoadedPolicy` for the protocol)."""

    agent: DreamerAgent
    spec: PolicySpec
    weights_path: Path
    spec_path: Path

    @property
    def config(self) -> RacingConfig:
        return self.spec.config

    def driver(self) -> DreamerDriver:
        identity = {**self.spec.driver_identity(self.weights_path), "algo": "dreamer"}
        return DreamerDriver(self.agent, self.config, self.spec.normalizer, identity)


__all__ = [
    "Actor",
    "DreamerAgent",
    "DreamerDriver",
    "DreamerRecipe",
    "LatentState",
    "LoadedDreamer",
    "SequenceBatch",
    "SequenceReplay",
    "WorldModel",
    "frozen",
    "lambda_returns",
    "to_env_units",
    "to_model_units",
]
