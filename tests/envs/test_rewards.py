import numpy as np
import pytest

from vision_rl.envs.rewards import (
    overtaking_reward,
    racing_reward,
    steering_change_penalty,
    wall_penalty_speed_mps,
    wrapped_gap_m,
)

LIMIT = np.pi / 6


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


def test_steering_change_penalty_takes_a_scale_per_car():
    # the angle usable at two speeds: the same 0.07 rad change costs (0.07/0.07)^2 c_s and (0.07/0.5)^2 c_s
    scale = np.array([0.07, 0.5])
    np.testing.assert_allclose(steering_change_penalty(np.zeros(2), np.full(2, 0.07), scale, 2.0), [2.0, 0.0392])


@pytest.mark.parametrize("scale", ["limit", "usable"])
def test_env_charges_the_steering_change_between_commands_and_not_at_an_episode_start(scale):
    from vision_rl.envs.core import RacingConfig, RacingCore, usable_steer_rad

    def rewards(c_s, steers):
        config = RacingConfig(
            track="expressway", n_groups=1, steer_change_penalty_c_s=c_s, steer_change_penalty_scale=scale
        )
        core = RacingCore(config, seed=3)
        core.reset_groups(np.array([0]))
        start = core.world.state.vehicle.steer_rad[0]
        out, speeds = [], []
        for ds in steers:
            vehicle = core.world.state.vehicle
            speeds.append(np.hypot(vehicle.vx_mps[0], vehicle.vy_mps[0]))
            out.append(core.step(np.array([[start + ds, 0.5]]), autoreset=False)[1][0])
        return np.array(out), start, np.array(speeds), core.car.wheelbase_m

    steers = [0.0, 0.02, -0.02, -0.02]
    base, start, speeds, wheelbase_m = rewards(0.0, steers)
    charged, *_ = rewards(2.0, steers)
    commands = start + np.array(steers)
    # the usable angle at the step's starting speed (here 37 m/s: 0.11 rad) against the command's limit
    scale_rad = LIMIT if scale == "limit" else usable_steer_rad(speeds, wheelbase_m)
    if scale == "usable":
        assert 0.10 < scale_rad.max() < 0.12
    changes = np.diff(np.concatenate([[start], commands])) / scale_rad
    np.testing.assert_allclose(base - charged, 2.0 * changes**2, rtol=1e-4, atol=1e-5)
    assert base[0] == pytest.approx(charged[0])  # the start command equals the placed wheel angle


def test_wall_penalty_speed_end_is_the_step_end_and_impact_the_larger_of_start_and_end():
    start = np.array([42.0, 20.0, 20.0])
    end = np.array([24.0, 20.0, 22.0])
    np.testing.assert_array_equal(wall_penalty_speed_mps(start, end, "end"), end)
    np.testing.assert_array_equal(wall_penalty_speed_mps(start, end, "impact"), [42.0, 20.0, 22.0])
    with pytest.raises(ValueError, match="'end' or 'impact'"):
        wall_penalty_speed_mps(start, end, "start")


def _into_the_hairpin(steps: int, omega: float = 0.97, **config):
    """A car placed at 154 km/h before expressway's 32 m hairpin (0.87 km), full left lock asked each step: the
    speeds (from the start's), rewards, wall contact and the throttle cut's steps left after each step."""
    from vision_rl.envs.core import RacingConfig, RacingCore

    core = RacingCore(
        RacingConfig(track="expressway", n_groups=1, steer_action="rate_scaled", normalize=False, **config), seed=0
    )
    core.reset_groups(np.array([0]))
    core.world.reset(s_m=np.array([860.0]), lateral_m=np.array([-2.5]), speed_mps=np.array([42.8]), car_ids=[0])
    core.steer_command_rad[:] = 0.0
    speeds, rewards, walls, left = [42.8], [], [], []
    for _ in range(steps):
        rewards.append(core.step(np.array([[-LIMIT, omega]]), autoreset=False)[1][0])
        v = core.world.state.vehicle
        speeds.append(float(np.hypot(v.vx_mps[0], v.vy_mps[0])))
        walls.append(bool(core.world.state.wall_contact[0]))
        left.append(int(core.throttle_cut_left[0]))
    return np.array(speeds), np.array(rewards), np.array(walls), np.array(left), core


def test_the_wall_brakes_a_car_that_enters_the_hairpin_flat_out_and_impact_charges_the_speed_that_hit():
    """The exploit state policies learned on expressway (docs/results/state-expressway-hatchback-clean): at
    154 km/h into the 32 m hairpin at 0.87 km with the throttle on, the outer wall takes the car to about 85 km/h
    within two 0.1 s steps; ``end`` charges that step at the speed left, ``impact`` at the speed that hit."""
    speeds, end_rewards, walls, _, _ = _into_the_hairpin(30, wall_penalty_speed="end")
    _, impact_rewards, _, _, _ = _into_the_hairpin(30, wall_penalty_speed="impact")
    hit = int(np.argmax(walls))
    assert walls[hit], "the car never reached the wall"
    assert 3.6 * (speeds[hit] - speeds[hit + 2]) > 50.0  # the wall as a brake: measured 153 -> 91 km/h in 0.2 s
    for k in (hit, hit + 1):  # each step charged at its start speed (the larger), not at what the wall left
        charged_more = end_rewards[k] - impact_rewards[k]
        assert charged_more == pytest.approx(0.005 * (speeds[k] ** 2 - speeds[k + 1] ** 2), rel=1e-6)
    np.testing.assert_allclose(end_rewards[:hit], impact_rewards[:hit])  # no contact, no difference


def test_a_wall_hit_cuts_the_throttle_for_the_set_time_and_leaves_the_brake():
    free, _, walls, left_free, _ = _into_the_hairpin(45)
    cut, _, walls_cut, left, core = _into_the_hairpin(45, wall_hit_throttle_cut_s=1.5)
    free, cut = free[1:], cut[1:]  # the speed after each step
    hit = int(np.argmax(walls))
    assert walls[hit] and not walls[:hit].any()
    np.testing.assert_array_equal(cut[: hit + 1], free[: hit + 1])  # the same up to the step that hits
    assert left[hit] == 15 and not left[:hit].any() and not left_free.any()  # 1.5 s of 0.1 s steps
    assert cut[hit + 1] < free[hit + 1]  # no throttle in the next step
    begins = np.flatnonzero(walls_cut[1:] & ~walls_cut[:-1]) + 1  # a later contact that begins re-arms the cut
    for k in range(hit + 1, len(left)):
        assert left[k] == (15 if k in begins else max(left[k - 1] - 1, 0))
    core.reset_groups(np.array([0]))
    assert core.throttle_cut_left[0] == 0 and not core.touching_wall[0]
    braking, _, _, _, _ = _into_the_hairpin(45, omega=-1.0)
    braking_cut, _, _, left_braking, _ = _into_the_hairpin(45, omega=-1.0, wall_hit_throttle_cut_s=1.5)
    assert left_braking.any()  # it hits the wall braking too
    np.testing.assert_array_equal(braking_cut, braking)  # the brake is never cut


def test_an_unknown_steering_penalty_scale_is_refused():
    from vision_rl.envs.core import RacingConfig

    with pytest.raises(ValueError, match=r"steer_change_penalty_scale must be one of .*'limit', 'usable'.*got 'speed'"):
        RacingConfig(steer_change_penalty_scale="speed")
