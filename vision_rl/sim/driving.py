"""Reference laps: the racing line and physical-limit (QSS) lap time of a car on a track, cached on disk
(`vision-rl limit`). The built-in AI's laps are timed by the lap-time protocol (`vision_rl.evaluation`).

The cache key is the track's geometry hash, a hash of every field of the car preset and :data:`CACHE_VERSION`,
so a changed track or preset is recomputed and a corrupt cache file is rewritten.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from vision_rl.files import atomic_write
from vision_rl.sim.racing_line import CURVATURE_MODELS, RacingLine, optimise_racing_line
from vision_rl.sim.speed_profile import SpeedProfile, profile_for_line
from vision_rl.sim.track import Track
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import VehicleParams, get_preset

#: Bump when the racing line or the speed profile changes: older cache files are then ignored.
CACHE_VERSION = 4
#: Distance the racing line keeps from each wall beyond the car's half width, m: the AI's tracking error at skill
#: 1.0 (0.3-0.6 m near the walls, measured) plus the footprint's extra width when the car is at an angle to the
#: walls. At 0.4 m the gt3 and tt_cup touched walls on 9 of 24 track/car pairs (0.01-1.65 s in two laps).
LINE_SAFETY_MARGIN_M = 0.6
#: The exact minimum-curvature line replaces the iterative QP's (the first of racing_line.CURVATURE_MODELS) only when
#: its QSS lap is shorter by more than this share: closer laps are a tie for the QSS model (the AI's laps differ
#: from it by 1-3 %), and the iterative QP is the reference formulation (the racetrack-database's lines). Measured
#: gains of the exact line: 0.3-1.4 % on expressway and flowing, 0.04-0.27 % on Monza and Spa (where it is 1.0-1.05 m
#: from the database's line against 0.6-0.9 m), negative elsewhere.
EXACT_LINE_MIN_GAIN = 0.003


def cache_dir() -> Path:
    """Where lines, profiles and observation statistics are cached: $VISION_RL_CACHE or ~/.cache/vision_rl."""
    return Path(os.environ.get("VISION_RL_CACHE", Path.home() / ".cache" / "vision_rl"))


def car_hash(car: VehicleParams) -> str:
    """Hash of every field of a preset (nested tyre parameters included)."""
    return hashlib.sha256(json.dumps(dataclasses.asdict(car), sort_keys=True, default=str).encode()).hexdigest()[:16]


def line_and_profile(track: Track, car: VehicleParams) -> tuple[RacingLine, SpeedProfile]:
    """The car's minimum-curvature racing line on the track and its QSS limit speed profile, from the disk cache
    when there, computed and cached otherwise."""
    path = cache_dir() / "lines" / f"{track.geometry_hash}-{car_hash(car)}-v{CACHE_VERSION}.npz"
    try:
        with np.load(path) as data:
            arrays = dict(data)
        return RacingLine.from_arrays(arrays), SpeedProfile.from_arrays(arrays)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError):
        pass
    # Both curvature models: the iterative QP's line is the faster one on most real tracks, the exact
    # minimum-curvature line on long constant-radius arcs (docs/notes/sim.md, racing_line.py).
    margin_m = 0.5 * car.width_m + LINE_SAFETY_MARGIN_M
    line, profile = (None, None)
    for model in CURVATURE_MODELS:
        candidate = optimise_racing_line(track, margin_m=margin_m, curvature_model=model)
        candidate_profile = profile_for_line(car, candidate)
        if profile is None or candidate_profile.lap_time_s < (1.0 - EXACT_LINE_MIN_GAIN) * profile.lap_time_s:
            line, profile = candidate, candidate_profile
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {**line.to_arrays(), **profile.to_arrays()}
    atomic_write(path, lambda tmp: _write_npz(tmp, arrays))
    return line, profile


def _write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    # Through an open file: np.savez would add ".npz" to the staging file's name.
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


def compute_limit(track_spec: str, car_name: str) -> dict[str, Any]:
    """Physical-limit lap time (flying lap on the racing line at the QSS speed profile) and the line's length."""
    t0 = time.perf_counter()
    track, car = load_track(track_spec), get_preset(car_name)
    t1 = time.perf_counter()
    line, profile = line_and_profile(track, car)
    return {
        "track": track.name,
        "car": car.name,
        "lap_time_s": profile.lap_time_s,
        "line_length_m": line.length_m,
        "max_speed_kmh": profile.max_speed_mps * 3.6,
        # The line and profile (solved, or read from the cache); loading the track comes before, apart.
        "seconds": time.perf_counter() - t1,
        "track_load_s": t1 - t0,
    }
