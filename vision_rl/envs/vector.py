"""M groups in one world as a batched environment: a gymnasium ``VectorEnv`` and a Stable-Baselines3 ``VecEnv``.

Both reset a finished sub-environment inside the same ``step`` call (gymnasium's ``AutoresetMode.SAME_STEP``, the
semantics SB3 expects): the returned observation of that index is the first of its new episode, and the last
one of the old episode is in the info (``final_obs`` for gymnasium, ``terminal_observation`` for SB3).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from vision_rl.envs.core import RacingConfig, RacingCore
from vision_rl.envs.observer import Observer
from vision_rl.envs.racing_env import action_space, physical_actions


class RacingVectorEnv(VectorEnv):
    """``config.n_groups`` racing sub-environments stepped together in one World (see :class:`RacingCore`); with
    ``normalized_spaces`` the spaces of TimeTrial-v2 (actions in [-1, 1] mapped onto the physical ranges,
    observations bounded where known)."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(
        self,
        config: RacingConfig,
        seed: int | None = None,
        observer: Observer | None = None,
        *,
        normalized_spaces: bool = False,
    ) -> None:
        self.config = config
        self.core = RacingCore(config, seed=seed, observer=observer)
        self.num_envs = config.n_groups
        self.normalized_spaces = bool(normalized_spaces)
        self.single_action_space = action_space(self.normalized_spaces)
        observer = self.core.observer
        self.single_observation_space = observer.bounded_space() if self.normalized_spaces else observer.space
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._needs_reset = True

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.core.seed(seed)
        self.core.reset_groups(np.arange(self.num_envs))
        self._needs_reset = False
        return self.core.observation(), {}

    def step(self, actions):
        if self._needs_reset:
            raise gym.error.ResetNeeded("call reset() before step()")
        actions = physical_actions(actions, self.normalized_spaces)
        obs, reward, terminated, truncated, infos = self.core.step(actions, autoreset=True)
        done = terminated | truncated
        out: dict[str, Any] = {}
        if done.any():
            final_obs = np.empty(self.num_envs, dtype=object)
            final_info = np.empty(self.num_envs, dtype=object)
            for g in np.flatnonzero(done):
                final_obs[g] = infos[g]["final_observation"]
                final_info[g] = infos[g]["final_info"]
            out = {"final_obs": final_obs, "_final_obs": done, "final_info": final_info, "_final_info": done}
        return obs, reward, terminated, truncated, out

    def close_extras(self, **kwargs: Any) -> None:
        self.core.observer.close()


def make_vector_env(
    config: RacingConfig | None = None, seed: int | None = None, observer: Observer | None = None, **overrides: Any
) -> RacingVectorEnv:
    """A gymnasium vector env; by default 20 time-trial cars on the default track (as the papers sample)."""
    import dataclasses

    base = config or RacingConfig(n_groups=20)
    return RacingVectorEnv(dataclasses.replace(base, **overrides), seed=seed, observer=observer)


def make_sb3_vec_env(
    config: RacingConfig | None = None, seed: int | None = None, observer: Observer | None = None, **overrides: Any
):
    """The same batched world as a Stable-Baselines3 ``VecEnv`` (imports SB3, and so torch, on first use)."""
    import dataclasses

    from vision_rl.envs.sb3 import RacingSB3VecEnv

    base = config or RacingConfig(n_groups=20)
    return RacingSB3VecEnv(dataclasses.replace(base, **overrides), seed=seed, observer=observer)
