import numpy as np
import pytest

from vision_rl.envs.rewards import overtaking_reward, racing_reward, steering_change_penalty, wrapped_gap_m


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


def test_steering_change_penalty_is_quadratic_in_the_change_and_zero_without_one():
    limit = np.pi / 6
    prev = np.array([0.0, limit, -limit, 0.1])
    now = np.array([0.0, -limit, -limit, 0.2])
    # no change, a full flip (2 limits: 4 c_s), no change at full lock, a 0.1 rad correction
    expected = 0.5 * np.array([0.0, 4.0, 0.0, (0.1 / limit) ** 2])
    np.testing.assert_allclose(steering_change_penalty(prev, now, limit, 0.5), expected)


def test_env_charges_the_steering_change_between_commands_and_not_at_an_episode_start():
    from vision_rl.envs.core import RacingConfig, RacingCore

    def rewards(c_s, steers):
        core = RacingCore(RacingConfig(track="expressway", n_groups=1, steer_change_penalty_c_s=c_s), seed=3)
        core.reset_groups(np.array([0]))
        start = core.world.state.vehicle.steer_rad[0]
        out = [core.step(np.array([[start + ds, 0.5]]), autoreset=False)[1][0] for ds in steers]
        return np.array(out), start

    steers = [0.0, 0.2, -0.2, -0.2]
    base, start = rewards(0.0, steers)
    charged, _ = rewards(2.0, steers)
    commands = start + np.array(steers)
    changes = np.diff(np.concatenate([[start], commands])) / (np.pi / 6)
    np.testing.assert_allclose(base - charged, 2.0 * changes**2, rtol=1e-5, atol=1e-5)
    assert base[0] == pytest.approx(charged[0])  # the start command equals the placed wheel angle
