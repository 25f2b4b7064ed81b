"""The entry points ``import vision_rl`` registers (by name, so that import stays light).

Each single-environment entry point wraps the environment in gymnasium's ``TimeLimit`` of its own episode length,
``episode_s / control_dt_s`` of the arguments ``gymnasium.make`` passes, so the made environment's
``spec.max_episode_steps`` says where its episodes are cut (1,000 steps for TimeTrial and Overtaking by default,
3,000 for PixelRacing); the environment cuts them there itself too, so the wrapper changes no episode. The
registered specs leave ``max_episode_steps`` unset: ``gymnasium.make`` would wrap a fixed number around every
environment, whatever ``episode_s`` it is given.

The vector entry points (``gymnasium.make_vec(id, num_envs, vectorization_mode="vector_entry_point")``) give the
native batched environments, ``num_envs`` cars in one world stepped together.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
from gymnasium.wrappers import TimeLimit

from vision_rl.envs.core import RacingConfig
from vision_rl.envs.pixel_racing import PixelRacing, PixelRacingConfig, PixelRacingVectorEnv
from vision_rl.envs.racing_env import Overtaking, TimeTrial, racing_config
from vision_rl.envs.vector import RacingVectorEnv


def _limited(env: TimeTrial | Overtaking | PixelRacing) -> gym.Env:
    return TimeLimit(env, env.config.max_episode_steps)


def time_trial(**kwargs: Any) -> gym.Env:
    """``vision_rl/TimeTrial-v1``/``-v2``: :class:`TimeTrial` in a ``TimeLimit`` of its episode length."""
    return _limited(TimeTrial(**kwargs))


def overtaking(**kwargs: Any) -> gym.Env:
    """``vision_rl/Overtaking-v1``/``-v2``: :class:`Overtaking` in a ``TimeLimit`` of its episode length."""
    return _limited(Overtaking(**kwargs))


def pixel_racing(**kwargs: Any) -> gym.Env:
    """``vision_rl/PixelRacing-v0``/``-v1``: :class:`PixelRacing` in a ``TimeLimit`` of its episode length."""
    return _limited(PixelRacing(**kwargs))


def _cut(config_class: type, config: dict[str, Any], max_episode_steps: int | None) -> dict[str, Any]:
    """The arguments ``config`` with the episode cut after ``max_episode_steps`` control steps where that is sooner
    than ``episode_s`` (as a ``TimeLimit`` of that length around the single environment would cut it)."""
    if max_episode_steps is None:
        return config
    if max_episode_steps < 1:
        raise ValueError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
    control_dt_s = config.get("control_dt_s", config_class.control_dt_s)
    if max_episode_steps >= round(config.get("episode_s", config_class.episode_s) / control_dt_s):
        return config
    return {**config, "episode_s": max_episode_steps * control_dt_s}


def time_trial_vector(
    num_envs: int, max_episode_steps: int | None = None, normalized_spaces: bool = False, **config: Any
) -> RacingVectorEnv:
    """``num_envs`` time-trial cars in one world (:class:`RacingVectorEnv`), with TimeTrial's defaults."""
    racing = racing_config(TimeTrial._defaults, _cut(RacingConfig, config, max_episode_steps), n_groups=num_envs)
    return RacingVectorEnv(racing, normalized_spaces=normalized_spaces)


def overtaking_vector(
    num_envs: int, max_episode_steps: int | None = None, normalized_spaces: bool = False, **config: Any
) -> RacingVectorEnv:
    """``num_envs`` overtaking groups in one world (:class:`RacingVectorEnv`), with Overtaking's defaults."""
    racing = racing_config(Overtaking._defaults, _cut(RacingConfig, config, max_episode_steps), n_groups=num_envs)
    return RacingVectorEnv(racing, normalized_spaces=normalized_spaces)


def pixel_racing_vector(
    num_envs: int, max_episode_steps: int | None = None, normalized_spaces: bool = False, **config: Any
) -> PixelRacingVectorEnv:
    """``num_envs`` PixelRacing cars in one world (:class:`PixelRacingVectorEnv`)."""
    config = _cut(PixelRacingConfig, config, max_episode_steps)
    return PixelRacingVectorEnv(num_envs, normalized_spaces=normalized_spaces, **config)
