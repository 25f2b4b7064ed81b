"""How well a Phase 1 encoder sees the states a driver visits: the encoder's error on the 27 targets along a lap.

Phase 1 trains the encoder on frames of the built-in AI (disrupted); Phase 2's policy then drives where the AI does
not (faster, closer to the walls, into them), and its observation is only as good as the encoder is there. For a
lap recorded by :func:`~vision_rl.evaluation.protocol.time_laps` (``record=True``), every protocol step's pose is
rendered as the driver's view, the true targets are computed from the pose as a capture computes them, and the
mean absolute error of the encoder's prediction is reported per target group, over the whole lap, over the frames
within :data:`NEAR_WALL_M` of a wall and over the steps in wall contact. The same figures for the built-in AI's lap
say how far the driver's states lie outside what the encoder learned from.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vision_rl.evaluation.outputs import driver_views
from vision_rl.evaluation.protocol import LapTiming
from vision_rl.sim import sensors

#: Target groups (column slices of ``sensors.TARGET_NAMES``) and their unit.
TARGET_GROUPS: dict[str, tuple[slice, str]] = {
    "edge_rays": (slice(0, 13), "m"),
    "min_edge_distance": (slice(13, 15), "m"),
    "centre_offset": (slice(15, 16), "m"),
    "heading": (slice(16, 17), "rad"),
    "curvature_ahead": (slice(17, 27), "1/m"),
}
#: A frame is near a wall when the car's centre is closer than this to one, m (the side of a car 1.7-1.8 m wide then
#: within about 0.6 m).
NEAR_WALL_M = 1.5
#: Frames rendered and predicted at once.
BATCH_FRAMES = 32


def lap_frames_and_targets(
    timing: LapTiming, run: int, image_hw_px: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Driver's-view frames (T, H, W, 3) uint8, true targets (T, 27) and wall contact (T,) of seed ``run``'s
    scored lap (its whole run when it scored none), one per recorded protocol step."""
    if timing.x_m.size == 0:
        raise ValueError("the timing holds no poses: run the protocol with record=True")
    start_s, end_s = timing.scored_window_s(run)
    steps = np.flatnonzero((timing.time_s > start_s) & (timing.time_s <= end_s))
    x, y, yaw = timing.x_m[steps, run], timing.y_m[steps, run], timing.yaw_rad[steps, run]
    track = timing.track
    proj = track.project(np.stack([x, y], axis=1))
    targets = sensors.environment_targets(track, sensors.WallRayCaster(track), x, y, yaw, proj.s_m, proj.lateral_m)
    frames = np.empty((len(steps), *image_hw_px, 3), dtype=np.uint8)
    for first, views in driver_views(timing, run, steps, image_hw_px, BATCH_FRAMES):
        frames[first : first + len(views)] = views
    return frames, targets, timing.wall_contact[steps, run]


def encoder_error(predicted: np.ndarray, true: np.ndarray, wall_contact: np.ndarray) -> dict[str, Any]:
    """Mean absolute error per target group of ``predicted`` against ``true`` targets (n, 27): over all frames,
    near a wall and in wall contact (None where no frame is)."""
    error = np.abs(np.asarray(predicted, dtype=np.float64) - np.asarray(true, dtype=np.float64))
    nearer_edge_m = true[:, TARGET_GROUPS["min_edge_distance"][0]].min(axis=1)
    out: dict[str, Any] = {"units": {name: unit for name, (_, unit) in TARGET_GROUPS.items()}}
    for subset, mask in (
        ("all", np.ones(len(error), dtype=bool)),
        ("near_wall", nearer_edge_m < NEAR_WALL_M),
        ("wall_contact", np.asarray(wall_contact, dtype=bool)),
    ):
        rows = error[mask]
        out[subset] = {
            "frames": int(mask.sum()),
            **{name: float(rows[:, cols].mean()) if len(rows) else None for name, (cols, _) in TARGET_GROUPS.items()},
        }
    return out


def encoder_error_on_lap(timing: LapTiming, run: int, encoder, image_hw_px: tuple[int, int]) -> dict[str, Any]:
    """:func:`encoder_error` of ``encoder`` (a frozen encoder with ``predict_targets``) on seed ``run``'s scored lap
    of ``timing``, rendered at ``image_hw_px`` (the encoder's input size)."""
    frames, true, wall_contact = lap_frames_and_targets(timing, run, image_hw_px)
    predicted = (
        np.concatenate(
            [
                np.asarray(encoder.predict_targets(frames[k : k + BATCH_FRAMES]), dtype=np.float64)
                for k in range(0, len(frames), BATCH_FRAMES)
            ]
        )
        if len(frames)
        else np.zeros((0, true.shape[1]))
    )
    return encoder_error(predicted, true, wall_contact)
