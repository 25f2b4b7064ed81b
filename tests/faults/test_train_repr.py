"""Faults of train-repr and its checkpoint: bad targets stop it before training, bad sizes are one line, a crafted
Lightning checkpoint never runs, other data are not resumed on, ckpt.pt refuses damage and other data, a full disk
leaves no partial file and keeps the previous last.ckpt, a run killed (SIGTERM, SIGKILL) after an epoch resumes to
the weights of an uninterrupted run."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.helpers.captures import TARGET_NAMES, write_synthetic_capture
from tests.helpers.processes import kill_and_read
from vision_rl.capture.h5format import REQUIRED_ATTRS, CaptureWriter, open_capture
from vision_rl.commands.main import main
from vision_rl.datasets import TargetValueError
from vision_rl.phase1_repr import EncoderCheckpointError, load_encoder
from vision_rl.phase1_repr.config import TrainReprConfig
from vision_rl.phase1_repr.train import train_repr

SMALL = {"epochs": 1, "batch_size": 8, "num_workers": 0, "width_mult": 0.25, "val_fraction": 0.25}
REPO = Path(__file__).resolve().parents[2]


def small_capture(path: Path, seed: int = 0) -> Path:
    write_synthetic_capture(path, n_laps=4, frames_per_lap=4, image_hw_px=(32, 48), seed=seed)  # 16 frames
    return path


def rewrite_target(path: Path, frame: int, name: str, value: float) -> None:
    """Write the capture again with one target changed, through the writer (valid checksums and hashes), as a
    capture program with a bug would have written it (an edit through HDF5 is refused before the targets are
    read: the file's hashes no longer match)."""
    with open_capture(path) as cap:
        columns = [cap.read_images(np.arange(cap.n_frames)), cap.targets, cap.dedicated, cap.pose, cap.time_s]
        columns += [cap.lap, cap.car_id]
        names = (cap.target_names, cap.target_units, cap.dedicated_names, cap.dedicated_units)
        attrs = {key: cap.attrs[key] for key in REQUIRED_ATTRS}
    columns[1][frame, list(TARGET_NAMES).index(name)] = value
    writer = CaptureWriter(
        path,
        image_hw_px=columns[0].shape[1:3],
        target_names=names[0],
        target_units=names[1],
        dedicated_names=names[2],
        dedicated_units=names[3],
        attrs=attrs,
        force=True,
    )
    writer.append(*columns)
    writer.close(complete=True)


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
    try:
        code = main(argv)
    except SystemExit as stop:  # argparse refuses a negative number itself, in one line too
        code = stop.code
    assert code == 2
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


# The command line of the runs killed below: 8 epochs of 3 steps on 12 frames, the shift and the photometric
# augmentation on, so that a resume that drew other random numbers than the run would have drawn ends elsewhere,
# and a loader worker kept from epoch to epoch (as by default), whose start a resume repeats.
KILLED_ARGV = [
    *("train-repr", "--data", "d.h5", "--epochs", "8", "--batch-size", "4", "--num-workers", "1"),
    *("--width-mult", "0.25", "--val-fraction", "0.25", "--shift-px", "2", "--seed", "3", "--no-progress", "--json"),
]


def _start(tmp_path: Path, out: str, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "vision_rl.commands.main", *KILLED_ARGV, "--out", out, *extra],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "PYTHONFAULTHANDLER": "1"},
        start_new_session=True,
    )


def _communicate(proc: subprocess.Popen, timeout_s: float) -> tuple[str, str]:
    """The run's stdout and stderr once it ends; a run still going after ``timeout_s`` fails the test with the
    stacks of its processes (SIGABRT makes faulthandler print them)."""
    try:
        return proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGABRT)
        _, stderr = proc.communicate(timeout=30)
        pytest.fail(f"the run did not end within {timeout_s:.0f} s; its stacks:\n{stderr[-6000:]}")


def _saved_epochs(last_ckpt: Path) -> int:
    """Finished epochs in a last.ckpt (0 while there is none); the file is only ever replaced whole."""
    if not last_ckpt.is_file():
        return 0
    return int(torch.load(last_ckpt, map_location="cpu", weights_only=True)["epoch"]) + 1


def _kill_after(proc: subprocess.Popen, last_ckpt: Path, epochs: int, sig: signal.Signals) -> tuple[int, str, str]:
    """Send ``sig`` once ``last_ckpt`` holds ``epochs`` finished epochs; the exit code, stdout and stderr.

    The run's group is stopped while each new last.ckpt is read, so that on a loaded machine its tiny epochs cannot
    run to the end between the read and the signal.
    """
    deadline, seen = time.monotonic() + 120, None
    try:
        while proc.poll() is None and time.monotonic() < deadline:
            stamp = last_ckpt.stat().st_mtime_ns if last_ckpt.is_file() else None
            if stamp == seen:
                time.sleep(0.01)
                continue
            os.killpg(proc.pid, signal.SIGSTOP)
            seen = stamp
            if _saved_epochs(last_ckpt) >= epochs:
                break
            os.killpg(proc.pid, signal.SIGCONT)
        assert proc.poll() is None, f"the run ended before the kill: {proc.communicate()[1][-2000:]}"
        assert _saved_epochs(last_ckpt) >= epochs, f"no last.ckpt of {epochs} epochs within 120 s"
        if sig == signal.SIGKILL:  # as a crash: its loader worker too, which else holds the pipes open until it notices
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
            os.killpg(proc.pid, signal.SIGCONT)
        stdout, stderr = _communicate(proc, 120)
        return proc.returncode, stdout, stderr
    finally:
        if proc.poll() is None:
            kill_and_read(proc)


def _finish(proc: subprocess.Popen) -> dict:
    try:
        stdout, stderr = _communicate(proc, 180)
    finally:
        if proc.poll() is None:
            kill_and_read(proc)
    assert proc.returncode == 0, stderr[-3000:]
    return json.loads(stdout)


def _weights(run: Path) -> dict[str, dict[str, torch.Tensor]]:
    """The last epoch's weights (last.ckpt) and the kept ones (ckpt.pt) of a finished run."""
    last = torch.load(run / "lightning" / "last.ckpt", map_location="cpu", weights_only=True)
    kept = torch.load(run / "ckpt.pt", map_location="cpu", weights_only=True)
    return {"last.ckpt": last["state_dict"], "ckpt.pt": kept["state_dict"]}


def test_a_run_killed_after_an_epoch_resumes_to_the_weights_of_an_uninterrupted_run(tmp_path: Path, fault) -> None:
    small_capture(tmp_path / "d.h5")
    reference = _start(tmp_path, "reference")
    killed = _start(tmp_path, "killed")  # both at once: the two cores share the imports' time
    last_ckpt = tmp_path / "killed" / "lightning" / "last.ckpt"
    code, stdout, stderr = _kill_after(killed, last_ckpt, 2, signal.SIGTERM)
    assert code == 143, stderr[-3000:]
    said = json.loads(stdout)
    assert said["interrupted"] and said["last_ckpt"] == "killed/lightning/last.ckpt" and "--resume" in said["note"]
    assert _saved_epochs(last_ckpt) >= 2 and not (tmp_path / "killed" / "ckpt.pt").exists()
    assert not list((tmp_path / "killed").rglob("*.tmp"))
    term_kept = _saved_epochs(last_ckpt)
    resumed = _start(tmp_path, "killed", "--resume")
    code, _, _ = _kill_after(resumed, last_ckpt, term_kept + 2, signal.SIGKILL)
    assert code == -signal.SIGKILL
    kill_kept = _saved_epochs(last_ckpt)
    result = _finish(_start(tmp_path, "killed", "--resume"))
    assert result["optimiser_steps"] == 24  # 8 epochs of 3 steps, none repeated or left out
    expected = _finish(reference)
    ours, theirs = _weights(tmp_path / "killed"), _weights(tmp_path / "reference")
    for name in ("last.ckpt", "ckpt.pt"):
        assert ours[name].keys() == theirs[name].keys()
        differ = [k for k in ours[name] if not torch.equal(ours[name][k], theirs[name][k])]
        assert not differ, f"{name}: {len(differ)} tensors differ from the uninterrupted run's, first {differ[:3]}"
    assert result["val_loss"] == expected["val_loss"] and result["best_epoch"] == expected["best_epoch"]
    metrics = json.loads((tmp_path / "killed" / "metrics.json").read_text())
    assert [e["epoch"] for e in metrics["epochs"]] == list(range(8))
    how = "exit 143, resumed from the last epoch's end to the uninterrupted run's weights, bit for bit"
    fault.recovered(f"train-repr stopped by SIGTERM with {term_kept} of 8 epochs saved", how)
    how = "resumed from the last epoch's end to the uninterrupted run's weights, bit for bit"
    fault.recovered(f"train-repr killed by SIGKILL with {kill_kept} of 8 epochs saved", how)


def test_a_full_disk_while_saving_last_ckpt_keeps_the_previous_one(tmp_path: Path, monkeypatch, capsys, fault) -> None:
    data = small_capture(tmp_path / "d.h5")
    out = tmp_path / "run"
    last = out / "lightning" / "last.ckpt"
    real_write_bytes = Path.write_bytes

    def full_disk_at_the_second_save(self: Path, data) -> int:
        if self.name.startswith(".last.ckpt.") and last.exists():  # staging the second epoch's checkpoint
            real_write_bytes(self, bytes(data)[:100])  # as a write cut off by ENOSPC leaves it
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write_bytes(self, data)

    monkeypatch.setattr(Path, "write_bytes", full_disk_at_the_second_save)
    argv = ["train-repr", "--data", str(data), "--out", str(out), "--epochs", "3", "--batch-size", "8"]
    argv += ["--num-workers", "0", "--width-mult", "0.25", "--val-fraction", "0.25", "--no-progress"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(last) in err and "No space left on device" in err, err
    assert _saved_epochs(last) == 1  # the first epoch's, whole
    assert not list(out.rglob("*.tmp")) and not (out / "ckpt.pt").exists()
    fault.refused("a full disk while train-repr saves last.ckpt after its second epoch", err.split("error: ", 1)[1])


def test_ctrl_c_inside_an_epoch_exits_130_keeping_the_last_epochs_end(tmp_path: Path, monkeypatch, capsys) -> None:
    from vision_rl.phase1_repr import train

    data = small_capture(tmp_path / "d.h5")
    out = tmp_path / "run"
    real = train._Throughput.on_train_batch_end

    def ctrl_c_in_the_second_epoch(self, trainer, *args) -> None:
        real(self, trainer, *args)
        if trainer.current_epoch == 1:
            raise KeyboardInterrupt

    monkeypatch.setattr(train._Throughput, "on_train_batch_end", ctrl_c_in_the_second_epoch)
    argv = ["train-repr", "--data", str(data), "--out", str(out), "--epochs", "3", "--batch-size", "4"]
    argv += ["--num-workers", "0", "--width-mult", "0.25", "--val-fraction", "0.25", "--no-progress", "--json"]
    sigterm_before = signal.getsignal(signal.SIGTERM)  # another test of this process (Ray's) may have set one
    signal.signal(signal.SIGINT, signal.default_int_handler)  # ... or left SIGINT ignored: Python's own before the run
    assert main(argv) == 130
    said = json.loads(capsys.readouterr().out)
    assert said["interrupted"] and said["finished_epochs"] == 1 and "--resume" in said["note"]
    assert _saved_epochs(out / "lightning" / "last.ckpt") == 1 and not (out / "ckpt.pt").exists()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # Lightning's SIG_IGN is undone
    assert signal.getsignal(signal.SIGTERM) == sigterm_before
