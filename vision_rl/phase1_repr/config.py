"""Phase 1's options that a command holds before it parses (train-repr's, the latency and training-step benches'): light
(no torch or Lightning), so that the commands' ``--help`` answers without loading them."""

from __future__ import annotations

import glob
import math
import os
from dataclasses import dataclass, field

from vision_rl.budget import require_memory


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


#: Lightning strategies train-repr offers: one device, or distributed data parallel over ``devices`` processes.
STRATEGIES = ("auto", "ddp")


def launch_rank() -> int:
    """This process's rank among those Lightning's DDP launcher started: 0 in the process the user started (and in
    a one-device run), > 0 in the copies of the command it started with ``LOCAL_RANK`` / ``NODE_RANK`` set."""
    try:
        return int(os.environ.get("LOCAL_RANK", "0") or 0) + int(os.environ.get("NODE_RANK", "0") or 0)
    except ValueError:
        return 0


#: The largest random shift train-repr allows, px: augmentation by a few pixels (datasets.augment.shift_frames).
MAX_SHIFT_PX = 64
#: The largest space2depth block, px: the stem sees 3 x block^2 channels.
MAX_SPACE2DEPTH_BLOCK_PX = 32
#: The frame size train-repr's memory is priced at before the capture files are read: the paper's 280 x 470.
PRICED_FRAME_HW_PX = (280, 470)
#: Parameters of the s2d encoder at --width-mult 1 (244,123; measured), which grow with its square.
_S2D_PARAMETERS = 2.5e5
#: Activations and their gradients per frame pixel and channel-width unit during a training step, bytes
#: (the s2d network keeps about 2M floats per 280 x 470 frame, twice for the gradients).
_STEP_BYTES_PER_PIXEL = 128


def _positive(value: float, option: str, minimum: float = 1) -> tuple[bool, str]:
    return (math.isfinite(value) and value >= minimum), f"{option} must be >= {minimum:g}, got {value}"


@dataclass(frozen=True)
class TrainReprConfig:
    """Train the Phase-1 encoder on capture files; writes ckpt.pt, metrics.json, TensorBoard logs and a figure."""

    data: str = ""
    """Training capture file(s): a path, a comma-separated list or a glob."""
    val: str = ""
    """Validation capture (undisturbed laps); empty: laps held out of ``data``."""
    val_fraction: float = 0.1
    """Share of frames held out by lap when ``val`` is empty."""
    epochs: int = 50
    """Training epochs (the paper: best of 50)."""
    max_steps: int = field(default=-1, metadata={"min": -1})
    """Stop after this many optimiser steps (-1: no limit)."""
    batch_size: int = 64
    """Frames per batch."""
    lr: float = 2e-3
    """AdamW peak learning rate (cosine decay to 0)."""
    weight_decay: float = 1e-4
    """AdamW weight decay on weights (not biases)."""
    backbone: str = "s2d"
    """s2d (the paper's design) or mobilenet_v3_small."""
    width_mult: float = 1.0
    """Multiply every channel count of the s2d encoder."""
    space2depth_block_px: int = 4
    """Space2depth block side, px."""
    augment: bool = True
    """Random brightness, contrast and saturation."""
    shift_px: int = 0
    """Random shift of up to this many pixels (0: off)."""
    balance_groups: bool = False
    """Weight the loss so that each target group counts alike (the 13 edge rays otherwise outweigh the heading
    angle 13 to 1): raises the heading's R^2, lowers the edges' and curvature's."""
    mirror: bool = False
    """Mirror half the training frames left-right with their targets (the view of the mirrored track): for
    encoders meant for other tracks; on the capture's own track it lowered R^2."""
    num_workers: int = 2
    """DataLoader worker processes."""
    seed: int = 0
    """Seed of weights, split and batches."""
    device: str = "auto"
    """auto, cpu or cuda."""
    precision: str = "32-true"
    """Lightning precision, e.g. 32-true, bf16-mixed."""
    devices: int = 1
    """Devices to train on at once: processes on CPUs, GPUs on CUDA (> 1 needs ``strategy`` ddp)."""
    strategy: str = "auto"
    """Lightning strategy: auto (one device) or ddp (one process per device, batches shared out)."""
    out: str = "runs/repr/default"
    """Output folder."""
    resume: bool = False
    """Continue the run in ``out`` from its last checkpoint."""
    checkpoint_every_min: float = 0.0
    """Also save ``lightning/last.ckpt`` inside an epoch every this many minutes (0: off; it is saved at every
    epoch's end regardless). A resume from inside an epoch redraws the order of the epoch's remaining frames, so it
    does not end in the weights of an uninterrupted run as a resume from an epoch's end does: for epochs of hours."""
    force: bool = False
    """Start over in an ``out`` that holds a run."""

    def __post_init__(self) -> None:
        # Bounds of every size, checked when the configuration is made (the command line reports them as one line).
        checks = (
            _positive(self.epochs, "--epochs"),
            _positive(self.batch_size, "--batch-size"),
            _positive(self.num_workers, "--num-workers", 0),
            _positive(self.space2depth_block_px, "--space2depth-block-px"),
            _positive(self.shift_px, "--shift-px", 0),
            _positive(self.weight_decay, "--weight-decay", 0),
            _positive(self.checkpoint_every_min, "--checkpoint-every-min", 0),
            (
                self.max_steps == -1 or self.max_steps >= 1,
                f"--max-steps must be >= 1 or -1 (no limit), got {self.max_steps}",
            ),
            (math.isfinite(self.lr) and self.lr > 0, f"--lr must be > 0, got {self.lr}"),
            (
                math.isfinite(self.width_mult) and self.width_mult > 0,
                f"--width-mult must be > 0, got {self.width_mult}",
            ),
            (0 < self.val_fraction < 1, f"--val-fraction must be within (0, 1), got {self.val_fraction}"),
            _positive(self.devices, "--devices"),
            (self.strategy in STRATEGIES, f"--strategy must be one of {', '.join(STRATEGIES)}, got {self.strategy!r}"),
            (self.devices == 1 or self.strategy == "ddp", f"--devices {self.devices} needs --strategy ddp"),
            (
                self.shift_px <= MAX_SHIFT_PX,
                f"--shift-px {self.shift_px} is out of range: at most {MAX_SHIFT_PX} px (a shift of a few pixels; "
                "beyond the frame it shows only replicated edges)",
            ),
            (
                self.space2depth_block_px <= MAX_SPACE2DEPTH_BLOCK_PX,
                f"--space2depth-block-px {self.space2depth_block_px} is out of range: at most "
                f"{MAX_SPACE2DEPTH_BLOCK_PX} px",
            ),
        )
        for ok, message in checks:
            if not ok:
                raise ValueError(message)
        _check_distinct_captures(self.data, self.val)
        _check_training_memory(self)


def _check_distinct_captures(data: str, val: str) -> None:
    """Refuse a validation capture that is also a training one: its R^2 would measure frames the encoder saw."""
    if not val:
        return
    parts = [part.strip() for part in data.split(",") if part.strip()]
    training = {os.path.realpath(path) for part in parts for path in (glob.glob(part) or [part])}
    for part in (p.strip() for p in val.split(",")):
        if part and os.path.realpath(part) in training:
            raise ValueError(
                f"--val {part} is also in --data: validation needs other laps than training (leave --val empty to "
                "hold laps of --data out)"
            )


def _check_training_memory(cfg: TrainReprConfig) -> None:
    """Price the encoder (weights, gradients, AdamW's two moments) and a batch's step against the memory budget."""
    h, w = PRICED_FRAME_HW_PX
    parameters = _S2D_PARAMETERS * cfg.width_mult**2 * max(1.0, (cfg.space2depth_block_px / 4) ** 2)
    require_memory(f"--width-mult {cfg.width_mult:g}", parameters * 4 * 4)
    step_bytes = float(cfg.batch_size) * h * w * (3 + _STEP_BYTES_PER_PIXEL * cfg.width_mult)
    require_memory(f"--batch-size {cfg.batch_size} (with --width-mult {cfg.width_mult:g})", step_bytes)
