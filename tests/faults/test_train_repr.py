"""Faults of train-repr and its checkpoint: bad targets stop it before training, bad sizes are one line, a crafted
Lightning checkpoint never runs, other data are not resumed on, ckpt.pt refuses damage and other data, a full disk
leaves no partial file."""

from __future__ import annotations

import errno
import json
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from tests.helpers.captures import TARGET_NAMES, write_synthetic_capture
from vision_rl.commands.main import main
from vision_rl.datasets import TargetValueError
from vision_rl.phase1_repr import EncoderCheckpointError, load_encoder
from vision_rl.phase1_repr.train import TrainReprConfig, train_repr

SMALL = {"epochs": 1, "batch_size": 8, "num_workers": 0, "width_mult": 0.25, "val_fraction": 0.25}


def small_capture(path: Path, seed: int = 0) -> Path:
    write_synthetic_capture(path, n_laps=4, frames_per_lap=4, image_hw_px=(32, 48), seed=seed)  # 16 frames
    return path


def rewrite_target(path: Path, frame: int, name: str, value: float) -> None:
    """Change one stored target through HDF5 (valid checksums) and drop the completion digest, as a capture
    program with a bug would have written it."""
    with h5py.File(path, "r+") as f:
        f["targets"][frame, list(TARGET_NAMES).index(name)] = value
        del f.attrs["content_sha256"]


@pytest.mark.parametrize(
    ("name", "value", "what"),
    [
        ("edge_distance_+00deg", np.nan, "a NaN edge distance"),
        ("centre_line_offset", np.inf, "an infinite centre-line offset"),
        ("min_distance_left_edge", 1e38, "a distance of 1e38 m"),
        ("heading_angle_to_centre_line", 40.0, "a heading angle of 40 rad"),
        ("curvature_40.0m_ahead", 50.0, "a curvature of 50 1/m (radius 2 cm)"),
    ],
)
def test_bad_targets_stop_training_before_it_starts(tmp_path: Path, name: str, value: float, what: str, fault):
    assert name in TARGET_NAMES
    data = small_capture(tmp_path / "d.h5")
    rewrite_target(data, 11, name, value)
    out = tmp_path / "run"
    with pytest.raises(TargetValueError) as info:
        train_repr(TrainReprConfig(data=str(data), out=str(out), **SMALL))
    message = str(info.value)
    assert str(data) in message and "frame 11" in message and repr(name) in message
    assert not (out / "ckpt.pt").exists() and not (out / "lightning").exists()  # nothing was trained
    fault.refused(f"train-repr on a capture with {what} in one frame", message)


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--epochs", "0"),
        ("--batch-size", "0"),
        ("--max-steps", "0"),
        ("--lr", "-0.1"),
        ("--val-fraction", "1.5"),
        ("--num-workers", "-1"),
        ("--width-mult", "0"),
    ],
)
def test_sizes_out_of_bounds_are_one_line(tmp_path: Path, option: str, value: str, capsys, fault) -> None:
    argv = ["train-repr", "--data", str(tmp_path / "none.h5"), "--out", str(tmp_path / "run"), option, value]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and option in err
    assert not (tmp_path / "run").exists()
    fault.refused(f"train-repr {option} {value}", err.split("error: ", 1)[1])


class _WritesMarker:
    """Unpickling this calls Path.touch: a file that runs code on load."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def test_a_crafted_lightning_checkpoint_never_runs(tmp_path: Path, capsys, fault) -> None:
    data = small_capture(tmp_path / "d.h5")
    out = tmp_path / "run"
    train_repr(TrainReprConfig(data=str(data), out=str(out), **SMALL))
    last = out / "lightning" / "last.ckpt"
    marker = tmp_path / "marker"
    crafted = torch.load(last, weights_only=True)
    crafted["callbacks"] = {"payload": _WritesMarker(marker)}
    torch.save(crafted, last)
    argv = [
        "train-repr",
        "--data",
        str(data),
        "--out",
        str(out),
        "--resume",
        "--epochs",
        "2",
        "--batch-size",
        "8",
        "--num-workers",
        "0",
        "--width-mult",
        "0.25",
        "--val-fraction",
        "0.25",
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert not marker.exists()
    assert "weights_only=False" not in err and "--force" in err and len(err.splitlines()) == 1
    fault.refused(
        "train-repr --resume on a last.ckpt crafted to write a file when unpickled", err.split("error: ", 1)[1]
    )


def test_resume_on_other_data_is_refused_naming_the_field(tmp_path: Path, fault) -> None:
    data = small_capture(tmp_path / "d.h5")
    out = tmp_path / "run"
    cfg = TrainReprConfig(data=str(data), out=str(out), **SMALL)
    train_repr(cfg)
    small_capture(data.with_name("other.h5"), seed=5).replace(data)  # same name, other frames
    with pytest.raises(ValueError, match=r"data\.train\[0\]\.content_sha256") as info:
        train_repr(TrainReprConfig(data=str(data), out=str(out), resume=True, **{**SMALL, "epochs": 2}))
    fault.refused("train-repr --resume after the capture file was replaced by another", str(info.value))


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("trained")
    data = small_capture(root / "d.h5")
    result = train_repr(TrainReprConfig(data=str(data), out=str(root / "run"), **SMALL))
    return Path(result["ckpt"]), json.loads((root / "run" / "data.json").read_text())


def test_the_checkpoint_records_its_data_and_refuses_other_data(trained, fault) -> None:
    ckpt, dataset = trained
    raw = torch.load(ckpt, weights_only=True)
    assert raw["dataset"] == dataset and raw["dataset"]["train"][0]["file"] == "d.h5"
    assert len(raw["dataset"]["train"][0]["content_sha256"]) == 64
    load_encoder(ckpt, expected_dataset=dataset)  # its own data: accepted
    other = json.loads(json.dumps(dataset))
    other["train"][0]["fingerprint_sha256"] = "0" * 64
    with pytest.raises(EncoderCheckpointError, match=r"dataset\.train\[0\]\.fingerprint_sha256") as info:
        load_encoder(ckpt, expected_dataset=other)
    fault.refused("an encoder loaded for data it was not trained on", str(info.value))


def test_a_damaged_checkpoint_tensor_is_named(trained, tmp_path: Path, fault) -> None:
    ckpt, _ = trained
    raw = torch.load(ckpt, weights_only=True)
    name = next(iter(raw["state_dict"]))
    raw["state_dict"][name] = raw["state_dict"][name].clone()
    raw["state_dict"][name].view(-1)[0] += 1e-3
    damaged = tmp_path / "ckpt.pt"
    torch.save(raw, damaged)
    with pytest.raises(EncoderCheckpointError, match=f"state_dict.{name}") as info:
        load_encoder(damaged)
    fault.refused("ckpt.pt with one weight changed", str(info.value))


def test_a_checkpoint_without_checksums_is_refused(trained, tmp_path: Path, fault) -> None:
    ckpt, _ = trained
    raw = torch.load(ckpt, weights_only=True)
    old = {k: v for k, v in raw.items() if k not in ("tensor_sha256", "field_sha256", "content_sha256", "dataset")}
    old["format_version"] = 1
    path = tmp_path / "old.pt"
    torch.save(old, path)
    with pytest.raises(EncoderCheckpointError, match="train it again") as info:
        load_encoder(path)
    fault.refused("ckpt.pt of format 1 (no checksums)", str(info.value))


def test_a_full_disk_while_saving_the_checkpoint_leaves_nothing(tmp_path: Path, monkeypatch, fault) -> None:
    data = small_capture(tmp_path / "d.h5")
    out = tmp_path / "run"
    real_save = torch.save

    def full_disk(obj, f, *args, **kwargs):
        if Path(str(f)).name.startswith(".ckpt.pt.") and str(f).endswith(".tmp"):  # the staged checkpoint
            Path(f).write_bytes(b"partial")  # as a write cut off by ENOSPC leaves it
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_save(obj, f, *args, **kwargs)

    monkeypatch.setattr(torch, "save", full_disk)
    with pytest.raises(OSError) as info:
        train_repr(TrainReprConfig(data=str(data), out=str(out), **SMALL))
    assert info.value.errno == errno.ENOSPC and str(out / "ckpt.pt") in str(info.value)
    assert not list(out.glob("*.tmp")) and not (out / "ckpt.pt").exists()
    fault.refused("a full disk while train-repr writes ckpt.pt", str(info.value))
