"""A small Phase-1 encoder checkpoint (32 x 48 frames, 27 targets) with known weights and target statistics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from vision_rl.phase1_repr import save_checkpoint
from vision_rl.phase1_repr.encoder import EncoderConfig, ReprNet

CFG = EncoderConfig(
    input_height_px=32,
    input_width_px=48,
    stem_channels=8,
    stage_channels=(16, 32),
    stage_blocks=(1, 1),
    stage_strides=(2, 2),
    n_targets=27,
)
NAMES = [f"t{i}" for i in range(27)]
UNITS = ["m"] * 27


def trained_net(cfg: EncoderConfig = CFG, seed: int = 0) -> ReprNet:
    """A network of ``cfg`` whose BatchNorm statistics moved off their initial values, in eval mode."""
    torch.manual_seed(seed)
    net = ReprNet(cfg).train()
    x = torch.randint(0, 256, (4, cfg.input_height_px, cfg.input_width_px, 3), dtype=torch.uint8)
    with torch.no_grad():
        net(x)  # BatchNorm running statistics away from their initial values
    return net.eval()


def write_checkpoint(path: Path, cfg: EncoderConfig = CFG) -> tuple[ReprNet, np.ndarray, np.ndarray]:
    """Save :func:`trained_net` at ``path`` with known target statistics; (the network, target mean, target std)."""
    net = trained_net(cfg)
    n = cfg.n_targets
    mean, std = np.linspace(-1, 1, n).astype(np.float32), np.linspace(0.5, 2, n).astype(np.float32)
    save_checkpoint(
        path,
        net,
        target_names=NAMES[:n],
        target_units=UNITS[:n],
        target_mean=mean,
        target_std=std,
        metrics={"val_loss": 0.5},
    )
    return net, mean, std
