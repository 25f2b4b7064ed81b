"""Reference laps: the racing line and physical-limit (QSS) lap time of a car on a track, cached on disk, and
the built-in AI driving it (`vision-rl limit`, `vision-rl drive`).

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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vision_rl.config import doc
from vision_rl.sim.ai_driver import DEFAULT_SKILL, AIDriver, DisruptionParams, Disruptor, StuckDetector
from vision_rl.sim.racing_line import CURVATURE_MODELS, RacingLine, optimise_racing_line
from vision_rl.sim.speed_profile import SpeedProfile, profile_for_line
from vision_rl.sim.track import Track
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import VehicleParams, get_preset
from vision_rl.sim.world import World, WorldConfig

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
#: Control step of the built-in AI: its steering feedforward leads by the 0.05 s actuator lag plus half a step.
AI_CONTROL_DT_S = 0.02


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
    # minimum-curvature line on long constant-radius arcs (racing_line's docstring).
    margin_m = 0.5 * car.width_m + LINE_SAFETY_MARGIN_M
    line, profile = (None, None)
    for model in CURVATURE_MODELS:
        candidate = optimise_racing_line(track, margin_m=margin_m, curvature_model=model)
        candidate_profile = profile_for_line(car, candidate)
        if profile is None or candidate_profile.lap_time_s < (1.0 - EXACT_LINE_MIN_GAIN) * profile.lap_time_s:
            line, profile = candidate, candidate_profile
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
    np.savez(tmp, **line.to_arrays(), **profile.to_arrays())
    tmp.replace(path)
    return line, profile


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


def drive_ai(
    track_spec: str,
    car_name: str,
    skill: float = DEFAULT_SKILL,
    laps: int = 1,
    disrupt: bool = False,
    seed: int = 0,
    n_cars: int = 1,
    record_path: bool = False,
) -> dict[str, Any]:
    """Built-in AI cars on flying laps: each starts 100 m before the line at its target speed (spread along the
    track when several) and drives until it has timed ``laps`` laps or runs out of time (3 limit laps per lap)."""
    track, car = load_track(track_spec), get_preset(car_name)
    line, profile = line_and_profile(track, car)
    world = World(track, car, n_cars=n_cars, config=WorldConfig(physics_dt_s=0.01, control_dt_s=AI_CONTROL_DT_S))
    disruption = DisruptionParams()
    skill = disruption.skill if disrupt and skill == DEFAULT_SKILL else skill
    ai = AIDriver(car, line, profile, n_cars, skill=skill, groups=world.model.groups)
    disruptor = Disruptor(n_cars, disruption, seed=seed) if disrupt else None
    s0 = np.mod(-100.0 - np.arange(n_cars) * track.length_m / n_cars, track.length_m)

    def place(ids: np.ndarray, s: np.ndarray, share: float) -> None:
        speed = share * skill * profile.speed_at(line.line_s_at(s))
        world.reset(s_m=s, lateral_m=line.lateral_at(s), speed_mps=speed, car_ids=ids)

    place(np.arange(n_cars), s0, 1.0)
    dt = AI_CONTROL_DT_S
    max_steps = int((laps + 1) * 3.0 * profile.lap_time_s / dt)
    stuck_detector = StuckDetector(
        world.state.unwrapped_s_m, round(disruption.stuck_after_s / dt), disruption.stuck_progress_m
    )
    speeds, path, stuck_resets = [], [], 0
    for _ in range(max_steps):
        steer, omega = ai.act(world.state)
        if disruptor is not None:
            steer, omega = disruptor(steer, omega, dt)
        world.step(steer, omega)
        st = world.state
        v = np.hypot(st.vehicle.vx_mps, st.vehicle.vy_mps)
        speeds.append(v.max())
        if record_path:
            heading_error = np.angle(np.exp(1j * (st.vehicle.yaw_rad - track.heading_at(st.s_m))))
            path.append(np.stack([st.vehicle.x_m, st.vehicle.y_m, v, st.lateral_m, heading_error], axis=1))
        # A car that has not moved stuck_progress_m in stuck_after_s is put back on the line, slowly.
        stuck = stuck_detector.update(st.unwrapped_s_m)
        if len(stuck):
            stuck_resets += len(stuck)
            laps_kept = [list(world.lap_times_s[i]) for i in stuck]
            place(stuck, st.s_m[stuck] + 5.0, 0.5)
            for i, kept in zip(stuck, laps_kept, strict=True):
                world.lap_times_s[i] = kept
            stuck_detector.reset(stuck, world.state.unwrapped_s_m)
        if all(len(t) >= laps for t in world.lap_times_s):
            break
    result: dict[str, Any] = {
        "track": track.name,
        "car": car.name,
        "skill": float(skill),
        "lap_times_s": [t for times in world.lap_times_s for t in times[:laps]],
        "completed_laps": int(sum(min(len(t), laps) for t in world.lap_times_s)),
        "wall_contact_s": float(world.state.wall_contact_time_s.sum()),
        "max_speed_kmh": float(max(speeds) * 3.6) if speeds else 0.0,
        "stuck_resets": stuck_resets,
        "limit_lap_time_s": profile.lap_time_s,
    }
    if record_path:
        result["path"] = np.stack(path)  # (steps, cars, 5): x, y, speed, lateral, heading error
        result["line"] = line
    return result


def plot_drive(track: Track, line: RacingLine, path: np.ndarray, out: str | os.PathLike[str], title: str) -> Path:
    """Walls, racing line and the driven path coloured by speed (km/h), as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    fig, ax = plt.subplots(figsize=(9, 7))
    for wall in (track.left_wall_xy_m, track.right_wall_xy_m):
        closed = np.vstack([wall, wall[:1]])
        ax.plot(closed[:, 0], closed[:, 1], color="0.25", lw=0.8)
    ax.plot(line.xy_m[:, 0], line.xy_m[:, 1], color="tab:blue", lw=0.6, ls="--", label="racing line")
    collection = None
    for car in range(path.shape[1]):
        xy = path[:, car, :2]
        segments = np.stack([xy[:-1], xy[1:]], axis=1)
        collection = LineCollection(segments, cmap="plasma", linewidths=1.6)
        collection.set_array(path[1:, car, 2] * 3.6)
        ax.add_collection(collection)
    if collection is not None:
        fig.colorbar(collection, ax=ax, label="speed (km/h)")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title)
    ax.legend(loc="upper right")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return out


# ------------------------------------------------------------------------------------------------------- commands
@dataclass
class LimitConfig:
    """Physical-limit lap time of a car on a track: the QSS speed profile on the minimum-curvature line."""

    track: str = field(default="expressway", metadata=doc("track: built-in name, random:SEED or CSV path"))
    car: str = field(default="hatchback", metadata=doc("car preset"))
    json: bool = field(default=False, metadata=doc("print figures as JSON"))


def run_limit(cfg: LimitConfig) -> int:
    from vision_rl.cli import emit

    emit(compute_limit(cfg.track, cfg.car), cfg.json)
    return 0


@dataclass
class DriveConfig:
    """Drive the built-in AI and report lap times, wall contact and top speed (optionally a plot)."""

    track: str = field(default="expressway", metadata=doc("track: built-in name, random:SEED or CSV path"))
    car: str = field(default="hatchback", metadata=doc("car preset"))
    driver: str = field(default="ai", metadata=doc("who drives: 'ai' (the built-in AI)"))
    skill: float = field(default=DEFAULT_SKILL, metadata=doc("share of the limit speed profile the AI aims for"))
    laps: int = field(default=1, metadata=doc("timed laps per car (flying laps)"))
    disrupt: bool = field(default=False, metadata=doc("add the data-collection disruptions"))
    cars: int = field(default=1, metadata=doc("AI cars on track (ghosts to each other)"))
    seed: int = field(default=0, metadata=doc("seed of the disruptions"))
    plot: str = field(default="", metadata=doc("write a PNG of the walls, line and driven path"))
    json: bool = field(default=False, metadata=doc("print figures as JSON"))


def run_drive(cfg: DriveConfig) -> int:
    from vision_rl.cli import emit

    if cfg.driver != "ai":
        raise ValueError(f"--driver {cfg.driver!r}: only 'ai' is built; policies are driven by `evaluate`")
    if not 0.0 < cfg.skill <= 1.0:
        raise ValueError(f"--skill must be in (0, 1], got {cfg.skill}")
    result = drive_ai(cfg.track, cfg.car, cfg.skill, cfg.laps, cfg.disrupt, cfg.seed, cfg.cars, bool(cfg.plot))
    if cfg.plot:
        track = load_track(cfg.track)
        title = f"{track.name}, {cfg.car}, AI skill {result['skill']:.2f}"
        result["plot"] = str(plot_drive(track, result.pop("line"), result.pop("path"), cfg.plot, title))
    emit(result, cfg.json)
    return 0


def simulator_demo(track_spec: str, car_name: str) -> dict[str, Any]:
    """The built-in AI's lap beside the physical limit: what `pipeline` showed before the learning stages."""
    limit = compute_limit(track_spec, car_name)
    ai = drive_ai(track_spec, car_name, laps=1)
    lap = ai["lap_times_s"][0] if ai["lap_times_s"] else None
    return {
        "track": limit["track"],
        "car": limit["car"],
        "limit_lap_time_s": limit["lap_time_s"],
        "ai_lap_time_s": lap,
        "ai_gap_to_limit_pct": None if lap is None else 100.0 * (lap / limit["lap_time_s"] - 1.0),
        "ai_wall_contact_s": ai["wall_contact_s"],
    }
