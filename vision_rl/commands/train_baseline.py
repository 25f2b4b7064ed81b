"""`train-baseline`: a Table III baseline of the overtaking paper (bc, gail, td3, sac, dreamer) on the single-car
race."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from vision_rl.commands.choices import BASELINE_ALGOS, SAC_PRESETS
from vision_rl.commands.output import emit, interrupt_on_sigterm, progress_bar, restore_sigterm, show
from vision_rl.overtaking.config import TrainBaselineConfig

#: ``--tiny``: tiny sizes (2 cars, a few hundred steps, short evaluations) where an option was left at its default.
TINY = dict(
    steps=300,
    cars=2,
    learning_starts=100,
    batch_size=32,
    buffer_size=5_000,
    eval_every_steps=200,
    eval_laps=1,
    eval_time_limit_s=30.0,
    checkpoint_every_steps=0,
    bc_max_epochs=20,
    gail_disc_every_steps=100,
)


@dataclass(frozen=True)
class TrainBaselineOptions(TrainBaselineConfig):
    """A Table III baseline on the single-car race (MLP 2 x 256, the 96-D observation); online ones (gail, td3, sac,
    dreamer) continue their run folder when run again."""

    option_choices: ClassVar[dict[str, tuple[str, ...]]] = {"algo": BASELINE_ALGOS, "preset": SAC_PRESETS}

    tiny: bool = False
    """Tiny sizes for options left at their defaults: seconds."""
    progress: bool = True
    """Show a progress bar on stderr."""
    json: bool = False
    """Print the result as JSON."""


def format_train_baseline(result: dict[str, Any]) -> list[str]:
    algo = result["algo"]
    lines = [
        f"{algo}: policy {result['out']} ({result['status']})"
        + (" (interrupted: saved; run the same command to continue)" if result.get("interrupted") else "")
    ]
    if algo == "bc" and result.get("fit"):
        fit = result["fit"]
        lines.append(
            f"  {fit['epochs']} epochs, {fit['updates']} updates, best held-out mse {fit['best_held_out_mse']:.5f} "
            f"(epoch {fit['best_epoch']}), {fit['stopped']}; {result.get('updates_per_s')} updates/s"
        )
    session = result.get("session")
    if session:
        lines.append(
            f"  this session: {session['steps']} steps, {session['updates']} updates in {session['wall_s']} s "
            f"({session['transitions_per_s']} transitions/s, {session['updates_per_s']} updates/s)"
        )
    if result.get("num_timesteps") is not None:
        lines.append(
            f"  total {result['num_timesteps']} of {result.get('steps')} steps, "
            f"{result.get('train_time_s')} s of training"
        )
    return lines


def run_train_baseline(opts: TrainBaselineOptions) -> int:
    """SIGTERM saves and exits like Ctrl-C (exit 130); the same command continues an online run."""
    from vision_rl.config import flat_values, from_flat
    from vision_rl.overtaking.baseline_run import check_config, total_steps
    from vision_rl.overtaking.baselines import train_baseline

    defaults = flat_values(TrainBaselineConfig())
    values = {k: v for k, v in flat_values(opts).items() if k in defaults}
    if opts.tiny:
        tiny = {k: v for k, v in TINY.items() if not (k == "steps" and values["algo"] == "bc")}  # bc: epoch cap
        values.update({k: v for k, v in tiny.items() if values[k] == defaults[k]})
    cfg = from_flat(TrainBaselineConfig, values)
    check_config(cfg)
    total = cfg.bc_max_epochs if cfg.algo == "bc" else total_steps(cfg)
    unit = "epoch" if cfg.algo == "bc" else "step"
    previous = interrupt_on_sigterm()
    try:
        with progress_bar(total, unit, f"train-baseline {cfg.algo}", enabled=opts.progress) as bar:

            def progress(phase: str, done: int, end: int, figures: dict[str, Any] | None) -> None:
                extra = {}
                if figures and figures.get("held_out_mse") is not None:
                    extra["held_out_mse"] = f"{figures['held_out_mse']:.4f}"
                if figures and figures.get("lap_time_s") is not None:
                    extra["lap_s"] = f"{figures['lap_time_s']:.1f}"
                show(bar, min(done, end), end, **extra)

            result = train_baseline(cfg, progress)
    finally:
        restore_sigterm(previous)
    emit(result, opts.json, format_train_baseline)
    return 130 if result.get("interrupted") else 0
