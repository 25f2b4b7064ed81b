"""Shared fixtures of the Phase-2 tests: a small track, tiny encoders and a tiny trained policy (the private cache
is the root conftest's)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.conftest import renderer_available  # noqa: F401  (the Phase-2 tests import it from here)
from tests.sim.conftest import stadium_points
from vision_rl.sim.sensors import TARGET_NAMES, TARGET_UNITS

#: A stadium of 150 m straights and 60 m-radius bends, 6 m from the centre line to each wall: a 677 m lap, about 26 s
#: at the limit (the built-in AI completes laps here; on tighter stadiums it hit walls when this was written).
STADIUM = (150.0, 60.0, 6.0)


def stadium_csv(path: Path, straight_m: float, radius_m: float, half_width_m: float) -> Path:
    """Counter-clockwise stadium in the racetrack-database CSV format; s = 0 at the origin, on the bottom straight."""
    xy = stadium_points(straight_m, radius_m)
    rows = np.column_stack([xy, np.full(len(xy), half_width_m), np.full(len(xy), half_width_m)])
    np.savetxt(path, rows, delimiter=",", header="x_m,y_m,w_tr_right_m,w_tr_left_m")
    return path


@pytest.fixture(scope="session")
def small_track(tmp_path_factory) -> str:
    return str(stadium_csv(tmp_path_factory.mktemp("track") / "stadium.csv", *STADIUM))


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


@pytest.fixture(scope="session")
def tiny_encoders(tmp_path_factory) -> tuple[Path, Path]:
    """Two encoder checkpoints of one architecture with different weights (so different SHA-256)."""
    root = tmp_path_factory.mktemp("encoders")
    return write_tiny_encoder(root / "a" / "ckpt.pt", 0), write_tiny_encoder(root / "b" / "ckpt.pt", 1)


def tiny_train_config(track: str, out: Path, **kw):
    from vision_rl.phase2_rl.train import TrainPolicyConfig

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
    return TrainPolicyConfig(**{**base, **kw})


@pytest.fixture(scope="session")
def state_run(tmp_path_factory, small_track) -> tuple[Path, dict]:
    """A state policy trained for 200 steps (2 cars) on the small track: (run folder, train_policy result)."""
    from vision_rl.phase2_rl.train import train_policy

    out = tmp_path_factory.mktemp("runs") / "policy" / "tiny-state"
    return out, train_policy(tiny_train_config(small_track, out))


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
