"""The design card's four lines, run as written in that order in an empty folder (shrunk by extra options): each
exits 0 and says where it wrote what, and each finds what the line before it left."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers.rendering import renderer_available

BIN = Path(sys.executable).parent


def run(folder: Path, *argv: str) -> str:
    done = subprocess.run(
        [str(BIN / argv[0]), *argv[1:]], cwd=folder, capture_output=True, text=True, timeout=600, check=False
    )
    assert done.returncode == 0, f"{' '.join(argv)} exited {done.returncode}:\n{done.stdout}\n{done.stderr}"
    return done.stdout + done.stderr


def test_the_design_cards_lines_run_in_an_empty_folder(small_track, tmp_path):
    reason = renderer_available()
    if reason:
        pytest.skip(reason)
    tiny = ("--image-hw-px", "32", "48")
    text = run(tmp_path, "capture", "--disrupt-ai", "--laps", "2", "--track", small_track, "--fps", "5", *tiny)
    assert (tmp_path / "capture.h5").is_file() and "capture.h5" in text
    text = run(
        tmp_path, "train-repr", "--epochs", "1", "--max-steps", "2", "--num-workers", "0", "--val-fraction", "0.5"
    )
    assert (tmp_path / "ckpt.pt").is_file() and "ckpt.pt: ckpt.pt" in text and str(tmp_path) in text
    assert "training on the capture files here: capture.h5" in text
    text = run(
        tmp_path,
        "train-policy",
        "--encoder",
        "ckpt.pt",
        *("--track", small_track, "--steps", "60", "--cars", "2", "--learning-starts", "20", "--batch-size", "16"),
        *("--buffer-size", "1000", "--eval-every-steps", "0", "--stats-steps", "5", "--device", "cpu"),
    )
    assert "policy" in text and "metrics" in text
    text = run(tmp_path, "bench-latency", "--runs", "2", "--warmup", "1", *tiny, "--no-variants")
    assert "ms" in text
