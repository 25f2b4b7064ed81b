"""Phase 1's options that a command holds before it parses (the latency bench's, the training-step bench's): light
(no torch or Lightning), so that the commands' ``--help`` answers without loading them."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class BenchLatencyConfig:
    """Measure the encoder's batch-1 latency (uint8 frame in, 64-D out) and batched throughput."""

    encoder: str = ""
    """ckpt.pt to measure; empty: a freshly initialised default encoder."""
    backbone: str = "s2d"
    """Backbone of the fresh encoder: s2d or mobilenet_v3_small (a checkpoint fixes its own)."""
    device: str = "auto"
    """auto (cuda when torch sees a GPU, else cpu), cpu or cuda."""
    runtime: str = "auto"
    """The timed default path: auto (what Phase 2 runs: ONNX Runtime on a CPU when installed, else torch), torch or
    onnxruntime."""
    image_hw_px: tuple[int, int] = (280, 470)
    """Frame height and width of the fresh encoder, px (a checkpoint fixes its own)."""
    runs: int = 300
    """Timed batch-1 calls (percentiles up to p99 want >= 200)."""
    warmup: int = 30
    """Untimed calls first."""
    threads: int = 0
    """torch CPU threads (0: leave torch's default)."""
    batch_size: int = 32
    """Frames per call for the throughput figure."""
    variants: bool = True
    """Also time unfused, channels_last, torch.compile, ONNX."""


@dataclass(frozen=True)
class BenchTrainStepConfig:
    """Time Phase 1's training step (train-repr's augmentation, network, loss and AdamW) on random frames already on
    the device, for each batch size and precision: the ceiling a data pipeline has to feed."""

    device: str = "auto"
    """auto (cuda when torch sees a GPU, else cpu), cpu or cuda."""
    image_hw_px: tuple[int, int] = (280, 470)
    """Frame height and width, px (the paper's game screen: 280 x 470)."""
    batch_sizes: tuple[int, ...] = (64, 256)
    """Frames per step (train-repr's default batch is 64)."""
    precisions: tuple[str, ...] = ("fp32", "bf16")
    """fp32, or bf16 (torch.autocast; the weights and optimiser stay fp32)."""
    steps: int = 20
    """Steps per timed repeat."""
    repeats: int = 5
    """Timed repeats; the median is the figure, the extremes the spread."""
    warmup: int = 10
    """Untimed steps first."""
    threads: int = 0
    """torch CPU threads (0: leave torch's default)."""
