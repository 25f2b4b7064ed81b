"""Stable-Baselines3 ``VecEnv`` over the batched racing core (kept apart: importing SB3 imports torch)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from vision_rl.envs.core import RacingConfig, RacingCore
from vision_rl.envs.observer import Observer
from vision_rl.envs.racing_env import action_space


class RacingSB3VecEnv(VecEnv):
    """``config.n_groups`` egos as SB3 sub-environments: same-step reset, ``terminal_observation`` and
    ``TimeLimit.truncated`` in the infos, as SB3's own vectorised environments report them."""

    def __init__(self, config: RacingConfig, seed: int | None = None, observer: Observer | None = None) -> None:
        self.config = config
        self.core = RacingCore(config, seed=seed, observer=observer)
        self.render_mode = None
        super().__init__(config.n_groups, self.core.observer.space, action_space())
        self._actions: np.ndarray | None = None

    def reset(self):
        seed = self._seeds[0] if self._seeds and self._seeds[0] is not None else None
        if seed is not None:
            self.core.seed(seed)
        self._reset_seeds()
        self.core.reset_groups(np.arange(self.num_envs))
        return self.core.observation()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        # The labels are of the states the actions were chosen in: asked before the step.
        labels = self.core.ai_actions() if self.core.labeller is not None else None
        out = self._sb3_step(*self.core.step(self._actions, autoreset=True))
        if labels is not None:
            for info, label in zip(out[3], labels, strict=True):
                info["ai_action"] = label
        return out

    def guided_step(self):
        """:meth:`RacingCore.guided_step` (the built-in AI drives the egos) in the terms of :meth:`step_wait`:
        (obs, rewards, dones, infos, the actions that ask for what the AI did)."""
        *step, actions = self.core.guided_step(autoreset=True)
        return (*self._sb3_step(*step), actions)

    @staticmethod
    def _sb3_step(obs, reward, terminated, truncated, infos):
        """The core's step in SB3's terms: ``terminal_observation`` and ``TimeLimit.truncated`` in the infos."""
        out = []
        for g, info in enumerate(infos):
            if "final_info" in info:
                sb3_info = dict(info["final_info"])
                sb3_info["terminal_observation"] = info["final_observation"]
                sb3_info["TimeLimit.truncated"] = bool(truncated[g] and not terminated[g])
            else:
                sb3_info = info
            out.append(sb3_info)
        return obs, reward, terminated | truncated, out

    def close(self) -> None:
        self.core.observer.close()

    # The sub-environments are rows of one world, not separate objects: attribute access goes to the core.
    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        owner = self if attr_name == "render_mode" else self.core
        return [getattr(owner, attr_name)] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self.core, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        return [getattr(self.core, method_name)(*method_args, **method_kwargs)] * len(self._indices(indices))

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(self._indices(indices))

    def _indices(self, indices) -> Sequence[int]:
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else list(indices)
