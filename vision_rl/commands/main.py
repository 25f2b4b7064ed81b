"""vision-rl: simulate, capture, train and race cars that drive from what they see.

`capture`, `train-repr`, `train-policy` and `bench-latency` are also console scripts of their own (aliases of the
same commands); `vision-rl bench-latency` is `vision-rl bench latency`, the name the design card gives it.
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import inspect
import os
import sys
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NoReturn

from vision_rl.commands.options import add_config_arguments, config_from_args


@dataclass(frozen=True)
class Command:
    help: str
    """One line for `vision-rl --help`."""
    module: str
    """Module holding the options class and the run function, imported only when the command runs."""
    options: str
    """Name of the options dataclass in ``module``."""
    run: str
    """Name of the ``run(options) -> exit code`` function in ``module``."""


_C = "vision_rl.commands"

COMMANDS: dict[str, Command] = {
    "tracks": Command(
        "the tracks (built-in and racetrack-database); --check drives them",
        f"{_C}.tracks",
        "TracksOptions",
        "run_tracks",
    ),
    "limit": Command("physical-limit (QSS) lap time of a car", f"{_C}.limit", "LimitOptions", "run_limit"),
    "drive": Command(
        "the built-in AI (or the straight driver) through the lap-time protocol",
        f"{_C}.drive",
        "DriveOptions",
        "run_drive",
    ),
    "bench sim": Command("simulator throughput", f"{_C}.bench", "BenchSimOptions", "run_bench_sim"),
    "bench env": Command("environment throughput", f"{_C}.bench", "BenchEnvOptions", "run_bench_env"),
    "bench ddpg": Command("DDPG updates/s per variant and layout", f"{_C}.bench", "BenchDDPGOptions", "run_bench_ddpg"),
    "bench render": Command("renderer and capture throughput", f"{_C}.bench", "BenchRenderOptions", "run_bench_render"),
    "bench train-repr": Command(
        "Phase-1 training step, frames/s per batch and precision",
        f"{_C}.bench_train_repr",
        "BenchTrainReprOptions",
        "run_bench_train_repr",
    ),
    "bench latency": Command(
        "Phase 1: encoder latency, batch 1 (also the console script bench-latency)",
        f"{_C}.bench_latency",
        "BenchLatencyOptions",
        "run_bench_latency",
    ),
    "bench scaling": Command(
        "capture, Phase-1 training and sampling, 1 vs 2 workers",
        f"{_C}.bench_scaling",
        "BenchScalingOptions",
        "run_bench_scaling",
    ),
    "capture": Command("record frames and targets to HDF5", f"{_C}.capture", "CaptureOptions", "run_capture"),
    "train-repr": Command(
        "Phase 1: train the frame encoder on capture files", f"{_C}.train_repr", "TrainReprOptions", "run_train_repr"
    ),
    "bench-latency": Command(
        "Phase 1: encoder latency, batch 1 (as bench latency)",
        f"{_C}.bench_latency",
        "BenchLatencyOptions",
        "run_bench_latency",
    ),
    "train-policy": Command(
        "Phase 2: SAC on the state or the frozen embedding",
        f"{_C}.train_policy",
        "TrainPolicyOptions",
        "run_train_policy",
    ),
    "experiment": Command(
        "Phase 2 over several training seeds: mean, spread, best",
        f"{_C}.experiment",
        "ExperimentOptions",
        "run_experiment_command",
    ),
    "curves": Command(
        "experiments' learning curves on one figure (Fig. 3 right)", f"{_C}.curves", "CurvesOptions", "run_curves"
    ),
    "tune": Command(
        "Phase 2: an Optuna search over train-policy's recipe", f"{_C}.tune", "TuneOptions", "run_tune_command"
    ),
    "evaluate": Command("a policy through the lap-time protocol", f"{_C}.evaluate", "EvaluateOptions", "run_evaluate"),
    "leaderboard": Command(
        "lap-time table: AI, straight driver, limit, policies (Table 1)",
        f"{_C}.evaluate",
        "LeaderboardOptions",
        "run_leaderboard",
    ),
    "convert-policy": Command(
        "a run of an older policy format to this one (SB3 zip to no pickle; sealed with content hashes)",
        f"{_C}.convert_policy",
        "ConvertPolicyOptions",
        "run_convert_policy",
    ),
    "train-overtaking": Command(
        "curriculum SAC (Agents 1-3) or standard SAC for overtaking",
        f"{_C}.train_overtaking",
        "TrainOvertakingOptions",
        "run_train_overtaking",
    ),
    "evaluate-overtaking": Command(
        "settings A/B of the overtaking paper (or --curves: Fig. 3)",
        f"{_C}.evaluate_overtaking",
        "EvaluateOvertakingOptions",
        "run_evaluate_overtaking",
    ),
    "record-demos": Command(
        "the built-in AI's demonstrations of the single-car race",
        f"{_C}.record_demos",
        "RecordDemosOptions",
        "run_record_demos",
    ),
    "train-baseline": Command(
        "a Table III baseline (bc, gail, td3, sac, dreamer) on the single-car race",
        f"{_C}.train_baseline",
        "TrainBaselineOptions",
        "run_train_baseline",
    ),
    "table3": Command(
        "Table III: AI and baselines on the protocol, beside the paper", f"{_C}.table3", "Table3Options", "run_table3"
    ),
    "dreamer-model": Command(
        "a Dreamer run's world-model prediction error on held-out laps",
        f"{_C}.dreamer_model",
        "DreamerModelOptions",
        "run_dreamer_model",
    ),
    "play": Command(
        "drive the protocol's laps yourself (keyboard or gamepad)", f"{_C}.play", "PlayOptions", "run_play"
    ),
    "pipeline": Command("the whole job (--quick: small)", f"{_C}.pipeline", "PipelineOptions", "run_pipeline"),
    "train-ddpg": Command(
        "DDPG, asymmetric actor-critic from pixels", f"{_C}.train_ddpg", "TrainDDPGOptions", "run_train_ddpg"
    ),
    "evaluate-ddpg": Command(
        "a DDPG agent through the lap-time protocol", f"{_C}.evaluate_ddpg", "EvaluateDDPGOptions", "run_evaluate_ddpg"
    ),
    "compare-ddpg": Command(
        "DDPG runs at equal training time (distance per episode)",
        f"{_C}.evaluate_ddpg",
        "CompareDDPGOptions",
        "run_compare_ddpg",
    ),
    "diagnose-ddpg": Command(
        "DDPG agents: a diverged critic, saturated keys",
        f"{_C}.evaluate_ddpg",
        "DiagnoseDDPGOptions",
        "run_diagnose_ddpg",
    ),
    "ddpg-reference": Command(
        "our DDPG beside SB3's DDPG and TD3 on a Gymnasium task",
        f"{_C}.ddpg_reference",
        "DDPGReferenceOptions",
        "run_ddpg_reference",
    ),
    "report": Command(
        "the README's and the docs' result tables from the records (--check: fail if stale)",
        f"{_C}.report",
        "ReportOptions",
        "run_report",
    ),
}


def _debug() -> bool:
    return os.environ.get("VISION_RL_DEBUG", "") not in ("", "0")


class _Parser(argparse.ArgumentParser):
    """argparse's refusals in one line, as the commands' own (``--help`` still shows the usage)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def parse_command(name: str, argv: Sequence[str]) -> Any:
    """The command's options from ``argv``, checked and not yet run: argparse exits (2) on a malformed option, a
    ValueError names a value out of range or over the memory budget."""
    command = COMMANDS[name]
    options_cls = getattr(importlib.import_module(command.module), command.options)
    parser = _Parser(prog=f"vision-rl {name}", description=inspect.getdoc(options_cls))
    add_config_arguments(parser, options_cls)
    args = parser.parse_args(list(argv))
    return config_from_args(options_cls, args)


def _thread_error_in_one_line(prog: str) -> Callable[[threading.ExceptHookArgs], None]:
    """An error in a thread of a library (TensorBoard's writer on a full disk) in one line, not its traceback: the
    command's own error or exit code says the rest."""

    def hook(args: threading.ExceptHookArgs) -> None:
        where = args.thread.name if args.thread is not None else "a thread"
        print(f"{prog}: error in {where}: {args.exc_type.__name__}: {args.exc_value}", file=sys.stderr)

    return hook


def run_command(name: str, argv: Sequence[str]) -> int:
    """Parse ``argv`` into the command's options and run it; bad input is a one-line error (exit 2)."""
    command = COMMANDS[name]
    prog = f"vision-rl {name}"
    previous_hook = threading.excepthook
    if not _debug():
        threading.excepthook = _thread_error_in_one_line(prog)
    try:
        options = parse_command(name, argv)
        return int(getattr(importlib.import_module(command.module), command.run)(options))
    except (ValueError, OSError) as exc:  # bad input (a track file, a checkpoint, a dataset): say what, not a trace
        if _debug():
            raise
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM where the command had nothing of its own to save (its set-up)
        if _debug():
            raise
        print(f"{prog}: stopped by Ctrl-C or SIGTERM; the files it wrote are whole or absent", file=sys.stderr)
        return 130
    finally:
        threading.excepthook = previous_hook


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--version"]:
        from vision_rl.files import package_version

        print(f"vision-rl {package_version()}")
        return 0
    for words in (2, 1):
        name = " ".join(argv[:words])
        if len(argv) >= words and name in COMMANDS:
            return run_command(name, argv[words:])
    # A group's first word alone (`vision-rl bench --help`) lists the group's commands.
    group = {n: c for n, c in COMMANDS.items() if argv and n.startswith(f"{argv[0]} ")}
    shown = group or COMMANDS
    width = max(len(n) for n in shown)
    listing = "\n".join(f"  {n:<{width}}  {c.help}" for n, c in shown.items())
    usage = f"usage: vision-rl COMMAND [options] | --version\n\n{__doc__.splitlines()[0]}\n\ncommands:\n{listing}\n"
    rest = argv[1:] if group else argv
    if not rest or rest[0] in ("-h", "--help"):
        print(usage)
        return 0 if rest else 2
    unknown = " ".join(argv[:2]) if group else argv[0]
    print(f"vision-rl: error: unknown command {unknown!r}{_suggestion(unknown)}", file=sys.stderr)
    return 2


def _suggestion(word: str) -> str:
    """``"; did you mean 'train-policy'?"`` for a near miss of a command's name, else a pointer to the listing."""
    close = difflib.get_close_matches(word, list(COMMANDS), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else " (vision-rl --help lists the commands)"


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
