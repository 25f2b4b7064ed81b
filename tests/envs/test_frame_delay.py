"""The vision frame delay: frames of the state some control steps (or a fraction of one) ago, features current."""

import numpy as np
import pytest

from vision_rl.envs.observer import PoseHistory
from vision_rl.envs.racing_env import TimeTrial
from vision_rl.sim.world import WorldState

TRACK = "technical"
DT_S = 0.1


class _Vehicle:
    def __init__(self, x, y, yaw):
        self.x_m, self.y_m, self.yaw_rad = (np.asarray(a, dtype=float) for a in (x, y, yaw))


def _state(x, y, yaw) -> WorldState:
    # PoseHistory reads only the vehicle's pose.
    class _S:
        vehicle = _Vehicle(x, y, yaw)

    return _S()


def test_whole_steps_back_give_the_pose_of_that_step_and_fractions_interpolate_across_the_yaw_wrap():
    history = PoseHistory(2 * DT_S, DT_S)
    history.restart(_state([0.0, 5.0], [0.0, 0.0], [3.0, 0.0]))
    for k in range(1, 4):  # car 0 turns through +pi: 3.0, 3.1, -3.08 (= 3.2 - 2 pi), ...
        history.remember(_state([10.0 * k, 5.0], [0.0, k], [np.angle(np.exp(1j * (3.0 + 0.1 * k))), 0.0]))
    x, y, yaw = history.delayed(None)
    np.testing.assert_allclose(x, [10.0, 5.0])  # two steps before step 3
    np.testing.assert_allclose(y, [0.0, 1.0])
    np.testing.assert_allclose(np.angle(np.exp(1j * (yaw - np.array([3.1, 0.0])))), 0.0, atol=1e-12)

    half = PoseHistory(0.5 * DT_S, DT_S)
    half.restart(_state([0.0], [0.0], [3.1]))
    half.remember(_state([4.0], [2.0], [-3.1]))  # 0.083 rad further round, across +pi
    x, y, yaw = half.delayed(None)
    np.testing.assert_allclose([x[0], y[0]], [2.0, 1.0])
    assert np.cos(yaw[0]) == pytest.approx(-1.0, abs=1e-9)  # pi: halfway along the short arc, not through 0


def test_restart_forgets_only_the_placed_cars_and_history_starts_at_the_first_pose():
    history = PoseHistory(1.5 * DT_S, DT_S)
    history.restart(_state([0.0, 0.0], [0.0, 0.0], [0.0, 0.0]))
    history.remember(_state([1.0, 1.0], [0.0, 0.0], [0.0, 0.0]))
    history.remember(_state([2.0, 2.0], [0.0, 0.0], [0.0, 0.0]))
    history.restart(_state([50.0, 2.0], [0.0, 0.0], [0.0, 0.0]), np.array([0]))
    x, _, _ = history.delayed(None)
    np.testing.assert_allclose(x, [50.0, 0.5])  # car 0 placed anew: its pose now; car 1: 1.5 steps back


@pytest.mark.parametrize("delay_s", [-0.1, float("nan"), 2.0])
def test_a_delay_out_of_range_is_refused(delay_s):
    with pytest.raises(ValueError, match="frame delay"):
        PoseHistory(delay_s, DT_S)


def test_env_frames_lag_by_the_delay_and_features_do_not(gl_available):
    def rollout(delay_s):
        env = TimeTrial(track=TRACK, observation="vision", image_hw_px=(24, 40), frame_delay_s=delay_s)
        obs, _ = env.reset(seed=5)
        out = [obs]
        rng = np.random.default_rng(0)
        for _ in range(5):
            out.append(env.step(np.array([rng.uniform(-0.3, 0.3), 1.0], dtype=np.float32))[0])
        env.close()
        return out

    plain, delayed = rollout(0.0), rollout(2 * DT_S)
    for k in range(6):
        np.testing.assert_array_equal(delayed[k]["features"], plain[k]["features"])
        np.testing.assert_array_equal(delayed[k]["image"], plain[max(k - 2, 0)]["image"])
    assert not np.array_equal(plain[5]["image"], plain[3]["image"])  # the car moved: the lag is visible


def test_an_observer_put_into_the_environment_takes_its_delay():
    from vision_rl.envs.core import RacingConfig, RacingCore
    from vision_rl.envs.observer import Observer

    core = RacingCore(RacingConfig(track=TRACK, observation="vision", frame_delay_s=0.25))
    assert core.observer.pose_history.steps_back == pytest.approx(2.5)
    core.observer = Observer("vision", core.track, core.car, core.groups)  # as a trainer does with its encoder
    assert core.observer.pose_history.steps_back == pytest.approx(2.5)
