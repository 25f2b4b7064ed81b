"""`vision-rl tune`: an Optuna search over train-policy's recipe, each trial scored by the lap-time protocol."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, ClassVar

from vision_rl.commands.choices import POLICY_CHOICES
from vision_rl.commands.options import comma_list
from vision_rl.commands.output import emit, interrupt_on_sigterm, progress_bar, restore_sigterm, show
from vision_rl.phase2_rl.config import SEARCH_SPACE, TrainPolicyConfig


@dataclass(frozen=True)
class TuneOptions(TrainPolicyConfig):
    """Search train-policy's recipe with Optuna (TPE, median pruning): each trial trains a policy from the base
    recipe (the train-policy options given here) with the --space options drawn, and scores it by the protocol.
    Resumable: run it again with the same --out (or in a second terminal, to use the other core)."""

    option_choices: ClassVar[dict[str, tuple[str, ...]]] = POLICY_CHOICES

    out: str = "runs/tune/study"
    """Study folder: study.db (Optuna's SQLite), study.json and one train-policy run per trial."""
    trials: int = 20
    """Complete or pruned trials the study holds when the command ends."""
    space: str = ",".join(SEARCH_SPACE)
    """Comma-separated options to search (the base recipe's value for the others)."""
    eval_starts: int = 3
    """Protocol starts that score a trained policy."""
    wall_weight: float = 0.0
    """Seconds of score per second of wall contact in the scored laps (0: lap time alone; 1: search for clean laps)."""
    prune_after_steps: int = 100_000
    """Steps before the median pruner may stop a trial (0: never prune)."""
    sampler_seed: int = 0
    """Seed of the TPE sampler (--seed is the training seed of every trial)."""
    steps: int = 300_000
    """Environment steps of each trial."""
    progress: bool = True
    """Show a progress bar on stderr."""
    json: bool = False
    """Print the result as JSON."""


def format_tune(result: dict[str, Any]) -> list[str]:
    lines = [f"study {result['study_db']}: {len(result['trials'])} trials ({result['score']})"]
    for t in result["trials"]:
        score = "-" if t["score_s"] is None else f"{t['score_s']:.3f}"
        extra = f" lap {t['lap_time_s']:.3f} s, {t['finished']}" if t.get("lap_time_s") else ""
        lines.append(f"  #{t['number']:<3} {t['state']:<8} score {score:>9}{extra}  {t['params']}")
    if result["best"] is not None:
        lines.append(f"best: trial {result['best']['number']}, score {result['best']['score_s']:.3f} s")
        lines.append(
            f"  one training seed: confirm it with `vision-rl experiment --seeds 0,1,2 {result['best_flags']}`"
        )
    if result["interrupted"]:
        lines.append("interrupted: run the same command again to continue the study")
    return lines


def run_tune_command(opts: TuneOptions) -> int:
    from vision_rl.phase2_rl.tune import TuneConfig, check_tune, run_tune

    base = TrainPolicyConfig(**{f.name: getattr(opts, f.name) for f in fields(TrainPolicyConfig)})
    tune = TuneConfig(
        opts.trials,
        tuple(comma_list(opts.space)),
        opts.eval_starts,
        opts.wall_weight,
        opts.prune_after_steps,
        opts.sampler_seed,
    )
    check_tune(base, tune)
    previous = interrupt_on_sigterm()
    try:
        with progress_bar(opts.steps, "step", "trial", enabled=opts.progress) as bar:

            def started(number: int, params: dict[str, Any]) -> None:
                bar.set_description(f"trial {number}")
                show(bar, 0, opts.steps)

            def step(steps: int, total: int, last_eval: dict[str, Any] | None) -> None:
                show(bar, steps, total)

            result = run_tune(base, tune, opts.out, started, step)
    except KeyboardInterrupt:
        emit(
            {"interrupted": True, "resume": "run the same command again"},
            opts.json,
            lambda r: ["interrupted: the study and the finished trials are saved; run the same command again"],
        )
        return 130
    finally:
        restore_sigterm(previous)
    emit(result, opts.json, format_tune)
    return 0
