"""The encoder's error along a driver's lap: the frames are the driver's views at the recorded poses, the targets
are the poses' geometry, and each prediction is compared with its own frame's targets."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers.drivers import CentreLineFollower
from tests.helpers.rendering import renderer_available
from vision_rl.evaluation.encoder_error import (
    BATCH_FRAMES,
    NEAR_WALL_M,
    encoder_error,
    encoder_error_on_lap,
    lap_frames_and_targets,
)
from vision_rl.evaluation.protocol import time_laps

HW_PX = (48, 80)


def test_error_per_group_over_all_frames_near_the_wall_and_in_contact():
    true = np.zeros((4, 27))
    true[:, 13:15] = [[5.0, 5.0], [1.0, 6.0], [6.0, 0.5], [4.0, 4.0]]  # frames 1 and 2 within 1.5 m of a wall
    predicted = true.copy()
    predicted[:, 15] += [0.1, 0.2, 0.3, 0.4]  # centre offset off by these, m
    predicted[2, :13] -= 2.0  # every edge ray of frame 2 two metres short
    out = encoder_error(predicted, true, wall_contact=np.array([False, False, True, False]))
    assert NEAR_WALL_M == 1.5 and out["near_wall"]["frames"] == 2 and out["wall_contact"]["frames"] == 1
    assert out["all"]["centre_offset"] == pytest.approx(0.25)
    assert out["near_wall"]["centre_offset"] == pytest.approx(0.25)
    assert out["wall_contact"]["centre_offset"] == pytest.approx(0.3)
    assert out["all"]["edge_rays"] == pytest.approx(0.5) and out["wall_contact"]["edge_rays"] == pytest.approx(2.0)
    assert out["all"]["heading"] == 0.0 and out["units"]["heading"] == "rad"
    none = encoder_error(predicted, true, wall_contact=np.zeros(4, dtype=bool))["wall_contact"]
    assert none["frames"] == 0 and none["edge_rays"] is None


class _Replay:
    """An 'encoder' that answers the k-th frame it is shown with row k of ``answers``: it shows that predictions
    are compared with their own frame's targets across batches."""

    def __init__(self, answers: np.ndarray) -> None:
        self.answers, self.shown = answers, 0

    def predict_targets(self, frames: np.ndarray) -> np.ndarray:
        rows = self.answers[self.shown : self.shown + len(frames)]
        self.shown += len(frames)
        return rows


def test_frames_are_the_drivers_views_and_targets_their_geometry(small_track):
    reason = renderer_available()
    if reason:
        pytest.skip(reason)
    from vision_rl.render import RenderConfig, Renderer

    timing = time_laps(
        CentreLineFollower(), small_track, "hatchback", seeds=[0, 1], laps=1, time_limit_s=4.0, record=True
    )
    frames, targets, contact = lap_frames_and_targets(timing, 1, HW_PX)
    steps = len(timing.time_s)
    assert steps == 40 > BATCH_FRAMES and frames.shape == (steps, *HW_PX, 3) and targets.shape == (steps, 27)
    # A centre-line follower: on the centre line, along it, never at the wall.
    assert np.abs(targets[:, 15]).max() < 0.3 and np.abs(targets[:, 16]).max() < 0.1 and not contact.any()
    # Frame k is what car 1 saw at step k, rendered alone, past the first batch too.
    k = BATCH_FRAMES + 3
    config = RenderConfig(width_px=HW_PX[1], height_px=HW_PX[0], max_views=1)
    with Renderer(timing.track, config, car_length_m=timing.car.length_m, car_width_m=timing.car.width_m) as r:
        alone = r.render(timing.x_m[k : k + 1, 1], timing.y_m[k : k + 1, 1], timing.yaw_rad[k : k + 1, 1])
    np.testing.assert_array_equal(frames[k], alone[0])
    assert not np.array_equal(frames[k], frames[0])
    answers = targets.copy()
    answers[:, 15] += 0.4
    error = encoder_error_on_lap(timing, 1, _Replay(answers), HW_PX)
    assert error["all"]["frames"] == steps and error["all"]["centre_offset"] == pytest.approx(0.4)
    assert error["all"]["edge_rays"] == pytest.approx(0.0, abs=1e-9)


def test_a_timing_without_poses_is_refused(small_track):
    timing = time_laps(CentreLineFollower(), small_track, "hatchback", seeds=[0], laps=1, time_limit_s=1.0)
    with pytest.raises(ValueError, match="record=True"):
        lap_frames_and_targets(timing, 0, HW_PX)
