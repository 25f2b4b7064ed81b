"""`vision-rl experiment`: a train-policy recipe over several training seeds, with mean, spread and best."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, ClassVar

from vision_rl.commands.choices import POLICY_CHOICES
from vision_rl.commands.output import emit, interrupt_on_sigterm, progress_bar, restore_sigterm, show
from vision_rl.config import nested
from vision_rl.phase2_rl.config import TrainPolicyConfig
from vision_rl.training.schedules import EvaluationSchedule


@dataclass(frozen=True)
class ExperimentOptions(TrainPolicyConfig):
    """Train one SAC recipe once per training seed (each a train-policy run), time each with the lap-time protocol
    and report the mean and standard deviation over seeds and the best of them. Resumes unfinished seeds."""

    option_choices: ClassVar[dict[str, tuple[str, ...]]] = POLICY_CHOICES

    training_seeds: str = "0,1,2"
    """Training seeds, comma-separated (each trains its own policy)."""
    seeds_at_once: int = 1
    """Seeds trained side by side, each in its own process (about one core each with the cpu preset; 1: one after
    another)."""
    out: str = ""
    """Experiment folder (default runs/experiment/<kind>-<track>-<car>); one train-policy run per seed inside."""
    seed: int = 0
    """Unused here: --training-seeds gives the training seeds."""
    resume: bool = False
    """Unused here: an experiment always resumes its unfinished seeds."""
    force: bool = False
    """Unused here: an experiment folder is never overwritten (use another --out)."""
    evaluation: EvaluationSchedule = nested(
        EvaluationSchedule(seeds=3), prefix="eval_", help={"seeds": "Start seeds of each policy's evaluation."}
    )
    """The periodic evaluations; their seeds also time each seed's final policy."""
    name: str = ""
    """Name of the leaderboard row (default: the folder's name)."""
    progress: bool = True
    """Show a progress bar on stderr."""
    json: bool = False
    """Print the result as JSON."""


def format_experiment(result: dict[str, Any]) -> list[str]:
    from vision_rl.evaluation.outputs import format_lap_time

    def block(title: str, s: dict[str, Any], per_seed: list[dict[str, Any]]) -> list[str]:
        spread = "" if s["lap_time_std_s"] is None else f" +- {s['lap_time_std_s']:.2f} s"
        lines = [
            f"  {title}: lap 2 mean {format_lap_time(s['lap_time_mean_s'])}{spread} over "
            f"{s['n_training_seeds_finished']} seeds that finished; best {format_lap_time(s['best_lap_time_s'])};"
            f" starts finished {s['finished']}"
        ]
        for r in per_seed:
            wall = "-" if r["wall_contact_s"] is None else f"{r['wall_contact_s']:.2f} s"
            kept = ""
            if "kept_at_steps" in r:
                kept = (
                    ", no held-out evaluation clean: last weights"
                    if r["kept_at_steps"] is None
                    else f", kept at {r['kept_at_steps']} steps"
                )
            lines.append(
                f"    seed {r['seed']}: {format_lap_time(r['lap_time_s'])} ({r['finished']} finished, "
                f"wall contact {wall}{kept})"
            )
        return lines

    s = result["summary"]
    lines = [
        f"{result['name']}: {s['n_training_seeds']} training seeds of {result['observation']} SAC, "
        f"{result['steps']} steps each, on {result['track']} / {result['car']}"
    ]
    lines += block("last weights", s, result["per_seed"])
    if result.get("selected"):
        chosen = result["selected"]
        lines += block("weights chosen by the held-out starts", chosen["summary"], chosen["per_seed"])
    lines.append(f"  record: {result['experiment_json']}")
    return lines


def run_experiment_command(opts: ExperimentOptions) -> int:
    from vision_rl.phase2_rl.experiment import parse_seeds, run_experiment

    seeds = parse_seeds(opts.training_seeds)
    train = TrainPolicyConfig(**{f.name: getattr(opts, f.name) for f in fields(TrainPolicyConfig)})
    previous = interrupt_on_sigterm()
    try:
        with progress_bar(opts.steps * len(seeds), "step", "experiment", enabled=opts.progress) as bar:
            result = run_experiment(
                train,
                seeds,
                opts.out,
                opts.evaluation.seeds,
                opts.name,
                lambda done, total: show(bar, done, total),
                opts.seeds_at_once,
            )
    except KeyboardInterrupt:
        emit(
            {"interrupted": True, "resume": "run the same command again"},
            opts.json,
            lambda r: ["interrupted: the finished seeds and the current run are saved; run the same command again"],
        )
        return 130
    finally:
        restore_sigterm(previous)
    emit(result, opts.json, format_experiment)
    return 0
