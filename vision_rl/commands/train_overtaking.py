"""`train-overtaking`: curriculum SAC (stages 1-3, Agents 1-3) or standard SAC on the overtaking task."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from vision_rl.commands.choices import OVERTAKING_AGENTS, SAC_PRESETS
from vision_rl.commands.output import emit, interrupt_on_sigterm, progress_bar, restore_sigterm, show
from vision_rl.overtaking.config import TrainOvertakingConfig

#: ``--tiny``: the whole chain at tiny sizes (2 cars, a few hundred steps per stage, short evaluations).
TINY = dict(
    cars=2,
    stage1_max_steps=200,
    stage2_steps=100,
    stage3_steps=100,
    standard_steps=400,
    learning_starts=50,
    batch_size=32,
    buffer_size=5_000,
    eval_every_steps=100,
    eval_laps=1,
    eval_time_limit_s=40.0,
    eval_episodes=2,
    eval_episode_s=5.0,
    checkpoint_every_steps=0,
)


@dataclass(frozen=True)
class TrainOvertakingOptions(TrainOvertakingConfig):
    """Curriculum SAC of the overtaking paper (Agents 1-3 share stages 1-2 in one --out) or standard SAC."""

    option_choices: ClassVar[dict[str, tuple[str, ...]]] = {"agent": OVERTAKING_AGENTS, "preset": SAC_PRESETS}

    tiny: bool = False
    """Tiny sizes (2 cars, a few hundred steps per stage) for options left at their defaults: seconds."""
    progress: bool = True
    """Show a progress bar on stderr."""
    json: bool = False
    """Print the result as JSON."""


def format_train_overtaking(result: dict[str, Any]) -> list[str]:
    lines = [
        f"agent {result['agent']}: policy {result['policy']}"
        + (" (interrupted: saved; run the same command to continue)" if result["interrupted"] else "")
    ]
    for b in result["stages"]:
        span = (
            f"steps {b['start_steps']}-{b['end_steps']}"
            if b["end_steps"] is not None
            else f"from step {b['start_steps']}"
            if b["start_steps"] is not None
            else ""
        )
        crit = ""
        if b.get("criterion"):
            met = b["criterion"]["met"]
            crit = ", criterion " + (f"met at {b['criterion']['met_at_steps']} steps" if met else "not met (step cap)")
        lines.append(
            f"  {b['stage']:<14} {b['status']:<12} {span}, c_w = c_c = {b['penalty_c']}, "
            f"buffer {b['buffer_size']}{crit}"
        )
    if result.get("ai_lap_time_s") is not None:
        lines.append(f"built-in AI lap (stage-1 reference): {result['ai_lap_time_s']:.2f} s")
    return lines


def run_train_overtaking(opts: TrainOvertakingOptions) -> int:
    """SIGTERM saves and exits like Ctrl-C (exit 130); the same command continues the run."""
    from vision_rl.config import flat_values, from_flat
    from vision_rl.overtaking.curriculum import check_config, stages_of, train_overtaking

    defaults = flat_values(TrainOvertakingConfig())
    values = {k: v for k, v in flat_values(opts).items() if k in defaults}
    if opts.tiny:  # tiny sizes where the option was left at its default: options given explicitly win
        values.update({k: v for k, v in TINY.items() if values[k] == defaults[k]})
    cfg = from_flat(TrainOvertakingConfig, values)
    check_config(cfg)
    total = sum(s.steps for s in stages_of(cfg))
    previous = interrupt_on_sigterm()
    try:
        with progress_bar(total, "step", f"train-overtaking {cfg.agent}", enabled=opts.progress) as bar:

            def progress(stage: str, steps: int, end: int, last_eval: dict[str, Any] | None) -> None:
                extra = {"stage": stage}
                if last_eval is not None and last_eval.get("overtaking_return") is not None:
                    extra["return"] = f"{last_eval['overtaking_return']:.0f}"
                show(bar, min(steps, total), total, **extra)

            result = train_overtaking(cfg, progress)
    finally:
        restore_sigterm(previous)
    emit(result, opts.json, format_train_overtaking)
    return 130 if result["interrupted"] else 0
