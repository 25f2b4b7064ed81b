"""Photometric and shift augmentation: ranges, geometry of the shift, determinism with a generator."""

from __future__ import annotations

import torch

from vision_rl.datasets.augment import FrameAugmentation, shift_frames


def ramp_frames(n: int, h: int = 10, w: int = 16) -> torch.Tensor:
    """Channel 0 holds the column index, channel 1 the row index: a shift shows as a constant offset."""
    cols = torch.arange(w, dtype=torch.float32).view(1, 1, w).expand(n, h, w)
    rows = torch.arange(h, dtype=torch.float32).view(1, h, 1).expand(n, h, w)
    return torch.stack([cols, rows, torch.zeros(n, h, w)], dim=1)


def test_shift_moves_each_frame_by_an_integer_within_range() -> None:
    x = ramp_frames(64)
    out = shift_frames(x, 3, torch.Generator().manual_seed(0))
    assert out.shape == x.shape
    # In the interior (away from replicated edges) out[..., c] = c - dx and out[r, ...] = r - dy.
    dx = (x[:, 0, 5, 5] - out[:, 0, 5, 5]).round()
    dy = (x[:, 1, 5, 5] - out[:, 1, 5, 5]).round()
    assert dx.abs().max() <= 3 and dy.abs().max() <= 3
    assert len(set(dx.tolist())) > 3  # frames get their own shifts
    interior = out[:, 0, 3:7, 3:13] - (x[:, 0, 3:7, 3:13] - dx.view(-1, 1, 1))
    assert interior.abs().max() == 0
    # Edges are replicated: column values stay inside the original range.
    assert out[:, 0].min() >= 0 and out[:, 0].max() <= 15


def test_photometric_changes_stay_in_range_and_brightness_scales() -> None:
    g = torch.Generator().manual_seed(1)
    x = torch.rand(32, 3, 8, 8, generator=g) * 0.5 + 0.2
    only_brightness = FrameAugmentation(brightness=0.2, contrast=0.0, saturation=0.0)
    out = only_brightness(x, torch.Generator().manual_seed(2))
    ratio = out / x
    per_frame = ratio.flatten(1)
    assert torch.allclose(per_frame.min(dim=1).values, per_frame.max(dim=1).values, rtol=1e-5)
    assert per_frame.min() >= 0.8 - 1e-6 and per_frame.max() <= 1.2 + 1e-6
    full = FrameAugmentation()(x, torch.Generator().manual_seed(3))
    assert full.min() >= 0 and full.max() <= 1 and not torch.equal(full, x)
    again = FrameAugmentation()(x, torch.Generator().manual_seed(3))
    assert torch.equal(full, again)
    assert not FrameAugmentation(brightness=0, contrast=0, saturation=0).enabled
