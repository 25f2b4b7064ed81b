"""`vision-rl curves`: experiments' learning curves on one figure; apart from `experiment` so that its ``--help``
loads no simulator."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from vision_rl.commands.options import comma_list, comma_paths
from vision_rl.commands.output import emit


@dataclass(frozen=True)
class CurvesOptions:
    """Experiments' learning curves on one figure (the vision paper's Fig. 3 right): the protocol lap against
    environment steps (and the paper's epochs; the epochs alone when the experiments' control steps differ) and
    training minutes, the mean over each experiment's seeds with its spread, the physical limit, the built-in AI,
    and when each mean first beats the AI."""

    files: str = ""
    """Comma-separated learning_curves.json of experiments (EXPERIMENT/learning_curves.json) (required)."""
    names: str = ""
    """Comma-separated names of those experiments in the legend."""
    track: str = "expressway"
    """Track of the experiments (for the limit and the AI's lap)."""
    car: str = "hatchback"
    """Car of the experiments."""
    out: str = "runs/curves"
    """Folder of compare.png and compare.json."""
    json: bool = False
    """Print the result as JSON."""


def format_curves(result: dict[str, Any]) -> list[str]:
    from vision_rl.evaluation.outputs import format_lap_time

    limit, ai = format_lap_time(result["limit_lap_time_s"]), format_lap_time(result["ai_lap_time_s"])
    lines = [f"limit {limit}, built-in AI {ai}"]
    for s in result["series"]:
        beat = s["time_to_beat_ai"]
        when = (
            "never"
            if beat is None
            else (
                f"{beat['num_timesteps']} steps ({beat['epochs']:g} epochs, "
                f"{beat['train_time_s'] / 60:.1f} min of training)"
            )
        )
        lines.append(
            f"  {s['name']}: {len(s['per_seed'])} seeds, last mean {format_lap_time(s['mean_lap_time_s'][-1])}"
            f" ({s['seeds_finished'][-1]} finished); beats the AI at {when}"
        )
    lines.append(f"files: {result['files']['png']}, {result['files']['json']}")
    return lines


def run_curves(opts: CurvesOptions) -> int:
    from vision_rl.evaluation.leaderboard import AI_SEEDS
    from vision_rl.evaluation.protocol import BuiltinAI, time_laps
    from vision_rl.phase2_rl.experiment import compare_learning_curves

    files = comma_paths(opts.files)
    if not files:
        raise ValueError("--files: give at least one learning_curves.json")
    names = comma_list(opts.names) or [str(f) for f in files]
    if len(names) != len(files):
        raise ValueError(f"--names gives {len(names)} names for {len(files)} curve files")
    ai = time_laps(BuiltinAI(), opts.track, opts.car, seeds=AI_SEEDS).summary()
    result = compare_learning_curves(files, names, ai["limit_lap_time_s"], ai["best_lap_time_s"], opts.out)
    emit(result, opts.json, format_curves)
    return 0
