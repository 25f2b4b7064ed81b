"""Tiny Phase-2 policies: small untrained encoder checkpoints, a train-policy config of a few hundred steps, and
held-out starts that lap in scripted times."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vision_rl.sim.sensors import TARGET_NAMES, TARGET_UNITS


def write_tiny_encoder(path: Path, seed: int) -> Path:
    """A small untrained encoder checkpoint (96 x 64 frames, 64-D embedding); the seed sets its weights."""
    import torch

    from vision_rl.phase1_repr import EncoderConfig, ReprNet, save_checkpoint

    torch.manual_seed(seed)
    cfg = EncoderConfig(
        input_height_px=64,
        input_width_px=96,
        stem_channels=8,
        stage_channels=(16, 32),
        stage_blocks=(1, 1),
        stage_strides=(2, 2),
    )
    net = ReprNet(cfg).eval()
    return save_checkpoint(
        path,
        net,
        target_names=TARGET_NAMES,
        target_units=TARGET_UNITS,
        target_mean=np.zeros(27),
        target_std=np.ones(27),
    )


def tiny_train_config(track: str, out: Path, **kw):
    """train-policy for 200 steps of 2 cars on ``track``, evaluated and saved every 100; ``kw`` overrides any field."""
    from vision_rl.config import from_flat
    from vision_rl.phase2_rl.config import TrainPolicyConfig

    base = dict(
        track=track,
        cars=2,
        steps=200,
        out=str(out),
        learning_starts=50,
        batch_size=32,
        buffer_size=5_000,
        eval_every_steps=100,
        eval_laps=1,
        checkpoint_every_steps=100,
        device="cpu",
    )
    return from_flat(TrainPolicyConfig, {**base, **kw})


def script_held_out_laps(
    monkeypatch, mean_laps_s: list[float | list[float | None] | None], clean: bool = True
) -> list[list[int]]:
    """Make train-policy's held-out starts (``--select-starts``) lap in the scripted mean times, one per evaluation
    (None: no start finished), 0.1 s either side of the mean, or in a list of each start's lap (None: that start did
    not finish); finished laps are ``clean`` or not; the protocol's own starts are timed as they drive. Returns the
    held-out start seeds of each call, as they are asked for."""
    from vision_rl.phase2_rl import train as train_module

    real, script, asked = train_module.time_laps, iter(mean_laps_s), []

    class Scripted:
        def __init__(self, seeds: list[int]) -> None:
            self.mean_s = next(script)
            self.seeds = seeds

        def summary(self) -> dict:
            laps = (
                self.mean_s
                if isinstance(self.mean_s, list)
                else [
                    None if self.mean_s is None else self.mean_s + (0.1 if i % 2 else -0.1)
                    for i in range(len(self.seeds))
                ]
            )
            return {
                "n_finished": sum(lap is not None for lap in laps),
                "seeds": [
                    {"lap_time_s": lap, "finished": lap is not None, "clean": clean and lap is not None} for lap in laps
                ],
            }

    def time_laps(driver, track, car, seeds, laps):
        seeds = list(seeds)
        if seeds[0] < train_module.SELECT_SEED_BASE:
            return real(driver, track, car, seeds, laps)
        asked.append(seeds)
        return Scripted(seeds)

    monkeypatch.setattr(train_module, "time_laps", time_laps)
    return asked
