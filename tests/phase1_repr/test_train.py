"""train-repr: the loss falls on a learnable synthetic capture; the command writes and resumes its run."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from tests.helpers.captures import TARGET_NAMES, frames_and_targets, write_synthetic_capture
from vision_rl.datasets import TargetStandardiser
from vision_rl.datasets.augment import target_mirror
from vision_rl.phase1_repr import load_encoder
from vision_rl.phase1_repr.config import TrainReprConfig
from vision_rl.phase1_repr.encoder import EncoderConfig
from vision_rl.phase1_repr.train import ReprModule, group_targets, regression_metrics, train_repr


def test_loss_falls_on_sixteen_frames(tmp_path: Path) -> None:
    written = write_synthetic_capture(tmp_path / "d.h5", n_laps=4, frames_per_lap=4)  # 16 frames
    images = torch.from_numpy(written["images"])
    std = TargetStandardiser.from_targets(written["targets"])
    targets = torch.from_numpy(std.transform(written["targets"]))
    torch.manual_seed(0)
    cfg = EncoderConfig(
        input_height_px=64,
        input_width_px=96,
        stem_channels=16,
        stage_channels=(32, 64),
        stage_blocks=(1, 1),
        stage_strides=(2, 2),
    )
    module = ReprModule(cfg.to_dict(), list(TARGET_NAMES), ["m"] * 27, std.mean.tolist(), std.std.tolist())
    opt = torch.optim.AdamW(module.parameters(), lr=3e-3)
    losses = []
    for _ in range(40):
        loss = F.mse_loss(module.predict_standardised(images), targets)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    module.eval()
    with torch.no_grad():
        final = F.mse_loss(module.predict_standardised(images), targets).item()
    assert losses[0] > 0.5  # standardised targets: an untrained net is far off
    assert final < 0.25 * losses[0], (losses[0], final)


def test_mirroring_flips_half_the_frames_with_their_targets() -> None:
    frames, true, _ = frames_and_targets(32, (64, 96), seed=0)
    images = torch.from_numpy(frames)
    std = TargetStandardiser.from_targets(true)
    targets = torch.from_numpy(std.transform(true))
    cfg = EncoderConfig(input_height_px=64, input_width_px=96)
    module = ReprModule(cfg.to_dict(), list(TARGET_NAMES), ["m"] * 27, std.mean.tolist(), std.std.tolist(), mirror=True)
    torch.manual_seed(0)
    out_images, out_targets = module.mirror_half(images, targets)
    physical = std.inverse(out_targets.numpy())
    perm, sign = target_mirror(TARGET_NAMES)
    flipped = [not torch.equal(a, b) for a, b in zip(out_images, images, strict=True)]
    assert 0 < sum(flipped) < len(images)
    for k, was_flipped in enumerate(flipped):
        if was_flipped:
            assert torch.equal(out_images[k], images[k].flip(1))  # (H, W, 3): W is dim 1
            np.testing.assert_allclose(physical[k], true[k, perm] * sign, rtol=1e-5, atol=1e-5)
        else:
            np.testing.assert_allclose(physical[k], true[k], rtol=1e-5, atol=1e-5)


def test_balanced_loss_counts_each_target_group_alike() -> None:
    cfg = EncoderConfig(input_height_px=64, input_width_px=96).to_dict()
    names, zeros, ones = list(TARGET_NAMES), [0.0] * 27, [1.0] * 27
    plain = ReprModule(cfg, names, ["m"] * 27, zeros, ones)
    balanced = ReprModule(cfg, names, ["m"] * 27, zeros, ones, balance_groups=True)
    heading = names.index("heading_angle_to_centre_line")
    error = torch.zeros(4, 27)
    error[:, heading] = 1.0  # a unit error on the heading angle only
    assert plain.loss(error, torch.zeros(4, 27)).item() == pytest.approx(1 / 27)
    # Five groups: the heading angle alone is a fifth of the loss.
    assert balanced.loss(error, torch.zeros(4, 27)).item() == pytest.approx(1 / 5)
    error[:] = 1.0
    assert balanced.loss(error, torch.zeros(4, 27)).item() == pytest.approx(1.0)  # weights average to 1
    edges = [i for i, n in enumerate(names) if n.startswith("edge_distance_")]
    error[:] = 0.0
    error[:, edges] = 1.0
    assert balanced.loss(error, torch.zeros(4, 27)).item() == pytest.approx(1 / 5)


def test_metrics_per_target_and_group() -> None:
    names = ["edge_distance_+00deg", "edge_distance_+15deg", "centre_line_offset", "curvature_40.0m_ahead", "x"]
    assert group_targets(names) == {
        "edge_distances": [0, 1],
        "centre_offset": [2],
        "curvature_ahead": [3],
        "other": [4],
    }
    true = np.array([[0.0, 1, 2, 3, 4], [2.0, 3, 4, 5, 4]])
    pred = true + np.array([[1.0, 0, 0, 0, 0], [1.0, 0, 1, 0, 0]])
    m = regression_metrics(pred, true, names)
    assert m["rmse"]["edge_distance_+00deg"] == pytest.approx(1.0)
    assert m["rmse"]["centre_line_offset"] == pytest.approx(np.sqrt(0.5))
    # edge group: squared errors 1 + 1 over squares about the means 1 + 1 + 1 + 1 -> R^2 = 0.5
    assert m["r2"]["edge_distances"] == pytest.approx(0.5)
    assert m["r2"]["curvature_ahead"] == pytest.approx(1.0)
    assert np.isnan(m["r2"]["other"])  # a constant target has no variance to explain


def test_train_repr_writes_run_and_resumes(tmp_path: Path) -> None:
    data = tmp_path / "d.h5"
    write_synthetic_capture(data, n_laps=4, frames_per_lap=4)
    out = tmp_path / "run"
    cfg = TrainReprConfig(
        data=str(data), epochs=2, batch_size=8, num_workers=0, out=str(out), width_mult=0.25, val_fraction=0.25
    )
    result = train_repr(cfg)
    assert result["n_train_frames"] == 12 and result["n_val_frames"] == 4  # one lap of four held out
    metrics = json.loads((out / "metrics.json").read_text())
    assert [e["epoch"] for e in metrics["epochs"]] == [0, 1]
    assert set(metrics["epochs"][0]["val_rmse"]) == set(TARGET_NAMES)
    assert set(metrics["epochs"][0]["val_r2"]) == {
        "edge_distances",
        "min_edge_distances",
        "centre_offset",
        "heading_angle",
        "curvature_ahead",
    }
    assert metrics["best"]["val_loss"] == min(e["val_loss"] for e in metrics["epochs"])
    assert metrics["units"]["centre_line_offset"] == "m"
    assert (out / "pred_vs_true.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert list((out / "tensorboard").glob("events.out.tfevents.*"))
    enc = load_encoder(result["ckpt"], expected_input_hw_px=(64, 96), expected_target_names=TARGET_NAMES)
    assert enc.metrics["epoch"] == metrics["best"]["epoch"]
    assert enc(np.zeros((2, 64, 96, 3), dtype=np.uint8)).shape == (2, 64)

    with pytest.raises(FileExistsError, match="--resume"):
        train_repr(cfg)
    heard = []
    train_repr(dataclasses.replace(cfg, epochs=3, resume=True), lambda done, total, _: heard.append((done, total)))
    assert heard and all(0 < done <= total for done, total in heard)  # the progress callback hears the resumed epoch
    metrics = json.loads((out / "metrics.json").read_text())
    assert [e["epoch"] for e in metrics["epochs"]] == [0, 1, 2]  # history kept, one more epoch run


def test_sigterm_in_training_stops_at_the_next_batch_edge_and_a_second_one_at_once():
    # Raising from inside the signal handler could leave a lock of the interrupted code taken (a hung teardown).
    from vision_rl.phase1_repr.train import _HoldToBatchEdge

    heard = []

    def handler(signum, frame):
        heard.append(signum)
        raise KeyboardInterrupt

    previous = signal.getsignal(signal.SIGTERM)
    stop = _HoldToBatchEdge(handler)
    try:
        stop.on_train_start(None, None)
        stop.on_train_batch_start(None, None, None, 0)  # no signal: the batch goes on
        os.kill(os.getpid(), signal.SIGTERM)  # inside a batch: only held
        assert heard == []
        with pytest.raises(KeyboardInterrupt):
            stop.on_train_batch_end(None, None, None, None, 0)
        assert heard == [signal.SIGTERM]
        os.kill(os.getpid(), signal.SIGTERM)
        with pytest.raises(KeyboardInterrupt):  # a stop that a batch does not reach: the second signal acts at once
            os.kill(os.getpid(), signal.SIGTERM)
        assert heard == [signal.SIGTERM, signal.SIGTERM]
    finally:
        stop.on_exception(None, None, None)
    assert signal.getsignal(signal.SIGTERM) is handler  # the fit's handler back; Lightning restores its own after
    signal.signal(signal.SIGTERM, previous)
