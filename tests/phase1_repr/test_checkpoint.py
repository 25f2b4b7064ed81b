"""ckpt.pt: round trip through load_encoder, weights_only loading, clear errors for the wrong checkpoint."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.helpers.checkpoints import CFG, NAMES, trained_net, write_checkpoint
from vision_rl.files import file_sha256
from vision_rl.phase1_repr import EncoderCheckpointError, load_encoder, read_checkpoint
from vision_rl.phase1_repr.checkpoint import checkpoint_checksums


def test_round_trip_gives_the_same_embedding(tmp_path: Path) -> None:
    path = tmp_path / "ckpt.pt"
    net, mean, std = write_checkpoint(path)
    raw = torch.load(path, weights_only=True)  # the contract: plain tensors and containers only
    assert raw["encoder_config"]["input_height_px"] == 32 and raw["target_names"] == NAMES
    assert raw["encoder_config"]["pixel_mean"] == list(CFG.pixel_mean)
    frames = np.random.default_rng(3).integers(0, 256, (5, 32, 48, 3), dtype=np.uint8)
    enc = load_encoder(path, expected_input_hw_px=(32, 48), expected_target_names=NAMES)
    with torch.no_grad():
        rep_ref, pred_ref = net(torch.from_numpy(frames))
    rep = enc(frames)
    assert rep.shape == (5, 64) and rep.dtype == torch.float32 and not rep.requires_grad
    torch.testing.assert_close(rep, rep_ref, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(enc(torch.from_numpy(frames)), rep)  # tensor input too
    physical = enc.predict_targets(frames)
    torch.testing.assert_close(
        physical, pred_ref * torch.from_numpy(std) + torch.from_numpy(mean), rtol=1e-4, atol=1e-4
    )
    unfused = load_encoder(path, fuse=False)
    torch.testing.assert_close(unfused(frames), rep_ref)
    assert enc.metrics == {"val_loss": 0.5} and enc.rep_dim == 64 and enc.input_hw_px == (32, 48)
    assert len(file_sha256(path)) == 64


def test_frozen_module_stays_frozen(tmp_path: Path) -> None:
    path = tmp_path / "ckpt.pt"
    write_checkpoint(path)
    enc = load_encoder(path)
    enc.train()
    assert not enc.training and not enc.net.training
    assert all(not p.requires_grad for p in enc.parameters())
    with pytest.raises(ValueError, match=r"\(N, 32, 48, 3\)"):
        enc(np.zeros((1, 64, 96, 3), dtype=np.uint8))


def test_other_input_size_or_target_count_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "ckpt.pt"
    write_checkpoint(path)
    with pytest.raises(EncoderCheckpointError, match=r"32x48 \(HxW\) frames, expected 280x470"):
        load_encoder(path, expected_input_hw_px=(280, 470))
    small = tmp_path / "five.pt"
    write_checkpoint(small, dataclasses.replace(CFG, n_targets=5))
    with pytest.raises(EncoderCheckpointError, match="5 targets, expected 27"):
        load_encoder(small, expected_target_names=NAMES)
    with pytest.raises(EncoderCheckpointError, match="first difference"):
        load_encoder(path, expected_target_names=["x", *NAMES[1:]])


def test_corrupt_truncated_and_inconsistent_checkpoints(tmp_path: Path) -> None:
    path = tmp_path / "ckpt.pt"
    write_checkpoint(path)
    data = path.read_bytes()
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(data[: len(data) // 2])
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a checkpoint at all" * 10)
    for bad in (truncated, garbage, tmp_path / "absent.pt"):
        with pytest.raises(EncoderCheckpointError) as info:
            load_encoder(bad)
        assert str(bad) in str(info.value)
    ckpt = read_checkpoint(path)

    def save_signed(payload: dict, to: Path) -> None:  # inconsistent content under valid checksums
        torch.save({**payload, **checkpoint_checksums(payload)}, to)

    other = tmp_path / "other_weights.pt"
    save_signed({**ckpt, "state_dict": trained_net(dataclasses.replace(CFG, stem_channels=16)).state_dict()}, other)
    with pytest.raises(EncoderCheckpointError, match="do not fit"):
        load_encoder(other)
    names = tmp_path / "names.pt"
    save_signed({**ckpt, "target_names": NAMES[:20]}, names)
    with pytest.raises(EncoderCheckpointError, match="predicts 27 targets"):
        load_encoder(names)
    edited = tmp_path / "edited.pt"
    torch.save({**ckpt, "target_names": ["x", *NAMES[1:]]}, edited)  # an edit without new checksums
    with pytest.raises(EncoderCheckpointError, match="field 'target_names' does not match"):
        load_encoder(edited)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(EncoderCheckpointError, match="not a vision_rl encoder"):
        load_encoder(foreign)
