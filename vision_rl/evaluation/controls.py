"""How a lap is driven where the steering is hardest: the car's wheel angle and pedal at every 0.1 s protocol step
of the scored lap, at speeds where one step of the car's steering rate limit exceeds the angle usable there.

At those speeds (above 128 km/h for the hatchback) the built-in AI holds the throttle fully open and steers well
inside the usable angle; the clean SAC policies held the throttle at 0.96-0.98 and swung the wheel between the
ends of the usable angle (docs/results/state-expressway-hatchback-clean). The figures say which a lap does.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from vision_rl.envs.core import SPEED_SCALED_STEER_G_MULTIPLE, usable_steer_rad
from vision_rl.evaluation.protocol import STEP_S, LapTiming
from vision_rl.sim.vehicle import GRAVITY_MPS2, VehicleParams

#: The pedal at or above this is full throttle (the pedal's lag leaves the last percent).
FULL_THROTTLE = 0.99
#: A wheel angle at or beyond this share of the usable angle is at the end of the range.
RANGE_END_SHARE = 0.9


def fast_speed_mps(car: VehicleParams) -> float:
    """The speed above which one 0.1 s step of ``car``'s steering rate limit moves the wheel further than the angle
    usable at that speed (:func:`vision_rl.envs.core.usable_steer_rad`), m/s."""
    rate_step_rad = car.max_steer_rate_radps * STEP_S
    return math.sqrt(SPEED_SCALED_STEER_G_MULTIPLE * car.wheelbase_m * GRAVITY_MPS2 / rate_step_rad)


def lap_controls(timing: LapTiming, index: int) -> dict[str, Any]:
    """Over the steps of run ``index``'s scored lap (a ``record=True`` timing) faster than :func:`fast_speed_mps`:
    ``steps``, ``full_throttle_share``, ``range_end_share`` (wheel at :data:`RANGE_END_SHARE` of the usable angle
    or beyond) and ``steer_sign_change_share`` (the wheel's side differs from the step before)."""
    if timing.steer_rad.size == 0:
        raise ValueError("the timing holds no records: run the protocol with record=True")
    if timing.scored(index) is None:
        raise ValueError(f"run {index} did not finish its scored lap: {timing.runs[index].dnf_reason}")
    t0, t1 = timing.scored_window_s(index)
    inside = (timing.time_s > t0) & (timing.time_s <= t1)
    speed = timing.speed_mps[inside, index]
    steer = timing.steer_rad[inside, index]
    fast_mps = fast_speed_mps(timing.car)
    fast = speed > fast_mps
    usable = usable_steer_rad(speed, timing.car.wheelbase_m)
    flips = np.sign(steer[1:]) != np.sign(steer[:-1])
    both_fast = fast[1:] & fast[:-1]
    n = int(fast.sum())
    return {
        "fast_above_kmh": 3.6 * fast_mps,
        "steps": n,
        "full_throttle_share": float(np.mean(timing.omega[inside, index][fast] >= FULL_THROTTLE)) if n else None,
        "range_end_share": float(np.mean(np.abs(steer[fast]) >= RANGE_END_SHARE * usable[fast])) if n else None,
        "steer_sign_change_share": float(np.mean(flips[both_fast])) if both_fast.any() else None,
    }
