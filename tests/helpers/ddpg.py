"""Tiny DDPG runs: a train-ddpg config of a few dozen steps on small frames, and hand-made run folders for
compare-ddpg."""

from __future__ import annotations

import json

from vision_rl.config import from_flat
from vision_rl.ddpg.train import TrainDDPGConfig

#: Frames of the tiny runs, (height, width) px.
HW = (32, 48)
#: What every tiny run shares: 2 cars, a small buffer and batch, no evaluation and no checkpoint.
_TINY = dict(
    cars=2, buffer_size=200, learning_starts=8, batch_size=8, eval_every_steps=0, eval_seeds=0, checkpoint_every_steps=0
)


def ddpg_config(track: str, out, **kw) -> TrainDDPGConfig:
    """train-ddpg for 24 steps of 2 cars on ``track`` with one sampler actor, no evaluation and no checkpoint;
    ``kw`` overrides any option (flat names)."""
    base = dict(steps=24, image_hw_px=HW, workers=1, max_staleness=0, version_every_updates=2)
    return from_flat(TrainDDPGConfig, {**_TINY, "track": track, "out": str(out), **base, **kw})


def timed_ddpg_config(track: str, out, **kw) -> TrainDDPGConfig:
    """train-ddpg of the state actor, 2 cars sampled in-process, stopped by a training budget of 1.2 s (not by its
    steps), no evaluation and no checkpoint; ``kw`` overrides any option (flat names)."""
    base = dict(variant="state-actor", steps=10**7, train_minutes=0.02)
    return from_flat(TrainDDPGConfig, {**_TINY, "track": track, "out": str(out), **base, **kw})


def hand_made_run(
    folder,
    variant: str,
    minutes: float,
    episodes: list[tuple[float, float, int]],
    track="Catalunya",
    updates=600,
    cpu_minutes: float | None = None,
):
    """A run folder whose episodes end at (training minute, distance m, laps); ``cpu_minutes`` None: a run from
    before the CPU-time counter."""
    folder.mkdir()
    counters = {"train_time_s": 60.0 * minutes, "num_steps": 1000, "n_updates": updates}
    if cpu_minutes is not None:
        counters["train_cpu_s"] = 60.0 * cpu_minutes
    sidecar = {"hyper": {"variant": variant}, "env": {"track": track, "car": "gt3"}, "seed": 1, "counters": counters}
    (folder / "ddpg.json").write_text(json.dumps(sidecar))
    lines = [
        json.dumps(
            {"train_time_s": 60.0 * m, "distance_m": d, "laps": laps, "return": d, "steps": 10, "end": "crash 2"}
        )
        for m, d, laps in episodes
    ]
    (folder / "episodes.jsonl").write_text("".join(line + "\n" for line in lines))
    return folder
