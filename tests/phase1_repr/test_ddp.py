"""train-repr --devices 2 --strategy ddp: two CPU processes (gloo) train one epoch, each on half the batches, and
rank 0 alone writes a ckpt.pt of the one-device format."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from tests.helpers.captures import TARGET_NAMES, write_synthetic_capture
from vision_rl.phase1_repr import load_encoder
from vision_rl.phase1_repr.checkpoint import save_checkpoint
from vision_rl.phase1_repr.config import TrainReprConfig
from vision_rl.phase1_repr.encoder import EncoderConfig, ReprNet

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"devices": 2}, "--devices 2 needs --strategy ddp"),
        ({"strategy": "fsdp"}, "--strategy must be one of"),
        ({"devices": 0, "strategy": "ddp"}, "--devices must be >= 1"),
    ],
)
def test_device_options_are_checked(change, words):
    with pytest.raises(ValueError, match=words):
        TrainReprConfig(data="d.h5", **change)


def test_two_cpu_processes_train_one_epoch_and_rank_zero_writes_the_checkpoint(tmp_path):
    write_synthetic_capture(tmp_path / "d.h5", n_laps=8, frames_per_lap=4)  # 32 frames: 24 to train, 8 held out
    argv = [
        "train-repr",
        "--data",
        "d.h5",
        "--devices",
        "2",
        "--strategy",
        "ddp",
        "--device",
        "cpu",
        "--epochs",
        "1",
        "--batch-size",
        "4",
        "--num-workers",
        "0",
        "--width-mult",
        "0.25",
        "--val-fraction",
        "0.25",
        "--out",
        "run",
        "--json",
        "--no-progress",
    ]
    # Lightning starts the second process by running this command line again: run it as a command, not in pytest.
    proc = subprocess.run(
        [sys.executable, "-m", "vision_rl.commands.main", *argv],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout)  # one JSON document: the second process printed nothing
    assert result["devices"] == 2 and result["n_train_frames"] == 24 and result["n_val_frames"] == 8
    assert result["optimiser_steps"] == 3  # 24 frames / 2 processes / batches of 4: each process took half
    assert result["train_frames_per_s"] > 0
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert [e["epoch"] for e in metrics["epochs"]] == [0] and set(metrics["epochs"][0]["val_rmse"]) == set(TARGET_NAMES)
    assert not list((tmp_path / "run").rglob("*.tmp"))

    # The checkpoint has exactly the entries of one written by a one-device run, and loads as one.
    ckpt = tmp_path / "run" / "ckpt.pt"
    enc = load_encoder(ckpt, expected_input_hw_px=(64, 96), expected_target_names=TARGET_NAMES)
    assert enc.metrics["epoch"] == 0
    net = ReprNet(EncoderConfig(input_height_px=64, input_width_px=96, n_targets=27).scaled(0.25))
    reference = save_checkpoint(
        tmp_path / "reference.pt",
        net,
        target_names=TARGET_NAMES,
        target_units=["m"] * 27,
        target_mean=[0.0] * 27,
        target_std=[1.0] * 27,
        metrics={},
        dataset={},
    )
    ours, theirs = (torch.load(p, map_location="cpu", weights_only=True) for p in (ckpt, reference))
    assert set(ours) == set(theirs)
    assert set(ours["state_dict"]) == set(theirs["state_dict"])  # the bare network: no DDP "module." prefix
    assert ours["encoder_config"] == theirs["encoder_config"]
