"""`train-policy`: Phase 2, SAC on the 38-D state or on the frozen encoder's embedding plus 11 features."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from vision_rl.commands.choices import POLICY_CHOICES
from vision_rl.commands.output import emit, format_sampling, interrupt_on_sigterm, progress_bar, restore_sigterm, show
from vision_rl.phase2_rl.config import TrainPolicyConfig


@dataclass(frozen=True)
class TrainPolicyOptions(TrainPolicyConfig):
    """Train a SAC driving policy on the batched time-trial env (state, or vision with --encoder)."""

    option_choices: ClassVar[dict[str, tuple[str, ...]]] = POLICY_CHOICES

    progress: bool = True
    """Show a progress bar on stderr."""
    json: bool = False
    """Print the result as JSON."""


def format_train_policy(result: dict[str, Any]) -> list[str]:
    from vision_rl.evaluation.outputs import format_lap_time

    lines = [
        f"policy: {result['policy']} ({result['observation']}), {result['num_timesteps']} steps, "
        f"{result['n_updates']} updates, {result['train_time_s']:.0f} s of training"
        + (" (interrupted: saved, continue with --resume)" if result["interrupted"] else ""),
        f"metrics: {result['metrics_jsonl']}   TensorBoard: {result['tensorboard']}",
    ]
    lines += format_sampling(result.get("sampling"))
    last = result.get("last_eval")
    if last:
        lines.append(
            f"last evaluation at {last['num_timesteps']} steps: lap {format_lap_time(last['lap_time_s'])}, "
            f"{last['distance_m']:.0f} m driven"
        )
    return lines


def run_train_policy(opts: TrainPolicyOptions) -> int:
    """SIGTERM (a scheduler's stop, ``kill``) saves and exits like Ctrl-C: a job started in the background of a
    non-interactive shell ignores SIGINT. Exit code 130 after an interruption."""
    from vision_rl.evaluation.outputs import format_lap_time
    from vision_rl.phase2_rl.train import train_policy

    previous = interrupt_on_sigterm()
    try:
        with progress_bar(opts.steps, "step", "train-policy", enabled=opts.progress) as bar:

            def progress(steps: int, total: int, last_eval: dict[str, Any] | None) -> None:
                lap = {} if last_eval is None else {"lap": format_lap_time(last_eval["lap_time_s"])}
                show(bar, steps, total, **lap)

            result = train_policy(opts, progress)
    finally:
        restore_sigterm(previous)
    emit(result, opts.json, format_train_policy)
    return 130 if result["interrupted"] else 0
