"""Small tracks with known geometry for the simulator tests."""

import numpy as np
import pytest

from vision_rl.sim.track import Track


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


@pytest.fixture(scope="session")
def stadium() -> Track:
    """400 m straights, 60 m radius bends, 6 m from the centre line to each wall; s = 0 at the origin."""
    return Track.from_centre_line("stadium", stadium_points(), 6.0, 6.0)


@pytest.fixture(scope="session")
def circle() -> Track:
    """Counter-clockwise circle of radius 100 m about the origin, 5 m to each wall."""
    a = np.linspace(0.0, 2 * np.pi, 400, endpoint=False)
    return Track.from_centre_line("circle", 100.0 * np.stack([np.cos(a), np.sin(a)], axis=1), 5.0, 5.0)
