"""vision_rl: learning to race from pixels on an open simulator.

``import vision_rl`` registers the gymnasium ids ``vision_rl/TimeTrial-v1``/``-v2``, ``vision_rl/Overtaking-v1``/``-v2``
and ``vision_rl/PixelRacing-v0``/``-v1`` (pixels for the actor, motion and the racing line for the critic) by string
entry point, so ``gymnasium.make("vision_rl/TimeTrial-v2")`` and ``gymnasium.make_vec("vision_rl/TimeTrial-v2",
num_envs=8, vectorization_mode="vector_entry_point")`` work and the environments (with numba, and moderngl for
pixels) load only when one is made. The newer version of each takes actions in [-1, 1] and bounds its observations
where it can; the older keeps its physical action ranges. This module imports nothing else: ``import vision_rl.sim``
stays light.
"""

from gymnasium.envs.registration import register, registry

#: (name, entry point in vision_rl.envs.registration, older version, newer version with normalized spaces).
_ENVIRONMENTS = (
    ("TimeTrial", "time_trial", 1, 2),
    ("Overtaking", "overtaking", 1, 2),
    ("PixelRacing", "pixel_racing", 0, 1),
)
for _name, _entry, _old, _new in _ENVIRONMENTS:
    for _version, _kwargs in ((_old, {}), (_new, {"normalized_spaces": True})):
        if f"vision_rl/{_name}-v{_version}" not in registry:
            register(
                id=f"vision_rl/{_name}-v{_version}",
                entry_point=f"vision_rl.envs.registration:{_entry}",
                vector_entry_point=f"vision_rl.envs.registration:{_entry}_vector",
                kwargs=_kwargs,
            )


def __getattr__(name: str):
    """``vision_rl.evaluate``: the door for agents trained outside the project
    (:func:`vision_rl.training.outside.evaluate`), imported on first use, so that ``import vision_rl`` loads gymnasium
    alone (the one exception tests/test_layering.py allows this module)."""
    if name == "evaluate":
        from vision_rl.training.outside import evaluate

        globals()["evaluate"] = evaluate
        return evaluate
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
