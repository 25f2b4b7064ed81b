"""The papers' rewards as pure batched functions.

Racing (overtaking paper Eq. 1, vision paper Eq. 3): ``r = (cp_t - cp_{t-1}) - c_w * wall * |v|^2``.
Overtaking (overtaking paper Eq. 2): racing ``- c_c * car * |v|^2`` plus, for every other car i of the ego's group
within ``c_d`` metres of track progress, ``c_r * (dcp_i(t-1) - dcp_i(t))`` with ``dcp_i = cp_i - cp_ego`` wrapped to
half a lap: closing on a car ahead is rewarded, pulling away from one behind is rewarded, falling back is penalised.
"""

from __future__ import annotations

import numpy as np


def racing_reward(
    progress_m: np.ndarray, wall_contact: np.ndarray, speed_mps: np.ndarray, wall_penalty_c_w: float
) -> np.ndarray:
    """Signed centre-line progress (m) over the step minus the wall penalty ``c_w * |v|^2`` while touching a wall."""
    return progress_m - wall_penalty_c_w * wall_contact * np.square(speed_mps)


def wall_penalty_speed_mps(speed_start_mps: np.ndarray, speed_end_mps: np.ndarray, at: str) -> np.ndarray:
    """The speed the wall penalty squares: ``end``, the car's speed when the step ends (the papers' ``v_t``), or
    ``impact``, the larger of the step's start and end speeds.

    ``impact`` is not in the papers. A hit takes its speed away within the step, so ``end`` charges a car that
    brakes on the wall at the speed the wall left it: state policies learned to enter the
    expressway's 32 m hairpin at 154 km/h with the throttle on and let the outer wall take them to 85 km/h in one
    0.1 s step, charged as an 85 km/h touch (docs/results/state-expressway-hatchback-clean). ``impact``
    charges the kinetic energy the car brought to the wall, which the papers name as the term's purpose ("proportional
    to the square of the car's speed", overtaking paper Sec. IV-B)."""
    if at == "end":
        return speed_end_mps
    if at == "impact":
        return np.maximum(speed_start_mps, speed_end_mps)
    raise ValueError(f"the wall penalty's speed must be 'end' or 'impact', got {at!r}")


def steering_change_penalty(
    steer_prev_rad: np.ndarray,
    steer_now_rad: np.ndarray,
    steer_scale_rad: float | np.ndarray,
    steer_change_penalty_c_s: float,
) -> np.ndarray:
    """``c_s * ((steer_now - steer_prev) / steer_scale)^2``: the cost of a change of the steering command, measured
    against the command's limit or, per car, the angle usable at its speed.

    Not in either paper. SAC on the papers' reward learns bang-bang steering here (the command flips sign on 75-83 %
    of control steps, by 0.44-0.54 rad on average, in three 1M-step state policies), which the actuator's rate limit
    turns into a weave; a full flip costs ``4 c_s``, a 0.1 rad correction ``0.04 c_s``."""
    change = (steer_now_rad - steer_prev_rad) / steer_scale_rad
    return steer_change_penalty_c_s * np.square(change)


def off_track_penalty(beyond_edge_line: np.ndarray, speed_mps: np.ndarray, off_track_penalty_c_o: float) -> np.ndarray:
    """``c_o * |v|^2`` for a car whose body ends the step over the painted edge line (a wheel on the kerb or
    shoulder band before the wall).

    Not in either paper: GT Sport's Tokyo Expressway has its walls at the track's edge, ours have a band between.
    Policies on the papers' reward enter slow corners faster than the AI, run wide over that band and lean on the
    outer wall (docs/results/state-expressway-hatchback-speed-scaled); this term, of the wall term's form, charges
    running wide before the wall is reached."""
    return off_track_penalty_c_o * beyond_edge_line * np.square(speed_mps)


def wrapped_gap_m(cp_other_m: np.ndarray, cp_ego_m: np.ndarray, lap_length_m: float) -> np.ndarray:
    """``cp_i - cp_ego`` in metres of track, wrapped to (-half lap, half lap]: positive when car i is ahead."""
    half = 0.5 * lap_length_m
    return half - np.mod(half - (cp_other_m - cp_ego_m), lap_length_m)


def overtaking_reward(
    racing: np.ndarray,
    car_contact: np.ndarray,
    speed_mps: np.ndarray,
    gap_prev_m: np.ndarray,
    gap_now_m: np.ndarray,
    car_penalty_c_c: float,
    overtake_gain_c_r: float,
    detection_range_c_d_m: float,
) -> np.ndarray:
    """Eq. 2. ``gap_prev_m``/``gap_now_m`` (n_egos, k_others) are wrapped gaps to the ego's opponents (NaN = none)."""
    near = np.abs(gap_now_m) < detection_range_c_d_m
    closing = np.where(near, overtake_gain_c_r * (gap_prev_m - gap_now_m), 0.0)
    return racing - car_penalty_c_c * car_contact * np.square(speed_mps) + np.nansum(closing, axis=-1)
