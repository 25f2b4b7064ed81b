"""bench scaling: the capture row measured for real (tiny), the train and sampling rows' arithmetic, the sampling row
without the distributed sampler, and its option checks."""

from __future__ import annotations

import json
import sys
import types

import numpy as np
import pytest

import vision_rl.commands.bench_scaling as bench
from vision_rl.commands.main import main


def test_capture_row_measures_one_and_two_workers(gl_available, ray_local, tmp_path, capsys):
    a = np.linspace(0.0, 2 * np.pi, 120, endpoint=False)
    rows = np.stack([40 * np.cos(a), 40 * np.sin(a), np.full(120, 6.0), np.full(120, 6.0)], axis=1)
    np.savetxt(tmp_path / "circle.csv", rows, delimiter=",", header="x_m,y_m,w_tr_right_m,w_tr_left_m")
    argv = [
        "bench",
        "scaling",
        "--rows",
        "capture",
        "--track",
        str(tmp_path / "circle.csv"),
        "--cars",
        "2",
        "--image-hw-px",
        "32",
        "48",
        "--capture-frames",
        "24",
        "--repeats",
        "1",
        "--json",
    ]
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out)
    capture = result["rows"]["capture"]
    assert set(capture) == {"frames/s", "frames/s inside the shards", "CPU ms per frame"}
    fps = capture["frames/s"]
    assert fps["workers_1"]["median"] > 0 and fps["workers_2"]["median"] > 0
    assert fps["ratio"] == pytest.approx(fps["workers_2"]["median"] / fps["workers_1"]["median"])
    assert capture["CPU ms per frame"]["workers_2"]["runs"][0] > 0


def test_train_row_compares_one_and_two_devices(monkeypatch, tmp_path):
    calls = []

    def fake_train_run(devices, data, out, opts):
        calls.append(devices)
        return {"train_frames_per_s": 100.0 * devices**0.5 + len(calls), "n_train_frames": 64}

    monkeypatch.setattr(bench, "train_run", fake_train_run)
    row = bench._train_row(bench.BenchScalingOptions(repeats=3), "cap.json", tmp_path)
    assert calls == [1, 2, 1, 2, 1, 2]  # alternating, so that a change of load hits both
    figure = row["training frames/s"]
    assert figure["workers_1"]["runs"] == [101.0, 103.0, 105.0]
    assert figure["ratio"] == pytest.approx(figure["workers_2"]["median"] / 103.0)


def test_sampling_row_says_when_the_distributed_sampler_is_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "vision_rl.training.sampling_bench", types.ModuleType("sampling_bench"))
    row = bench._sampling_row(bench.BenchScalingOptions(repeats=1))
    assert "bench_sampling is not available" in row["missing"]
    lines = bench._lines({"cpus": 2, "repeats": 1, "rows": {"sampling": row}, "targets": {}})
    assert any(line.startswith("sampling") and "not available" in line for line in lines)


def test_sampling_row_calls_bench_sampling_with_each_worker_count(monkeypatch):
    module = types.ModuleType("sampling_bench")
    heard = []

    def bench_sampling(workers: int, seconds: float, seed: int) -> dict:
        heard.append((workers, seconds, seed))
        return {
            "sampled_transitions_per_s": 400.0 * workers,
            "learner_updates_per_s": 20.0,
            "learner_share_of_standalone": 0.97,
        }

    module.bench_sampling = bench_sampling
    monkeypatch.setitem(sys.modules, "vision_rl.training.sampling_bench", module)
    row = bench._sampling_row(bench.BenchScalingOptions(repeats=2, sampling_seconds=3.0, seed=5))
    assert heard == [(1, 3.0, 5), (2, 3.0, 5), (1, 3.0, 6), (2, 3.0, 6)]
    assert row["sampled transitions/s"]["ratio"] == pytest.approx(2.0)
    assert row["learner updates/s"]["ratio"] == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--rows", "render"], "--rows takes capture, train, sampling"),
        (["--rows", "train"], "include capture"),
        (["--repeats", "0"], "--repeats"),
    ],
)
def test_bad_options_are_one_line(argv, words, capsys):
    assert main(["bench", "scaling", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err
