import dataclasses
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from vision_rl.sim import speed_profile as sp_mod
from vision_rl.sim import vehicle
from vision_rl.sim.racing_line import optimise_racing_line
from vision_rl.sim.speed_profile import (
    CarLimits,
    SpeedProfile,
    cornering_speed_mps,
    profile_for_line,
    slip_table,
    speed_profile,
)
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import GRAVITY_MPS2, get_preset

G = GRAVITY_MPS2


def _constant_mu(car, **changes):
    """The preset with load-insensitive tyres (mu constant), so that sqrt(mu g R) is the exact cornering speed."""
    front = dataclasses.replace(car.tyre_front, load_sensitivity=0.0)
    rear = dataclasses.replace(car.tyre_rear, load_sensitivity=0.0)
    return dataclasses.replace(car, tyre_front=front, tyre_rear=rear, **changes)


def _circle(radius_m: float, n: int = 2000):
    length = 2.0 * math.pi * radius_m
    return np.arange(n) * (length / n), np.full(n, 1.0 / radius_m), length


def test_cornering_speed_on_a_circle_is_sqrt_mu_g_r():
    car = _constant_mu(get_preset("hatchback"))
    radii = np.array([20.0, 50.0, 100.0, 300.0])
    v = cornering_speed_mps(car, 1.0 / radii)
    np.testing.assert_allclose(v, np.sqrt(car.tyre_front.peak_mu * G * radii), rtol=1e-6)
    # Turning right is the same as turning left.
    np.testing.assert_allclose(cornering_speed_mps(car, -1.0 / radii), v)


def test_profile_on_a_circle_is_sqrt_mu_g_r_within_one_percent():
    awd = _constant_mu(get_preset("hatchback"), drag_area_m2=0.0, rolling_resistance=0.0, drive="awd")
    s, kappa, length = _circle(100.0)
    prof = speed_profile(awd, s, kappa, length)
    expected = math.sqrt(awd.tyre_front.peak_mu * G * 100.0)
    # Steady: the same speed all round, a touch below the pure-cornering limit because the tyres must also drive
    # against their own cornering drag (slip angles dissipate power).
    assert np.ptp(prof.speed_mps) < 1e-3 * expected  # hovering at the steady speed, 1 m samples
    assert prof.speed_mps[0] == pytest.approx(expected, rel=0.01)
    assert prof.speed_mps[0] < expected
    assert prof.lap_time_s == pytest.approx(length / prof.speed_mps.mean(), rel=1e-6)
    # Front-wheel drive loads the already busier front axle with all of that drive: slower still (1.1 % here).
    fwd = speed_profile(dataclasses.replace(awd, drive="fwd"), s, kappa, length)
    assert 0.98 * expected < fwd.speed_mps[0] < prof.speed_mps[0]


def test_profile_on_a_circle_with_downforce():
    # Aero balance equal to the weight balance, so both axles reach their limit together:
    # m v^2 / R = mu (m g + 0.5 rho ClA v^2)  =>  v^2 = mu g R / (1 - mu rho ClA R / (2 m)).
    gt3 = get_preset("gt3")
    car = _constant_mu(
        gt3,
        downforce_front_share=gt3.cg_to_rear_axle_m / gt3.wheelbase_m,
        drag_area_m2=0.0,
        rolling_resistance=0.0,
    )
    radius, mu = 100.0, car.tyre_front.peak_mu
    expected = math.sqrt(
        mu * G * radius / (1.0 - mu * car.air_density_kgpm3 * car.downforce_area_m2 * radius / (2.0 * car.mass_kg))
    )
    assert cornering_speed_mps(car, np.array([1.0 / radius]))[0] == pytest.approx(expected, rel=1e-6)
    prof = speed_profile(car, *_circle(radius))
    assert prof.speed_mps.mean() == pytest.approx(expected, rel=0.01)
    assert expected > 1.05 * math.sqrt(mu * G * radius)  # the downforce term matters here


def test_top_speed_where_power_meets_drag():
    car = get_preset("tt_cup")  # no rev limit: top speed from power, drag and rolling resistance
    s, kappa, length = _circle(50_000.0, n=4000)  # 314 km of near-straight
    prof = speed_profile(car, s, kappa, length)

    def surplus(v):
        downforce = 0.5 * car.air_density_kgpm3 * car.downforce_area_m2 * v * v
        resist = 0.5 * car.air_density_kgpm3 * car.drag_area_m2 * v * v + car.rolling_resistance * (
            car.weight_n + downforce
        )
        return car.wheel_power_w / v - resist

    assert prof.max_speed_mps == pytest.approx(brentq(surplus, 10.0, 150.0), rel=0.005)
    hatch = get_preset("hatchback")  # rev-limited at 178 km/h
    top = speed_profile(hatch, s, kappa, length).max_speed_mps
    assert hatch.max_speed_mps - 1.0 < top <= hatch.max_speed_mps


@pytest.fixture(scope="module")
def technical_hatchback():
    track = load_track("technical")
    car = get_preset("hatchback")
    line = optimise_racing_line(track, 0.5 * car.width_m + 0.5)
    return car, line, profile_for_line(car, line)


def test_profile_is_feasible_and_maximal(technical_hatchback):
    car, line, prof = technical_hatchback
    p = sp_mod._pack(car, 1.0)
    slip_f, slip_r = slip_table(car.tyre_front), slip_table(car.tyre_rear)
    v, ds = prof.speed_mps, np.diff(np.append(prof.s_m, prof.length_m))
    v_next = np.roll(v, -1)
    kappa, kappa_next = line.curvature_1pm, np.roll(line.curvature_1pm, -1)
    a_max = np.array([sp_mod._accel_limit(p, v[i], kappa[i], slip_f, slip_r, False) for i in range(len(v))])
    a_min = np.array([sp_mod._accel_limit(p, v_next[i], kappa_next[i], slip_f, slip_r, True) for i in range(len(v))])
    tol = 1e-6
    assert np.all(v <= prof.cornering_speed_mps + tol)
    assert np.all(v_next**2 <= v**2 + 2.0 * a_max * ds + tol)  # never accelerates harder than the car can
    assert np.all(v**2 <= v_next**2 - 2.0 * a_min * ds + tol)  # never brakes harder than the car can
    # Maximal: every sample is held down by a limit (cornering, the acceleration from the one before, or the
    # braking into the one after), never slower for no reason.
    v_prev, a_prev = np.roll(v, 1), np.roll(a_max, 1)
    ds_prev = np.roll(ds, 1)
    by_corner = v >= prof.cornering_speed_mps - 1e-6
    by_accel = v**2 >= v_prev**2 + 2.0 * a_prev * ds_prev - 1e-6
    by_brake = v**2 >= v_next**2 - 2.0 * a_min * ds - 1e-6
    assert np.all(by_corner | by_accel | by_brake)
    assert 60.0 < prof.lap_time_s < 200.0
    # Braking is the car's: about 0.75-0.8 g for the road-tyre hatchback (rear axle limits with its brake balance).
    assert -0.85 * G < prof.accel_mps2.min() < -0.6 * G


def test_more_grip_is_faster_and_the_cache_arrays_round_trip(technical_hatchback):
    car, line, prof = technical_hatchback
    slower = profile_for_line(car, line, grip_scale=0.9)
    assert slower.lap_time_s > prof.lap_time_s * 1.02
    again = SpeedProfile.from_arrays(prof.to_arrays())
    assert again.lap_time_s == prof.lap_time_s
    np.testing.assert_allclose(prof.speed_at(prof.s_m + prof.length_m), prof.speed_mps)


def test_axle_grip_is_the_vehicle_models():
    rng = np.random.default_rng(0)
    fz = rng.uniform(1000.0, 15000.0, 50)
    transfer = rng.uniform(0.0, 0.5, 50) * fz
    ours = np.array([sp_mod._axle_grip_n(f, t, 1.6, -0.15, 4000.0) for f, t in zip(fz, transfer, strict=True)])
    np.testing.assert_allclose(ours, vehicle._axle_grip_n(fz, transfer, 1.6, -0.15, 4000.0), rtol=1e-12)


def test_slip_table_inverts_the_magic_formula():
    tyre = vehicle.ROAD_TYRE
    table = slip_table(tyre)
    util = np.linspace(0.0, 1.0, len(table))
    alpha = np.arcsin(table[:-1])
    np.testing.assert_allclose(
        vehicle._magic_formula(tyre.stiffness_b_per_rad, tyre.shape_c, tyre.curvature_e, alpha), util[:-1], atol=1e-9
    )
    assert np.arcsin(table[-1]) == pytest.approx(tyre.peak_slip_angle_rad, rel=1e-6)


def test_car_limits_for_the_driver():
    car = get_preset("hatchback")
    limits = CarLimits(car)
    v = np.array([20.0, 20.0, 20.0])
    kappa = np.array([0.0, 0.6 * G / 400.0, 1.2 / 20.0])  # straight, 0.6 g, beyond the limit
    alpha_f, alpha_r, drive, brake = limits(v, kappa)
    assert alpha_f[0] == pytest.approx(0.0, abs=1e-12) and drive[0] > 0.0 and brake[0] > 0.0
    assert alpha_f[1] > alpha_r[1] > 0.0  # the front-heavy FWD hatchback understeers
    assert brake[1] < brake[0]  # cornering uses part of the ellipses
    assert brake[2] == 0.0 and drive[2] == 0.0  # nothing left beyond the cornering limit


def test_bad_inputs_raise():
    car = get_preset("hatchback")
    with pytest.raises(ValueError):
        speed_profile(car, np.array([0.0, 1.0]), np.array([0.0, 0.0]), 2.0)  # too few samples
    with pytest.raises(ValueError):
        speed_profile(car, np.array([0.0, 2.0, 1.0]), np.zeros(3), 3.0)  # not increasing
    with pytest.raises(ValueError):
        speed_profile(car, np.arange(5.0), np.full(5, np.nan), 5.0)
    with pytest.raises(ValueError):
        speed_profile(car, np.arange(5.0), np.zeros(5), 5.0, grip_scale=0.0)


@pytest.mark.parametrize("car_name", ["hatchback", "gt3"])
def test_car_limits_table_follows_the_exact_model(car_name):
    limits = CarLimits(get_preset(car_name))
    rng = np.random.default_rng(0)
    v = rng.uniform(1.0, 90.0, 5000)
    kappa = rng.uniform(-1.0, 1.0, 5000) ** 3 * 0.2  # more samples on gentle bends, both signs
    table, exact = np.array(limits(v, kappa)), np.array(limits.exact(v, kappa))
    largest_force_n = exact[2:].max()
    force_error_n = np.abs(table[2:] - exact[2:]).max(axis=0)
    assert np.percentile(np.abs(table[:2] - exact[:2]), 99) < 2e-5  # rad
    assert np.percentile(force_error_n, 99) < 5e-4 * largest_force_n
    # Where an axle saturates the drive or brake limit can jump to zero (gt3: 4.2 kN to 0 within 1 % of curvature):
    # there a lookup can be off by the jump, but only for the few samples that land in it.
    assert (force_error_n > 0.01 * largest_force_n).mean() < 0.002
