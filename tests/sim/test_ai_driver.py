import numpy as np
import pytest

from vision_rl.sim.ai_driver import DEFAULT_SKILL, AIDriver, AIParams, DisruptionParams, Disruptor
from vision_rl.sim.racing_line import optimise_racing_line
from vision_rl.sim.speed_profile import profile_for_line
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import get_preset
from vision_rl.sim.world import World, WorldConfig

CONFIG = WorldConfig(physics_dt_s=0.01, control_dt_s=0.02)
#: Wall clearance of the racing line beyond the car's half width, m: the AI's tracking error at skill 1.0 (up to
#: about 0.7 m, measured) plus the footprint's extra width at an angle. At 0.5 m the gt3 brushed walls.
SAFETY_M = 0.75


def _setup(track_spec: str, car_name: str):
    track, car = load_track(track_spec), get_preset(car_name)
    line = optimise_racing_line(track, 0.5 * car.width_m + SAFETY_M)
    return track, car, line, profile_for_line(car, line)


def _flying_laps(track_spec, car_name, skills, laps=1):
    """Cars on the racing line 150 m before the start/finish line at their target speed; returns world, limit."""
    track, car, line, limit = _setup(track_spec, car_name)
    skills = np.asarray(skills, dtype=float)
    n = len(skills)
    world = World(track, car, n_cars=n, config=CONFIG)
    ai = AIDriver(car, line, limit, n, skill=skills)
    s0 = np.full(n, track.length_m - 150.0)
    line_s = line.line_s_at(s0)
    heading = np.interp(
        line_s, np.append(line.s_m, line.length_m), np.unwrap(np.append(line.heading_rad, line.heading_rad[0]))
    )
    world.reset(s0, line.lateral_at(s0), skills * ai.reference.speed_at(line_s), heading - track.heading_at(s0))
    max_error = np.zeros(n)
    steps = int((laps + 0.5) * 1.5 * limit.lap_time_s / CONFIG.control_dt_s)
    for _ in range(steps):
        world.step(*ai.act(world.state))
        err = np.abs(world.state.lateral_m - line.lateral_at(world.state.s_m))
        max_error = np.maximum(max_error, err)
        if all(len(t) >= laps for t in world.lap_times_s):
            break
    return world, limit, max_error


def test_skill_one_is_near_the_limit_and_the_default_clearly_slower():
    world, limit, max_error = _flying_laps("technical", "hatchback", [1.0, DEFAULT_SKILL])
    lap_full, lap_default = (world.lap_times_s[i][0] / limit.lap_time_s - 1.0 for i in range(2))
    # Measured: +1.6 % and +10.3 %. The issue: within 4 % at skill 1.0, 8-12 % slower at the default skill.
    assert 0.0 < lap_full <= 0.04
    assert 0.08 <= lap_default <= 0.12
    np.testing.assert_array_equal(world.state.wall_contact_time_s, 0.0)
    assert max_error[0] < 0.5  # metres off the racing line at most


def test_ai_completes_a_lap_on_an_unseen_random_track_with_the_gt3():
    world, limit, _ = _flying_laps("random:4242", "gt3", [1.0, DEFAULT_SKILL])
    assert [len(t) for t in world.lap_times_s] == [1, 1]
    assert world.lap_times_s[0][0] / limit.lap_time_s - 1.0 <= 0.04  # measured +2.1 %, default skill +10.7 %
    # Measured 0 s of wall contact at both skills; at the limit a brush is tolerated (on the one-QP line the gt3
    # touched once at 220 km/h for 0.12 s).
    assert world.state.wall_contact_time_s[0] < 0.5
    assert world.state.wall_contact_time_s[1] == 0.0


def test_commands_are_deterministic():
    def run():
        track, car, line, limit = _setup("technical", "tt_cup")
        world = World(track, car, n_cars=3, config=CONFIG)
        ai = AIDriver(car, line, limit, 3, skill=[1.0, 0.9, 0.8])
        world.reset(np.array([0.0, 500.0, 1000.0]), 0.0, 20.0)
        out = []
        for _ in range(300):
            steer, omega = ai.act(world.state)
            world.step(steer, omega)
            out.append(np.concatenate([steer, omega, world.state.vehicle.x_m]))
        return np.array(out)

    np.testing.assert_array_equal(run(), run())


def test_commands_stay_in_range_and_batch_like_single_cars():
    track, car, line, limit = _setup("technical", "hatchback")
    world = World(track, car, n_cars=4, config=CONFIG)
    ai = AIDriver(car, line, limit, 4, skill=[1.0, 0.9, 0.7, 0.5])
    world.reset(np.array([10.0, 700.0, 1400.0, 2100.0]), np.array([2.0, -2.0, 0.0, 1.0]), 15.0, 0.2)
    steer, omega = ai.act(world.state)
    assert np.all(np.abs(steer) <= car.steer_limit_rad) and np.all(np.abs(omega) <= 1.0)
    # Car 2 alone in a world gets the same command as in the batch.
    single = World(track, car, n_cars=1, config=CONFIG)
    single.reset(1400.0, 0.0, 15.0, 0.2)
    s1, o1 = AIDriver(car, line, limit, 1, skill=0.7).act(single.state)
    np.testing.assert_allclose([s1[0], o1[0]], [steer[2], omega[2]], rtol=1e-12)
    # A car left of the line steers right, and a car right of it steers left (on a straight).
    on_straight = World(track, car, n_cars=2, config=CONFIG)
    s_straight = float(track.s_m[np.argmin(np.abs(np.convolve(track.curvature_1pm, np.ones(101), "same")))])
    on_straight.reset(s_straight, line.lateral_at(np.array([s_straight]))[0] + np.array([1.0, -1.0]), 20.0)
    st, _ = AIDriver(car, line, limit, 2, skill=0.9).act(on_straight.state)
    assert st[0] < 0.0 < st[1]


def test_opponent_follows_a_slower_car_without_contact():
    track, car, line, limit = _setup("expressway", "tt_cup")
    world = World(track, car, n_cars=2, groups=np.array([0, 0]), config=CONFIG)
    ai = AIDriver(car, line, limit, 2, skill=np.array([0.5, 1.0]), groups=np.array([0, 0]))
    s = np.array([60.0, 30.0])  # car 0, slow, 30 m ahead of car 1 on the start of the main straight
    world.reset(s, line.lateral_at(s), np.array([20.0, 30.0]))
    contact = False
    for _ in range(int(20.0 / CONFIG.control_dt_s)):
        world.step(*ai.act(world.state))
        contact |= bool(world.state.car_contact.any())
    gap = track.progress_delta(world.state.s_m[1], world.state.s_m[0])
    assert not contact
    assert car.length_m < gap < 60.0  # it closed up and stayed behind
    # Without groups the same fast car simply drives through (ghosts): no following.
    ghost = AIDriver(car, line, limit, 2, skill=np.array([0.5, 1.0]))
    assert ghost._follow_speed(world.state, np.array([20.0, 30.0]))[1] == np.inf


def test_disruptor_is_seeded_bounded_and_holds_its_offsets():
    params = DisruptionParams(steer_offset_rad=0.1, omega_offset=0.4, hold_s=(0.5, 1.0), quiet_probability=0.25)
    n, dt = 200, 0.02

    def run(seed):
        d = Disruptor(n, params, seed=seed)
        return np.array([np.concatenate(d(np.zeros(n), np.zeros(n), dt)) for _ in range(200)])

    a, b, c = run(3), run(3), run(4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    steer = a[:, :n]
    assert np.abs(steer).max() <= 0.1 and np.abs(a[:, n:]).max() <= 0.4
    changes = np.flatnonzero(np.diff(steer[:, 0]) != 0.0)
    held_steps = np.diff(changes)
    assert held_steps.min() >= 0.5 / dt - 1 and held_steps.max() <= 1.0 / dt + 1
    first = steer[0]
    assert 0.15 < np.mean(first == 0.0) < 0.35  # the quiet periods


def test_bad_arguments_raise():
    _, car, line, limit = _setup("technical", "hatchback")
    with pytest.raises(ValueError, match="skill"):
        AIDriver(car, line, limit, 2, skill=[1.0, 1.5])
    with pytest.raises(ValueError, match="groups"):
        AIDriver(car, line, limit, 2, groups=np.array([0, 0, 1]))
    with pytest.raises(ValueError, match="grip_usage"):
        AIParams(grip_usage=0.0)


def test_steering_never_asks_the_front_tyres_past_their_peak_slip_near_the_limit():
    track, car, line, limit = _setup("technical", "gt3")
    world = World(track, car, n_cars=1, config=CONFIG)
    ai = AIDriver(car, line, limit, 1, skill=1.0)
    s = np.array([200.0])
    # Off the line by 1.5 m (near the wall: the world refuses a car placed beyond it) and pointing away from the line
    # at the reference speed: the path feedback alone would ask for more lock than the front tyres can use.
    world.reset(s, line.lateral_at(s) + 1.5, ai.reference.speed_at(line.line_s_at(s)), 0.3)
    veh = world.state.vehicle
    front_path = np.arctan2(veh.vy_mps + car.cg_to_front_axle_m * veh.yaw_rate_radps, veh.vx_mps)
    peak = car.tyre_front.peak_slip_angle_rad
    uncapped, _ = AIDriver(car, line, limit, 1, skill=1.0, params=AIParams(front_slip_share=0.0)).act(world.state)
    capped, _ = ai.act(world.state)
    assert np.abs(uncapped - front_path)[0] > peak  # the state needs the cap
    np.testing.assert_allclose(np.abs(capped - front_path), peak, rtol=1e-9)
    # Well below the reference speed (a slower or a disrupted car, which must steer against its offsets) it is off.
    world.reset(s, line.lateral_at(s) + 1.5, 0.8 * ai.reference.speed_at(line.line_s_at(s)), 0.3)
    slow, _ = ai.act(world.state)
    slow_uncapped, _ = AIDriver(car, line, limit, 1, skill=1.0, params=AIParams(front_slip_share=0.0)).act(world.state)
    assert slow[0] == slow_uncapped[0]


def test_a_car_running_wide_in_a_corner_lifts():
    track, car, line, limit = _setup("technical", "hatchback")
    # The tightest corner of the line, a car on the line and one 1 m wide of it (towards the outside).
    i = int(np.argmax(np.abs(np.convolve(line.curvature_1pm, np.ones(21) / 21, "same"))))
    s = np.full(2, line.track_s_m[i])
    outside = -np.sign(line.curvature_1pm[i])
    world = World(track, car, n_cars=2, config=CONFIG)
    ai = AIDriver(car, line, limit, 2, skill=1.0)
    world.reset(s, line.lateral_at(s) + np.array([0.0, outside * 1.0]), ai.reference.speed_mps[i])
    _, omega = ai.act(world.state)
    _, no_lift = AIDriver(car, line, limit, 2, skill=1.0, params=AIParams(wide_lift_per_m=0.0)).act(world.state)
    # The lift is wide_lift_per_m * (1 m - deadband) = 0.7 off the command; being 1 m off the line alone changes
    # the command by much less (its speed target and feedforward are read a metre further along).
    lift = ai.params.wide_lift_per_m * (1.0 - ai.params.wide_deadband_m)
    assert abs(no_lift[1] - omega[0]) < 0.15
    # (then clipped where an axle's friction ellipse caps the braking)
    assert omega[1] < no_lift[1] - min(lift, 0.3)
    # Well below the limit (a slower or disrupted car) it does not lift.
    world.reset(s, line.lateral_at(s) + np.array([0.0, outside * 1.0]), 0.8 * ai.reference.speed_mps[i])
    _, slow = ai.act(world.state)
    _, slow_no_lift = AIDriver(car, line, limit, 2, skill=1.0, params=AIParams(wide_lift_per_m=0.0)).act(world.state)
    assert slow[1] == slow_no_lift[1]
