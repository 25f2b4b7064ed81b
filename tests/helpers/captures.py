"""Small capture files written with CaptureWriter whose targets are a known function of the image.

Each frame is a grey background of brightness v with a black vertical bar at column fraction u; every target is
a fixed linear mix of u and v, so a network can learn all of them from the pixels.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vision_rl.capture.h5format import CaptureWriter

try:  # the sensors module owns the names; the tests only need 27 and 11 of them
    from vision_rl.sim.sensors import DEDICATED_NAMES, DEDICATED_UNITS, TARGET_NAMES, TARGET_UNITS
except ImportError:  # pragma: no cover - while sensors is being written
    TARGET_NAMES = tuple(f"target_{i}" for i in range(27))
    TARGET_UNITS = ("m",) * 27
    DEDICATED_NAMES = tuple(f"dedicated_{i}" for i in range(11))
    DEDICATED_UNITS = ("1",) * 11

ATTRS = {
    "track_name": "synthetic",
    "track_geometry_hash": "0123abcd",
    "car_preset": "hatchback",
    "renderer_settings": {"camera": "hood", "fov_deg": 70.0},
    "seed": 7,
}


def frames_and_targets(n: int, image_hw_px: tuple[int, int], seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(images uint8 (n, H, W, 3), targets float32 (n, 27), latent (n, 2) = u, v)."""
    rng = np.random.default_rng(seed)
    h, w = image_hw_px
    u = rng.uniform(0.15, 0.85, n)
    v = rng.uniform(0.3, 0.9, n)
    images = np.empty((n, h, w, 3), dtype=np.uint8)
    images[:] = (v * 255).astype(np.uint8)[:, None, None, None]
    cols = np.arange(w)[None, :]
    bar = np.abs(cols - (u * w)[:, None]) < max(2, w // 16)  # (n, w)
    images[np.broadcast_to(bar[:, None, :], (n, h, w))] = 0
    mix = np.random.default_rng(1234).normal(size=(2, 27))
    offset = np.linspace(-1.0, 1.0, 27)
    targets = (np.stack([u, v], axis=1) @ mix + offset).astype(np.float32)
    return images, targets, np.stack([u, v], axis=1)


def write_synthetic_capture(
    path: Path,
    *,
    n_laps: int = 4,
    frames_per_lap: int = 4,
    image_hw_px: tuple[int, int] = (64, 96),
    car_ids: tuple[int, ...] = (0,),
    seed: int = 0,
    complete: bool = True,
    batch: int = 4,
) -> dict[str, np.ndarray]:
    """Write a capture of len(car_ids) * n_laps * frames_per_lap frames; returns what was written."""
    n = len(car_ids) * n_laps * frames_per_lap
    images, targets, latent = frames_and_targets(n, image_hw_px, seed)
    car = np.repeat(np.asarray(car_ids, dtype=np.int32), n_laps * frames_per_lap)
    lap = np.tile(np.repeat(np.arange(n_laps, dtype=np.int32), frames_per_lap), len(car_ids))
    rng = np.random.default_rng(seed + 1)
    dedicated = rng.normal(size=(n, 11)).astype(np.float32)
    pose = rng.normal(size=(n, 3))
    time_s = np.arange(n) / 60.0
    writer = CaptureWriter(
        path,
        image_hw_px=image_hw_px,
        target_names=TARGET_NAMES,
        target_units=TARGET_UNITS,
        dedicated_names=DEDICATED_NAMES,
        dedicated_units=DEDICATED_UNITS,
        attrs=ATTRS,
    )
    for s in range(0, n, batch):
        sl = slice(s, s + batch)
        writer.append(images[sl], targets[sl], dedicated[sl], pose[sl], time_s[sl], lap[sl], car[sl])
    writer.close(complete=complete)
    return {
        "images": images,
        "targets": targets,
        "dedicated": dedicated,
        "pose": pose,
        "time": time_s,
        "lap": lap,
        "car_id": car,
        "latent": latent,
    }
