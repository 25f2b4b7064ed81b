"""vision_rl: learning to race from pixels on an open simulator.

``import vision_rl`` registers the gymnasium ids ``vision_rl/TimeTrial-v1``, ``vision_rl/Overtaking-v1`` and
``vision_rl/PixelRacing-v0`` (pixels for the actor, motion and the racing line for the critic) by
string entry point, so ``gymnasium.make("vision_rl/TimeTrial-v1")`` works and the environments (with numba, and
moderngl for pixels) load only when one is made. This module imports nothing else: ``import vision_rl.sim`` stays
light.
"""

from gymnasium.envs.registration import register, registry

for _name in ("TimeTrial", "Overtaking"):
    if f"vision_rl/{_name}-v1" not in registry:
        register(id=f"vision_rl/{_name}-v1", entry_point=f"vision_rl.envs.racing_env:{_name}", max_episode_steps=None)
if "vision_rl/PixelRacing-v0" not in registry:
    register(
        id="vision_rl/PixelRacing-v0", entry_point="vision_rl.envs.pixel_racing:PixelRacing", max_episode_steps=None
    )
