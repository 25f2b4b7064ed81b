"""vision-rl: simulate, capture, train and race cars that drive from what they see.

The design card's names (`capture`, `train-repr`, `train-policy`, `bench-latency`) are console-script aliases of
the same commands.

Every command is one config dataclass (a doc line per field) and one ``run(config) -> exit code`` function, both
imported only when that command runs, so `vision-rl tracks` never loads torch. Figures go to stdout as text, or
as one JSON object with ``--json``.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from vision_rl.config import add_config_arguments, config_from_args, doc


def emit(result: Any, as_json: bool, lines: Callable[[Any], list[str]] | None = None) -> None:
    """Print a command's figures: JSON, the given text lines, or ``key: value`` rows."""
    if as_json:
        print(json.dumps(result, indent=2))
    elif lines is not None:
        print("\n".join(lines(result)))
    else:
        for key, value in result.items():
            print(f"{key}: {value}")


# --------------------------------------------------------------------------------------- the simulator's commands


@dataclass
class TracksConfig:
    """List the built-in tracks with their length, narrowest width and number of corners."""

    json: bool = field(default=False, metadata=doc("print one JSON list instead of a table"))


def run_tracks(cfg: TracksConfig) -> int:
    from vision_rl.sim.track_library import BUILTIN_TRACKS, load_track, track_summary

    rows = [track_summary(load_track(name)) for name in BUILTIN_TRACKS]

    def table(rows: list[dict]) -> list[str]:
        out = [f"{'name':<14}{'length_m':>10}{'min_width_m':>13}{'corners':>9}"]
        out += [f"{r['name']:<14}{r['length_m']:>10.1f}{r['min_width_m']:>13.2f}{r['corners']:>9d}" for r in rows]
        return [*out, "Also: random:SEED (procedural), or the path of a racetrack-database CSV."]

    emit(rows, cfg.json, table)
    return 0


@dataclass
class BenchSimConfig:
    """Measure simulator throughput: physics, a full control step with sensors, and the lidar."""

    track: str = field(default="expressway", metadata=doc("track: built-in name, random:SEED or CSV path"))
    car: str = field(default="hatchback", metadata=doc("car preset"))
    repeats: int = field(default=7, metadata=doc("timed repeats; medians are reported"))
    json: bool = field(default=False, metadata=doc("print figures as JSON"))


def run_bench_sim(cfg: BenchSimConfig) -> int:
    from vision_rl.sim.bench import bench_sim

    emit(bench_sim(cfg.track, cfg.car, cfg.repeats), cfg.json)
    return 0


@dataclass
class BenchEnvConfig:
    """Measure environment throughput: 20 time-trial cars through the SB3 VecEnv, 20 overtaking groups of 6."""

    track: str = field(default="expressway", metadata=doc("track: built-in name, random:SEED or CSV path"))
    car: str = field(default="hatchback", metadata=doc("car preset"))
    repeats: int = field(default=5, metadata=doc("timed repeats of 100 steps; medians are reported"))
    json: bool = field(default=False, metadata=doc("print figures as JSON"))


def run_bench_env(cfg: BenchEnvConfig) -> int:
    from vision_rl.envs.bench import bench_env

    emit(bench_env(cfg.track, cfg.car, repeats=cfg.repeats), cfg.json)
    return 0


@dataclass
class BenchRenderConfig:
    """Measure the renderer (one view, 20 tiled views), capture end to end (physics, targets, render, write) and
    random read-back of the captured frames (2 DataLoader workers)."""

    track: str = field(default="expressway", metadata=doc("track: built-in name, random:SEED or CSV path"))
    repeats: int = field(default=5, metadata=doc("timed repeats; medians are reported"))
    capture_frames: int = field(default=2000, metadata=doc("frames of the end-to-end capture measurement (4 cars)"))
    json: bool = field(default=False, metadata=doc("print figures as JSON"))


def run_bench_render(cfg: BenchRenderConfig) -> int:
    import tempfile

    from vision_rl.capture.sim_capture import CaptureConfig, capture_sim
    from vision_rl.datasets.bench import bench_readback
    from vision_rl.render.bench import bench_render

    result = bench_render(n_views=20, repeats=cfg.repeats, track=cfg.track)
    with tempfile.TemporaryDirectory() as tmp:
        cap = capture_sim(CaptureConfig(out=f"{tmp}/bench.h5", track=cfg.track, cars=4, max_frames=cfg.capture_frames))
        result.update(capture_fps=cap["capture_fps"], bytes_per_frame=cap["bytes_per_frame"])
        # Random frames of that capture, read back the way training reads them (2 DataLoader worker processes).
        result.update(bench_readback(cap["out"], n_workers=2, repeats=cfg.repeats))
    result["targets"] = {
        "render_fps_470x280": ">= 300", "render_fps_batch20": ">= 400", "capture_fps": ">= 150",
        "bytes_per_frame": "<= 50,000 (15 GB for 300,000 frames)", "readback_fps": ">= 2,000 (2 worker processes)",
    }  # fmt: skip
    emit(result, cfg.json)
    return 0


# ------------------------------------------------------------------------------------------------------ registry


@dataclass(frozen=True)
class Command:
    help: str
    """One line for `vision-rl --help`."""
    module: str
    """Module holding the config class and the run function, imported only when the command runs."""
    config: str
    run: str


COMMANDS: dict[str, Command] = {
    "tracks": Command("list the built-in tracks", __name__, "TracksConfig", "run_tracks"),
    "limit": Command("physical-limit (QSS) lap time of a car", "vision_rl.sim.driving", "LimitConfig", "run_limit"),
    "drive": Command("drive the built-in AI: lap times, a plot", "vision_rl.sim.driving", "DriveConfig", "run_drive"),
    "bench sim": Command("simulator throughput", __name__, "BenchSimConfig", "run_bench_sim"),
    "bench env": Command("environment throughput", __name__, "BenchEnvConfig", "run_bench_env"),
    "bench render": Command("renderer and capture throughput", __name__, "BenchRenderConfig", "run_bench_render"),
    "train-repr": Command(
        "Phase 1: train the frame encoder on capture files", "vision_rl.phase1_repr.train", "TrainReprConfig",
        "run_train_repr",
    ),
    "bench-latency": Command(
        "Phase 1: encoder latency, batch 1", "vision_rl.phase1_repr.bench", "BenchLatencyConfig", "run_bench_latency"
    ),
    "pipeline": Command("the whole job (--quick: small)", "vision_rl.pipeline", "PipelineConfig", "run_pipeline"),
    "capture": Command(
        "record frames and targets to HDF5", "vision_rl.capture.sim_capture", "CaptureConfig", "run_capture"
    ),
    "train-policy": Command(
        "Phase 2: SAC on the state or the frozen embedding", "vision_rl.phase2_rl.train", "TrainPolicyConfig",
        "run_train_policy",
    ),
    "evaluate": Command(
        "Phase 2: the papers' lap protocol", "vision_rl.phase2_rl.evaluate", "EvaluateConfig", "run_evaluate"
    ),
    "leaderboard": Command(
        "Phase 2: AI, limit and policies (Table 1)", "vision_rl.phase2_rl.leaderboard", "LeaderboardConfig",
        "run_leaderboard",
    ),
}  # fmt: skip


def _run_command(name: str, argv: Sequence[str]) -> int:
    command = COMMANDS[name]
    prog = f"vision-rl {name}"
    module = importlib.import_module(command.module)
    config_cls = getattr(module, command.config)
    parser = argparse.ArgumentParser(prog=prog, description=config_cls.__doc__)
    add_config_arguments(parser, config_cls)
    args = parser.parse_args(list(argv))
    try:
        return int(getattr(module, command.run)(config_from_args(config_cls, args)))
    except (ValueError, OSError) as exc:  # bad input (a track file, a checkpoint, a dataset): say what, not a trace
        if os.environ.get("VISION_RL_DEBUG"):
            raise
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    for words in (2, 1):
        name = " ".join(argv[:words])
        if len(argv) >= words and name in COMMANDS:
            return _run_command(name, argv[words:])
    # A group's first word alone (`vision-rl bench --help`) lists the group's commands.
    group = {n: c for n, c in COMMANDS.items() if argv and n.startswith(f"{argv[0]} ")}
    shown = group or COMMANDS
    width = max(len(n) for n in shown)
    listing = "\n".join(f"  {n:<{width}}  {c.help}" for n, c in shown.items())
    usage = f"usage: vision-rl COMMAND [options]\n\n{__doc__.splitlines()[0]}\n\ncommands:\n{listing}\n"
    rest = argv[1:] if group else argv
    if not rest or rest[0] in ("-h", "--help"):
        print(usage)
        return 0 if rest else 2
    print(f"{usage}\nvision-rl: error: unknown command {' '.join(argv[:2])!r}", file=sys.stderr)
    return 2


def _alias(command: str) -> Callable[[], int]:
    def entry() -> int:
        return main([command, *sys.argv[1:]])

    return entry


capture_main = _alias("capture")
train_repr_main = _alias("train-repr")
train_policy_main = _alias("train-policy")
bench_latency_main = _alias("bench-latency")

if __name__ == "__main__":
    sys.exit(main())
