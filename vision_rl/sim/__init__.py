"""The racing simulator: tracks, vehicle dynamics, a multi-car world with contact, sensors, built-in AI.

Depends on numpy, scipy and numba only; no other vision_rl package is imported here.
"""

from vision_rl.sim.sensors import (
    DEDICATED_NAMES,
    DEDICATED_UNITS,
    TARGET_NAMES,
    TARGET_UNITS,
    WallRayCaster,
    dedicated_features,
    environment_targets,
    lidar,
)
from vision_rl.sim.track import Projection, Track, TrackError
from vision_rl.sim.track_library import BUILTIN_TRACKS, DEFAULT_TRACK, load_track, track_summary
from vision_rl.sim.vehicle import DEFAULT_CAR, PRESETS, VehicleParams, VehicleState, get_preset
from vision_rl.sim.world import World, WorldConfig, WorldState, world_step

__all__ = [
    "BUILTIN_TRACKS",
    "DEDICATED_NAMES",
    "DEDICATED_UNITS",
    "DEFAULT_CAR",
    "DEFAULT_TRACK",
    "PRESETS",
    "TARGET_NAMES",
    "TARGET_UNITS",
    "Projection",
    "Track",
    "TrackError",
    "VehicleParams",
    "VehicleState",
    "WallRayCaster",
    "World",
    "WorldConfig",
    "WorldState",
    "dedicated_features",
    "environment_targets",
    "get_preset",
    "lidar",
    "load_track",
    "track_summary",
    "world_step",
]
