"""The one lap-time protocol. Every lap time in the project comes from :func:`time_laps`, whoever drives.

A rolling start per seed, ``laps`` laps of which the last is scored, every car alone, a stuck rule and a time limit
(:data:`PROTOCOL_VERSION`; :func:`rules` is recorded with every evaluation). A driver (:class:`Driver`) is anything
with ``control_dt_s``, ``reset(world, car_ids)`` and ``act(state) -> (n, 2) [steer rad, omega]`` for its batch of
cars; the built-in AI is one (:class:`BuiltinAI`). The rules in full: docs/notes/evaluation.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

import numpy as np

from vision_rl.sim.ai_driver import DEFAULT_SKILL, AIDriver, DisruptionParams, Disruptor
from vision_rl.sim.driving import line_and_profile
from vision_rl.sim.fleet import AI_CONTROL_DT_S, STUCK_RULE, StuckDetector, ai_ticks
from vision_rl.sim.track import Track
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import VehicleParams, get_preset
from vision_rl.sim.world import World, WorldConfig, WorldState

#: Bump when a rule below changes: evaluations of another version are refused by the leaderboard.
PROTOCOL_VERSION = 1
#: The protocol's step, s: the papers' 10 Hz control rate.
STEP_S = 0.1
#: Speed of the rolling start, as a share of the QSS limit speed at the line: the built-in AI's default skill.
START_SPEED_SHARE = DEFAULT_SKILL
#: Uniform jitter of the start per seed: lateral offset from the racing line (m) and relative speed.
START_JITTER_LATERAL_M = 0.25
START_JITTER_SPEED = 0.02
#: Time limit per lap, as a multiple of the QSS limit lap time.
TIME_LIMIT_LIMIT_LAPS = 3.0
#: A scored lap with at most this much wall contact is clean, s.
CLEAN_WALL_CONTACT_S = 0.5
#: Cars a network-driven driver observes and acts for in one batch: the protocol's 3 starts, so that an evaluation
#: of 3 seeds or fewer computes as before the batches, and the first 3 of more seeds as those 3 (before, a policy's
#: start 0 lapped in 2:11.385 among 13 starts and in 2:13.090 among 3: README, the lap-time protocol).
DRIVER_BATCH_CARS = 3


def rules() -> dict[str, Any]:
    """The protocol's rules as recorded with every evaluation."""
    return {
        "version": PROTOCOL_VERSION,
        "step_s": STEP_S,
        "start": "rolling",
        "start_speed_share_of_limit": START_SPEED_SHARE,
        "start_jitter": {"lateral_m": START_JITTER_LATERAL_M, "speed_fraction": START_JITTER_SPEED},
        "stuck_rule": asdict(STUCK_RULE),
        "time_limit_limit_laps_per_lap": TIME_LIMIT_LIMIT_LAPS,
        "clean_wall_contact_s": CLEAN_WALL_CONTACT_S,
        "driver_batch_cars": DRIVER_BATCH_CARS,
    }


class Driver(Protocol):
    """Drives a batch of cars of one world."""

    control_dt_s: float
    """How often :meth:`act` is called, s: a whole fraction of :data:`STEP_S` or a whole number of 0.02 s."""

    def reset(self, world: World, car_ids: np.ndarray) -> None:
        """A new run: the driver drives cars ``car_ids`` of ``world`` (all its cars, in the protocol)."""

    def act(self, state: WorldState) -> np.ndarray:
        """Commands (len(car_ids), 2): steering angle in rad, omega in [-1, 1] (throttle > 0, brake < 0)."""


class BuiltinAI:
    """The built-in AI (:class:`vision_rl.sim.ai_driver.AIDriver`) as a protocol driver, acting at its 50 Hz."""

    control_dt_s = AI_CONTROL_DT_S

    def __init__(self, skill: float | None = None, disruption: DisruptionParams | None = None, seed: int = 0):
        """``skill`` None: :data:`DEFAULT_SKILL`, or the disruption's slower skill when disrupted."""
        if skill is None:
            skill = disruption.skill if disruption is not None else DEFAULT_SKILL
        if not 0.0 < skill <= 1.0:
            raise ValueError(f"skill must be in (0, 1], got {skill}")
        self.skill = float(skill)
        self.disruption = disruption
        self.seed = seed
        self._ai: AIDriver | None = None

    @property
    def identity(self) -> dict[str, Any]:
        return {"driver": "built-in AI", "skill": self.skill, "disrupted": self.disruption is not None}

    def reset(self, world: World, car_ids: np.ndarray) -> None:
        line, profile = line_and_profile(world.track, world.car)
        self._ids = np.asarray(car_ids)
        self._ai = AIDriver(world.car, line, profile, world.n_cars, skill=self.skill, groups=world.model.groups)
        self._disruptor = (
            Disruptor(world.n_cars, self.disruption, seed=self.seed) if self.disruption is not None else None
        )

    def act(self, state: WorldState) -> np.ndarray:
        assert self._ai is not None, "reset() first"
        steer, omega = self._ai.act(state)
        if self._disruptor is not None:
            steer, omega = self._disruptor(steer, omega, self.control_dt_s)
        return np.stack([steer, omega], axis=1)[self._ids]


class StraightDriver:
    """Full throttle with the wheels straight, never steering: the floor a learned driver must beat. Our walls keep a
    car's speed along them, so on some tracks this driver laps, riding the walls (docs/simulator.md)."""

    control_dt_s = AI_CONTROL_DT_S
    identity = {"driver": "straight", "steer_rad": 0.0, "omega": 1.0}

    def reset(self, world: World, car_ids: np.ndarray) -> None:
        self._n_cars = len(car_ids)

    def act(self, state: WorldState) -> np.ndarray:
        return np.tile([0.0, 1.0], (self._n_cars, 1))


@dataclass
class LapRecord:
    """One completed lap."""

    lap_time_s: float
    wall_contact_s: float
    car_contact_s: float
    off_track_s: float
    avg_speed_kmh: float
    """Centre-line lap length over lap time."""
    distance_m: float
    """Path length driven by the car's centre."""
    wall_hits: int = 0
    """Wall contacts that began in the lap."""
    fastest_wall_hit_kmh: float = 0.0
    """Speed at the start of the driver step in which the lap's fastest-begun wall contact began (0: none), km/h."""


@dataclass
class SeedRun:
    """One seed's run: its completed laps and, if it did not complete them all, why."""

    seed: int
    laps: list[LapRecord]
    dnf_reason: str | None
    distance_m: float
    """Path length driven over the whole run, m."""
    time_s: float
    """Time the run lasted, s."""


@dataclass
class LapTiming:
    """What :func:`time_laps` measured; with ``record``, every protocol step's poses of every seed."""

    track: Track
    car: VehicleParams
    laps: int
    runs: list[SeedRun]
    limit_lap_time_s: float
    time_limit_s: float
    start_speed_mps: np.ndarray
    time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """(T,) time of each recorded step, s; the arrays below are (T, n_seeds)."""
    x_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    y_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    yaw_rad: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    speed_mps: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    wall_contact: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))
    steer_rad: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    """The front wheels' angle at the end of each recorded step, rad (after the steering's lag)."""
    omega: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    """The pedal at the end of each recorded step, -1 (full brake) to 1 (full throttle), after its lag."""

    def scored(self, i: int) -> LapRecord | None:
        """Seed i's scored lap (the last of ``laps``), or None if it did not complete it."""
        run = self.runs[i]
        return run.laps[self.laps - 1] if len(run.laps) >= self.laps else None

    def scored_window_s(self, i: int) -> tuple[float, float]:
        """Start and end time of seed i's scored lap (the whole run if it has none), s."""
        lap = self.scored(i)
        if lap is None:
            return 0.0, math.inf
        start = float(sum(r.lap_time_s for r in self.runs[i].laps[: self.laps - 1]))
        return start, start + lap.lap_time_s

    def best_index(self) -> int:
        """Index of the seed with the fastest scored lap (the first seed when none finished)."""
        scores = [math.inf if self.scored(i) is None else self.scored(i).lap_time_s for i in range(len(self.runs))]
        return int(np.argmin(scores))

    def summary(self) -> dict[str, Any]:
        """JSON-ready figures: per seed and lap, and the best and median scored lap over seeds."""
        seeds = []
        for i, run in enumerate(self.runs):
            lap = self.scored(i)
            seeds.append(
                {
                    "seed": run.seed,
                    "laps": [asdict(r) for r in run.laps],
                    "lap_time_s": None if lap is None else lap.lap_time_s,
                    "finished": lap is not None,
                    "dnf_reason": run.dnf_reason,
                    "clean": lap is not None and lap.wall_contact_s <= CLEAN_WALL_CONTACT_S,
                    "distance_m": run.distance_m,
                    "time_s": run.time_s,
                }
            )
        scores = np.array([math.inf if s["lap_time_s"] is None else s["lap_time_s"] for s in seeds])
        best = self.best_index()
        median = float(np.median(scores))
        best_lap = self.scored(best)
        return {
            "protocol": {**rules(), "laps": self.laps, "scored_lap": self.laps, "time_limit_s": self.time_limit_s},
            "track_name": self.track.name,
            "track_geometry_hash": self.track.geometry_hash,
            "car": self.car.name,
            "limit_lap_time_s": self.limit_lap_time_s,
            "seeds": seeds,
            "n_seeds": len(seeds),
            "n_finished": int(np.isfinite(scores).sum()),
            "best_seed": self.runs[best].seed,
            "best_lap_time_s": None if best_lap is None else best_lap.lap_time_s,
            "best_lap": None if best_lap is None else asdict(best_lap),
            "median_lap_time_s": median if math.isfinite(median) else None,
            "clean": seeds[best]["clean"],
        }


def _start(track: Track, car: VehicleParams, seeds: Sequence[int]) -> tuple[np.ndarray, np.ndarray, float]:
    """(lateral offsets, speeds, limit lap time) of the seeds' rolling starts on the line."""
    line, profile = line_and_profile(track, car)
    u = np.array([np.random.default_rng(int(seed)).uniform(-1.0, 1.0, 2) for seed in seeds]).reshape(len(seeds), 2)
    lateral = line.lateral_at(np.zeros(1))[0] + u[:, 0] * START_JITTER_LATERAL_M
    speed = START_SPEED_SHARE * profile.speed_at(line.line_s_at(np.zeros(1)))[0] * (1.0 + u[:, 1] * START_JITTER_SPEED)
    return lateral, speed, profile.lap_time_s


def world_tick_s(control_dt_s: float) -> tuple[float, int]:
    """The protocol world's tick for a driver acting every ``control_dt_s`` seconds and how many ticks it holds a
    command: the driver's own step where that divides :data:`STEP_S`, else the AI's 0.02 s (docs/notes/evaluation.md,
    the rules)."""
    per_step = round(STEP_S / control_dt_s) if control_dt_s > 0 else 0
    if per_step >= 1 and abs(per_step * control_dt_s - STEP_S) < 1e-9:
        return control_dt_s, 1
    held = ai_ticks(control_dt_s)
    if held is not None:
        return AI_CONTROL_DT_S, held
    raise ValueError(
        f"a driver must act every {STEP_S} s, a whole fraction of it or a whole multiple of {AI_CONTROL_DT_S} s, "
        f"not {control_dt_s}"
    )


class _HeldCommand:
    """The driver's command, asked every ``act_every`` world ticks and held in between. A driver holding its command
    over several ticks sees the contacts of all of them, as its training environment shows them over a control step
    (vision_rl.sim.fleet.AIFleet.advance)."""

    def __init__(self, driver: Driver, n: int, act_every: int) -> None:
        self.driver, self.n, self.act_every = driver, n, act_every
        self.ticks = 0
        self.wall_since_ask, self.car_since_ask = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        self.action = np.zeros((n, 2))

    def command(self, state: WorldState) -> np.ndarray:
        """The (n, 2) command of the next tick: the driver's answer on an asking tick, else the held one."""
        if self.ticks % self.act_every == 0:
            seen = state
            if self.act_every > 1:
                seen = seen._replace(wall_contact=self.wall_since_ask, car_contact=self.car_since_ask)
                self.wall_since_ask, self.car_since_ask = np.zeros(self.n, dtype=bool), np.zeros(self.n, dtype=bool)
            self.action = np.asarray(self.driver.act(seen), dtype=np.float64).reshape(self.n, 2)
        self.ticks += 1
        return self.action

    def saw(self, state: WorldState) -> None:
        """Remember a tick's contacts for the next asking tick."""
        self.wall_since_ask |= state.wall_contact
        self.car_since_ask |= state.car_contact


class _Tally:
    """What the protocol counts per seed while it runs: which cars still drive, why one stopped, when, and each lap's
    figures (cumulative wall, car, off-track, distance and wall hits at each lap's end: a lap's figures are the
    differences)."""

    def __init__(self, n: int) -> None:
        self.active = np.ones(n, dtype=bool)
        self.dnf: list[str | None] = [None] * n
        self.end_time_s = np.zeros(n)
        self.off_track_s = np.zeros(n)
        self.distance_m = np.zeros(n)
        self.marks: list[list[np.ndarray]] = [[np.zeros(5)] for _ in range(n)]
        self.wall_hits = np.zeros(n)
        self.fastest_hit_mps = np.zeros(n)  # of the lap under way
        self.fastest_hit_per_lap_mps: list[list[float]] = [[] for _ in range(n)]

    def count_tick(self, track: Track, st: WorldState, events, touching_before: np.ndarray, speed_before_mps, dt):
        """Add one world tick of ``dt`` seconds that ended in ``st``; the tick's contacts began where they touch now
        and did not before."""
        veh = st.vehicle
        active = self.active
        hit = active & st.wall_contact & ~touching_before
        self.wall_hits += hit
        self.fastest_hit_mps = np.maximum(self.fastest_hit_mps, np.where(hit, speed_before_mps, 0.0))
        self.off_track_s += dt * (active & track.beyond_edge_line(st.s_m, st.lateral_m))
        self.distance_m += dt * active * np.hypot(veh.vx_mps, veh.vy_mps)
        for i in np.flatnonzero(events.lap_completed & active):
            self.marks[i].append(
                np.array(
                    [
                        st.wall_contact_time_s[i],
                        st.car_contact_time_s[i],
                        self.off_track_s[i],
                        self.distance_m[i],
                        self.wall_hits[i],
                    ]
                )
            )
            self.fastest_hit_per_lap_mps[i].append(float(self.fastest_hit_mps[i]))
            self.fastest_hit_mps[i] = 0.0

    def end_step(self, st: WorldState, laps: int, stuck: StuckDetector) -> None:
        """After a protocol step: cars that completed ``laps`` laps are done, stuck cars are a DNF."""
        finished = self.active & (st.laps_completed >= laps)
        self.end_time_s[finished] = st.time_s[finished]
        self.active &= ~finished
        stuck_now = np.intersect1d(stuck.update(st.unwrapped_s_m), np.flatnonzero(self.active))
        for i in stuck_now:
            self.dnf[i] = f"stuck: {STUCK_RULE.describe()}, at {st.time_s[i]:.1f} s, {st.s_m[i]:.0f} m into the lap"
        self.end_time_s[stuck_now] = st.time_s[stuck_now]
        self.active[stuck_now] = False

    def lap_records(self, i: int, lap_times_s: list[float], laps: int, lap_length_m: float) -> list[LapRecord]:
        """Seed i's completed laps, at most ``laps``."""
        marks = self.marks[i]
        records = []
        for k, lap_time_s in enumerate(lap_times_s[: len(marks) - 1][:laps]):
            wall, car_s, off, dist, hits = marks[k + 1] - marks[k]
            records.append(
                LapRecord(
                    lap_time_s=float(lap_time_s),
                    wall_contact_s=float(wall),
                    car_contact_s=float(car_s),
                    off_track_s=float(off),
                    avg_speed_kmh=float(3.6 * lap_length_m / lap_time_s),
                    distance_m=float(dist),
                    wall_hits=round(float(hits)),
                    fastest_wall_hit_kmh=3.6 * self.fastest_hit_per_lap_mps[i][k],
                )
            )
        return records


_RECORDED = ("t", "x", "y", "yaw", "v", "wall", "steer", "omega")


def _record_step(rec: dict[str, list[np.ndarray]], st: WorldState, wall_step: np.ndarray) -> None:
    """One protocol step's poses of every seed, for :class:`LapTiming`'s recorded arrays."""
    veh = st.vehicle
    rec["t"].append(st.time_s[0])
    rec["x"].append(veh.x_m.copy())
    rec["y"].append(veh.y_m.copy())
    rec["yaw"].append(veh.yaw_rad.copy())
    rec["v"].append(np.hypot(veh.vx_mps, veh.vy_mps))
    rec["wall"].append(wall_step)
    rec["steer"].append(veh.steer_rad.copy())
    rec["omega"].append(veh.omega.copy())


def _store_recording(timing: LapTiming, rec: dict[str, list[np.ndarray]]) -> None:
    timing.time_s = np.asarray(rec["t"])
    timing.x_m, timing.y_m, timing.yaw_rad = (np.stack(rec[k]) for k in ("x", "y", "yaw"))
    timing.speed_mps, timing.wall_contact = np.stack(rec["v"]), np.stack(rec["wall"])
    timing.steer_rad, timing.omega = np.stack(rec["steer"]), np.stack(rec["omega"])


def _protocol_step(world: World, held: _HeldCommand, tally: _Tally, world_steps: int, dt: float) -> np.ndarray:
    """One protocol step of ``world_steps`` ticks of ``dt`` seconds; returns which cars touched a wall in it."""
    wall_step = np.zeros(world.n_cars, dtype=bool)
    for _ in range(world_steps):
        action = held.command(world.state)
        touching_before = world.state.wall_contact.copy()
        speed_before_mps = np.hypot(world.state.vehicle.vx_mps, world.state.vehicle.vy_mps)
        events = world.step(action[:, 0], action[:, 1])
        st = world.state
        wall_step |= st.wall_contact
        held.saw(st)
        tally.count_tick(world.track, st, events, touching_before, speed_before_mps, dt)
    return wall_step


def _checked_seeds(seeds: Sequence[int], laps: int) -> list[int]:
    seeds = [int(s) for s in seeds]
    if len(seeds) < 1:
        raise ValueError("the protocol needs at least one seed")
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must differ, got {seeds}")
    if laps < 1:
        raise ValueError(f"laps must be >= 1, got {laps}")
    return seeds


def time_laps(
    driver: Driver,
    track: Track | str,
    car: VehicleParams | str,
    seeds: Sequence[int] = (0, 1, 2),
    laps: int = 2,
    time_limit_s: float = 0.0,
    record: bool = False,
) -> LapTiming:
    """Run the protocol: ``driver`` drives one car per seed for ``laps`` laps (the rules: docs/notes/evaluation.md).

    ``time_limit_s`` 0: 3 x the QSS limit lap time per lap. ``record`` keeps every step's poses (plots, videos).
    """
    track = track if isinstance(track, Track) else load_track(track)
    car = car if isinstance(car, VehicleParams) else get_preset(car)
    seeds = _checked_seeds(seeds, laps)
    n = len(seeds)
    dt, act_every = world_tick_s(driver.control_dt_s)
    world_steps = round(STEP_S / dt)
    world = World(track, car, n_cars=n, groups=np.arange(n), config=WorldConfig(control_dt_s=dt))
    lateral, speed, limit_lap_s = _start(track, car, seeds)
    world.reset(s_m=np.zeros(n), lateral_m=lateral, speed_mps=speed)
    driver.reset(world, np.arange(n))
    limit_s = time_limit_s if time_limit_s > 0 else laps * TIME_LIMIT_LIMIT_LAPS * limit_lap_s
    tally = _Tally(n)
    held = _HeldCommand(driver, n, act_every)
    stuck = StuckDetector(world.state.unwrapped_s_m, STEP_S, STUCK_RULE)
    rec: dict[str, list[np.ndarray]] = {k: [] for k in _RECORDED}
    for _ in range(math.ceil(limit_s / STEP_S - 1e-9)):
        wall_step = _protocol_step(world, held, tally, world_steps, dt)
        if record:
            _record_step(rec, world.state, wall_step)
        tally.end_step(world.state, laps, stuck)
        if not tally.active.any():
            break
    st = world.state
    for i in np.flatnonzero(tally.active):
        tally.dnf[i] = f"time limit: {laps} laps not done in {limit_s:.0f} s"
        tally.end_time_s[i] = st.time_s[i]
    runs = [
        SeedRun(
            seed,
            tally.lap_records(i, world.lap_times_s[i], laps, track.length_m),
            tally.dnf[i],
            float(tally.distance_m[i]),
            float(tally.end_time_s[i]),
        )
        for i, seed in enumerate(seeds)
    ]
    timing = LapTiming(track, car, laps, runs, float(limit_lap_s), float(limit_s), speed)
    if record and rec["t"]:
        _store_recording(timing, rec)
    return timing
