"""Gymnasium environments over the simulator: ``vision_rl/TimeTrial`` and ``vision_rl/Overtaking`` (v1, v2) and
``vision_rl/PixelRacing`` (v0, v1), registered by ``import vision_rl`` (entry points: :mod:`.registration`), and the
batched vector environments (gymnasium ``VectorEnv`` and Stable-Baselines3 ``VecEnv``) with M groups per world."""

from vision_rl.envs.core import SCENARIOS, RacingConfig, RacingCore
from vision_rl.envs.racing_env import Overtaking, TimeTrial
from vision_rl.envs.vector import RacingVectorEnv, make_sb3_vec_env, make_vector_env

__all__ = [
    "SCENARIOS",
    "Overtaking",
    "RacingConfig",
    "RacingCore",
    "RacingVectorEnv",
    "TimeTrial",
    "make_sb3_vec_env",
    "make_vector_env",
]
