"""How a lap is driven at speed: the threshold by hand, hand-made laps of a slalom and of a steady wheel, and the
AI's protocol lap."""

from __future__ import annotations

import numpy as np
import pytest

from vision_rl.envs.core import usable_steer_rad
from vision_rl.evaluation.controls import fast_speed_mps, lap_controls
from vision_rl.evaluation.protocol import STEP_S, BuiltinAI, LapRecord, LapTiming, SeedRun, time_laps
from vision_rl.sim.vehicle import get_preset

CAR = get_preset("hatchback")


def test_the_fast_speed_is_where_one_rate_step_exceeds_the_usable_angle():
    # hatchback: 6 * 2.566 m * 9.80665 / (1.2 rad/s * 0.1 s) = 1258 m^2/s^2, so 35.5 m/s (128 km/h)
    v = fast_speed_mps(CAR)
    assert v == pytest.approx(np.sqrt(6 * CAR.wheelbase_m * 9.80665 / (CAR.max_steer_rate_radps * 0.1)))
    assert 3.6 * v == pytest.approx(127.7, abs=0.1)
    assert usable_steer_rad(np.array([v]), CAR.wheelbase_m)[0] == pytest.approx(CAR.max_steer_rate_radps * STEP_S)


def _lap(speed_mps: np.ndarray, steer_rad: np.ndarray, omega: np.ndarray) -> LapTiming:
    """A one-lap timing whose recorded steps carry the given speed, wheel angle and pedal."""
    n = len(speed_mps)
    lap_s = n * STEP_S
    record = LapRecord(lap_s, 0.0, 0.0, 0.0, 100.0, 1000.0)
    timing = LapTiming(None, CAR, 1, [SeedRun(0, [record], None, 1000.0, lap_s)], lap_s, 3 * lap_s, speed_mps[:1])
    timing.time_s = np.arange(1, n + 1) * STEP_S
    timing.speed_mps, timing.steer_rad, timing.omega = speed_mps[:, None], steer_rad[:, None], omega[:, None]
    return timing


def test_a_slalom_at_the_ends_of_the_range_and_a_steady_wheel_by_hand():
    fast, slow = 40.0, 20.0
    end = usable_steer_rad(np.array([fast]), CAR.wheelbase_m)[0]
    # 10 fast steps swinging between the ends of the usable angle at 0.97 pedal, then 10 slow ones that do not count
    speed = np.r_[np.full(10, fast), np.full(10, slow)]
    steer = np.r_[np.tile([end, -end], 5), np.zeros(10)]
    omega = np.r_[np.full(10, 0.97), np.ones(10)]
    c = lap_controls(_lap(speed, steer, omega), 0)
    assert c["steps"] == 10 and c["full_throttle_share"] == 0.0 and c["range_end_share"] == 1.0
    assert c["steer_sign_change_share"] == 1.0  # 9 changes of side over the 9 pairs of fast steps
    # a steady wheel at a third of the angle, the throttle open on 7 of 10 steps
    steady = lap_controls(_lap(np.full(10, fast), np.full(10, end / 3), np.r_[np.ones(7), np.full(3, 0.5)]), 0)
    assert (steady["full_throttle_share"], steady["range_end_share"], steady["steer_sign_change_share"]) == (
        pytest.approx(0.7),
        0.0,
        0.0,
    )


def test_a_lap_never_that_fast_or_not_recorded(small_track):
    slow = lap_controls(_lap(np.full(5, 20.0), np.zeros(5), np.ones(5)), 0)
    assert slow["steps"] == 0 and slow["full_throttle_share"] is None
    timing = time_laps(BuiltinAI(), small_track, "hatchback", seeds=(0,), laps=1)
    with pytest.raises(ValueError, match="record=True"):
        lap_controls(timing, 0)


def test_the_ais_fast_steps_keep_the_throttle_open_and_the_wheel_inside_its_range():
    timing = time_laps(BuiltinAI(skill=1.0), "expressway", "hatchback", seeds=(0,), laps=1, record=True)
    c = lap_controls(timing, 0)
    assert c["steps"] > 500  # a third of the lap or more
    assert c["full_throttle_share"] > 0.8 and c["range_end_share"] < 0.02 and c["steer_sign_change_share"] < 0.1
