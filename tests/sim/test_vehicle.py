"""Vehicle dynamics: hand-computed physics pieces, realism targets, robustness, determinism, speed paths.

Realism checks drive the presets with simple controllers on an open plane (no track); every car of a sweep runs in
one batch.
"""

from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from vision_rl.sim import vehicle as vm
from vision_rl.sim.vehicle import (
    DEFAULT_CAR,
    GRAVITY_MPS2,
    PRESETS,
    TyreParams,
    VehicleState,
    advance,
    axle_loads_n,
    get_preset,
    initial_state,
    step,
)

G = GRAVITY_MPS2
KMH = 1.0 / 3.6
DT = 0.01


# ---------------------------------------------------------------------------------------------------- helpers
def _straight_line(params, omega_cmd: float, speed_mps: float, t_end_s: float):
    """One car on a straight with a constant throttle/brake command: (t, x, vx) per substep."""
    state = initial_state(1, speed_mps=speed_mps)
    n = round(t_end_s / DT)
    t, x, v = np.arange(n + 1) * DT, np.zeros(n + 1), np.zeros(n + 1)
    v[0] = speed_mps
    for k in range(n):
        state = step(params, state, 0.0, omega_cmd, DT)
        x[k + 1], v[k + 1] = state.x_m[0], state.vx_mps[0]
    return t, x, v


def _circle_sweep(params, speed_mps, radius_m, t_end_s: float = 20.0, ctrl_dt_s: float = 0.05) -> dict:
    """Each car starts on its own counter-clockwise circle (centre (0, R)) at its target speed and is held there by
    a path controller (curvature feed-forward, course and radius feedback with an integral) and a PI speed
    controller. A car "holds" when, over the last 3 s, it stays within 0.5 m of the circle and 0.3 m/s of its speed.
    Returns per-car arrays: held, steady steer, measured ay, nominal ay = v^2 / R, mean roll."""
    speed = np.asarray(speed_mps, dtype=float)
    radius = np.asarray(radius_m, dtype=float)
    n = speed.size
    wheelbase = params.wheelbase_m
    state = initial_state(n, speed_mps=speed)._replace(
        yaw_rate_radps=speed / radius, steer_rad=np.arctan(wheelbase / radius)
    )
    i_radius = np.zeros(n)
    i_speed = np.zeros(n)
    n_sub = round(ctrl_dt_s / DT)
    log = []
    for _ in range(round(t_end_s / ctrl_dt_s)):
        rel_x, rel_y = state.x_m, state.y_m - radius
        e_radius = np.hypot(rel_x, rel_y) - radius  # > 0: outside, turn in more
        course = state.yaw_rad + np.arctan2(state.vy_mps, state.vx_mps)
        e_course = np.angle(np.exp(1j * (np.arctan2(rel_y, rel_x) + np.pi / 2 - course)))
        v = np.hypot(state.vx_mps, state.vy_mps)
        lookahead = np.maximum(v, 5.0) * 1.0
        i_radius += e_radius * ctrl_dt_s
        kappa = 1.0 / radius + 2.0 * e_course / lookahead + (2.0 * e_radius + 0.5 * i_radius) / lookahead**2
        i_speed += (speed - v) * ctrl_dt_s
        omega = np.clip(0.5 * (speed - v) + 0.2 * i_speed, -1.0, 1.0)
        state = advance(params, state, np.arctan(wheelbase * kappa), omega, DT, n_sub)
        log.append((e_radius, v, state.steer_rad, state.ay_mps2, state.roll_rad))
    e_radius, v, steer, ay, roll = (np.array(a) for a in zip(*log, strict=True))
    last = slice(-round(3.0 / ctrl_dt_s), None)
    held = (np.abs(e_radius[last]).max(0) < 0.5) & (np.abs(v[last] - speed).max(0) < 0.3)
    return {
        "held": held,
        "steer": steer[last].mean(0),
        "ay": ay[last].mean(0),
        "ay_nominal": speed**2 / radius,
        "roll": roll[last].mean(0),
    }


def _max_held_ay_g(result: dict) -> float:
    assert result["held"].any() and not result["held"].all(), "the sweep must bracket the limit"
    return float(result["ay_nominal"][result["held"]].max() / G)


SKIDPAD_RADIUS_M = 50.0
SKIDPAD_AY_G = np.arange(0.1, 2.0, 0.02)


@pytest.fixture(scope="module")
def skidpad() -> dict:
    """Constant-radius (50 m) speed sweep for every preset, 0.1 g to 2 g in 0.02 g steps."""
    ay = SKIDPAD_AY_G * G
    return {
        name: _circle_sweep(get_preset(name), np.sqrt(ay * SKIDPAD_RADIUS_M), np.full(ay.size, SKIDPAD_RADIUS_M))
        for name in PRESETS
    }


def _random_state(n: int, rng: np.random.Generator) -> VehicleState:
    state = initial_state(n, rng.normal(0, 50, n), rng.normal(0, 50, n), rng.uniform(-np.pi, np.pi, n))
    return state._replace(
        vx_mps=rng.uniform(-2.0, 80.0, n),
        vy_mps=rng.normal(0.0, 2.0, n),
        yaw_rate_radps=rng.normal(0.0, 0.5, n),
        steer_rad=rng.uniform(-0.4, 0.4, n),
        omega=rng.uniform(-1.0, 1.0, n),
        ax_mps2=rng.normal(0.0, 5.0, n),
        ay_mps2=rng.normal(0.0, 5.0, n),
    )


# ---------------------------------------------------------------------------------------------------- parameters
def test_presets_carry_the_identified_figures():
    assert set(PRESETS) == {"hatchback", "tt_cup", "gt3"}
    assert DEFAULT_CAR == "hatchback"
    hatch, tt, gt3 = get_preset("hatchback"), get_preset("tt_cup"), get_preset("gt3")
    # The values identified inside GT Sport.
    assert (hatch.mass_kg, hatch.yaw_inertia_kgm2, hatch.cg_to_front_axle_m, hatch.cg_to_rear_axle_m) == (
        1355.0,
        2064.0,
        0.946,
        1.620,
    )
    tt_figures = (tt.mass_kg, tt.yaw_inertia_kgm2, tt.cg_to_front_axle_m, tt.cg_to_rear_axle_m)
    assert tt_figures == (1195.0, 1185.0, 1.02, 1.484)
    assert (hatch.drive, tt.drive, gt3.drive) == ("fwd", "fwd", "rwd")
    assert (hatch.max_power_w, tt.max_power_w, gt3.max_power_w) == (77_000.0, 228_000.0, 370_000.0)
    assert hatch.downforce_area_m2 == 0.0 and gt3.downforce_area_m2 > 1.0
    assert hatch.tyre_front.peak_mu == 1.0 and gt3.tyre_rear.peak_mu > 1.4  # road tyres vs slicks
    assert hatch.wheelbase_m == pytest.approx(2.566)
    for p in PRESETS.values():
        assert p.steer_limit_rad == min(np.pi / 6, p.max_steer_rad)
        assert p.static_front_load_n + p.static_rear_load_n == pytest.approx(p.mass_kg * G)


def test_get_preset_unknown_name_lists_the_presets():
    with pytest.raises(ValueError, match=r"gt3, hatchback, tt_cup"):
        get_preset("f1")


@pytest.mark.parametrize(
    "change",
    [
        {"drive": "4wd"},
        {"mass_kg": -1.0},
        {"mass_kg": float("nan")},
        {"brake_front_share": 1.2},
        {"drag_area_m2": -0.1},
        {"kinematic_below_mps": 6.0, "dynamic_above_mps": 5.0},
    ],
)
def test_bad_vehicle_params_are_rejected(change):
    with pytest.raises(ValueError):
        replace(get_preset("hatchback"), **change)


def test_bad_tyre_params_are_rejected():
    good = get_preset("hatchback").tyre_rear
    with pytest.raises(ValueError, match="curvature_e"):
        replace(good, curvature_e=1.2)
    with pytest.raises(ValueError):
        replace(good, peak_mu=0.0)


def test_magic_formula_peak_and_cornering_stiffness():
    tyre = TyreParams(
        stiffness_b_per_rad=10.0,
        shape_c=1.9,
        curvature_e=0.97,
        peak_mu=1.0,
        load_sensitivity=-0.1,
        nominal_load_n=4000.0,
    )
    b, c, e = tyre.stiffness_b_per_rad, tyre.shape_c, tyre.curvature_e
    peak = tyre.peak_slip_angle_rad
    assert 0.15 < peak < 0.21  # the dry-tarmac curve peaks near 10 deg
    assert vm._magic_formula(b, c, e, peak) == pytest.approx(1.0, abs=1e-12)
    for off in (0.9, 1.1, 2.0):
        assert vm._magic_formula(b, c, e, off * peak) < 1.0 - 1e-4
    assert vm._magic_formula(b, c, e, -peak) == pytest.approx(-1.0, abs=1e-12)  # odd in the slip angle
    # Slope at zero slip is B C D for a wheel at nominal load (D = mu Fz).
    h = 1e-7
    slope = 4000.0 * (vm._magic_formula(b, c, e, h) - vm._magic_formula(b, c, e, -h)) / (2 * h)
    assert slope == pytest.approx(tyre.cornering_stiffness_npr(4000.0), rel=1e-6)
    assert tyre.cornering_stiffness_npr(4000.0) == pytest.approx(10.0 * 1.9 * 4000.0)
    # Load sensitivity: mu falls 10 % per extra nominal load.
    assert tyre.mu_at(8000.0) == pytest.approx(0.9)


# ---------------------------------------------------------------------------------------------------- hand-computed
def test_static_load_split_transfer_and_downforce():
    hatch = get_preset("hatchback")
    m, lf, lr, h = hatch.mass_kg, hatch.cg_to_front_axle_m, hatch.cg_to_rear_axle_m, hatch.cg_height_m
    front, rear = axle_loads_n(hatch, 0.0, 0.0)
    assert front == pytest.approx(m * G * lr / (lf + lr), rel=1e-12)
    assert rear == pytest.approx(m * G * lf / (lf + lr), rel=1e-12)
    front_acc, rear_acc = axle_loads_n(hatch, 0.0, 3.0)  # accelerating: load moves to the rear
    assert front - front_acc == pytest.approx(m * 3.0 * h / (lf + lr), rel=1e-12)
    assert rear_acc - rear == pytest.approx(m * 3.0 * h / (lf + lr), rel=1e-12)
    gt3 = get_preset("gt3")
    v = 60.0
    downforce = 0.5 * gt3.air_density_kgpm3 * gt3.downforce_area_m2 * v**2
    f60, r60 = axle_loads_n(gt3, v, 0.0)
    f0, r0 = axle_loads_n(gt3, 0.0, 0.0)
    assert f60 - f0 == pytest.approx(gt3.downforce_front_share * downforce, rel=1e-12)
    assert r60 - r0 == pytest.approx((1 - gt3.downforce_front_share) * downforce, rel=1e-12)


def test_contact_impulse_in_the_acceleration_state_keeps_loads_and_forces_physical():
    """The world writes wall/car impulses (hundreds of m/s^2) into ax, ay; the next substep must not turn them into
    absurd tyre loads or forces."""
    p = get_preset("hatchback")
    weight = p.mass_kg * G
    front, rear = axle_loads_n(p, 0.0, np.array([-1000.0, 1000.0]))
    np.testing.assert_allclose(front + rear, weight)
    assert (front >= 0.05 * weight - 1e-9).all() and (rear >= 0.05 * weight - 1e-9).all()
    state = initial_state(4, speed_mps=30.0)._replace(
        ax_mps2=np.array([-1000.0, 1000.0, 0.0, -800.0]), ay_mps2=np.array([0.0, 0.0, 900.0, -900.0])
    )
    state = state._replace(vy_mps=np.array([0.0, 0.0, 2.0, -2.0]))
    out = step(p, state, 0.1, 0.5, DT)
    assert np.isfinite(np.array(out)).all()
    assert np.hypot(out.ax_mps2, out.ay_mps2).max() < 1.5 * G


@pytest.mark.parametrize("name", ["hatchback", "gt3"])
def test_coasting_deceleration_is_drag_plus_rolling_resistance(name):
    p = get_preset(name)
    speeds = np.array([8.0, 20.0, 35.0, 50.0, 70.0])
    state = step(p, initial_state(speeds.size, speed_mps=speeds), 0.0, 0.0, DT)
    rho = p.air_density_kgpm3
    expected = (
        -(
            0.5 * rho * p.drag_area_m2 * speeds**2
            + p.rolling_resistance * (p.mass_kg * G + 0.5 * rho * p.downforce_area_m2 * speeds**2)
        )
        / p.mass_kg
    )
    np.testing.assert_allclose(state.ax_mps2, expected, rtol=0.01)
    np.testing.assert_allclose(state.vx_mps, speeds + DT * expected, rtol=1e-4)


def test_coast_down_matches_the_ode_solution():
    """10 s of coasting from 40 m/s against scipy's solution of m dv/dt = -(0.5 rho CdA v^2 + Crr m g)."""
    p = get_preset("hatchback")
    k = 0.5 * p.air_density_kgpm3 * p.drag_area_m2 / p.mass_kg
    ref = solve_ivp(lambda t, v: -(k * v**2 + p.rolling_resistance * G), (0, 10), [40.0], rtol=1e-10, atol=1e-10)
    state = advance(p, initial_state(1, speed_mps=40.0), 0.0, 0.0, DT, 1000)
    assert state.vx_mps[0] == pytest.approx(ref.y[0, -1], rel=5e-3)
    assert 40.0 - ref.y[0, -1] > 3.0  # the test would notice missing drag


def test_low_speed_turn_follows_the_kinematic_bicycle():
    """At 1 m/s (below kinematic_below_mps) a steady steer gives r = v tan(delta) / L and vy = lr r exactly."""
    p = get_preset("hatchback")
    delta = 0.3
    state = initial_state(1, speed_mps=1.0)._replace(steer_rad=np.array([delta]))
    state = advance(p, state, delta, 0.0, DT, 20)
    v = state.vx_mps[0]
    assert 0.9 < v < 1.0  # rolling resistance only
    assert state.yaw_rate_radps[0] == pytest.approx(v * np.tan(delta) / p.wheelbase_m, rel=1e-12)
    assert state.vy_mps[0] == pytest.approx(p.cg_to_rear_axle_m * state.yaw_rate_radps[0], rel=1e-12)


def test_actuator_lag_and_steering_rate_limit():
    p = get_preset("hatchback")
    state = initial_state(3)
    cmd = np.array([0.01, 1.0, -np.inf])  # small, beyond the limit, absurd
    gain = 1.0 - np.exp(-DT / p.steer_lag_s)
    rate_step = p.max_steer_rate_radps * DT
    s1 = step(p, state, cmd, 0.0, DT)
    np.testing.assert_allclose(s1.steer_rad, [0.01 * gain, rate_step, -rate_step], rtol=1e-12)
    steer = [s1.steer_rad]
    s = s1
    for _ in range(150):
        s = step(p, s, cmd, 0.0, DT)
        steer.append(s.steer_rad)
    steer = np.array(steer)
    assert np.abs(np.diff(steer, axis=0)).max() <= rate_step * (1 + 1e-12)
    np.testing.assert_allclose(steer[-1], [0.01, p.steer_limit_rad, -p.steer_limit_rad], rtol=1e-9)
    # The throttle/brake command is lagged and clipped to [-1, 1].
    o = step(p, initial_state(2), 0.0, np.array([0.5, 7.0]), DT).omega
    np.testing.assert_allclose(o, np.array([0.5, 1.0]) * (1 - np.exp(-DT / p.omega_lag_s)), rtol=1e-12)


# ---------------------------------------------------------------------------------------------------- realism targets
def test_hatchback_top_speed_and_0_to_100():
    p = get_preset("hatchback")
    t, _, v = _straight_line(p, 1.0, 0.0, 15.0)
    t_100 = t[np.argmax(v >= 100 * KMH)]
    assert 9.0 <= t_100 <= 12.0, t_100
    cruise = advance(p, initial_state(1, speed_mps=v[-1]), 0.0, 1.0, DT, 15_000)
    later = advance(p, cruise, 0.0, 1.0, DT, 1_000)
    assert abs(later.vx_mps[0] - cruise.vx_mps[0]) < 0.01  # it has settled
    assert 170.0 <= later.vx_mps[0] / KMH <= 185.0, later.vx_mps[0] / KMH


def test_hatchback_brakes_from_100_in_33_to_45_m():
    _, x, v = _straight_line(get_preset("hatchback"), -1.0, 100 * KMH, 6.0)
    stop = np.argmax(v <= 0.0)
    assert v[stop] == 0.0 and (v >= 0.0).all()  # stops on exactly 0 and never rolls backwards
    assert 33.0 <= x[stop] <= 45.0, x[stop]
    assert x[-1] == x[stop]  # and stays stopped


def test_skidpad_road_tyres_and_slicks(skidpad):
    hatch = _max_held_ay_g(skidpad["hatchback"])
    assert 0.85 <= hatch <= 1.0, hatch
    for name in ("tt_cup", "gt3"):
        assert _max_held_ay_g(skidpad[name]) >= 1.3, name
    # The accelerometer reads the centripetal acceleration v^2 / R of every car that holds its circle.
    for result in skidpad.values():
        held = result["held"]
        np.testing.assert_allclose(result["ay"][held], result["ay_nominal"][held], rtol=0.02)


def test_hatchback_understeers(skidpad):
    """At constant radius the steady steer angle starts at the kinematic L/R and grows with lateral acceleration."""
    p = get_preset("hatchback")
    r = skidpad["hatchback"]
    kinematic = np.arctan(p.wheelbase_m / SKIDPAD_RADIUS_M)
    linear = r["held"] & (r["ay_nominal"] <= 0.6 * G)
    gradient = np.polyfit(r["ay_nominal"][linear], r["steer"][linear], 1)[0]
    assert gradient > 0.0005, gradient  # rad per m/s^2; 0.0005 = 0.28 deg/g
    low = np.argmin(np.abs(SKIDPAD_AY_G - 0.1))
    assert r["steer"][low] == pytest.approx(kinematic, rel=0.03)
    near_limit = np.argmin(np.abs(SKIDPAD_AY_G - 0.8))
    assert r["held"][near_limit] and r["steer"][near_limit] > kinematic * 1.05


def test_gt3_holds_more_lateral_acceleration_at_200_than_at_80_kmh():
    gt3 = get_preset("gt3")
    ay = np.arange(0.8, 3.0, 0.04) * G
    limits = {}
    for kmh in (80.0, 200.0):
        v = kmh * KMH
        limits[kmh] = _max_held_ay_g(_circle_sweep(gt3, np.full(ay.size, v), v**2 / ay))
    assert limits[200.0] > 1.05 * limits[80.0], limits


def test_body_roll_and_pitch_signs(skidpad):
    """Left turns roll the body right (roll > 0, about the roll gradient times ay); braking pitches the nose down."""
    p = get_preset("hatchback")
    r = skidpad["hatchback"]
    held = r["held"]
    np.testing.assert_allclose(r["roll"][held], p.roll_gradient_radpmps2 * r["ay"][held], rtol=0.02)
    state = step(p, initial_state(1, speed_mps=30.0), 0.0, -1.0, DT)
    for _ in range(30):
        state = step(p, state, 0.0, -1.0, DT)
    assert state.ax_mps2[0] < -5.0 and state.pitch_rad[0] > 0.0 and state.pitch_rate_radps[0] != 0.0


def test_all_drive_layouts_accelerate_and_weight_bias_decides_traction():
    hatch, gt3 = get_preset("hatchback"), get_preset("gt3")
    speeds = {}
    for base in (hatch, gt3):
        for drive in ("fwd", "rwd", "awd"):
            s = advance(replace(base, drive=drive), initial_state(1), 0.0, 1.0, DT, 200)
            speeds[base.name, drive] = s.vx_mps[0]
    assert all(v > 8.0 for v in speeds.values()), speeds
    # AWD uses both axles' grip; the driven axle with more weight on it launches harder.
    assert speeds["hatchback", "awd"] > speeds["hatchback", "fwd"] > speeds["hatchback", "rwd"]
    assert speeds["gt3", "awd"] > speeds["gt3", "rwd"] > speeds["gt3", "fwd"]


# ---------------------------------------------------------------------------------------------------- robustness
@pytest.mark.parametrize("name", sorted(PRESETS))
def test_standstill_stays_at_rest(name):
    p = get_preset(name)
    state = initial_state(4, x_m=1.0, y_m=2.0, yaw_rad=0.5)
    steer = np.array([0.0, p.steer_limit_rad, -p.steer_limit_rad, 0.0])
    omega = np.array([-1.0, -1.0, 0.0, 0.0])
    out = advance(p, state, steer, omega, DT, 500)
    assert np.isfinite(np.array(out)).all()
    for f in ("vx_mps", "vy_mps", "yaw_rate_radps", "ax_mps2", "ay_mps2"):
        assert (getattr(out, f) == 0.0).all(), f
    np.testing.assert_array_equal(out.x_m, 1.0)
    np.testing.assert_array_equal(out.y_m, 2.0)
    np.testing.assert_array_equal(out.yaw_rad, 0.5)


def test_braking_to_a_stop_at_low_speed_never_reverses():
    p = get_preset("gt3")  # the strongest brakes: the largest speed change per substep
    state = initial_state(3, speed_mps=np.array([0.05, 1.0, 4.0]))
    for _ in range(300):
        state = step(p, state, 0.2, -1.0, DT)
        assert (state.vx_mps >= 0.0).all()
    assert (state.vx_mps == 0.0).all() and (state.yaw_rate_radps == 0.0).all()


def test_one_million_car_steps_of_random_actions():
    """3 presets x 1,000 cars x 334 control steps (10 substeps each) of uniform random actions, incl. out-of-range
    values, NaN and inf: just over 1,000,000 car-steps (10 M substeps)."""
    rng = np.random.default_rng(7)
    n = 1000
    speed_bound = 300 * KMH * 1.02
    for name in PRESETS:
        p = get_preset(name)
        state = initial_state(n, yaw_rad=rng.uniform(-4, 4, n), speed_mps=rng.uniform(0, 300 * KMH, n))
        for k in range(334):
            steer = rng.uniform(-1.5, 1.5, n)
            omega = rng.uniform(-2.0, 2.0, n)
            if k == 5:
                steer[:10], omega[10:20], steer[20:30], omega[30:40] = np.nan, np.nan, np.inf, -np.inf
            state = advance(p, state, steer, omega, DT, 10)
            block = np.array(state)
            assert np.isfinite(block).all(), name
            assert np.hypot(state.vx_mps, state.vy_mps).max() < speed_bound, name
            assert np.abs(state.yaw_rate_radps).max() < 10.0, name
            assert np.abs(state.steer_rad).max() <= p.steer_limit_rad
            assert np.abs(state.omega).max() <= 1.0


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_noisy_actions_at_300_kmh_stay_physical(name):
    """New random actions every 10 ms substep at 300 km/h: no blow-up, accelerations within tyre-plus-aero limits."""
    p = get_preset(name)
    rng = np.random.default_rng(3)
    n = 200
    state = initial_state(n, speed_mps=300 * KMH)
    peak = 0.0
    for _ in range(400):
        state = step(p, state, rng.normal(0.0, 0.3, n), rng.normal(0.3, 0.7, n), DT)
        peak = max(peak, np.hypot(state.ax_mps2, state.ay_mps2).max())
    assert np.isfinite(np.array(state)).all()
    assert peak < 4.0 * G, peak


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_small_disturbances_decay_at_every_speed(name):
    """The explicit 10 ms step is stable across the kinematic/dynamic blend and up to top speed."""
    p = get_preset(name)
    speeds = np.array([1.0, 2.5, 3.5, 4.5, 6.0, 10.0, 30.0, 60.0, 85.0])
    state = initial_state(speeds.size, speed_mps=speeds)._replace(
        vy_mps=0.02 * speeds, yaw_rate_radps=np.full(speeds.size, 0.05)
    )
    out = advance(p, state, 0.0, 0.0, DT, 300)
    assert (np.abs(out.vy_mps) < 0.05 * np.abs(state.vy_mps)).all()
    assert (np.abs(out.yaw_rate_radps) < 0.05 * np.abs(state.yaw_rate_radps)).all()


def test_bad_inputs_raise():
    p = get_preset("hatchback")
    state = initial_state(3)
    with pytest.raises(ValueError):
        step(p, state, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        step(p, state, np.zeros(2), 0.0, DT)
    with pytest.raises(ValueError):
        step(p, state._replace(vx_mps=np.zeros(2)), 0.0, 0.0, DT)
    with pytest.raises(ValueError):
        advance(p, state, 0.0, 0.0, DT, -1)


# ---------------------------------------------------------------------------------------------------- contracts
def test_initial_state_broadcasts_and_wraps_yaw():
    s = initial_state(3, x_m=np.array([1.0, 2.0, 3.0]), y_m=5.0, yaw_rad=3 * np.pi / 2, speed_mps=10.0)
    assert isinstance(s, VehicleState) and len(s) == 14
    for a in s:
        assert a.shape == (3,) and a.dtype == np.float64
    np.testing.assert_array_equal(s.x_m, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(s.yaw_rad, -np.pi / 2)
    np.testing.assert_array_equal(s.vx_mps, 10.0)
    assert not np.array(s)[4:].any()


def test_step_is_pure():
    p = get_preset("hatchback")
    state = _random_state(50, np.random.default_rng(0))
    before = [a.copy() for a in state]
    steer, omega = np.full(50, 0.2), np.full(50, 0.5)
    out = step(p, state, steer, omega, DT)
    for a, b in zip(state, before, strict=True):
        np.testing.assert_array_equal(a, b)
    assert not any(np.shares_memory(a, b) for a in out for b in state)
    assert (steer == 0.2).all() and (omega == 0.5).all()


def test_determinism_and_independence_of_the_batch():
    p = get_preset("tt_cup")
    rng = np.random.default_rng(1)
    state = _random_state(64, rng)
    steer, omega = rng.uniform(-0.5, 0.5, 64), rng.uniform(-1, 1, 64)
    a = advance(p, state, steer, omega, DT, 200)
    b = advance(p, state, steer, omega, DT, 200)
    np.testing.assert_array_equal(np.array(a), np.array(b))
    # Car 17 alone gives bit for bit what it gives inside the batch.
    alone = advance(p, VehicleState(*(f[17:18] for f in state)), steer[17:18], omega[17:18], DT, 200)
    np.testing.assert_array_equal(np.array(alone)[:, 0], np.array(a)[:, 17])
    # advance(n) is n calls of step.
    s = state
    for _ in range(200):
        s = step(p, s, steer, omega, DT)
    np.testing.assert_array_equal(np.array(s), np.array(a))


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_numpy_and_numba_paths_agree(name):
    """The element-wise physics run on whole numpy arrays and compiled per car give the same result."""
    p = get_preset(name)
    rng = np.random.default_rng(5)
    n = 500
    state = _random_state(n, rng)
    steer, omega = rng.uniform(-0.7, 0.7, n), rng.uniform(-1.3, 1.3, n)
    steer[:5] = np.nan
    ref = tuple(state)
    for _ in range(10):
        ref = vm._step_numpy(p._packed, ref, steer, omega, DT)
    out = advance(p, state, steer, omega, DT, 10)
    np.testing.assert_allclose(np.array(out), np.array(ref), rtol=1e-9, atol=1e-9)


def test_bench_physics_reports_a_rate():
    result = vm.bench_physics(n_cars=50, n_substeps=5, repeats=2)
    assert result["physics_car_substeps_per_s"] > 0.0
    assert result["n_cars"] == 50
