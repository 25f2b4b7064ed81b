"""Faults of `capture`: a resume with any changed setting, options out of bounds, SIGTERM and SIGKILL at a random
point of a run (subprocesses), a full disk."""

from __future__ import annotations

import dataclasses
import errno
import random
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from vision_rl.capture.h5format import CaptureFormatError, open_capture
from vision_rl.capture.sim_capture import CaptureConfig, capture_sim
from vision_rl.commands.main import main

REPO = Path(__file__).resolve().parents[2]


def circle_csv(path: Path, radius_m: float = 40.0) -> Path:
    a = np.linspace(0.0, 2 * np.pi, 120, endpoint=False)
    rows = np.stack([radius_m * np.cos(a), radius_m * np.sin(a), np.full(120, 6.0), np.full(120, 6.0)], axis=1)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, rows, delimiter=",", header="x_m,y_m,w_tr_right_m,w_tr_left_m")
    return path


@pytest.fixture(scope="module")
def partial_capture(tmp_path_factory, gl_available) -> tuple[CaptureConfig, Path]:
    """An interrupted capture of 8 frames (2 cars, 32x48 px) on a small circle."""
    root = tmp_path_factory.mktemp("partial")
    track = circle_csv(root / "circle.csv")
    cfg = CaptureConfig(
        out=str(root / "run.h5"), track=str(track), laps=2, cars=2, fps=10, image_hw_px=(32, 48), seed=3, max_frames=8
    )
    result = capture_sim(cfg)
    assert not result["complete"] and result["frames_in_file"] == 8
    return cfg, root


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"fps": 20.0}, "fps"),
        ({"disrupt_ai": False}, "disrupted"),
        ({"disrupt_steer_offset_rad": 0.6}, "disrupt_steer_offset_rad"),
        ({"car": "gt3"}, "car_preset"),
        ({"seed": 4}, "seed"),
        ({"cars": 3}, "cars"),
        ({"image_hw_px": (32, 64)}, "image_width"),
        ({"track": "OTHER"}, "track_geometry_hash"),
    ],
)
def test_resume_with_a_changed_setting_is_refused_naming_it(partial_capture, tmp_path, change, field, fault):
    cfg, _ = partial_capture
    out = tmp_path / "run.h5"
    out.write_bytes(Path(cfg.out).read_bytes())
    if change.get("track") == "OTHER":  # same file name, another geometry
        change = {"track": str(circle_csv(tmp_path / "circle.csv", radius_m=45.0))}
    with pytest.raises(CaptureFormatError) as info:
        capture_sim(dataclasses.replace(cfg, out=str(out), resume=True, max_frames=0, **change))
    message = str(info.value)
    assert f"cannot resume: {field} is " in message and "--force" in message and len(message.splitlines()) == 1
    assert "{" not in message  # one field, not whole dicts
    with open_capture(out) as f:
        assert f.n_frames == 8  # nothing was appended
    fault.refused(f"capture --resume with another {field}", message)


@pytest.mark.parametrize(
    "argv",
    [
        ["--cars", "100000"],
        ["--cars", "0"],
        ["--laps", "0"],
        ["--laps", "-1"],
        ["--fps", "0"],
        ["--fps", "-5"],
        ["--image-hw-px", "0", "64"],
        ["--max-frames", "-1"],
        ["--flush-interval-s", "-1"],
        ["--disrupt-steer-offset-rad", "-0.1"],
        ["--no-disrupt", "--disrupt-steer-offset-rad", "0.6"],
    ],
)
def test_options_out_of_bounds_are_one_line(tmp_path, argv, capsys, fault):
    out = tmp_path / "x.h5"
    try:
        code = main(["capture", "--out", str(out), *argv])
    except SystemExit as stop:  # argparse refuses a negative number itself, in one line too
        code = stop.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and argv[0] in err
    assert not out.exists()
    fault.refused(f"capture {' '.join(argv)}", err.split("error: ", 1)[1])


# A capture through the command, reporting each written batch's frame count on stdout (the bar is hidden when
# stderr is no terminal), so the test knows what had been written when it sent the signal.
_CAPTURE_PROCESS = textwrap.dedent(
    """
    import sys
    sys.path.insert(0, {repo!r})
    import vision_rl.commands.capture as cmd
    real_show = cmd.show
    def show(bar, done, total=None, **figures):
        real_show(bar, done, total, **figures)
        print(figures["frames"], flush=True)
    cmd.show = show
    from vision_rl.commands.main import main
    sys.exit(main({argv!r}))
    """
)


def _start_capture(argv: list[str]) -> tuple[subprocess.Popen, list[tuple[float, int]], threading.Thread]:
    code = _CAPTURE_PROCESS.format(repo=str(REPO), argv=["capture", *argv])
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    reports: list[tuple[float, int]] = []

    def read() -> None:
        for line in proc.stdout:
            if line.strip().isdigit():
                reports.append((time.monotonic(), int(line)))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    return proc, reports, reader


@pytest.mark.parametrize(
    ("sig", "flush_interval_s", "seed"),
    [(signal.SIGTERM, 2.0, 0), (signal.SIGKILL, 0.0, 1), (signal.SIGKILL, 0.5, 2)],
)
def test_a_killed_capture_loses_at_most_the_flush_interval_and_resumes(
    gl_available, tmp_path, sig, flush_interval_s, seed, fault
):
    track = circle_csv(tmp_path / "circle.csv")
    out = tmp_path / "run.h5"
    # 10 laps: on an idle machine 2 laps were done within the 0.8 s before the kill, so nothing was left to kill
    argv = [
        "--out",
        str(out),
        "--track",
        str(track),
        "--laps",
        "10",
        "--cars",
        "2",
        "--fps",
        "10",
        "--image-hw-px",
        "32",
        "48",
        "--seed",
        "5",
        "--flush-interval-s",
        str(flush_interval_s),
        "--json",
    ]
    proc, reports, reader = _start_capture(argv)
    deadline = time.monotonic() + 120
    while not reports and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert reports, f"the capture never wrote a batch: {proc.stderr.read()[-2000:] if proc.poll() is not None else ''}"
    time.sleep(random.Random(seed).uniform(0.0, 0.8))  # a random point of the run
    killed_at = time.monotonic()
    proc.send_signal(sig)
    proc.wait(timeout=60)
    reader.join(timeout=30)  # the reader thread alone reads stdout, to its end
    stderr = proc.stderr.read()
    reported = max(frames for _, frames in reports)
    kept_targets = None
    try:
        with open_capture(out) as f:
            assert not f.complete
            kept = f.n_frames
            kept_targets = f.targets
            f.read_images(np.arange(kept))  # every kept frame passes its checksum
    except CaptureFormatError as exc:
        # A SIGKILL inside HDF5's rewrite of the last table chunk (seen once in a loaded CI run) damages rows already
        # committed: they are named, never read, and --resume rewrites them from the journal.
        assert sig == signal.SIGKILL and "fail their checksum" in str(exc) and "--resume" in str(exc), str(exc)
        with h5py.File(out, "r") as raw:
            kept = int(raw.attrs["n_frames"])
    if sig == signal.SIGTERM:
        assert proc.returncode == 143, stderr
        assert kept == reported  # stopped between batches: nothing lost
        how = f"stopped between batches, {kept} of {reported} frames kept"
    else:
        assert proc.returncode == -signal.SIGKILL
        # Every frame reported at least one flush interval (and a slack for a slow batch) before the kill is kept.
        safe = [frames for t, frames in reports if t + flush_interval_s + 0.5 < killed_at]
        assert kept >= (max(safe) if safe else 0), (kept, reports[-5:])
        if flush_interval_s == 0:
            assert kept >= reported
        how = f"{kept} of {reported} frames kept (flush every {flush_interval_s:g} s)"
        if kept_targets is None:
            how += ", a chunk damaged in its rewrite restored from the journal"
    resumed = subprocess.run(
        [sys.executable, "-m", "vision_rl.commands.main", "capture", *argv, "--resume"],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=REPO,
    )
    assert resumed.returncode == 0, resumed.stderr
    with open_capture(out) as f:
        assert f.complete and f.n_frames > kept
        if kept_targets is not None:
            np.testing.assert_array_equal(f.targets[:kept], kept_targets)  # the kept frames are untouched
        f.read_images(np.arange(f.n_frames))
    fault.recovered(f"{signal.Signals(sig).name} at a random point of a capture", f"{how}; --resume completed it")


def test_a_full_disk_names_the_file_and_resume_completes_it(gl_available, tmp_path, monkeypatch, capsys, fault):
    track = circle_csv(tmp_path / "circle.csv")
    out = tmp_path / "run.h5"
    argv = [
        "capture",
        "--out",
        str(out),
        "--track",
        str(track),
        "--laps",
        "1",
        "--cars",
        "2",
        "--fps",
        "10",
        "--image-hw-px",
        "32",
        "48",
        "--flush-interval-s",
        "0",
    ]
    real_flush = h5py.File.flush
    calls = {"n": 0}

    def filling_disk(self):
        calls["n"] += 1
        if calls["n"] > 6:  # the file is made and a few batches are in: then the disk is full
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_flush(self)

    monkeypatch.setattr(h5py.File, "flush", filling_disk)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(out) in err and "disk full" in err
    monkeypatch.setattr(h5py.File, "flush", real_flush)
    # No temporary file; the journal of the incomplete file stays for the resume.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["circle.csv", "run.h5", "run.h5.journal.npz"]
    with open_capture(out) as f:
        assert not f.complete and f.n_frames > 0
    fault.refused("a full disk (ENOSPC) during a capture", err.split("error: ", 1)[1])
    assert main([*argv, "--resume"]) == 0
    with open_capture(out) as f:
        assert f.complete
        f.read_images(np.arange(f.n_frames))
    fault.recovered("a full disk (ENOSPC) during a capture", "the flushed frames stay; --resume completed the file")
