"""`bench-latency` and `bench train-repr`: --json emits their keys, the text names the budget and the frame size."""

import json

import pytest

from vision_rl.commands.bench_latency import BenchLatencyOptions, run_bench_latency
from vision_rl.phase1_repr.bench import PAPER_BUDGET_MS


def test_json_output_has_the_keys(capsys) -> None:
    opts = BenchLatencyOptions(image_hw_px=(64, 96), runs=5, warmup=1, batch_size=2, variants=False, json=True)
    assert run_bench_latency(opts) == 0
    result = json.loads(capsys.readouterr().out)
    for key in ("p50_ms", "p90_ms", "p99_ms", "variants", "budget_ms", "throughput_fps", "threads", "parameters"):
        assert key in result
    assert 0 < result["p50_ms"] <= result["p90_ms"] <= result["p99_ms"]
    assert result["budget_ms"] == PAPER_BUDGET_MS == 8.0
    assert result["input_hw_px"] == [64, 96] and result["runs"] == 5
    default = "onnxruntime" if result["runtime"] == "onnxruntime" else "eager"
    assert list(result["variants"]) == [default] and result["variants"][default]["p50_ms"] == result["p50_ms"]
    assert result["within_budget"] == (result["p50_ms"] <= 8.0)


def test_text_output_prints_the_budget_beside(capsys) -> None:
    run_bench_latency(BenchLatencyOptions(image_hw_px=(64, 96), runs=3, warmup=0, batch_size=2, variants=False))
    text = capsys.readouterr().out
    assert "p50" in text and "budget: 8 ms" in text and "frames 96x64" in text


def test_bench_train_repr_prints_a_row_per_batch_and_precision(capsys) -> None:
    from vision_rl.commands.main import main

    argv = [
        "bench",
        "train-repr",
        "--image-hw-px",
        "32",
        "48",
        "--batch-sizes",
        "2",
        "3",
        "--precisions",
        "fp32",
        "--steps",
        "1",
        "--repeats",
        "1",
        "--warmup",
        "0",
        "--threads",
        "1",
    ]
    assert main([*argv, "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    assert [(r["batch_size"], r["precision"]) for r in rows] == [(2, "fp32"), (3, "fp32")]
    assert main(argv) == 0
    assert "frames 48x32" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exit_info:  # argparse refuses it before the command runs
        main([*argv[:5], "--batch-sizes", "64", "x"])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.strip().endswith("argument --batch-sizes: 'x' is not an integer")
