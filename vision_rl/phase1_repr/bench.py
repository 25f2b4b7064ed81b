"""`bench-latency`: batch-1 latency of the encoder, uint8 frame to 64-D vector, against the paper's 8 ms budget.

Each timed call starts from a uint8 numpy frame (N, H, W, 3), as the renderer or a grabber hands it over, and ends
with phi_rep on the host side (CUDA is synchronised), so conversion, normalisation and transfer are included. The
headline figures (``p50_ms``...) time the path Phase 2 runs (``--runtime auto``: ONNX Runtime on a CPU where it is
installed, torch otherwise); ``variants`` times the others side by side.

`bench train-repr` (:func:`bench_train_step`): Phase 1's training step in frames/s, on frames already on the device.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vision_rl.files import first_line
from vision_rl.phase1_repr.checkpoint import build_network, read_checkpoint
from vision_rl.phase1_repr.config import BenchLatencyConfig, BenchTrainStepConfig
from vision_rl.phase1_repr.encoder import EncoderConfig, ReprNet, count_parameters
from vision_rl.phase1_repr.onnx_runtime import OnnxEmbedding, onnxruntime_installed, resolve_runtime

#: The vision paper's inference time per frame, measured there on a GPU (section 3: "averages around 8 ms").
PAPER_BUDGET_MS = 8.0


def _percentiles(times_s: list[float]) -> dict[str, float]:
    ms = np.asarray(times_s) * 1e3
    return {
        "p50_ms": float(np.percentile(ms, 50)),
        "p90_ms": float(np.percentile(ms, 90)),
        "p99_ms": float(np.percentile(ms, 99)),
        "mean_ms": float(ms.mean()),
    }


def _time_calls(fn: Callable[[np.ndarray], Any], frames: np.ndarray, runs: int, warmup: int, sync: Callable[[], None]):
    for _ in range(warmup):
        fn(frames)
    sync()
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn(frames)
        sync()
        times.append(time.perf_counter() - t0)
    return times


def _torch_path(net: ReprNet, device: torch.device, channels_last: bool = False) -> Callable[[np.ndarray], Any]:
    if channels_last:
        net = net.to(memory_format=torch.channels_last)

    def run(frames: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            return net.embed(torch.from_numpy(frames).to(device, non_blocking=True)).cpu().numpy()

    return run


def _compiled_path(net: ReprNet, device: torch.device) -> Callable[[np.ndarray], Any]:
    compiled = torch.compile(net.embed, dynamic=False)

    def run(frames: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            return compiled(torch.from_numpy(frames).to(device)).cpu().numpy()

    return run


def require_device(name: str) -> torch.device:
    """``name`` as a torch device (``auto``: cuda when torch sees a GPU, else cpu), or one clear line: a name torch
    does not know, or a GPU torch cannot see."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    try:
        device = torch.device(name)
    except RuntimeError:
        raise ValueError(f"--device {name!r} is not a torch device: auto, cpu, cuda or cuda:N") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"--device {name}: torch sees no CUDA GPU here (or is a CPU build)")
    return device


def bench_latency(cfg: BenchLatencyConfig) -> dict[str, Any]:
    """Time the encoder as configured; returns the figures (``p50_ms``, ``p90_ms``, ``p99_ms``, ``variants``...)."""
    if cfg.runs < 1 or cfg.warmup < 0 or cfg.batch_size < 1:
        raise ValueError("runs and batch_size must be >= 1 and warmup >= 0")
    device = require_device(cfg.device)
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    runtime = resolve_runtime(cfg.runtime, device)
    if cfg.encoder:
        trained = build_network(read_checkpoint(cfg.encoder), cfg.encoder)
        source = str(cfg.encoder)
    else:
        torch.manual_seed(0)
        h, w = cfg.image_hw_px
        enc_cfg = EncoderConfig(backbone=cfg.backbone, input_height_px=h, input_width_px=w)
        trained = ReprNet(enc_cfg).eval()
        source = f"freshly initialised {cfg.backbone} encoder"
    fused_net = _copy(trained).fuse_for_inference().to(device)
    h, w = fused_net.config.input_height_px, fused_net.config.input_width_px
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 256, (1, h, w, 3), dtype=np.uint8)
    batch = rng.integers(0, 256, (cfg.batch_size, h, w, 3), dtype=np.uint8)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)

    def onnx_path() -> Callable[[np.ndarray], Any]:
        return OnnxEmbedding(_copy(fused_net), torch.get_num_threads())

    default_name = "onnxruntime" if runtime == "onnxruntime" else "eager"
    default_path = onnx_path() if runtime == "onnxruntime" else _torch_path(fused_net, device)
    times = _time_calls(default_path, frame, cfg.runs, cfg.warmup, sync)
    batch_runs = max(3, min(20, cfg.runs // 10))
    batch_times = _time_calls(default_path, batch, batch_runs, 1, sync)
    result: dict[str, Any] = {
        "encoder": source,
        "device": str(device),
        "device_name": torch.cuda.get_device_name(device) if device.type == "cuda" else _cpu_name(),
        "runtime": runtime,
        "threads": torch.get_num_threads(),
        "input_hw_px": [h, w],
        "parameters": count_parameters(trained),
        "runs": cfg.runs,
        **_percentiles(times),
        "budget_ms": PAPER_BUDGET_MS,
        "batch_size": cfg.batch_size,
        "throughput_fps": float(cfg.batch_size / np.median(batch_times)),
        "torch_version": torch.__version__,
    }
    result["within_budget"] = result["p50_ms"] <= PAPER_BUDGET_MS
    variants: dict[str, Any] = {default_name: _percentiles(times)}
    if cfg.variants:
        builders: dict[str, Callable[[], Callable[[np.ndarray], Any]]] = {
            "eager": lambda: _torch_path(fused_net, device),
            "unfused": lambda: _torch_path(_copy(trained).to(device), device),
            "channels_last": lambda: _torch_path(_copy(fused_net), device, channels_last=True),
            "torch_compile": lambda: _compiled_path(_copy(fused_net), device),
        }
        if device.type == "cpu":
            builders["onnxruntime"] = onnx_path
        for name, build in builders.items():
            if name in variants:
                continue
            if name == "onnxruntime" and not onnxruntime_installed():
                variants[name] = {"skipped": "onnxruntime is not installed (pip install 'vision_rl[onnx]')"}
                continue
            try:
                t0 = time.perf_counter()
                fn = build()
                fn(frame)  # compile or export here, outside the timing
                setup_s = time.perf_counter() - t0
                variants[name] = {
                    **_percentiles(_time_calls(fn, frame, cfg.runs, cfg.warmup, sync)),
                    "setup_s": setup_s,
                }
            except Exception as exc:  # a variant that does not work on this machine is reported, not fatal
                variants[name] = {"error": f"{type(exc).__name__}: {first_line(exc)[:200]}"}
    result["variants"] = variants
    return result


def _copy(net: ReprNet) -> ReprNet:
    clone = ReprNet(net.config).eval()
    if net.fused:
        clone.fuse_for_inference()
    clone.load_state_dict(net.state_dict())
    return clone.to(next(net.parameters()).device)


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return f"{line.split(':', 1)[1].strip()} ({os.cpu_count()} logical CPUs)"
    except OSError:
        pass
    return f"{os.cpu_count()} logical CPUs"


PRECISIONS = ("fp32", "bf16")


def bench_train_step(cfg: BenchTrainStepConfig) -> dict[str, Any]:
    """One row per (batch size, precision): step time and frames/s (median of ``repeats``, with their spread), and
    the loss on the fixed batch before and after, which falls when the step trains."""
    if min(cfg.steps, cfg.repeats) < 1 or cfg.warmup < 0 or not cfg.batch_sizes or min(cfg.batch_sizes) < 1:
        raise ValueError("steps, repeats and every batch size must be >= 1, warmup >= 0")
    unknown = [p for p in cfg.precisions if p not in PRECISIONS]
    if unknown or not cfg.precisions:
        raise ValueError(f"precision {', '.join(unknown) or '(none)'}: choose from {', '.join(PRECISIONS)}")
    device = require_device(cfg.device)
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    h, w = cfg.image_hw_px
    rows = [
        _time_train_step(cfg, device, batch_size, precision)
        for batch_size in cfg.batch_sizes
        for precision in cfg.precisions
    ]
    return {
        "device": str(device),
        "device_name": torch.cuda.get_device_name(device) if device.type == "cuda" else _cpu_name(),
        "threads": torch.get_num_threads(),
        "input_hw_px": [h, w],
        "torch_version": torch.__version__,
        "rows": rows,
    }


def _time_train_step(cfg: BenchTrainStepConfig, device: torch.device, batch_size: int, precision: str) -> dict:
    from vision_rl.datasets.augment import FrameAugmentation
    from vision_rl.phase1_repr.train import ReprModule

    h, w = cfg.image_hw_px
    n_targets = EncoderConfig().n_targets
    torch.manual_seed(0)
    module = (
        ReprModule(
            encoder_config=EncoderConfig(input_height_px=h, input_width_px=w).to_dict(),
            target_names=[f"t{k}" for k in range(n_targets)],
            target_units=["1"] * n_targets,
            target_mean=[0.0] * n_targets,
            target_std=[1.0] * n_targets,
            augmentation=dataclasses.asdict(FrameAugmentation()),
        )
        .to(device)
        .train()
    )
    optimiser = torch.optim.AdamW(module.parameters(), lr=module.hparams.lr, weight_decay=module.hparams.weight_decay)
    images = torch.randint(0, 256, (batch_size, h, w, 3), dtype=torch.uint8, device=device)
    targets = torch.randn(batch_size, n_targets, device=device)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)

    def step() -> torch.Tensor:
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bf16"):
            loss = module.loss(module.predict_standardised(images, augment=True).float(), targets)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        return loss.detach()  # no host sync per step: the GPU queues the steps as training does

    loss_first = float(step())
    for _ in range(cfg.warmup):
        step()
    sync()
    times = []
    for _ in range(cfg.repeats):
        t0 = time.perf_counter()
        for _ in range(cfg.steps):
            loss = step()
        sync()
        times.append((time.perf_counter() - t0) / cfg.steps)
    step_s = float(np.median(times))
    return {
        "batch_size": batch_size,
        "precision": precision,
        "step_ms": 1e3 * step_s,
        "frames_per_s": batch_size / step_s,
        "frames_per_s_spread": [batch_size / max(times), batch_size / min(times)],
        "loss_first": loss_first,
        "loss_last": float(loss),
    }
