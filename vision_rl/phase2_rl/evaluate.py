"""`evaluate`: the papers' time-trial protocol for a trained policy (vision paper, section 4 "Reinforcement Learning
using Representation", after Fuchs et al.): two consecutive laps, the second is the score, best over seeds.

Protocol as implemented here:

- **Rolling start** on the start/finish line (s = 0) on the racing line at the built-in AI's speed there
  (``start_skill`` x the limit profile), which starts the lap clock; ``--start standing`` starts at rest instead.
  The second lap's time is the score, so the start speed does not enter it (the reason the papers score lap 2).
- **Seeds** jitter the start: seed k offsets the car sideways by up to +-0.25 m and its start speed by up to
  +-2 % (uniform, ``numpy.random.default_rng(k)``); the policy acts deterministically (its mean action). All seeds
  drive at once as groups of one world (no contact between them); a given seed list gives the same laps every run.
- A car that gains less than 5 m in 20 s counts as stuck and is out; every run stops after ``time_limit_s``
  (default: 3 x the QSS limit lap time per lap).
- Figures: the scored lap of every seed, the best and the median over seeds (a seed without a scored lap counts as
  infinitely slow), wall-contact time on the scored lap and over the whole run.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vision_rl.config import doc
from vision_rl.envs.core import RacingConfig, RacingCore
from vision_rl.phase2_rl.artifact import MODEL_NAME, LoadedPolicy, load_policy

EVALUATION_FORMAT = "vision_rl.evaluation"
START_KINDS = ("rolling", "standing")


@dataclass(frozen=True)
class StartJitter:
    """Per-seed perturbation of the start (uniform in +-each value)."""

    lateral_m: float = 0.25
    """Sideways offset from the racing line, m."""
    speed_fraction: float = 0.02
    """Relative change of the rolling-start speed."""


@dataclass(frozen=True)
class StuckRule:
    """A car that gains less than ``min_progress_m`` over ``window_s`` is out of the run."""

    window_s: float = 20.0
    min_progress_m: float = 5.0


@dataclass
class ProtocolRun:
    """What happened in one protocol run: laps per seed and, when recorded, every control step's poses."""

    seeds: list[int]
    laps: int
    start: str
    start_speed_mps: np.ndarray
    lap_times_s: list[list[float]]
    wall_at_lap_end_s: list[list[float]]
    """Cumulative wall-contact time at the end of each completed lap, s."""
    wall_total_s: np.ndarray
    distance_m: np.ndarray
    stuck: np.ndarray
    time_limit_s: float
    time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """(T,) time of each recorded step, s; the arrays below are (T, n_seeds)."""
    x_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    y_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    yaw_rad: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    speed_mps: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    wall_contact: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))

    def score_s(self, i: int) -> float | None:
        """Seed i's scored lap (the last of ``laps``), or None if it did not complete it."""
        return self.lap_times_s[i][self.laps - 1] if len(self.lap_times_s[i]) >= self.laps else None

    def scored_window_s(self, i: int) -> tuple[float, float]:
        """Start and end time of seed i's scored lap (the whole run if it has none), s."""
        score = self.score_s(i)
        if score is None:
            return 0.0, math.inf
        start = float(sum(self.lap_times_s[i][: self.laps - 1]))
        return start, start + score

    def summary(self) -> dict[str, Any]:
        per_seed = []
        for i, seed in enumerate(self.seeds):
            score = self.score_s(i)
            marks = self.wall_at_lap_end_s[i][: self.laps]
            per_lap_wall = np.diff(np.concatenate([[0.0], marks])) if marks else np.zeros(0)
            per_seed.append(
                {
                    "seed": int(seed),
                    "lap_times_s": [float(t) for t in self.lap_times_s[i][: self.laps]],
                    "lap_time_s": None if score is None else float(score),
                    "wall_contact_s": None if score is None else float(per_lap_wall[self.laps - 1]),
                    "wall_contact_total_s": float(marks[-1] if score is not None else self.wall_total_s[i]),
                    "finished": score is not None,
                    "stuck": bool(self.stuck[i]),
                    "distance_m": float(self.distance_m[i]),
                }
            )
        scores = np.array([math.inf if s["lap_time_s"] is None else s["lap_time_s"] for s in per_seed])
        best = int(np.argmin(scores))
        median = float(np.median(scores))
        return {
            "protocol": {
                "laps": self.laps,
                "scored_lap": self.laps,
                "start": self.start,
                "start_speed_mps": [float(v) for v in self.start_speed_mps],
                "start_jitter": dataclasses.asdict(StartJitter()),
                "stuck_rule": dataclasses.asdict(StuckRule()),
                "time_limit_s": self.time_limit_s,
            },
            "seeds": per_seed,
            "n_seeds": len(per_seed),
            "n_finished": int(np.isfinite(scores).sum()),
            "best_seed": int(self.seeds[best]),
            "best_lap_time_s": float(scores[best]) if np.isfinite(scores[best]) else None,
            "median_lap_time_s": median if np.isfinite(median) else None,
            "wall_contact_s": per_seed[best]["wall_contact_s"],
        }


Controller = Callable[[RacingCore], tuple[np.ndarray, np.ndarray]]


def run_protocol(
    core: RacingCore,
    act: Controller,
    laps: int = 2,
    seeds: Sequence[int] = (0,),
    start: str = "rolling",
    time_limit_s: float = 0.0,
    record: bool = True,
    jitter: StartJitter | None = None,
    stuck: StuckRule | None = None,
) -> ProtocolRun:
    """Drive the core's egos (one per seed) from the start line for ``laps`` laps with ``act(core) -> (steer rad,
    omega)`` per control step. ``time_limit_s`` 0: 3 x the limit lap time per lap."""
    cfg = core.config
    n = cfg.n_groups
    if core.group_size != 1:
        raise ValueError("the time-trial protocol drives cars alone (scenario time_trial)")
    if len(seeds) != n:
        raise ValueError(f"the core has {n} egos but {len(seeds)} seeds were given")
    if laps < 1:
        raise ValueError(f"laps must be >= 1, got {laps}")
    if start not in START_KINDS:
        raise ValueError(f"start must be one of {START_KINDS}, got {start!r}")
    jitter = jitter or StartJitter()
    stuck_rule = stuck or StuckRule()
    u = np.array([np.random.default_rng(int(seed)).uniform(-1.0, 1.0, 2) for seed in seeds]).reshape(n, 2)
    s0 = np.zeros(n)
    lateral = core.line.lateral_at(s0) + u[:, 0] * jitter.lateral_m
    speed = np.zeros(n)
    if start == "rolling":
        ai_speed = cfg.start_skill * core.profile.speed_at(core.line.line_s_at(s0))
        speed = ai_speed * (1.0 + u[:, 1] * jitter.speed_fraction)
    core.world.reset(s_m=s0, lateral_m=lateral, speed_mps=speed, car_ids=core.ego_ids)
    limit_s = time_limit_s if time_limit_s > 0 else laps * 3.0 * core.profile.lap_time_s
    dt = cfg.control_dt_s
    window = max(1, round(stuck_rule.window_s / dt))
    ids = core.ego_ids
    done = np.zeros(n, dtype=bool)
    out = np.zeros(n, dtype=bool)
    wall_marks: list[list[float]] = [[] for _ in range(n)]
    last_u = core.world.state.unwrapped_s_m[ids].copy()
    rec: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "x", "y", "yaw", "v", "wall")}
    for step in range(math.ceil(limit_s / dt - 1e-9)):
        steer, omega = act(core)
        events = core.world.step(steer, omega)
        st = core.world.state
        veh = st.vehicle
        if record:
            rec["t"].append(st.time_s[ids[0]])
            rec["x"].append(veh.x_m[ids])
            rec["y"].append(veh.y_m[ids])
            rec["yaw"].append(veh.yaw_rad[ids])
            rec["v"].append(np.hypot(veh.vx_mps[ids], veh.vy_mps[ids]))
            rec["wall"].append(st.wall_contact[ids])
        for g in np.flatnonzero(events.lap_completed[ids]):
            wall_marks[g].append(float(st.wall_contact_time_s[ids[g]]))
        done |= st.laps_completed[ids] >= laps
        if (step + 1) % window == 0:
            u_now = st.unwrapped_s_m[ids]
            out |= ~done & (u_now - last_u < stuck_rule.min_progress_m)
            last_u = u_now.copy()
        if np.all(done | out):
            break
    st = core.world.state
    run = ProtocolRun(
        seeds=[int(s) for s in seeds],
        laps=laps,
        start=start,
        start_speed_mps=speed,
        lap_times_s=[list(core.world.lap_times_s[i]) for i in ids],
        wall_at_lap_end_s=wall_marks,
        wall_total_s=st.wall_contact_time_s[ids].copy(),
        distance_m=st.unwrapped_s_m[ids].copy(),
        stuck=out & ~done,
        time_limit_s=float(limit_s),
    )
    if record and rec["t"]:
        run.time_s = np.asarray(rec["t"])
        run.x_m, run.y_m, run.yaw_rad = (np.stack(rec[k]) for k in ("x", "y", "yaw"))
        run.speed_mps, run.wall_contact = np.stack(rec["v"]), np.stack(rec["wall"])
    return run


def policy_controller(policy: LoadedPolicy) -> Controller:
    def act(core: RacingCore) -> tuple[np.ndarray, np.ndarray]:
        a = policy.act(policy.observer(core))
        return a[:, 0], a[:, 1]

    return act


def protocol_core(config: RacingConfig, n_seeds: int) -> RacingCore:
    """A core for the protocol: ``n_seeds`` lone egos, no normalisation (the policy's observer applies its own)."""
    cfg = dataclasses.replace(config, n_groups=n_seeds, scenario="time_trial", normalize=False, stuck_timeout_s=None)
    return RacingCore(cfg, seed=0)


# ------------------------------------------------------------------------------------------------- outputs
def format_lap_time(seconds: float | None) -> str:
    """``m:ss.sss`` (the papers' table format), or ``DNF``."""
    if seconds is None or not math.isfinite(seconds):
        return "DNF"
    minutes, ms = divmod(round(seconds * 1000.0), 60_000)  # round first: 59.9996 s is 1:00.000, not 0:60.000
    return f"{minutes}:{ms / 1000.0:06.3f}"


def plot_trajectory(core: RacingCore, run: ProtocolRun, index: int, path: str | os.PathLike[str], title: str) -> Path:
    """The walls and seed ``index``'s scored lap (the whole run if it has none), coloured by speed; wall
    contacts marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    track = core.track
    t0, t1 = run.scored_window_s(index)
    keep = (run.time_s >= t0 - 1e-9) & (run.time_s <= t1 + 1e-9)
    x, y, v = run.x_m[keep, index], run.y_m[keep, index], run.speed_mps[keep, index] * 3.6
    wall = run.wall_contact[keep, index]
    fig, ax = plt.subplots(figsize=(8, 7))
    for wall_xy in (track.left_wall_xy_m, track.right_wall_xy_m):
        closed = np.vstack([wall_xy, wall_xy[:1]])
        ax.plot(closed[:, 0], closed[:, 1], color="0.5", lw=0.8)
    if len(x) > 1:
        points = np.stack([x, y], axis=1)
        segments = np.stack([points[:-1], points[1:]], axis=1)
        lines = LineCollection(segments, cmap="plasma", linewidths=2.0)
        lines.set_array(0.5 * (v[:-1] + v[1:]))
        ax.add_collection(lines)
        fig.colorbar(lines, ax=ax, label="speed (km/h)", shrink=0.8)
    if wall.any():
        ax.plot(x[wall], y[wall], "x", color="red", ms=5, label="wall contact")
        ax.legend(loc="upper right")
    ax.plot(*track.centre_xy_m[0], "ks", ms=6)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _video_writer(path: Path, fps: float):
    check_video_dependencies()
    import imageio.v2 as imageio

    # Even frame sizes suffice for yuv420p; the default block of 16 would rescale 470 x 280.
    return imageio.get_writer(str(path), fps=fps, codec="libx264", quality=7, macro_block_size=2)


class VideoDependencyError(ValueError):
    """The video writer's packages are missing; the message names what to install."""


def check_video_dependencies() -> None:
    """Raise :class:`VideoDependencyError` now rather than after a long evaluation."""
    try:
        import imageio  # noqa: F401
        import imageio_ffmpeg  # noqa: F401  (the ffmpeg binary the mp4 writer needs)
    except ImportError as exc:
        raise VideoDependencyError(
            "--video needs imageio with its ffmpeg plugin: pip install 'imageio[ffmpeg]' "
            f"(it bundles a static ffmpeg binary); {exc}"
        ) from exc


def write_video(
    core: RacingCore, run: ProtocolRun, index: int, path: str | os.PathLike[str], map_size_px: int = 120
) -> Path:
    """An mp4 of seed ``index``'s driver's view over the whole run, with a small track map (top right) and the
    speed and lap clock (bottom left). Frames come from the offscreen renderer, 20 poses per render pass."""
    from PIL import Image, ImageDraw

    from vision_rl.render import RenderConfig, Renderer

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cfg = core.config
    width, height = cfg.image_size_px
    track = core.track
    centre = track.centre_xy_m
    lo, hi = centre.min(axis=0), centre.max(axis=0)
    margin = 6
    scale = (map_size_px - 2 * margin) / float(max(hi - lo))

    def to_map(xy: np.ndarray) -> np.ndarray:
        px = (xy - lo) * scale + margin
        return np.stack([px[..., 0], map_size_px - px[..., 1]], axis=-1)

    base_map = Image.new("RGBA", (map_size_px, map_size_px), (0, 0, 0, 120))
    outline = [tuple(p) for p in to_map(np.vstack([centre, centre[:1]]))]
    ImageDraw.Draw(base_map).line(outline, fill=(255, 255, 255, 230), width=2)
    lap_starts = np.cumsum([0.0, *run.lap_times_s[index]])
    writer = _video_writer(path, fps=1.0 / cfg.control_dt_s)
    batch = 20
    renderer = Renderer(
        track, RenderConfig(width_px=width, height_px=height, max_views=batch),
        car_length_m=core.car.length_m, car_width_m=core.car.width_m,
    )  # fmt: skip
    try:
        for begin in range(0, len(run.time_s), batch):
            sl = slice(begin, min(begin + batch, len(run.time_s)))
            k = sl.stop - sl.start
            # Each pose is its own group, so the views of one pass do not see each other's cars.
            frames = renderer.render(
                run.x_m[sl, index], run.y_m[sl, index], run.yaw_rad[sl, index], groups=np.arange(k)
            )
            for j in range(k):
                t = float(run.time_s[sl.start + j])
                image = Image.fromarray(frames[j]).convert("RGBA")
                overlay = base_map.copy()
                cx, cy = to_map(np.array([run.x_m[sl.start + j, index], run.y_m[sl.start + j, index]]))
                ImageDraw.Draw(overlay).ellipse((cx - 3, cy - 3, cx + 3, cy + 3), fill=(255, 40, 40, 255))
                image.alpha_composite(overlay, (width - map_size_px - 4, 4))
                lap = int(np.searchsorted(lap_starts, t, side="right"))
                clock = t - lap_starts[min(lap, len(lap_starts)) - 1]
                text = f"{run.speed_mps[sl.start + j, index] * 3.6:5.0f} km/h  lap {lap}  {format_lap_time(clock)}"
                draw = ImageDraw.Draw(image)
                draw.rectangle((2, height - 16, 8 + 6 * len(text), height - 2), fill=(0, 0, 0, 140))
                draw.text((5, height - 15), text, fill=(255, 255, 255, 255))
                writer.append_data(np.asarray(image.convert("RGB")))
    finally:
        renderer.close()
        writer.close()
    return path


def evaluation_path(zip_path: Path) -> Path:
    """``evaluation.json`` beside a run's ``policy.zip``; ``<stem>.evaluation.json`` beside any other zip."""
    name = "evaluation.json" if zip_path.name == MODEL_NAME else f"{zip_path.stem}.evaluation.json"
    return zip_path.parent / name


def default_policy_name(zip_path: Path) -> str:
    if zip_path.name == MODEL_NAME:
        return zip_path.parent.name
    if zip_path.parent.name == "checkpoints":
        return f"{zip_path.parent.parent.name}/{zip_path.stem}"
    return zip_path.stem


def evaluate_policy(
    policy: str | os.PathLike[str] | LoadedPolicy,
    laps: int = 2,
    seeds: int = 3,
    seed: int = 0,
    start: str = "rolling",
    encoder: str = "",
    time_limit_s: float = 0.0,
    video: str = "",
    plot: str = "",
    name: str = "",
    device: str = "cpu",
    write: bool = True,
    encoder_runtime: str = "auto",
) -> dict[str, Any]:
    """Run the protocol for a policy (path or loaded); returns the summary and, with ``write``, stores it as
    ``evaluation.json`` beside the policy for the leaderboard."""
    if seeds < 1:
        raise ValueError(f"seeds must be >= 1, got {seeds}")
    if video:
        check_video_dependencies()
    loaded = policy if isinstance(policy, LoadedPolicy) else load_policy(policy, encoder, device, encoder_runtime)
    core = protocol_core(loaded.config, seeds)
    run = run_protocol(core, policy_controller(loaded), laps, list(range(seed, seed + seeds)), start, time_limit_s)
    result = run.summary()
    spec = loaded.spec
    result = {
        "format": EVALUATION_FORMAT,
        "name": name or default_policy_name(loaded.zip_path),
        "policy": str(loaded.zip_path),
        "observation": spec.observation,
        "track": core.config.track,
        "track_name": core.track.name,
        "track_geometry_hash": core.track.geometry_hash,
        "car": core.config.car,
        "encoder_sha256": spec.encoder_sha256,
        "num_timesteps": spec.num_timesteps,
        "train_time_s": spec.train_time_s,
        **result,
    }
    best = result["seeds"].index(next(s for s in result["seeds"] if s["seed"] == result["best_seed"]))
    title = (f"{result['name']}: lap {laps} {format_lap_time(result['best_lap_time_s'])} "
             f"(seed {result['best_seed']}, {core.track.name}, {core.config.car})")  # fmt: skip
    result["plot"] = str(plot_trajectory(core, run, best, plot, title)) if plot else None
    result["video"] = str(write_video(core, run, best, video)) if video else None
    if core.renderer is not None:
        core.renderer.close()
    if write:
        out = evaluation_path(loaded.zip_path)
        tmp = out.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps(result, indent=2))
        os.replace(tmp, out)
        result["evaluation_json"] = str(out)
    return result


# ------------------------------------------------------------------------------------------------- command
@dataclass
class EvaluateConfig:
    """Evaluate a policy: two consecutive laps from the start line, lap 2 scored, best and median over seeds."""

    policy: str = field(default="", metadata=doc("policy: a train-policy run folder or its policy.zip"))
    laps: int = field(default=2, metadata=doc("consecutive laps; the last one is the score (the papers: 2)"))
    seeds: int = field(default=3, metadata=doc("start seeds (small start jitter each), driven at once"))
    seed: int = field(default=0, metadata=doc("first seed"))
    start: str = field(default="rolling", metadata=doc("rolling (AI speed on the line) or standing start"))
    encoder: str = field(default="", metadata=doc("vision: encoder ckpt.pt (refused unless the trained one)"))
    time_limit_s: float = field(default=0.0, metadata=doc("stop a run after this long, s (0: 3 x limit lap per lap)"))
    video: str = field(default="", metadata=doc("write the best seed's driver's view with a track map (mp4)"))
    plot: str = field(default="", metadata=doc("write the best seed's trajectory coloured by speed (png)"))
    name: str = field(default="", metadata=doc("name on the leaderboard (default: the run folder's name)"))
    device: str = field(default="cpu", metadata=doc("torch device of the policy and encoder"))
    write: bool = field(default=True, metadata=doc("store evaluation.json beside the policy for the leaderboard"))
    encoder_runtime: str = field(default="auto", metadata=doc("vision: auto (ONNX Runtime on a CPU when installed, "
                                                              "2-6x faster than torch here), torch or onnxruntime"))
    json: bool = field(default=False, metadata=doc("print the result as JSON"))


def format_evaluation(result: dict[str, Any]) -> list[str]:
    lines = [
        f"{result['name']} ({result['observation']}, {result['track_name']}, {result['car']}): "
        f"best lap {result['protocol']['scored_lap']} {format_lap_time(result['best_lap_time_s'])}, "
        f"median {format_lap_time(result['median_lap_time_s'])}, "
        f"{result['n_finished']}/{result['n_seeds']} seeds finished ({result['protocol']['start']} start)",
    ]
    for s in result["seeds"]:
        laps = ", ".join(format_lap_time(t) for t in s["lap_times_s"]) or "-"
        wall = "-" if s["wall_contact_s"] is None else f"{s['wall_contact_s']:.1f} s"
        status = "" if s["finished"] else (" (stuck)" if s["stuck"] else " (time limit)")
        lines.append(f"  seed {s['seed']}: laps {laps}; wall contact on the scored lap {wall}; "
                     f"{s['distance_m']:.0f} m driven{status}")  # fmt: skip
    for key in ("plot", "video", "evaluation_json"):
        if result.get(key):
            lines.append(f"{key}: {result[key]}")
    return lines


def run_evaluate(cfg: EvaluateConfig) -> int:
    if not cfg.policy:
        raise ValueError("evaluate needs --policy: a train-policy run folder or its policy.zip")
    result = evaluate_policy(
        cfg.policy, cfg.laps, cfg.seeds, cfg.seed, cfg.start, cfg.encoder, cfg.time_limit_s, cfg.video, cfg.plot,
        cfg.name, cfg.device, cfg.write, cfg.encoder_runtime,
    )  # fmt: skip
    print(json.dumps(result, indent=2) if cfg.json else "\n".join(format_evaluation(result)))
    return 0
