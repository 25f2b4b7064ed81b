"""Shared tracks of the render tests (the ``gl_available`` guard is the root conftest's)."""

import numpy as np
import pytest

from vision_rl.sim.track import Track


def circle_track(name: str, radius_m: float, width_m: float) -> Track:
    """Counter-clockwise circle about the origin; s = 0 at (radius, 0) heading +y."""
    a = np.linspace(0.0, 2 * np.pi, 400, endpoint=False)
    return Track.from_centre_line(name, radius_m * np.stack([np.cos(a), np.sin(a)], axis=1), width_m, width_m)


@pytest.fixture(scope="session")
def wide_circle() -> Track:
    """Radius 600 m (no kerbs), 30 m from the centre line to each wall: the far wall is 60 m away."""
    return circle_track("wide", 600.0, 30.0)


@pytest.fixture(scope="session")
def tight_circle() -> Track:
    """Radius 60 m, 6 m to each wall: a corner all the way round (kerbs everywhere)."""
    return circle_track("tight", 60.0, 6.0)
