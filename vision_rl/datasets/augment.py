"""On-the-fly photometric and small-shift augmentation of frame batches (torch ops, batched, any device)."""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import torch


@dataclass(frozen=True)
class FrameAugmentation:
    """Random per-frame changes applied to float frames in [0, 1], shape (N, 3, H, W).

    Photometric changes leave the geometry, and so the targets, untouched. A shift moves the picture as a small
    camera yaw or pitch would, which the heading and edge targets do not follow: keep ``shift_px`` to a few pixels
    (0 turns it off; the default).
    """

    brightness: float = 0.2
    """Multiplicative brightness factor drawn from [1 - b, 1 + b] (dimensionless)."""
    contrast: float = 0.2
    """Contrast factor around the frame's mean grey, from [1 - c, 1 + c]."""
    saturation: float = 0.2
    """Saturation factor around each pixel's grey, from [1 - s, 1 + s]."""
    shift_px: int = 0
    """Largest shift, pixels, drawn uniformly in [-shift_px, shift_px] per axis; edges are replicated."""

    @property
    def enabled(self) -> bool:
        return self.brightness > 0 or self.contrast > 0 or self.saturation > 0 or self.shift_px > 0

    def __call__(self, x: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        if x.ndim != 4 or x.shape[1] != 3:
            raise ValueError(f"expected float frames (N, 3, H, W), got {tuple(x.shape)}")
        n = x.shape[0]

        def factor(amount: float) -> torch.Tensor:
            u = torch.rand(n, 1, 1, 1, generator=generator, device="cpu").to(x.device, x.dtype)
            return 1.0 + amount * (2.0 * u - 1.0)

        # ITU-R BT.601 luma weights, as torchvision's rgb_to_grayscale.
        luma = torch.tensor([0.299, 0.587, 0.114], device=x.device, dtype=x.dtype).view(1, 3, 1, 1)
        if self.brightness > 0:
            x = x * factor(self.brightness)
        if self.contrast > 0:
            mean = (x * luma).sum(dim=1, keepdim=True).mean(dim=(2, 3), keepdim=True)
            x = (x - mean) * factor(self.contrast) + mean
        if self.saturation > 0:
            grey = (x * luma).sum(dim=1, keepdim=True)
            x = (x - grey) * factor(self.saturation) + grey
        x = x.clamp(0.0, 1.0)
        if self.shift_px > 0:
            x = shift_frames(x, self.shift_px, generator)
        return x


def shift_frames(x: torch.Tensor, max_shift_px: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """Shift each frame of (N, C, H, W) by its own integer (dy, dx) in [-max, max], replicating the edges."""
    n, _, h, w = x.shape
    k = int(max_shift_px)
    d = torch.randint(-k, k + 1, (2, n), generator=generator, device="cpu").to(x.device)
    rows = (torch.arange(h, device=x.device).view(1, h) - d[0].view(n, 1)).clamp_(0, h - 1)  # (n, h)
    cols = (torch.arange(w, device=x.device).view(1, w) - d[1].view(n, 1)).clamp_(0, w - 1)  # (n, w)
    batch = torch.arange(n, device=x.device).view(n, 1, 1)
    # Advanced indices around the channel slice put their broadcast (n, h, w) first: result (n, h, w, c).
    out = x[batch, :, rows.view(n, h, 1), cols.view(n, 1, w)]
    return out.permute(0, 3, 1, 2).contiguous()


_LEFT_RIGHT = {"min_distance_left_edge": "min_distance_right_edge", "min_distance_right_edge": "min_distance_left_edge"}


def target_mirror(target_names: tuple[str, ...] | list[str]) -> tuple[np.ndarray, np.ndarray]:
    """How the targets of a frame change when the frame is mirrored left-right: ``mirrored = y[:, perm] * sign``.

    A mirrored frame is what the car would see on the mirrored track at the mirrored pose (the camera sits on the
    car's centre line), so every target has an exact mirrored value: the edge rays at +a and -a swap, so do the left
    and right minimum distances, and the signed centre offset, heading angle and curvatures change sign.
    """
    names = list(target_names)
    perm, sign = np.arange(len(names)), np.ones(len(names))
    for i, name in enumerate(names):
        edge = re.fullmatch(r"edge_distance_([+-])(\d+)deg", name)
        if edge:
            angle = int(edge.group(2))
            partner = f"edge_distance_{-angle if edge.group(1) == '+' else angle:+03d}deg"
        elif name in _LEFT_RIGHT:
            partner = _LEFT_RIGHT[name]
        elif name in ("centre_line_offset", "heading_angle_to_centre_line") or name.startswith("curvature_"):
            partner, sign[i] = name, -1.0
        else:
            raise ValueError(f"no mirrored value known for target {name!r}")
        if partner not in names:
            raise ValueError(f"target {name!r} mirrors to {partner!r}, which is not among the targets")
        perm[i] = names.index(partner)
    return perm, sign
