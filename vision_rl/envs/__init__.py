"""Gymnasium environments over the simulator: ``vision_rl/TimeTrial-v0`` and ``vision_rl/Overtaking-v0``, and the
batched vector environments (gymnasium ``VectorEnv`` and Stable-Baselines3 ``VecEnv``) with M groups per world."""

from gymnasium.envs.registration import register, registry

from vision_rl.envs.core import SCENARIOS, RacingConfig, RacingCore
from vision_rl.envs.racing_env import Overtaking, TimeTrial
from vision_rl.envs.vector import RacingVectorEnv, make_sb3_vec_env, make_vector_env

for _name, _cls in (("TimeTrial", TimeTrial), ("Overtaking", Overtaking)):
    _id = f"vision_rl/{_name}-v0"
    if _id not in registry:
        register(id=_id, entry_point=f"vision_rl.envs.racing_env:{_cls.__name__}", max_episode_steps=None)

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
