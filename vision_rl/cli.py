"""`vision-rl <command>`: the umbrella command line. The design card's names (`capture`, `train-repr`,
`train-policy`, `bench-latency`) are console-script aliases of the same commands.

Every command is one config dataclass (a doc line per field, CleanRL style) turned into argparse options, and one
function that runs it. Figures go to stdout as text, or as one JSON object with `--json`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

# ---------------------------------------------------------------------------------------------------- config plumbing


def _help(text: str) -> dict[str, str]:
    return {"help": text}


def _add_config_arguments(parser: argparse.ArgumentParser, config_cls: type) -> None:
    for f in dataclasses.fields(config_cls):
        flag = "--" + f.name.replace("_", "-")
        help_text = f.metadata.get("help", "")
        default = f.default if f.default is not dataclasses.MISSING else None
        if f.type in ("bool", bool):
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=default, help=help_text)
            continue
        kind = {"int": int, "float": float, "str": str}.get(str(f.type).replace(" | None", ""), str)
        parser.add_argument(flag, type=kind, default=default, help=f"{help_text} (default: {default})")


def _config_from_args(config_cls: type, args: argparse.Namespace) -> Any:
    return config_cls(**{f.name: getattr(args, f.name) for f in dataclasses.fields(config_cls)})


def _emit(result: dict[str, Any], as_json: bool, lines: Callable[[dict[str, Any]], list[str]] | None = None) -> None:
    if as_json:
        print(json.dumps(result, indent=2))
    elif lines is not None:
        print("\n".join(lines(result)))
    else:
        for key, value in result.items():
            print(f"{key}: {value}")


# ------------------------------------------------------------------------------------------------------- commands


@dataclass
class TracksConfig:
    """List the built-in tracks with their length, narrowest width and number of corners."""

    json: bool = field(default=False, metadata=_help("print one JSON list instead of a table"))


def run_tracks(cfg: TracksConfig) -> int:
    from vision_rl.sim.track_library import BUILTIN_TRACKS, load_track, track_summary

    rows = [track_summary(load_track(name)) for name in BUILTIN_TRACKS]
    if cfg.json:
        print(json.dumps(rows, indent=2))
    else:
        print(f"{'name':<14}{'length_m':>10}{'min_width_m':>13}{'corners':>9}")
        for r in rows:
            print(f"{r['name']:<14}{r['length_m']:>10.1f}{r['min_width_m']:>13.2f}{r['corners']:>9d}")
        print("Also: random:SEED (procedural), or the path of a racetrack-database CSV.")
    return 0


@dataclass
class BenchSimConfig:
    """Measure simulator throughput: physics, a full control step with sensors, and the lidar."""

    track: str = field(default="expressway", metadata=_help("track: built-in name, random:SEED or CSV path"))
    car: str = field(default="hatchback", metadata=_help("car preset"))
    repeats: int = field(default=7, metadata=_help("timed repeats; medians are reported"))
    json: bool = field(default=False, metadata=_help("print figures as JSON"))


def run_bench_sim(cfg: BenchSimConfig) -> int:
    from vision_rl.sim.bench import bench_sim

    _emit(bench_sim(cfg.track, cfg.car, cfg.repeats), cfg.json)
    return 0


@dataclass
class PipelineConfig:
    """The whole two-phase job (capture, train-repr, train-policy, evaluate, leaderboard)."""

    quick: bool = field(default=False, metadata=_help("small sizes that finish in minutes on a laptop CPU"))
    track: str = field(default="expressway", metadata=_help("track: built-in name, random:SEED or CSV path"))
    car: str = field(default="hatchback", metadata=_help("car preset"))
    json: bool = field(default=False, metadata=_help("print figures as JSON"))


def run_pipeline(cfg: PipelineConfig) -> int:
    from vision_rl.sim.demo import simulator_demo

    # Until capture and training land, the main job demonstrates the simulator layer they build on.
    result = simulator_demo(cfg.track, cfg.car)
    result["note"] = (
        "capture, train-repr, train-policy and evaluate are not built yet; this run shows the simulator they build on"
    )
    _emit(result, cfg.json)
    return 0


# ------------------------------------------------------------------------------------------- commands not built yet

_MISSING_PARTS = {
    "capture": "the offscreen renderer and capture layer (vision_rl/render, vision_rl/capture)",
    "train-repr": "Phase 1 representation learning (vision_rl/datasets, vision_rl/phase1_repr)",
    "train-policy": "Phase 2 SAC training (vision_rl/envs, vision_rl/phase2_rl)",
    "evaluate": "Phase 2 policy evaluation (vision_rl/phase2_rl)",
    "leaderboard": "Phase 2 policy evaluation (vision_rl/phase2_rl)",
    "bench-latency": "the Phase 1 encoder (vision_rl/phase1_repr)",
}


def _not_built(name: str) -> Callable[[argparse.Namespace], int]:
    def run(_: argparse.Namespace) -> int:
        print(f"vision-rl {name}: not built yet: it needs {_MISSING_PARTS[name]}.", file=sys.stderr)
        return 2

    return run


# ------------------------------------------------------------------------------------------------------ dispatch

_COMMANDS: dict[str, tuple[type, Callable[[Any], int]]] = {
    "tracks": (TracksConfig, run_tracks),
    "pipeline": (PipelineConfig, run_pipeline),
}
_BENCH_COMMANDS: dict[str, tuple[type, Callable[[Any], int]]] = {
    "sim": (BenchSimConfig, run_bench_sim),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="vision-rl", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (config_cls, func) in _COMMANDS.items():
        p = sub.add_parser(name, help=config_cls.__doc__, description=config_cls.__doc__)
        _add_config_arguments(p, config_cls)
        p.set_defaults(_run=lambda a, c=config_cls, f=func: f(_config_from_args(c, a)))
    bench = sub.add_parser("bench", help="throughput benchmarks that print figures")
    bench_sub = bench.add_subparsers(dest="bench_command", required=True, metavar="WHAT")
    for name, (config_cls, func) in _BENCH_COMMANDS.items():
        p = bench_sub.add_parser(name, help=config_cls.__doc__, description=config_cls.__doc__)
        _add_config_arguments(p, config_cls)
        p.set_defaults(_run=lambda a, c=config_cls, f=func: f(_config_from_args(c, a)))
    for name, part in _MISSING_PARTS.items():
        p = sub.add_parser(name, help=f"(not built yet: needs {part})")
        p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(_run=_not_built(name))
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args._run(args))


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
