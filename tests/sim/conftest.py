"""Small tracks with known geometry for the simulator tests."""

import numpy as np
import pytest

from tests.helpers.tracks import stadium_points
from vision_rl.sim.track import Track


@pytest.fixture(scope="session")
def stadium() -> Track:
    """400 m straights, 60 m radius bends, 6 m from the centre line to each wall; s = 0 at the origin."""
    return Track.from_centre_line("stadium", stadium_points(), 6.0, 6.0)


@pytest.fixture(scope="session")
def circle() -> Track:
    """Counter-clockwise circle of radius 100 m about the origin, 5 m to each wall."""
    a = np.linspace(0.0, 2 * np.pi, 400, endpoint=False)
    return Track.from_centre_line("circle", 100.0 * np.stack([np.cos(a), np.sin(a)], axis=1), 5.0, 5.0)
