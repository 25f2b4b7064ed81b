import numpy as np
import pytest

from vision_rl.envs.rewards import overtaking_reward, racing_reward, wrapped_gap_m


def test_racing_reward_is_progress_minus_wall_penalty_in_contact_only():
    progress = np.array([3.0, -2.0, 3.0, 3.0])
    wall = np.array([False, False, True, True])
    speed = np.array([30.0, 20.0, 10.0, 20.0])
    r = racing_reward(progress, wall, speed, 0.005)
    np.testing.assert_allclose(r, [3.0, -2.0, 3.0 - 0.5, 3.0 - 2.0])
    # The penalty scales with |v|^2: doubling the speed quadruples it.
    assert (3.0 - r[3]) == pytest.approx(4 * (3.0 - r[2]))


def test_wrapped_gap_is_signed_and_survives_the_line():
    lap = 1000.0
    gap = wrapped_gap_m(np.array([10.0, 990.0, 600.0, 100.0]), np.array([990.0, 10.0, 150.0, 700.0]), lap)
    np.testing.assert_allclose(gap, [20.0, -20.0, 450.0, 400.0])  # 600 m behind is 400 m ahead


def test_overtaking_term_rewards_closing_and_passing_penalises_falling_back_ignores_far_cars():
    racing = np.zeros(4)
    no_contact = np.zeros(4, dtype=bool)
    speed = np.full(4, 30.0)
    # Opponent ahead by 20 m: ego closes to 15 m (+), falls back to 25 m (-); opponent behind by 10 m: ego pulls
    # away to 12 m (+); opponent 80 m ahead, beyond c_d = 50 m: nothing.
    prev = np.array([[20.0], [20.0], [-10.0], [80.0]])
    now = np.array([[15.0], [25.0], [-12.0], [75.0]])
    r = overtaking_reward(racing, no_contact, speed, prev, now, 0.005, 1.0, 50.0)
    np.testing.assert_allclose(r, [5.0, -5.0, 2.0, 0.0])


def test_car_contact_penalty_scales_with_speed_squared():
    gaps = np.zeros((2, 0))
    r = overtaking_reward(np.zeros(2), np.array([True, True]), np.array([10.0, 20.0]), gaps, gaps, 0.01, 1.0, 50.0)
    np.testing.assert_allclose(r, [-1.0, -4.0])
