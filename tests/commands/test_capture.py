"""`capture`: the command's checks, and a small simulator capture through the dispatcher."""

import json

import numpy as np
import pytest

from vision_rl.capture.h5format import open_capture
from vision_rl.commands.capture import CaptureOptions, run_capture
from vision_rl.commands.main import main


def test_source_is_checked_before_anything_runs(tmp_path):
    with pytest.raises(ValueError, match="--source"):
        run_capture(CaptureOptions(out=str(tmp_path / "x.h5"), source="camera"))
    with pytest.raises(ValueError, match="--poses"):
        run_capture(CaptureOptions(out=str(tmp_path / "x.h5"), source="video:0"))


def test_a_small_capture_through_the_command(gl_available, tmp_path, capsys):
    a = np.linspace(0.0, 2 * np.pi, 120, endpoint=False)
    rows = np.stack([40 * np.cos(a), 40 * np.sin(a), np.full(120, 6.0), np.full(120, 6.0)], axis=1)
    track = tmp_path / "circle.csv"
    np.savetxt(track, rows, delimiter=",", header="x_m,y_m,w_tr_right_m,w_tr_left_m")
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
        "1",
        "--fps",
        "5",
        "--image-hw-px",
        "48",
        "64",
        "--no-disrupt",
        "--json",
    ]
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["complete"] and result["frames_in_file"] > 0
    with open_capture(out) as f:
        assert f.image_hw_px == (48, 64) and not f.attrs["disrupted"]


def test_a_policy_drives_a_capture_through_the_command(gl_available, state_run, small_track, tmp_path):
    run, _ = state_run
    out = tmp_path / "policy.h5"
    argv = [
        "capture",
        "--out",
        str(out),
        "--track",
        small_track,
        "--policy",
        str(run),
        "--laps",
        "1",
        "--cars",
        "2",
        "--fps",
        "10",
        "--max-frames",
        "20",
        "--image-hw-px",
        "48",
        "64",
        "--no-disrupt",
        "--json",
    ]
    assert main(argv) == 0
    with open_capture(out) as f:
        assert f.n_frames == 20 and f.attrs["driver"]["driver"] == "policy"
        assert f.attrs["driver"]["policy_sha256"] == json.loads((run / "policy.json").read_text())["weights_sha256"]
    with pytest.raises(ValueError, match=f"drives {small_track} with the hatchback: give --track"):
        run_capture(CaptureOptions(out=str(tmp_path / "x.h5"), policy=str(run), disrupt_ai=False))
    with pytest.raises(ValueError, match="leave out --workers"):
        run_capture(CaptureOptions(out=str(tmp_path / "y.json"), policy=str(run), workers=2))
