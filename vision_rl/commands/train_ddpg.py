"""`train-ddpg`: DDPG with an asymmetric actor-critic (pixel actor; critic on motion and the racing line) on
vision_rl/PixelRacing-v0, and its ablations (--variant symmetric, state-actor)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from vision_rl.commands.choices import DDPG_VARIANTS
from vision_rl.commands.output import emit, format_sampling, interrupt_on_sigterm, progress_bar, restore_sigterm, show
from vision_rl.ddpg.config import TRUNK_PRESETS, TrainDDPGConfig


@dataclass(frozen=True)
class TrainDDPGOptions(TrainDDPGConfig):
    """Train DDPG with an asymmetric actor-critic on PixelRacing-v0 (Catalunya, GT3 by default); evaluates through the
    lap-time protocol, saves without pickle, resumes, and saves on Ctrl-C or SIGTERM."""

    option_choices: ClassVar[dict[str, tuple[str, ...]]] = {"variant": DDPG_VARIANTS, "preset": TRUNK_PRESETS}

    progress: bool = True
    """Show a progress bar on stderr."""
    json: bool = False
    """Print the result as JSON."""


def _lap(seconds: float | None) -> str:
    from vision_rl.evaluation.outputs import format_lap_time

    return format_lap_time(seconds)


def format_train_ddpg(result: dict[str, Any]) -> list[str]:
    lines = [
        f"agent: {result['agent']} ({result['variant']}, {result['track']}, {result['car']}), {result['num_steps']} "
        f"steps, {result['n_updates']} updates, {result['episodes']} episodes, {result['train_time_s']:.0f} s of "
        f"training ({result['train_cpu_s']:.0f} s of CPU)"
        + (" (interrupted: saved, continue with --resume)" if result["interrupted"] else "")
        + (
            " (its --train-minutes are up: continue with --resume and more)"
            if result["stopped_by"] == "train_minutes"
            else ""
        ),
        f"metrics: {result['metrics_jsonl']}   episodes: {result['episodes_jsonl']}",
        *format_sampling(result.get("sampling")),
    ]
    last = result.get("last_eval")
    if last:
        lines.append(
            f"last evaluation at {last['num_steps']} steps: lap {_lap(last['lap_time_s'])}, "
            f"{last['distance_m']:.0f} m driven"
        )
    return lines


def run_train_ddpg(opts: TrainDDPGOptions) -> int:
    """SIGTERM saves and exits like Ctrl-C (a background job of a non-interactive shell ignores SIGINT). Exit code
    130 after an interruption."""
    from vision_rl.ddpg.train import train_ddpg

    previous = interrupt_on_sigterm()
    try:
        with progress_bar(opts.steps, "step", "train-ddpg", enabled=opts.progress) as bar:

            def progress(steps: int, total: int, last_eval: dict[str, Any] | None) -> None:
                lap = {} if last_eval is None else {"lap": _lap(last_eval["lap_time_s"])}
                show(bar, steps, total, **lap)

            result = train_ddpg(opts, progress)
    finally:
        restore_sigterm(previous)
    emit(result, opts.json, format_train_ddpg)
    return 130 if result["interrupted"] else 0
