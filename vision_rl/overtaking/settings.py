"""`evaluate-overtaking`: the overtaking paper's evaluation (section IV-C, Figs. 3-6): settings A and B, the
analysis of one run (Fig. 6), and the learning curves (Fig. 3).

Settings A and B put five built-in AI opponents ahead of the agent's car, 50 m (A) or 200 m (B) apart along the
centre line; the runs go at once in one world, each in its own collision group, until the agent leads all five, is
stuck or reaches the time limit. Per run, the paper's four metrics (total travel time and distance, car- and
wall-collision time) and the cars overtaken; over the runs, mean, standard deviation and best, beside the built-in
AI driving the agent's car (the reference row). The learning curves put the overtaking return of curriculum and
standard SAC runs on one axis. The rules in full: docs/notes/overtaking.md, "settings.py".
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from vision_rl.evaluation.protocol import START_JITTER_LATERAL_M, START_JITTER_SPEED, BuiltinAI, Driver
from vision_rl.files import atomic_write, sealed_record, write_json
from vision_rl.overtaking.curriculum import learning_curve, load_overtaking_policy
from vision_rl.sim.ai_driver import DEFAULT_SKILL, OPPONENT_SKILL_RANGE
from vision_rl.sim.driving import line_and_profile
from vision_rl.sim.fleet import AI_CONTROL_DT_S, STUCK_RULE, AIFleet, StuckDetector, ai_ticks
from vision_rl.sim.sensors import wrap_angle
from vision_rl.sim.track import Track
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import VehicleParams, get_preset
from vision_rl.sim.world import World, WorldConfig
from vision_rl.training.artifact import PolicyError

#: Setting name -> separation between consecutive cars along the centre line, m (section IV-C).
SETTINGS: dict[str, float] = {"A": 50.0, "B": 200.0}
OPPONENTS = 5
#: Default time limits, s: the last opponent starts 250 m (A) / 1,000 m (B) ahead, and an agent 5 % faster than
#: an opponent at 50 m/s gains 2.5 m/s, so 1,000 m take about 400 s.
DEFAULT_TIME_LIMIT_S: dict[str, float] = {"A": 300.0, "B": 600.0}
#: The agent leads an opponent by this much centre-line progress to count it as overtaken for ending the run, m.
LEAD_MARGIN_M = 10.0
METRICS = ("travel_time_s", "travel_distance_m", "car_contact_s", "wall_contact_s")
METRIC_LABELS = {
    "travel_time_s": "total travel time (s)",
    "travel_distance_m": "total travel distance (m)",
    "car_contact_s": "car-collision time (s)",
    "wall_contact_s": "wall-collision time (s)",
}


class SettingError(ValueError):
    """A setting or policy that cannot be evaluated as asked; the message says why."""


def check_opponent_skill(skill: tuple[float, float]) -> None:
    """Refuse an opponents' skill range that is not 0 < low <= high <= 1 (1: the QSS limit profile)."""
    low, high = (float(x) for x in skill)
    if not 0.0 < low <= high <= 1.0:  # also refuses NaN
        raise SettingError(f"--opponent-skill must be LOW HIGH with 0 < LOW <= HIGH <= 1, got {low:g} {high:g}")


def check_setting(setting: str) -> float:
    """The separation of ``setting`` (A or B), refusing another name."""
    if setting not in SETTINGS:
        raise SettingError(f"--setting must be one of {', '.join(SETTINGS)}, got {setting!r}")
    return SETTINGS[setting]


class RunTrace(NamedTuple):
    """One run of a setting sampled every :data:`TRACE_DT_S` from its start until it ended (T samples); car 0 is
    the agent, cars 1-5 the opponents in their start order."""

    time_s: np.ndarray
    """(T,) time since the start, s."""
    x_m: np.ndarray
    """(T, 6) world-frame positions, m."""
    y_m: np.ndarray
    """(T, 6)"""
    yaw_rad: np.ndarray
    """(T, 6)"""
    speed_mps: np.ndarray
    """(T,) the agent's speed, m/s."""
    gap_m: np.ndarray
    """(T, 5) each opponent's centre-line lead over the agent, m (negative: the agent is ahead)."""
    car_contact_s: np.ndarray
    """(T,) the agent's car-contact time so far, s."""
    wall_contact_s: np.ndarray
    """(T,) the agent's wall-contact time so far, s."""
    heading_error_rad: np.ndarray
    """(T,) the agent's heading against the track's direction where it is, rad in (-pi, pi] (0: along the track)."""
    steer_rad: np.ndarray
    """(T,) the agent's steering command at the sample, rad."""
    pedal: np.ndarray
    """(T,) the agent's pedal command at the sample, in [-1, 1]: throttle above 0, brake below."""


#: Sampling interval of a :class:`RunTrace`, s: the policies' control step.
TRACE_DT_S = 0.1


def run_setting(
    driver: Driver,
    track: Track | str,
    car: VehicleParams | str,
    setting: str,
    runs: int = 10,
    seed: int = 0,
    time_limit_s: float = 0.0,
    lead_margin_m: float = LEAD_MARGIN_M,
    opponent_skill: tuple[float, float] = OPPONENT_SKILL_RANGE,
) -> tuple[list[dict[str, Any]], list[RunTrace]]:
    """``runs`` runs of ``setting`` with ``driver`` on the agent's car (see the module's docstring): one dict of
    metrics per run, and each run's :class:`RunTrace`. Each opponent's skill is drawn from ``opponent_skill``
    (low, high; equal bounds: every opponent at that skill)."""
    separation_m = check_setting(setting)
    if runs < 1:
        raise SettingError(f"--runs must be >= 1, got {runs}")
    check_opponent_skill(opponent_skill)
    track = track if isinstance(track, Track) else load_track(track)
    car = car if isinstance(car, VehicleParams) else get_preset(car)
    limit_s = time_limit_s if time_limit_s > 0 else DEFAULT_TIME_LIMIT_S[setting]
    every = ai_ticks(driver.control_dt_s)
    if every is None:
        raise SettingError(f"a driver must act every {AI_CONTROL_DT_S} s or a whole multiple of it")
    field = _place_runs(driver, track, car, runs, seed, separation_m, opponent_skill)
    steps = math.ceil(limit_s / AI_CONTROL_DT_S - 1e-9)
    tracer = _Tracer(field.world, field.ego, runs, steps)
    end, reason = _drive_runs(driver, field, tracer, steps, every, lead_margin_m)
    return [
        {
            "run": r,
            "seed": seed + r,
            "opponent_skills": [round(float(x), 4) for x in field.skill[r, 1:]],
            **{name: round(float(end[name][r]), 3) for name in METRICS},
            "overtaken": int(end["overtaken"][r]),
            "all_overtaken": reason[r] == "all overtaken",
            "end": reason[r],
        }
        for r in range(runs)
    ], tracer.traces()


class _Field(NamedTuple):
    """The runs of a setting at their start: the agent's car and its five opponents per run, one group each."""

    world: World
    fleet: AIFleet
    ego: np.ndarray
    """(runs,) the agents' car ids."""
    skill: np.ndarray
    """(runs, 6) the cars' skills (the agent's column the default)."""
    start_gap_m: np.ndarray
    """(5,) each opponent's start lead over the agent along the centre line, m."""
    at_reset_m: np.ndarray
    """Every car's unwrapped centre-line progress at the start, m."""
    stuck: StuckDetector


def _place_runs(
    driver: Driver,
    track: Track,
    car: VehicleParams,
    runs: int,
    seed: int,
    separation_m: float,
    opponent_skill: tuple[float, float] = OPPONENT_SKILL_RANGE,
) -> _Field:
    """One world of ``runs`` groups: opponents on the racing line at their skill's speed, the agent on the start
    line with run ``r``'s draws from ``default_rng(seed + r)`` (the opponents' skills, the agent's start jitter)."""
    k = OPPONENTS + 1
    n = runs * k
    groups = np.repeat(np.arange(runs), k)
    world = World(track, car, n, groups, WorldConfig(control_dt_s=AI_CONTROL_DT_S))
    line, profile = line_and_profile(track, car)
    ego = np.arange(runs) * k
    skill = np.full((runs, k), DEFAULT_SKILL)
    jitter = np.empty((runs, 2))
    for r in range(runs):  # one draw per run (set-up, not a step)
        rng = np.random.default_rng(seed + r)
        skill[r, 1:] = rng.uniform(opponent_skill[0], opponent_skill[1], OPPONENTS)
        jitter[r] = rng.uniform(-1.0, 1.0, 2)
    fleet = AIFleet(world, line, profile, skill=skill.ravel())
    start_gap_m = np.arange(1, k) * separation_m
    s0 = np.tile(np.concatenate([[0.0], start_gap_m]), runs)
    fleet.place(np.arange(n), np.mod(s0, track.length_m))
    ego_s = np.zeros(runs)
    ego_speed = DEFAULT_SKILL * profile.speed_at(line.line_s_at(ego_s)) * (1.0 + jitter[:, 1] * START_JITTER_SPEED)
    world.reset(
        s_m=ego_s,
        lateral_m=line.lateral_at(ego_s) + jitter[:, 0] * START_JITTER_LATERAL_M,
        speed_mps=ego_speed,
        car_ids=ego,
    )
    at_reset_m = world.state.unwrapped_s_m.copy()
    driver.reset(world, ego)
    stuck = StuckDetector(world.state.unwrapped_s_m[ego], AI_CONTROL_DT_S, STUCK_RULE)
    return _Field(world, fleet, ego, skill, start_gap_m, at_reset_m, stuck)


class _Tracer:
    """Every run's :class:`RunTrace`, sampled into preallocated arrays every :data:`TRACE_DT_S` and where a run
    ends."""

    def __init__(self, world: World, ego: np.ndarray, runs: int, steps: int) -> None:
        k = OPPONENTS + 1
        self.world, self.ego, self.k, self.runs = world, ego, k, runs
        self.every = round(TRACE_DT_S / AI_CONTROL_DT_S)
        self.samples = np.zeros(runs, dtype=np.int64)
        rows_max = steps // self.every + 2
        self.trace = {
            name: np.zeros((rows_max, runs, *shape))
            for name, shape in (
                ("time_s", ()),
                ("x_m", (k,)),
                ("y_m", (k,)),
                ("yaw_rad", (k,)),
                ("speed_mps", ()),
                ("gap_m", (k - 1,)),
                ("car_contact_s", ()),
                ("wall_contact_s", ()),
                ("heading_error_rad", ()),
                ("steer_rad", ()),
                ("pedal", ()),
            )
        }

    def record(self, which: np.ndarray, gap: np.ndarray, action: np.ndarray) -> None:
        """A sample of the runs ``which``; ``gap`` (runs, 5): each opponent's lead over the agent now, m; ``action``
        (runs, 2): the agents' commands (steer rad, pedal)."""
        st, rows, ids = self.world.state, self.samples[which], self.ego[which]
        cars = ids[:, None] + np.arange(self.k)
        heading_error = wrap_angle(st.vehicle.yaw_rad[ids] - self.world.track.heading_at(st.s_m[ids]))
        for name, value in (
            ("time_s", st.time_s[ids]),
            ("x_m", st.vehicle.x_m[cars]),
            ("y_m", st.vehicle.y_m[cars]),
            ("yaw_rad", st.vehicle.yaw_rad[cars]),
            ("speed_mps", np.hypot(st.vehicle.vx_mps[ids], st.vehicle.vy_mps[ids])),
            ("gap_m", gap[which]),
            ("car_contact_s", st.car_contact_time_s[ids]),
            ("wall_contact_s", st.wall_contact_time_s[ids]),
            ("heading_error_rad", heading_error),
            ("steer_rad", action[which, 0]),
            ("pedal", action[which, 1]),
        ):
            self.trace[name][rows, which] = value
        self.samples[which] += 1

    def traces(self) -> list[RunTrace]:
        return [
            RunTrace(**{name: values[: self.samples[r], r] for name, values in self.trace.items()})
            for r in range(self.runs)
        ]


def _drive_runs(
    driver: Driver, field: _Field, tracer: _Tracer, steps: int, every: int, lead_margin_m: float
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Step the world until every run has ended (see the module's docstring); returns each run's metrics at its end
    and why it ended."""
    world, ego = field.world, field.ego
    runs, k = len(ego), OPPONENTS + 1
    active = np.ones(runs, dtype=bool)
    distance_m = np.zeros(runs)
    end = {name: np.zeros(runs) for name in (*METRICS, "overtaken")}
    reason = np.array(["time limit"] * runs, dtype=object)
    action = np.zeros((runs, 2))
    gap = np.tile(field.start_gap_m, (runs, 1))
    tracer.record(np.arange(runs), gap, action)
    for step in range(steps):
        if step % every == 0:
            action = np.asarray(driver.act(world.state), dtype=np.float64).reshape(runs, 2)
        field.fleet.advance(1, ego, action[:, 0], action[:, 1])
        st = world.state
        speed = np.hypot(st.vehicle.vx_mps[ego], st.vehicle.vy_mps[ego])
        distance_m += AI_CONTROL_DT_S * speed * active
        travelled = (st.unwrapped_s_m - field.at_reset_m).reshape(runs, k)
        gap = field.start_gap_m[None, :] + travelled[:, 1:] - travelled[:, :1]
        led = active & np.all(gap < -lead_margin_m, axis=1)
        stuck_now = np.zeros(runs, dtype=bool)
        stuck_now[field.stuck.update(st.unwrapped_s_m[ego])] = True
        stuck_now &= active & ~led
        ended = led | stuck_now | (active & (step == steps - 1))
        if (step + 1) % tracer.every == 0:
            tracer.record(np.flatnonzero(active), gap, action)
        elif ended.any():  # only the runs that end get a sample off the grid, so rows_max bounds every run
            tracer.record(np.flatnonzero(ended), gap, action)
        if ended.any():
            idx = np.flatnonzero(ended)
            end["travel_time_s"][idx] = st.time_s[ego[idx]]
            end["travel_distance_m"][idx] = distance_m[idx]
            end["car_contact_s"][idx] = st.car_contact_time_s[ego[idx]]
            end["wall_contact_s"][idx] = st.wall_contact_time_s[ego[idx]]
            end["overtaken"][idx] = np.sum(gap[idx] < 0.0, axis=1)
            reason[np.flatnonzero(led)] = "all overtaken"
            reason[np.flatnonzero(stuck_now)] = f"stuck: {STUCK_RULE.describe()}"
            active &= ~ended
        if not active.any():
            break
    return end, reason


def summarise_runs(runs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Mean, standard deviation and best (lowest) of each metric; all-five count; overtaken mean and range."""
    out: dict[str, Any] = {}
    for name in METRICS:
        values = np.array([r[name] for r in runs], dtype=np.float64)
        out[name] = {"mean": float(values.mean()), "std": float(values.std()), "best": float(values.min())}
    overtaken = np.array([r["overtaken"] for r in runs])
    out["all_overtaken_runs"] = int(sum(r["all_overtaken"] for r in runs))
    # "best" above includes runs that ended early, stuck: short, but no overtake. The fastest run that passed all five
    # is what the paper's bars compare.
    complete = [r["travel_time_s"] for r in runs if r["all_overtaken"]]
    out["fastest_all_five_s"] = float(min(complete)) if complete else None
    out["runs"] = len(runs)
    out["overtaken"] = {"mean": float(overtaken.mean()), "min": int(overtaken.min()), "max": int(overtaken.max())}
    return out


def evaluate_overtaking(
    policies: Sequence[str],
    setting: str,
    runs: int = 10,
    seed: int = 0,
    time_limit_s: float = 0.0,
    lead_margin_m: float = LEAD_MARGIN_M,
    reference: bool = True,
    names: Sequence[str] = (),
    track: str = "",
    car: str = "",
    device: str = "cpu",
    humans: Sequence[str] = (),
    opponent_skill: tuple[float, float] = OPPONENT_SKILL_RANGE,
) -> dict[str, Any]:
    """Each policy (a stage folder of train-overtaking) and, with ``reference``, the built-in AI through
    ``setting``; all on the policies' track and car (``track``/``car`` refuse a policy made for others, and say
    where to evaluate when no policy is given). ``humans``: ``setting.json`` files of ``play --setting``, added as
    reference rows (refused when made for another setting, track or car)."""
    separation_m = check_setting(setting)
    check_opponent_skill(opponent_skill)
    if humans and tuple(opponent_skill) != OPPONENT_SKILL_RANGE:
        raise SettingError("--human runs were driven against the default opponents: leave --opponent-skill as it is")
    if not policies and not reference and not humans:
        raise SettingError("nothing to evaluate: give --policy or --human, or keep --reference")
    if names and len(names) != len(policies):
        raise SettingError(f"--names gives {len(names)} names for {len(policies)} policies")
    loaded = [load_overtaking_policy(p, device) for p in policies]
    track_obj, car = _common_track_and_car(policies, loaded, track, car)
    drivers: list[tuple[str, Any, dict[str, Any]]] = []
    for i, (path, policy) in enumerate(zip(policies, loaded, strict=True)):
        driver = policy.driver()
        drivers.append((names[i] if names else _policy_name(Path(path)), driver, driver.identity))
    if reference:
        ai = BuiltinAI()
        drivers.append(("built-in AI", ai, ai.identity))
    rows = []
    for name, driver, identity in drivers:
        try:
            per_run, _ = run_setting(
                driver, track_obj, car, setting, runs, seed, time_limit_s, lead_margin_m, opponent_skill
            )
        finally:
            if hasattr(driver, "close"):
                driver.close()
        rows.append(
            {
                "name": name,
                "driver": identity,
                "reference": identity.get("driver") == "built-in AI",
                "runs": per_run,
                "summary": summarise_runs(per_run),
            }
        )
    for path in humans:
        rows.append(_human_row(path, setting, track_obj, car))
    return {
        "setting": setting,
        "separation_m": separation_m,
        "opponents": OPPONENTS,
        "runs": runs,
        "seed": seed,
        "time_limit_s": time_limit_s if time_limit_s > 0 else DEFAULT_TIME_LIMIT_S[setting],
        "lead_margin_m": lead_margin_m,
        "track_name": track_obj.name,
        "track_geometry_hash": track_obj.geometry_hash,
        "car": car,
        "opponent_skill_range": [float(x) for x in opponent_skill],
        "drivers": rows,
    }


def _common_track_and_car(policies: Sequence[str], loaded: Sequence[Any], track: str, car: str) -> tuple[Track, str]:
    """The track and car every policy was trained for (``track``/``car`` when given, else the first policy's; the
    expressway and tt_cup with no policy), refusing a policy made for others."""
    track_obj = load_track(track) if track else None
    for path, policy in zip(policies, loaded, strict=True):
        config = policy.config
        policy_track = load_track(config.track)
        if track_obj is None:
            track_obj, car = policy_track, car or config.car
        if policy_track.geometry_hash != track_obj.geometry_hash:
            raise PolicyError(
                f"policy {path} was trained on track {config.track!r} (geometry "
                f"{policy_track.geometry_hash[:12]}...), not {track_obj.name!r} "
                f"({track_obj.geometry_hash[:12]}...): evaluate it on its own track"
            )
        if car and config.car != car:
            raise PolicyError(f"policy {path} drives the car {config.car!r}, not {car!r}")
    if track_obj is None:
        track_obj = load_track("expressway")
    return track_obj, car or "tt_cup"


def _human_row(path: str | os.PathLike[str], setting: str, track: Track, car: str) -> dict[str, Any]:
    """A row of ``play --setting``, checked against what the others drove."""
    try:
        row = json.loads(Path(path).read_text())
        made_for = (row["setting"], row["track_geometry_hash"], row["car"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise SettingError(f"--human {path}: not a setting.json of vision-rl play --setting ({exc})") from None
    if made_for != (setting, track.geometry_hash, car):
        raise SettingError(
            f"--human {path} was driven in setting {row['setting']} on {row['track_name']} with the "
            f"{row['car']}, not setting {setting} on {track.name} with the {car}"
        )
    return {k: row[k] for k in ("name", "driver", "reference", "runs", "summary")}


def _policy_name(path: Path) -> str:
    folder = path if path.is_dir() else path.parent
    return f"{folder.parent.name}/{folder.name}"


def write_setting_outputs(result: dict[str, Any], out: str | os.PathLike[str]) -> dict[str, str]:
    """``overtaking_setting_<X>.json`` and the bar chart ``overtaking_setting_<X>.png`` (the paper's Figs. 4-5:
    mean with the standard deviation as error bars, the best run as a dot, the reference's best dashed)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stem = f"overtaking_setting_{result['setting']}"
    json_path, png_path = out / f"{stem}.json", out / f"{stem}.png"
    write_json(json_path, sealed_record(result))
    rows = result["drivers"]
    fig, axes = _pyplot().subplots(1, len(METRICS), figsize=(4.0 * len(METRICS), 4.0))
    x = np.arange(len(rows))
    for ax, metric in zip(axes, METRICS, strict=True):
        means = [r["summary"][metric]["mean"] for r in rows]
        stds = [r["summary"][metric]["std"] for r in rows]
        bests = [r["summary"][metric]["best"] for r in rows]
        if metric == "travel_time_s":  # the fastest run that passed all five (the plain best when none did)
            bests = [r["summary"].get("fastest_all_five_s") or b for r, b in zip(rows, bests, strict=True)]
        ax.bar(x, means, yerr=stds, capsize=4, color=["0.6" if r["reference"] else "C0" for r in rows])
        ax.plot(x, bests, "k.", label="best run")
        for r in rows:
            if r["reference"]:
                ax.axhline(r["summary"][metric]["best"], color="k", linestyle="--", linewidth=1, label="reference best")
        ax.set_xticks(x, [r["name"] for r in rows], rotation=30, ha="right", fontsize=8)
        ax.set_title(METRIC_LABELS[metric], fontsize=9)
    axes[0].legend(fontsize=7)
    counts = ", ".join(f"{r['name']}: {r['summary']['all_overtaken_runs']}/{r['summary']['runs']}" for r in rows)
    fig.suptitle(
        f"setting {result['setting']} ({result['separation_m']:g} m apart, {result['track_name']}, "
        f"{result['car']}); all 5 overtaken in {counts}",
        fontsize=9,
    )
    fig.tight_layout()
    _save_figure(fig, png_path)
    return {"json": str(json_path), "png": str(png_path)}


# ------------------------------------------------------------------------------------------------- Fig. 6


#: The driver's view of a pass is drawn at the last sample before it with the passed car this far ahead, m (at the
#: pass itself the car is beside the agent, out of a forward camera's view).
APPROACH_GAP_M = 10.0


def overtake_moments(trace: RunTrace) -> list[dict[str, Any]]:
    """The passes that stood: for each opponent the agent is ahead of at the end of the run, the last sample at
    which its lead turned negative, with the agent's position and speed there, and the approach sample (the last
    before the pass with the car :data:`APPROACH_GAP_M` ahead, or the pass itself); in time order."""
    moments = []
    final = trace.gap_m[-1] if len(trace.time_s) else np.zeros(0)
    for j in np.flatnonzero(final < 0.0):
        behind = trace.gap_m[:, j] >= 0.0  # the opponent still leads
        i = int(np.flatnonzero(behind)[-1]) + 1 if behind.any() else 0
        ahead = np.flatnonzero(trace.gap_m[:i, j] >= APPROACH_GAP_M)
        moments.append(
            {
                "opponent": int(j) + 1,
                "sample": i,
                "time_s": float(trace.time_s[i]),
                "x_m": float(trace.x_m[i, 0]),
                "y_m": float(trace.y_m[i, 0]),
                "speed_kmh": float(3.6 * trace.speed_mps[i]),
                "approach_sample": int(ahead[-1]) if len(ahead) else i,
            }
        )
    return sorted(moments, key=lambda m: m["time_s"])


def contact_intervals(time_s: np.ndarray, cumulative_s: np.ndarray) -> list[tuple[float, float]]:
    """The (start, end) times, s, of the sample intervals in which a cumulative contact time grew, neighbours
    merged."""
    grew = np.diff(cumulative_s) > 0.0
    edges = np.diff(np.concatenate([[0], grew.astype(np.int8), [0]]))
    return [
        (float(time_s[a]), float(time_s[b]))
        for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True)
    ]


def fastest_run(runs: Sequence[dict[str, Any]]) -> int:
    """Index of the fastest run that overtook all five; with none, the run that passed most, then the shortest."""
    return min(
        range(len(runs)), key=lambda r: (not runs[r]["all_overtaken"], -runs[r]["overtaken"], runs[r]["travel_time_s"])
    )


#: The entries of :func:`_trace_record` that hold one value per trace sample (the rest summarise the run).
TRACE_SERIES = ("time_s", "overtaken", "speed_kmh", "x_m", "y_m", "heading_error_rad", "steer_rad", "pedal")


def _trace_record(name: str, run: dict[str, Any], trace: RunTrace) -> dict[str, Any]:
    overtaken = np.sum(trace.gap_m < 0.0, axis=1)
    return {
        "name": name,
        "run": run,
        "moments": overtake_moments(trace),
        "car_contacts": contact_intervals(trace.time_s, trace.car_contact_s),
        "wall_contacts": contact_intervals(trace.time_s, trace.wall_contact_s),
        "time_s": np.round(trace.time_s, 2).tolist(),
        "overtaken": overtaken.tolist(),
        "speed_kmh": np.round(3.6 * trace.speed_mps, 1).tolist(),
        "x_m": np.round(trace.x_m, 2).tolist(),
        "y_m": np.round(trace.y_m, 2).tolist(),
        "heading_error_rad": np.round(trace.heading_error_rad, 3).tolist(),
        "steer_rad": np.round(trace.steer_rad, 4).tolist(),
        "pedal": np.round(trace.pedal, 3).tolist(),
    }


def analyse_overtaking(
    driver: Driver,
    name: str,
    track: Track | str,
    car: VehicleParams | str,
    setting: str = "A",
    runs: int = 10,
    seed: int = 0,
    time_limit_s: float = 0.0,
    lead_margin_m: float = LEAD_MARGIN_M,
    run: int | None = None,
) -> tuple[dict[str, Any], RunTrace]:
    """The paper's Fig. 6 data: ``driver``'s run ``run`` of ``setting`` (None: the fastest, :func:`fastest_run`)
    and the built-in AI's run with the same seed (the same opponents), each with the cars overtaken against time,
    the car- and wall-contact intervals, the passes that stood, the paths and the agent's heading and commands.
    Returns the record and the driver's trace (for :func:`write_analysis_outputs`' frames)."""
    if run is not None and not 0 <= run < runs:
        raise SettingError(f"--analysis-run must be in 0-{runs - 1} (of --runs {runs}), got {run}")
    rows, traces = run_setting(driver, track, car, setting, runs, seed, time_limit_s, lead_margin_m)
    best = fastest_run(rows) if run is None else run
    ai_rows, ai_traces = run_setting(BuiltinAI(), track, car, setting, 1, seed + best, time_limit_s, lead_margin_m)
    track = track if isinstance(track, Track) else load_track(track)
    return {
        "setting": setting,
        "separation_m": SETTINGS[setting],
        "runs": runs,
        "seed": seed,
        "run": best,
        "run_choice": "the fastest" if run is None else "asked",
        "track_name": track.name,
        "car": car if isinstance(car, str) else car.name,
        "trace_dt_s": TRACE_DT_S,
        "agent": {**_trace_record(name, rows[best], traces[best]), "driver": driver.identity},
        "reference": _trace_record("built-in AI", ai_rows[0], ai_traces[0]),
    }, traces[best]


def write_analysis_outputs(
    analysis: dict[str, Any],
    trace: RunTrace,
    track: Track,
    out: str | os.PathLike[str],
    frames: bool = True,
    car_length_m: float = 4.1,
    car_width_m: float = 1.7,
) -> dict[str, Any]:
    """``overtaking_analysis.json``; ``overtaking_timeline.png`` (cars overtaken against time, car collisions as
    long and wall collisions as short vertical lines, as the paper's Fig. 6); ``overtaking_paths.png`` (the agent's
    path coloured by speed 3 s either side of each pass, with the passed car's path); and, with ``frames``, the
    agent's driver view as it closes in on each pass (``overtake_<k>.png``, at the moment's approach sample)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, Any] = {"json": str(out / "overtaking_analysis.json")}
    write_json(out / "overtaking_analysis.json", sealed_record(analysis), indent=None)
    files["timeline"] = _save_figure(_timeline_figure(analysis), out / "overtaking_timeline.png")
    moments = analysis["agent"]["moments"]
    if moments:
        files["paths"] = _save_figure(_paths_figure(moments, trace, track), out / "overtaking_paths.png")
    if frames and moments:
        files["frames"] = _write_pass_views(moments, trace, track, out, car_length_m, car_width_m)
    return files


def _pyplot() -> Any:
    """matplotlib's pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save_figure(fig: Any, path: Path) -> str:
    """``fig`` as a PNG at ``path``, written atomically, then closed."""
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    _pyplot().close(fig)
    return str(path)


def _timeline_figure(analysis: dict[str, Any]) -> Any:
    """Cars overtaken against time, the agent's run above the built-in AI's, with their contacts; between them the
    agent's speed, pedal and heading against the track (how a run that stopped came to stop)."""
    fig, axes = _pyplot().subplots(3, 1, figsize=(8.0, 7.0))
    axes[1].sharex(axes[0])  # the AI's run has its own time axis: it may run to the limit
    for ax, record, color in zip(axes[::2], (analysis["agent"], analysis["reference"]), ("C0", "0.4"), strict=True):
        ax.step(record["time_s"], record["overtaken"], where="post", color=color)
        for start, _ in record["car_contacts"]:
            ax.axvline(start, ymin=0.0, ymax=1.0, color="r", linewidth=0.8)
        for start, _ in record["wall_contacts"]:
            ax.axvline(start, ymin=0.0, ymax=0.25, color="k", linewidth=0.8)
        ax.set_ylim(-0.2, 5.5)
        ax.set_ylabel("cars overtaken")
        run = record["run"]
        ax.set_title(
            f"{record['name']}: run {run['run']} (seed {run['seed']}), {run['overtaken']}/5 in "
            f"{run['travel_time_s']:.1f} s; car contact {run['car_contact_s']:.1f} s (long red), "
            f"wall {run['wall_contact_s']:.1f} s (short black)",
            fontsize=8,
        )
    agent, speed_ax = analysis["agent"], axes[1]
    speed_ax.plot(agent["time_s"], agent["speed_kmh"], color="C0", label="speed")
    speed_ax.set_ylabel("speed (km/h)")
    commands = speed_ax.twinx()
    commands.plot(agent["time_s"], agent["pedal"], color="C2", linewidth=0.8, label="pedal (throttle > 0)")
    commands.plot(agent["time_s"], agent["heading_error_rad"], color="C3", linewidth=0.8, label="heading - track (rad)")
    commands.set_ylim(-3.3, 3.3)
    commands.axhline(0.0, color="0.7", linewidth=0.5)
    commands.legend(loc="lower left", fontsize=7)
    speed_ax.set_title(f"{agent['name']}: speed (blue), pedal and heading against the track", fontsize=8)
    for ax in axes[1:]:
        ax.set_xlabel("time (s)")
    fig.suptitle(f"setting {analysis['setting']}, {analysis['track_name']}, {analysis['car']}", fontsize=9)
    fig.tight_layout()
    return fig


def _paths_figure(moments: list[dict[str, Any]], trace: RunTrace, track: Track) -> Any:
    """One panel per pass: the agent's path coloured by speed 3 s either side of it, the passed car's dashed."""
    import matplotlib

    fig, axes = _pyplot().subplots(1, len(moments), figsize=(3.2 * len(moments), 3.6), squeeze=False)
    half = round(3.0 / TRACE_DT_S)
    windows = [slice(max(m["sample"] - half, 0), m["sample"] + half + 1) for m in moments]
    kmh = 3.6 * trace.speed_mps
    norm = matplotlib.colors.Normalize(min(kmh[w].min() for w in windows), max(kmh[w].max() for w in windows))
    for ax, moment, window in zip(axes[0], moments, windows, strict=True):
        i, j = moment["sample"], moment["opponent"]
        xs, ys = trace.x_m[window], trace.y_m[window]
        for wall in (track.left_wall_xy_m, track.right_wall_xy_m):
            ax.plot(wall[:, 0], wall[:, 1], color="0.5", linewidth=0.8)
        ax.plot(xs[:, j], ys[:, j], color="0.2", linestyle="--", linewidth=1.0, label=f"opponent {j}")
        points = ax.scatter(xs[:, 0], ys[:, 0], c=kmh[window], cmap="viridis", norm=norm, s=6)
        ax.plot(trace.x_m[i, 0], trace.y_m[i, 0], "r+", markersize=10)
        centre = 0.5 * np.array([xs.min() + xs.max(), ys.min() + ys.max()])
        box = 0.5 * max(np.ptp(xs), np.ptp(ys)) + 15.0  # a square view: the path's extent and a margin, m
        ax.set_xlim(centre[0] - box, centre[0] + box)
        ax.set_ylim(centre[1] - box, centre[1] + box)
        ax.set_aspect("equal")
        ax.set_title(f"pass {j} at {moment['time_s']:.1f} s, {moment['speed_kmh']:.0f} km/h", fontsize=8)
        ax.tick_params(labelsize=6)
    fig.colorbar(points, ax=axes[0].tolist(), label="agent speed (km/h)", shrink=0.8)
    return fig


def _write_pass_views(
    moments: list[dict[str, Any]],
    trace: RunTrace,
    track: Track,
    out: Path,
    car_length_m: float,
    car_width_m: float,
) -> list[str]:
    """The agent's driver view at each pass's approach sample, ``overtake_<k>.png``; returns the paths."""
    from PIL import Image

    from vision_rl.render import Renderer

    samples = [m["approach_sample"] for m in moments]
    with Renderer(track, car_length_m=car_length_m, car_width_m=car_width_m) as renderer:
        views = [
            renderer.render(trace.x_m[i], trace.y_m[i], trace.yaw_rad[i], view_ids=np.array([0]))[0] for i in samples
        ]
    paths = []
    for moment, view in zip(moments, views, strict=True):
        path = out / f"overtake_{moment['opponent']}.png"
        atomic_write(path, lambda tmp, v=view: Image.fromarray(v).save(tmp, format="PNG"))
        paths.append(str(path))
    return paths


# ------------------------------------------------------------------------------------------------- Fig. 3


def _on_grid(curves: list[dict[str, Any]], axis: str, key: str = "overtaking_return") -> tuple[np.ndarray, np.ndarray]:
    """(grid, values (n_curves, len(grid))) with each curve interpolated on the union of their x values (NaN
    outside a curve's own range)."""
    xs = [np.array([r[axis] for r in c["records"] if r.get(key) is not None], dtype=np.float64) for c in curves]
    ys = [np.array([r[key] for r in c["records"] if r.get(key) is not None], dtype=np.float64) for c in curves]
    grid = np.unique(np.concatenate(xs)) if any(len(x) for x in xs) else np.zeros(0)
    values = np.full((len(curves), len(grid)), np.nan)
    for i, (x, y) in enumerate(zip(xs, ys, strict=True)):
        if len(x):
            inside = (grid >= x[0]) & (grid <= x[-1])
            values[i, inside] = np.interp(grid[inside], x, y)
    return grid, values


def learning_curves(
    runs: Sequence[str | os.PathLike[str]], curriculum_agent: str = "1", axis: str = "num_timesteps"
) -> dict[str, Any]:
    """Curriculum (``curriculum_agent``'s stages) and standard SAC over the run folders (one per training seed): mean
    and standard deviation of the overtaking return on a common axis (``num_timesteps`` or ``train_time_s``), the seeds
    behind each point and each seed's own curve, each seed's stage switches, and the steps at which the curriculum's
    mean first reaches standard SAC's final mean return, as a share of the steps at which standard SAC's own mean first
    reaches it (the issue's target: at most one half), and both read at several shares of that return (``reach``,
    :func:`reach_reading`). Only points that every seed with data reaches count for the target (a seed still
    training, or a curriculum whose stage 1 ended sooner, stops earlier); ``complete`` says every seed's agent and
    standard SAC have finished."""
    if axis not in ("num_timesteps", "train_time_s"):
        raise SettingError(f"axis must be num_timesteps or train_time_s, got {axis!r}")
    if not runs:
        raise SettingError("give at least one run folder of train-overtaking")
    result: dict[str, Any] = {"axis": axis, "runs": [str(r) for r in runs], "curriculum_agent": curriculum_agent}
    for label, agent in (("curriculum", curriculum_agent), ("standard", "standard")):
        curves = [learning_curve(r, agent) for r in runs]
        grid, values = _on_grid(curves, axis)
        with np.errstate(all="ignore"):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                mean, std = np.nanmean(values, axis=0), np.nanstd(values, axis=0)
        with_data = [i for i, c in enumerate(curves) if c["records"]]
        n_seeds = np.isfinite(values).sum(axis=0)
        result[label] = {
            "x": grid.tolist(),
            "mean": _nan_to_none(mean),
            "std": _nan_to_none(std),
            "n_seeds": n_seeds.tolist(),
            "seeds_with_data": len(with_data),
            "per_seed": [_nan_to_none(values[i]) for i in range(len(curves))],
            "stage_switches": [c["stage_switches"] for c in curves],
            "seeds_finished": sum(c["finished"] for c in curves),
        }

    standard = _common_mean(result["standard"])
    result["standard_final_return"] = standard[-1][1] if standard else None
    result["standard_final_x"] = standard[-1][0] if standard else None
    result["complete"] = all(result[k]["seeds_finished"] == len(runs) for k in ("standard", "curriculum"))
    if standard and axis == "num_timesteps":
        result["reach"] = reach_reading(result)
        # The target compares first arrivals: standard SAC may reach its final return well before its last step.
        target = result["reach"][-1]
        standard_reach, reach = target["standard"]["mean_x"], target["curriculum"]["mean_x"]
        result["standard_steps_to_final"] = standard_reach
        result["curriculum_steps_to_standard_final"] = reach
        result["share_of_standard_steps"] = None if reach is None else reach / standard_reach
    return result


#: The shares of standard SAC's final mean return at which Fig. 3 is read; the last, all of it, is the target's.
REACH_SHARES = (0.8, 0.9, 0.95, 1.0)


def _common_mean(data: dict[str, Any]) -> list[tuple[float, float]]:
    """A curve's mean where every seed with data has a point (a seed still training, or a curriculum whose stage 1
    ended sooner, stops earlier)."""
    return [
        (x, v)
        for x, v, n in zip(data["x"], data["mean"], data["n_seeds"], strict=True)
        if v is not None and n == data["seeds_with_data"]
    ]


def _first_reach(points: Iterable[tuple[float, float | None]], level: float) -> float | None:
    return next((x for x, v in points if v is not None and v >= level), None)


def reach_reading(curves: dict[str, Any], shares: Sequence[float] = REACH_SHARES) -> list[dict[str, Any]]:
    """Fig. 3 read at each share of standard SAC's final mean return: the steps at which each mean curve (where every
    seed has a point) and each seed's own curve first reach it (None: never)."""
    final = curves["standard_final_return"]
    reading = []
    for share in shares:
        level = share * final
        entry: dict[str, Any] = {"share": share, "level": level}
        for label in ("standard", "curriculum"):
            data = curves[label]
            entry[label] = {
                "mean_x": _first_reach(_common_mean(data), level),
                "per_seed_x": [_first_reach(zip(data["x"], v, strict=True), level) for v in data["per_seed"]],
            }
        reading.append(entry)
    return reading


def _nan_to_none(values: np.ndarray) -> list[float | None]:
    return [None if not np.isfinite(v) else float(v) for v in values]


def write_learning_curves(result: dict[str, Any], out: str | os.PathLike[str]) -> dict[str, str]:
    """``learning_curves_<axis>.json`` and ``.png``: mean lines with a +-1 std band, stage switches dashed red."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stem = f"learning_curves_{result['axis']}"
    json_path, png_path = out / f"{stem}.json", out / f"{stem}.png"
    write_json(json_path, sealed_record(result))
    fig, ax = _pyplot().subplots(figsize=(7.0, 4.0))
    for label, color in (("curriculum", "C0"), ("standard", "C1")):
        data = result[label]
        if not data["x"]:
            continue
        x = np.array(data["x"])
        mean = np.array([np.nan if v is None else v for v in data["mean"]])
        std = np.array([np.nan if v is None else v for v in data["std"]])
        name = f"curriculum SAC (agent {result['curriculum_agent']})" if label == "curriculum" else "standard SAC"
        every = np.array(data["n_seeds"]) == data["seeds_with_data"]
        # Solid where every seed has a point, dotted where some have stopped or are still training; each seed thin.
        ax.plot(x, np.where(every, mean, np.nan), color=color, label=f"{name}, mean of {data['seeds_with_data']} seeds")
        ax.plot(x, mean, color=color, linestyle=":", linewidth=1)
        ax.fill_between(x, mean - std, mean + std, where=every, color=color, alpha=0.25)
        for seed_values in data["per_seed"]:
            ax.plot(x, [np.nan if v is None else v for v in seed_values], color=color, linewidth=0.6, alpha=0.4)
    if result["axis"] == "num_timesteps":
        switches = [
            s["num_timesteps"]
            for seed in result["curriculum"]["stage_switches"]
            for s in seed
            if s["stage"] == "stage2" and s["num_timesteps"] is not None
        ]
        for i, step in enumerate(switches):
            ax.axvline(step, color="r", linestyle="--", linewidth=1, label="stage 1 -> 2" if i == 0 else None)
    ax.set_xlabel("environment steps" if result["axis"] == "num_timesteps" else "training time (s)")
    ax.set_ylabel("overtaking return (Eq. 2, stage-2 setting)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    _save_figure(fig, png_path)
    return {"json": str(json_path), "png": str(png_path)}


__all__ = [
    "METRICS",
    "SETTINGS",
    "TRACE_DT_S",
    "RunTrace",
    "SettingError",
    "analyse_overtaking",
    "contact_intervals",
    "evaluate_overtaking",
    "fastest_run",
    "learning_curves",
    "overtake_moments",
    "run_setting",
    "summarise_runs",
    "write_analysis_outputs",
    "write_learning_curves",
    "write_setting_outputs",
]
