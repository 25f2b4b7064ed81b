"""Normalized actions of the newer environment versions (TimeTrial-v2, Overtaking-v2, PixelRacing-v1).

Their action space is ``Box(-1, 1)``, as Stable-Baselines3 and most agents expect; the environment maps each entry
linearly onto its physical range (-1 to the range's low end, +1 to its high end) before anything else reads it, so
the older versions' physics, rewards and records stay as they were.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces


def unit_box(size: int) -> spaces.Box:
    """``Box(-1, 1, (size,), float32)``: a normalized action space."""
    return spaces.Box(-1.0, 1.0, (size,), dtype=np.float32)


def to_physical(action: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Normalized actions (..., k) in [-1, 1] (clipped) as physical ones in [low, high] (k,), float64:
    ``low + (a + 1) / 2 * (high - low)``; the ends map exactly onto ``low`` and ``high``."""
    a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    return low + 0.5 * (a + 1.0) * (high - low)


def bounded_box(low: np.ndarray, high: np.ndarray) -> spaces.Box:
    """A float32 ``Box`` of float64 bounds (-inf/inf where none is known). Rounding to float32 keeps order, so the
    float32 observation of any value within the float64 bounds lies within the box."""
    return spaces.Box(np.asarray(low, dtype=np.float32), np.asarray(high, dtype=np.float32), dtype=np.float32)
