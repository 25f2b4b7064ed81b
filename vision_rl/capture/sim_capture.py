"""Simulator capture: game-screen frames paired with the 27 targets and 11 dedicated features, written to HDF5.

The simulator's AI cars (or a trained policy) drive and every car's driver's view is rendered at the capture rate,
in place of the vision paper's HDMI grabber (section 4.1); a stopped capture keeps its frames and resumes. The two
frame sources, how laps are counted and resumed: docs/notes/capture.md.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from vision_rl.budget import BUDGET_ENV, memory_budget
from vision_rl.capture.h5format import CaptureWriter
from vision_rl.sim import sensors
from vision_rl.sim.ai_driver import DEFAULT_SKILL, DisruptionParams
from vision_rl.sim.driving import line_and_profile
from vision_rl.sim.fleet import AI_CONTROL_DT_S, AIFleet, StuckDetector, place_on_line
from vision_rl.sim.track import Track
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import get_preset
from vision_rl.sim.world import World, WorldConfig


@dataclass(frozen=True)
class CaptureConfig:
    """A simulator capture: built-in AI cars driving and their driver's views, the 27 targets and the 11 dedicated
    features written to one HDF5 file."""

    out: str = ""
    """Output .h5 file (required)."""
    track: str = "expressway"
    """Track: built-in name, random:SEED or CSV path."""
    car: str = "hatchback"
    """Car preset."""
    laps: int = 50
    """Laps to record, summed over all cars."""
    disrupt_ai: bool = True
    """Uniform random disruptions of the AI (off: clean laps for evaluation)."""
    disrupt_steer_offset_rad: float = DisruptionParams.steer_offset_rad
    """Disrupted AI: its steering offsets are uniform in +-this, rad. At 0.3 the AI's frames on expressway hold the
    heading within 24 degrees of the track and touch the walls only side-on; at 0.6, 2 in 100 show the car at a wall
    at an angle and 1 in 6 a heading error of 11-69 degrees, as a policy's laps do after a wall hit (a car turned
    round is placed again)."""
    cars: int = 4
    """AI cars driving (and rendered) together."""
    fps: float = 60.0
    """Capture rate, frames per second per car (GT Sport: 60)."""
    image_hw_px: tuple[int, int] = (280, 470)
    """Frame height and width, px (the vision paper's network input is 470 wide, 280 high)."""
    seed: int = 0
    """Seed of the disruptions and start points."""
    resume: bool = False
    """Continue an incomplete file up to ``laps``."""
    force: bool = False
    """Overwrite an existing file."""
    compression: str = "zstd"
    """Image compression: zstd, gzip, lzf or none."""
    max_frames: int = 0
    """Stop after this many new frames (0: when ``laps`` are in)."""
    flush_interval_s: float = 2.0
    """Longest time between writes to disk, s: a kill loses at most the frames of this interval (0: every batch)."""

    def __post_init__(self) -> None:
        # Bounds of every number, checked when the configuration is made (the command line reports them as one
        # line), not when a run is minutes in or the operating system kills it for memory.
        h, w = self.image_hw_px
        checks = (
            (self.laps >= 1, f"--laps must be >= 1, got {self.laps}"),
            (self.cars >= 1, f"--cars must be >= 1, got {self.cars}"),
            (math.isfinite(self.fps) and self.fps > 0, f"--fps must be > 0, got {self.fps}"),
            (h > 0 and w > 0, f"--image-hw-px must be two positive sizes (height, width), got {h} {w}"),
            (
                math.isfinite(self.disrupt_steer_offset_rad) and self.disrupt_steer_offset_rad >= 0,
                f"--disrupt-steer-offset-rad must be >= 0, got {self.disrupt_steer_offset_rad}",
            ),
            (
                self.disrupt_ai or self.disrupt_steer_offset_rad == DisruptionParams.steer_offset_rad,
                f"--disrupt-steer-offset-rad {self.disrupt_steer_offset_rad:g} with --no-disrupt: clean laps have no "
                "offsets; drop one of the two",
            ),
            (self.max_frames >= 0, f"--max-frames must be >= 0 (0: no limit), got {self.max_frames}"),
            (self.flush_interval_s >= 0, f"--flush-interval-s must be >= 0, got {self.flush_interval_s}"),
        )
        for ok, message in checks:
            if not ok:
                raise ValueError(message)
        limit = max_cars_for_memory(self.image_hw_px)
        if self.cars > limit:
            need_gb = self.cars * BYTES_PER_CAR_PIXEL * h * w / 1e9
            raise ValueError(
                f"--cars {self.cars} needs about {need_gb:.1f} GB for {h}x{w} px frames, over the memory budget of "
                f"{memory_budget()[0] / 1e9:.1f} GB ({BUDGET_ENV}): at most {limit} cars at this size"
            )

    @property
    def height(self) -> int:
        """Frame height, px: ``image_hw_px[0]`` (:func:`capture_sim` reads it by this name)."""
        return self.image_hw_px[0]

    @property
    def width(self) -> int:
        """Frame width, px: ``image_hw_px[1]``."""
        return self.image_hw_px[1]


#: Memory of one car's view per frame pixel during a capture, bytes: the renderer's colour and depth tiles (4 + 4,
#: and again for the label pass), the read-back (3), the writer's copy and up to two batches waiting for
#: compression (3 x 3); rounded up to leave room for the simulation and the compressed chunks.
BYTES_PER_CAR_PIXEL = 32


def max_cars_for_memory(image_hw_px: tuple[int, int]) -> int:
    """The most cars whose frames of ``image_hw_px`` (height, width) fit in the memory budget (>= 1)."""
    per_car = BYTES_PER_CAR_PIXEL * max(1, int(image_hw_px[0])) * max(1, int(image_hw_px[1]))
    return max(1, int(memory_budget()[0] // per_car))


def physics_step_for(fps: float) -> tuple[float, float, int]:
    """(physics_dt_s, control_dt_s, control_steps_per_frame) for a capture rate.

    The AI steers at least every ``AI_CONTROL_DT_S`` whatever the frame rate (it is tuned at 50 Hz: steering every
    0.1 s for a 10 fps capture, the undisturbed AI spun off now and then); physics steps are <= 10 ms."""
    if not 1.0 <= fps <= 200.0:
        raise ValueError(f"fps must be within 1..200, got {fps}")
    frame_dt = 1.0 / fps
    steps_per_frame = math.ceil(frame_dt / AI_CONTROL_DT_S - 1e-9)
    control_dt = frame_dt / steps_per_frame
    return control_dt / math.ceil(control_dt / 0.01 - 1e-9), control_dt, steps_per_frame


def capture_attrs(
    track: Track, cfg: CaptureConfig, renderer_settings: dict, source: str, driver: dict | None = None
) -> dict:
    """The file's attributes; ``driver``: who drove when not the built-in AI (a policy's identity)."""
    disrupted_sim = cfg.disrupt_ai and source == "sim"
    return {
        "track_name": track.name,
        "track_geometry_hash": track.geometry_hash,
        "car_preset": cfg.car,
        "renderer_settings": renderer_settings,
        "seed": cfg.seed,
        "source": source,
        "fps": float(cfg.fps),
        "disrupted": bool(cfg.disrupt_ai),
        **({"disrupt_steer_offset_rad": float(cfg.disrupt_steer_offset_rad)} if disrupted_sim else {}),
        "requested_laps": cfg.laps,
        **({"cars": int(cfg.cars)} if source == "sim" else {}),
        **({"driver": driver} if driver is not None else {}),
    }


def open_writer(
    path: Path, track: Track, cfg: CaptureConfig, renderer_settings: dict, source: str, driver: dict | None = None
) -> CaptureWriter:
    return CaptureWriter(
        path,
        image_hw_px=cfg.image_hw_px,
        target_names=sensors.TARGET_NAMES,
        target_units=sensors.TARGET_UNITS,
        dedicated_names=sensors.DEDICATED_NAMES,
        dedicated_units=sensors.DEDICATED_UNITS,
        attrs=capture_attrs(track, cfg, renderer_settings, source, driver),
        resume=cfg.resume,
        force=cfg.force,
        compression=cfg.compression,
        flush_interval_s=cfg.flush_interval_s,
    )


def _done_so_far(writer: CaptureWriter) -> tuple[int, np.ndarray, float]:
    """Frames, laps started per car (next lap index) and last time of the file a writer reopened (its rows as
    checked when it opened, so the writer keeps its lock on the file throughout)."""
    car_id, lap, time_s = (writer.resumed_rows(name) for name in ("car_id", "lap", "time"))
    if len(car_id) == 0:
        return 0, np.zeros(0, dtype=np.int64), 0.0
    next_lap = np.zeros(int(car_id.max()) + 1, dtype=np.int64)
    np.maximum.at(next_lap, car_id, lap.astype(np.int64) + 1)
    return len(car_id), next_lap, float(time_s.max())


#: A disrupted car turned further than this from the track's direction is re-placed as a stuck car is, rad: the
#: heading target wraps at +-pi, and the few frames of cars facing backwards (3 in 100 with steering offsets of 0.6
#: rad) widened its spread from 0.21 to 0.50 rad, which the encoder's loss, scaled by each target's spread, then
#: weighs about 6 times less on every frame.
MAX_DISRUPTED_HEADING_ERROR_RAD = math.pi / 2


def turned_round(track: Track, state) -> np.ndarray:
    """Indices of the cars of ``state`` (a world state) turned more than :data:`MAX_DISRUPTED_HEADING_ERROR_RAD` from
    the track's direction at their place."""
    error = sensors.wrap_angle(state.vehicle.yaw_rad - track.heading_at(state.s_m))
    return np.flatnonzero(np.abs(error) > MAX_DISRUPTED_HEADING_ERROR_RAD)


def driver_steps_per_frame(fps: float, control_dt_s: float) -> int:
    """Control steps of a driver acting every ``control_dt_s`` between two frames at ``fps``."""
    steps = round(1.0 / (fps * control_dt_s))
    if steps < 1 or abs(steps * control_dt_s * fps - 1.0) > 1e-9:
        raise ValueError(
            f"--fps {fps:g}: the driver acts every {control_dt_s:g} s, so frames must come a whole number of its "
            f"steps apart ({1.0 / control_dt_s:g} fps or a whole fraction of it)"
        )
    return steps


def _world_timing(cfg: CaptureConfig, driver) -> tuple[WorldConfig, float, int]:
    """(world configuration, control step in s, control steps per frame) of a capture driven by the AI or by
    ``driver``."""
    if driver is None:
        physics_dt, control_dt, steps_per_frame = physics_step_for(cfg.fps)
        return WorldConfig(physics_dt_s=physics_dt, control_dt_s=control_dt), control_dt, steps_per_frame
    if cfg.disrupt_ai:
        raise ValueError("a capture driven by a policy is not disrupted: give --no-disrupt")
    control_dt, steps_per_frame = driver.control_dt_s, driver_steps_per_frame(cfg.fps, driver.control_dt_s)
    return (
        WorldConfig(control_dt_s=control_dt),
        control_dt,
        steps_per_frame,
    )  # as in the policy's training and the protocol


def _open_or_resume(
    path: Path, track: Track, cfg: CaptureConfig, renderer_settings: dict, identity: dict | None, frame_dt_s: float
) -> tuple[CaptureWriter, int, np.ndarray, float]:
    """The writer, the frames already in the file, each car's next lap index and the time of the next frame, s."""
    writer = open_writer(path, track, cfg, renderer_settings, "sim", identity)
    if not (cfg.resume and writer.n_frames):
        return writer, 0, np.zeros(0, dtype=np.int64), 0.0
    frames_before, lap_offset, t_before = _done_so_far(writer)
    # The first new frame comes one frame after the last kept one.
    return writer, frames_before, lap_offset, t_before + frame_dt_s


def _start_driving(
    world: World, cfg: CaptureConfig, driver, rng: np.random.Generator
) -> tuple[Callable[..., None], Callable[[int], None]]:
    """Place the cars spread over the lap; returns ``place(ids, s_m, speed_share=1.0)``, which puts cars on the AI's
    racing line, and ``advance(steps)``, which drives every car that many control steps (the AI, or ``driver``)."""
    track, n = world.track, world.n_cars
    line, profile = line_and_profile(track, world.car)
    disruption = DisruptionParams(steer_offset_rad=cfg.disrupt_steer_offset_rad) if cfg.disrupt_ai else None
    skill = disruption.skill if disruption is not None else DEFAULT_SKILL
    fleet_seed = int(rng.integers(2**31))  # drawn with a driver too, so the start points do not depend on who drives
    if driver is None:
        fleet = AIFleet(world, line, profile, skill=skill, disruption=disruption, seed=fleet_seed)
        place, advance = fleet.place, fleet.advance
    else:  # the AI only places the cars on its line, at its speed

        def place(ids: np.ndarray, s_m: np.ndarray, speed_share: float = 1.0) -> None:
            place_on_line(world, line, profile, ids, s_m, speed_share * skill)

        def advance(steps: int) -> None:
            for _ in range(steps):
                action = np.asarray(driver.act(world.state), dtype=np.float64).reshape(n, 2)
                world.step(action[:, 0], action[:, 1])

    s0 = np.mod(rng.uniform(0, track.length_m) + np.arange(n) * track.length_m / n, track.length_m)
    place(np.arange(n), s0)
    if driver is not None:
        driver.reset(world, np.arange(n))
    return place, advance


class _Placements:
    """Each car's lap bookkeeping across its placements: the lap index of its frames (never reused: a lap cut by an
    interruption or a stuck-reset is not continued), the whole laps recorded and where its placement began; and the
    re-placing of stuck cars."""

    def __init__(self, world: World, place, driver, lap_offset: np.ndarray, frame_dt_s: float, disrupted: bool):
        n = world.n_cars
        self.world, self.place, self.driver, self.disrupted = world, place, driver, disrupted
        self.lap_index_base = np.pad(lap_offset, (0, max(0, n - len(lap_offset))))[:n]
        self.lap_count_base = np.maximum(self.lap_index_base - 1, 0)
        self.start_u = world.state.unwrapped_s_m.copy()
        # The disrupted AI may end up facing a wall: the project's stuck rule, checked every frame.
        self.stuck_detector = StuckDetector(world.state.unwrapped_s_m, frame_dt_s)
        self.resets = self.turned_resets = 0

    def completed(self) -> np.ndarray:
        """Whole laps each car has driven since its placement."""
        return np.floor((self.world.state.unwrapped_s_m - self.start_u) / self.world.track.length_m).astype(np.int64)

    def replace_stuck(self) -> None:
        """Capture wants frames, not a race: a stuck (or, disrupted, turned) car goes back on the racing line a little
        ahead, at half the AI's speed, and starts a new lap index: a lap never mixes two placements."""
        world, state = self.world, self.world.state
        stuck = self.stuck_detector.update(state.unwrapped_s_m)
        self.resets += len(stuck)
        if self.disrupted:
            turned = np.setdiff1d(turned_round(world.track, state), stuck)
            self.turned_resets += len(turned)
            stuck = np.union1d(stuck, turned)
        if not len(stuck):
            return
        done_now = np.floor((state.unwrapped_s_m[stuck] - self.start_u[stuck]) / world.track.length_m)
        self.lap_count_base[stuck] += done_now.astype(np.int64)
        self.lap_index_base[stuck] += done_now.astype(np.int64) + 1
        self.place(stuck, state.s_m[stuck] + 5.0, speed_share=0.5)
        self.start_u[stuck] = world.state.unwrapped_s_m[stuck]
        self.stuck_detector.reset(stuck, world.state.unwrapped_s_m)
        if self.driver is not None:  # its steering memory and frame history start again from the new poses
            self.driver.reset(world, np.arange(world.n_cars))


def _write_frame(
    writer: CaptureWriter, renderer, world: World, caster: sensors.WallRayCaster, time_s: float, lap: np.ndarray
) -> None:
    """Every car's driver's view with the targets, the dedicated features and the pose at this instant."""
    st = world.state
    v = st.vehicle
    n = world.n_cars
    images = renderer.render(v.x_m, v.y_m, v.yaw_rad, groups=world.model.groups)
    targets = sensors.environment_targets(world.track, caster, v.x_m, v.y_m, v.yaw_rad, st.s_m, st.lateral_m)
    dedicated = sensors.dedicated_features(v, st.wall_contact, st.prev_steer_cmd_rad)
    writer.append(
        images=images,
        targets=targets.astype(np.float32),
        dedicated=dedicated.astype(np.float32),
        pose=np.stack([v.x_m, v.y_m, v.yaw_rad], axis=1),
        time_s=np.full(n, time_s),
        lap=lap.astype(np.int32),
        car_id=np.arange(n, dtype=np.int32),
    )


def capture_sim(cfg: CaptureConfig, progress: Callable[[int, int], None] | None = None, driver=None) -> dict:
    """Drive, render and record until ``cfg.laps`` laps (over all cars) are in the file; returns a summary.

    ``progress(laps_done, frames)`` is called after every written batch (the command's progress bar). ``driver``
    (``control_dt_s``, ``reset(world, car_ids)``, ``act(state)`` and ``identity``, as the lap-time protocol's
    drivers): drives every car instead of the AI, which then only places the cars (at the start and after a stuck
    car); ``cfg.disrupt_ai`` must be off.
    """
    from vision_rl.render import RenderConfig, Renderer

    path = Path(cfg.out)
    track = load_track(cfg.track)
    car = get_preset(cfg.car)
    world_config, control_dt, steps_per_frame = _world_timing(cfg, driver)
    identity = None if driver is None else dict(driver.identity)
    n = cfg.cars
    render_cfg = RenderConfig(width_px=cfg.width, height_px=cfg.height, max_views=n)
    renderer_settings = {**asdict(render_cfg), "camera": asdict(render_cfg.camera)}
    writer, frames_before, lap_offset, t_before = _open_or_resume(
        path, track, cfg, renderer_settings, identity, steps_per_frame * control_dt
    )
    # A resumed run restarts the world from a state derived from the seed and the frames already kept.
    rng = np.random.default_rng([cfg.seed, frames_before])
    world = World(track, car, n_cars=n, config=world_config)
    place, advance = _start_driving(world, cfg, driver, rng)
    run = _Placements(world, place, driver, lap_offset, steps_per_frame * control_dt, cfg.disrupt_ai)
    laps_before = int(run.lap_count_base.sum())
    caster = sensors.WallRayCaster(track)
    frames = 0
    laps_done = laps_before
    t0 = time.perf_counter()
    interrupted = False
    try:
        with Renderer(track, render_cfg, car_length_m=car.length_m, car_width_m=car.width_m) as renderer:
            frame_step = 0
            while True:
                completed = run.completed()
                laps_done = int((run.lap_count_base + completed).sum())
                if laps_done >= cfg.laps or 0 < cfg.max_frames <= frames:
                    break
                frame_time_s = t_before + frame_step * steps_per_frame * control_dt
                _write_frame(writer, renderer, world, caster, frame_time_s, run.lap_index_base + completed)
                frames += n
                if progress is not None:
                    progress(laps_done - laps_before, frames)
                frame_step += 1
                advance(steps_per_frame)
                run.replace_stuck()
    except KeyboardInterrupt:
        interrupted = True
    finally:
        complete = not interrupted and laps_done >= cfg.laps
        writer.close(complete=complete)
    elapsed = time.perf_counter() - t0
    return {
        "out": str(path),
        "frames_written": frames,
        "frames_in_file": frames_before + frames,
        "laps_in_file": laps_done,
        "complete": complete,
        "interrupted": interrupted,
        "stuck_resets": run.resets,
        "turned_resets": run.turned_resets,
        "capture_fps": frames / elapsed if elapsed > 0 else 0.0,
        "bytes_per_frame": path.stat().st_size / max(frames_before + frames, 1),
        "elapsed_s": elapsed,
    }
