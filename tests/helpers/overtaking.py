"""Tiny overtaking runs: the car of the recorded demonstrations, and train-overtaking and train-baseline configs
of a few hundred steps."""

from __future__ import annotations

from pathlib import Path

from vision_rl.commands.train_overtaking import TINY
from vision_rl.config import from_flat
from vision_rl.overtaking.config import TrainBaselineConfig, TrainOvertakingConfig

#: The car of the small demonstrations (the root conftest's ``small_demos``).
DEMOS_CAR = "tt_cup"


def tiny_overtaking_config(track: str, out: Path, **kw) -> TrainOvertakingConfig:
    """train-overtaking at its ``--tiny`` sizes on ``track`` (stage 1 capped at 200 steps, 100 steps for each of
    stages 2 and 3 and 400 of standard SAC, 2 cars); ``kw`` overrides any field."""
    base = dict(TINY, track=track, out=str(out), device="cpu")
    return from_flat(TrainOvertakingConfig, {**base, **kw})


def tiny_baseline_config(track: str, demos, out, **kw) -> TrainBaselineConfig:
    """train-baseline for 300 steps of 2 cars on ``track`` from the demonstrations ``demos``; ``kw`` overrides any
    field."""
    base = dict(
        track=track,
        demos=str(demos),
        out=str(out),
        cars=2,
        steps=300,
        learning_starts=100,
        batch_size=32,
        buffer_size=5_000,
        eval_every_steps=200,
        eval_laps=1,
        eval_time_limit_s=20.0,
        checkpoint_every_steps=0,
        gail_disc_every_steps=100,
        bc_max_epochs=30,
        device="cpu",
    )
    return from_flat(TrainBaselineConfig, {**base, **kw})
