"""bench-latency: --json emits its keys, figures are ordered, a checkpoint fixes the frame size, every variant is
timed or says why not."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
from pathlib import Path

import pytest

from tests.phase1_repr.test_checkpoint import write
from vision_rl.phase1_repr.bench import PAPER_BUDGET_MS, BenchLatencyConfig, bench_latency, run_bench_latency


def test_json_output_has_the_keys(capsys) -> None:
    cfg = BenchLatencyConfig(width=96, height=64, runs=5, warmup=1, batch_size=2, variants=False, json=True)
    assert run_bench_latency(cfg) == 0
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
    run_bench_latency(BenchLatencyConfig(width=96, height=64, runs=3, warmup=0, batch_size=2, variants=False))
    text = capsys.readouterr().out
    assert "p50" in text and "budget: 8 ms" in text


def test_checkpoint_sets_the_frame_size(tmp_path: Path) -> None:
    path = tmp_path / "ckpt.pt"
    write(path)  # a 32x48 encoder
    result = bench_latency(BenchLatencyConfig(encoder=str(path), runs=3, warmup=0, batch_size=2, variants=False))
    assert result["input_hw_px"] == [32, 48] and result["encoder"] == str(path)


def test_bad_settings_are_refused() -> None:
    with pytest.raises(ValueError):
        bench_latency(BenchLatencyConfig(runs=0))


def test_every_variant_is_timed_or_says_why_not() -> None:
    cfg = BenchLatencyConfig(width=48, height=32, runs=3, warmup=1, batch_size=2, threads=1, runtime="torch")
    result = bench_latency(cfg)
    variants = result["variants"]
    assert result["runtime"] == "torch" and next(iter(variants)) == "eager"
    assert set(variants) == {"eager", "unfused", "channels_last", "torch_compile", "onnxruntime"}
    for name, figures in variants.items():
        assert ("p50_ms" in figures and figures["p50_ms"] > 0) or figures.get("error") or figures.get("skipped"), name
    assert "p50_ms" in variants["unfused"] and "p50_ms" in variants["channels_last"]


def test_backbone_option_builds_that_encoder() -> None:
    cfg = BenchLatencyConfig(backbone="mobilenet_v3_small", width=48, height=32, runs=2, warmup=0, batch_size=2,
                             variants=False)  # fmt: skip
    if importlib.util.find_spec("torchvision") is None:
        with pytest.raises(ImportError, match="pip install torchvision"):
            bench_latency(cfg)
        return
    s2d = bench_latency(dataclasses.replace(cfg, backbone="s2d"))
    mobilenet = bench_latency(cfg)
    assert "mobilenet_v3_small" in mobilenet["encoder"] and mobilenet["parameters"] > s2d["parameters"]
