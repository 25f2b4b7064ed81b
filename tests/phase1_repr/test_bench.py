"""bench_latency: figures are ordered, a checkpoint fixes the frame size, every variant is timed or says why not
(the command's output: tests/commands/test_bench_latency.py)."""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import pytest

from tests.helpers.checkpoints import write_checkpoint
from vision_rl.phase1_repr.bench import bench_latency, bench_train_step
from vision_rl.phase1_repr.config import BenchLatencyConfig, BenchTrainStepConfig


def test_checkpoint_sets_the_frame_size(tmp_path: Path) -> None:
    path = tmp_path / "ckpt.pt"
    write_checkpoint(path)  # a 32x48 encoder
    result = bench_latency(BenchLatencyConfig(encoder=str(path), runs=3, warmup=0, batch_size=2, variants=False))
    assert result["input_hw_px"] == [32, 48] and result["encoder"] == str(path)


def test_bad_settings_are_refused() -> None:
    with pytest.raises(ValueError):
        bench_latency(BenchLatencyConfig(runs=0))


def test_every_variant_is_timed_or_says_why_not() -> None:
    cfg = BenchLatencyConfig(image_hw_px=(32, 48), runs=3, warmup=1, batch_size=2, threads=1, runtime="torch")
    result = bench_latency(cfg)
    variants = result["variants"]
    assert result["runtime"] == "torch" and next(iter(variants)) == "eager"
    assert set(variants) == {"eager", "unfused", "channels_last", "torch_compile", "onnxruntime"}
    for name, figures in variants.items():
        assert ("p50_ms" in figures and figures["p50_ms"] > 0) or figures.get("error") or figures.get("skipped"), name
    assert "p50_ms" in variants["unfused"] and "p50_ms" in variants["channels_last"]


def test_backbone_option_builds_that_encoder() -> None:
    cfg = BenchLatencyConfig(
        backbone="mobilenet_v3_small", image_hw_px=(32, 48), runs=2, warmup=0, batch_size=2, variants=False
    )
    if importlib.util.find_spec("torchvision") is None:
        with pytest.raises(ImportError, match="pip install torchvision"):
            bench_latency(cfg)
        return
    s2d = bench_latency(dataclasses.replace(cfg, backbone="s2d"))
    mobilenet = bench_latency(cfg)
    assert "mobilenet_v3_small" in mobilenet["encoder"] and mobilenet["parameters"] > s2d["parameters"]


def test_the_training_step_bench_trains_and_times_each_batch_and_precision() -> None:
    cfg = BenchTrainStepConfig(
        image_hw_px=(32, 48), batch_sizes=(2, 4), precisions=("fp32", "bf16"), steps=2, repeats=2, warmup=3, threads=1
    )
    result = bench_train_step(cfg)
    rows = result["rows"]
    assert result["input_hw_px"] == [32, 48] and result["device"] == "cpu"
    assert [(r["batch_size"], r["precision"]) for r in rows] == [(2, "fp32"), (2, "bf16"), (4, "fp32"), (4, "bf16")]
    for r in rows:
        assert r["frames_per_s"] == pytest.approx(r["batch_size"] / (r["step_ms"] / 1e3))
        lo, hi = r["frames_per_s_spread"]
        assert lo <= r["frames_per_s"] <= hi
        # Eight steps on one fixed batch: a step that trains (not a forward pass alone) lowers its loss.
        assert r["loss_last"] < 0.9 * r["loss_first"], r


@pytest.mark.parametrize(
    "change,words",
    [
        ({"batch_sizes": (0,)}, "batch size"),
        ({"batch_sizes": ()}, "batch size"),
        ({"steps": 0}, "steps"),
        ({"precisions": ("fp8",)}, "precision fp8: choose from fp32, bf16"),
    ],
)
def test_the_training_step_bench_refuses_bad_settings(change, words) -> None:
    with pytest.raises(ValueError, match=words):
        bench_train_step(dataclasses.replace(BenchTrainStepConfig(image_hw_px=(32, 48)), **change))
