"""`bench-latency`: --json emits its keys, the text names the budget."""

import json

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
