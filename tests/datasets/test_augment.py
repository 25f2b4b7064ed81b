"""Photometric and shift augmentation: ranges, geometry of the shift, determinism with a generator."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vision_rl.datasets.augment import FrameAugmentation, shift_frames, target_mirror
from vision_rl.sim.sensors import TARGET_NAMES, WallRayCaster, environment_targets
from vision_rl.sim.track import Track
from vision_rl.sim.track_library import load_track


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


def test_mirrored_targets_are_the_targets_on_the_mirrored_track() -> None:
    # Mirror the world about the y axis: the driving direction stays, left and right swap (so do the walls' widths),
    # a car at (x, y, yaw) goes to (-x, y, pi - yaw). Its targets there are the mirror map of the original ones.
    track = load_track("technical")
    mirrored = Track(
        "mirrored",
        track.centre_xy_m * [-1.0, 1.0],
        np.pi - track.heading_rad,
        -track.curvature_1pm,
        track.width_right_m,
        track.width_left_m,
    )
    rng = np.random.default_rng(3)
    s = rng.uniform(0.0, track.length_m, 40)
    xy = track.position_at(s, rng.uniform(-0.8, 0.8, 40) * track.min_width_m / 2)
    yaw = track.heading_at(s) + rng.uniform(-0.5, 0.5, 40)

    def targets(t: Track, xy: np.ndarray, yaw: np.ndarray) -> np.ndarray:
        proj = t.project(xy)
        return environment_targets(t, WallRayCaster(t), xy[:, 0], xy[:, 1], yaw, proj.s_m, proj.lateral_m)

    original = targets(track, xy, yaw)
    seen_mirrored = targets(mirrored, xy * [-1.0, 1.0], np.pi - yaw)
    perm, sign = target_mirror(TARGET_NAMES)
    assert sorted(perm) == list(range(len(TARGET_NAMES))) and set(sign) == {-1.0, 1.0}
    np.testing.assert_allclose(original[:, perm] * sign, seen_mirrored, atol=1e-6)
    assert np.abs(original[:, perm] * sign - original).max() > 1.0  # the map is not the identity on real data


def test_unknown_targets_have_no_mirror() -> None:
    with pytest.raises(ValueError, match="no mirrored value"):
        target_mirror(["speed_mps"])
    with pytest.raises(ValueError, match="not among the targets"):
        target_mirror(["edge_distance_+15deg"])
