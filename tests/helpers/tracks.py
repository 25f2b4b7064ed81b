"""Small tracks of known geometry: the stadium's centre line and the Phase-2 tests' 677 m stadium as a CSV."""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: A stadium of 150 m straights and 60 m-radius bends, 6 m from the centre line to each wall: a 677 m lap, about 26 s
#: at the limit (the built-in AI completes laps here; on tighter stadiums it hit walls when this was written).
STADIUM = (150.0, 60.0, 6.0)


def stadium_points(straight_m: float = 400.0, radius_m: float = 60.0, step_m: float = 2.0) -> np.ndarray:
    """Counter-clockwise stadium: the bottom straight runs along +x from (0, 0), the top one back along y = 2R."""
    n_straight = int(straight_m / step_m)
    n_arc = int(np.pi * radius_m / step_m)
    bottom = np.stack([np.arange(n_straight) * step_m, np.zeros(n_straight)], axis=1)
    a = -np.pi / 2 + np.arange(n_arc) * np.pi / n_arc
    right = np.stack([straight_m + radius_m * np.cos(a), radius_m + radius_m * np.sin(a)], axis=1)
    top = np.stack([straight_m - np.arange(n_straight) * step_m, np.full(n_straight, 2 * radius_m)], axis=1)
    left = np.stack([radius_m * np.cos(a + np.pi), radius_m + radius_m * np.sin(a + np.pi)], axis=1)
    return np.vstack([bottom, right, top, left])


def stadium_csv(path: Path, straight_m: float, radius_m: float, half_width_m: float) -> Path:
    """Counter-clockwise stadium in the racetrack-database CSV format; s = 0 at the origin, on the bottom straight."""
    xy = stadium_points(straight_m, radius_m)
    rows = np.column_stack([xy, np.full(len(xy), half_width_m), np.full(len(xy), half_width_m)])
    np.savetxt(path, rows, delimiter=",", header="x_m,y_m,w_tr_right_m,w_tr_left_m")
    return path
