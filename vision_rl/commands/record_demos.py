"""`record-demos`: demonstrations of the single-car race for the imitation baselines (BC, GAIL)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from vision_rl.commands.output import emit, progress_bar, show
from vision_rl.overtaking.config import RecordDemosConfig


@dataclass(frozen=True)
class RecordDemosOptions(RecordDemosConfig):
    """The built-in AI's demonstrations (observations, actions, rewards, episode starts) of the single-car race, in
    the environment's 10 Hz action space, to a file without pickle with a checksum and fingerprint."""

    progress: bool = True
    """Show a progress bar on stderr."""
    json: bool = False
    """Print the result as JSON."""


def format_record_demos(result: dict[str, Any]) -> list[str]:
    return [
        f"{result['out']}: {result['n_transitions']} transitions in {result['n_episodes']} episodes, "
        f"{result['laps_driven']:.2f} laps, mean reward {result['mean_reward']:.3f} per step"
        + (
            f" (the laps are those of the {result['n_recorded_now']} recorded now)"
            if result["n_recorded_now"] != result["n_transitions"]
            else ""
        ),
        f"demonstrator: {result['demonstrator']['driver']} (skill {result['demonstrator']['skill']})"
        + (f", labelling {result['driven_by']['learner']}'s driving" if "learner" in result["driven_by"] else ""),
        f"recorded in {result['record_time_s']:.1f} s ({result['transitions_per_s']:.0f} transitions/s)",
    ]


def run_record_demos(opts: RecordDemosOptions) -> int:
    import dataclasses

    from vision_rl.overtaking.demos import check_record_config, record_demos

    fields = {f.name for f in dataclasses.fields(RecordDemosConfig)}
    cfg = RecordDemosConfig(**{k: v for k, v in dataclasses.asdict(opts).items() if k in fields})
    check_record_config(cfg)
    learner = None
    if cfg.learner:  # DAgger: a Table III policy drives, the AI labels
        from vision_rl.overtaking.baseline_run import check_table_track
        from vision_rl.overtaking.baselines import load_baseline

        policy = load_baseline(cfg.learner)
        check_table_track(policy, cfg.track, cfg.car)
        learner = policy.act
    with progress_bar(None, "lap", "record-demos", enabled=opts.progress) as bar:
        result = record_demos(cfg, lambda done, total: show(bar, int(done), int(total) or None), learner)
    emit(result, opts.json, format_record_demos)
    return 0
