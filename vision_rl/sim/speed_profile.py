"""Quasi-steady-state (QSS) speed profile and lap time of a car on a racing line: the physical-limit lap.

The car is the dynamic single-track model of :mod:`vision_rl.sim.vehicle` at steady state, point by point; a forward
and a backward pass under the cornering limit (numba loops) give the profile. The model's terms: docs/notes/sim.md.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numba
import numpy as np

from vision_rl.sim.vehicle import GRAVITY_MPS2, TyreParams, VehicleParams

#: Highest speed the cornering-limit search considers, m/s: above every preset's top speed (gt3 about 83 m/s).
MAX_SEARCH_SPEED_MPS = 150.0

#: Lowest speed of a profile, m/s: keeps power / v finite; no corner of a real track is this slow.
MIN_SPEED_MPS = 1.0

#: Laps of forward/backward passes at most; a lap closes on itself within 1e-9 m/s in two or three.
_MAX_PASS_LAPS = 20

#: Samples of the tabulated inverse Magic Formula (utilisation -> slip angle).
_SLIP_TABLE_SIZE = 257

# Indices of the packed car parameters (module constants: numba folds them into the compiled code).
(
    _MASS,
    _LF,
    _LR,
    _H,
    _TRACK,
    _ROLL_FRONT,
    _HALF_RHO_CLA,
    _DF_FRONT,
    _HALF_RHO_CDA,
    _CRR,
    _WHEEL_POWER,
    _DRIVE_CAP,
    _DRIVE_FRONT,
    _VMAX,
    _BRAKE,
    _BRAKE_FRONT,
    _MU_F,
    _LS_F,
    _FZ0_F,
    _LONG_F,
    _MU_R,
    _LS_R,
    _FZ0_R,
    _LONG_R,
    _GRIP_SCALE,
) = range(25)
_N_PACKED = 25


def _pack(car: VehicleParams, grip_scale: float) -> np.ndarray:
    values = {
        _MASS: car.mass_kg,
        _LF: car.cg_to_front_axle_m,
        _LR: car.cg_to_rear_axle_m,
        _H: car.cg_height_m,
        _TRACK: car.track_width_m,
        _ROLL_FRONT: car.roll_stiffness_front_share,
        _HALF_RHO_CLA: 0.5 * car.air_density_kgpm3 * car.downforce_area_m2,
        _DF_FRONT: car.downforce_front_share,
        _HALF_RHO_CDA: 0.5 * car.air_density_kgpm3 * car.drag_area_m2,
        _CRR: car.rolling_resistance,
        _WHEEL_POWER: car.wheel_power_w,
        _DRIVE_CAP: car.max_drive_force_n,
        _DRIVE_FRONT: car.drive_front_share,
        _VMAX: car.max_speed_mps,
        _BRAKE: car.max_brake_force_n,
        _BRAKE_FRONT: car.brake_front_share,
        _MU_F: car.tyre_front.peak_mu,
        _LS_F: car.tyre_front.load_sensitivity,
        _FZ0_F: car.tyre_front.nominal_load_n,
        _LONG_F: car.tyre_front.long_to_lat_mu_ratio,
        _MU_R: car.tyre_rear.peak_mu,
        _LS_R: car.tyre_rear.load_sensitivity,
        _FZ0_R: car.tyre_rear.nominal_load_n,
        _LONG_R: car.tyre_rear.long_to_lat_mu_ratio,
        _GRIP_SCALE: grip_scale,
    }
    return np.array([values[i] for i in range(_N_PACKED)], dtype=np.float64)


def slip_table(tyre: TyreParams, size: int = _SLIP_TABLE_SIZE) -> np.ndarray:
    """sin(slip angle) at which the tyre's Magic Formula gives utilisation ``linspace(0, 1, size)`` of its peak.

    Inverts ``u = sin(C atan(B a - E (B a - atan(B a))))`` on its rising branch: the inner argument is
    ``tan(asin(u) / C)``, and ``x - E (x - atan x)`` is increasing in ``x = B a`` for E <= 1 (bisection).
    """
    util = np.linspace(0.0, 1.0, size)
    target = np.tan(np.arcsin(util) / tyre.shape_c)
    lo, hi = np.zeros(size), np.full(size, 1e3)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        below = mid - tyre.curvature_e * (mid - np.arctan(mid)) < target
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    slip = np.minimum(0.5 * (lo + hi) / tyre.stiffness_b_per_rad, tyre.peak_slip_angle_rad)
    return np.sin(slip)


@numba.njit(cache=True)
def _axle_grip_n(fz_axle, transfer_n, mu0, load_sens, fz0):
    """Peak force of an axle's two wheels (N), ``transfer_n`` moved to the outer wheel: vehicle._axle_grip_n."""
    transfer_n = min(transfer_n, 0.5 * fz_axle)
    f_out = 0.5 * fz_axle + transfer_n
    f_in = 0.5 * fz_axle - transfer_n
    mu_out = mu0 * max(1.0 + load_sens * (f_out - fz0) / fz0, 0.2)
    mu_in = mu0 * max(1.0 + load_sens * (f_in - fz0) / fz0, 0.2)
    return mu_out * f_out + mu_in * f_in


@numba.njit(cache=True)
def _table(tab, u):
    x = min(max(u, 0.0), 1.0) * (len(tab) - 1)
    i = min(int(x), len(tab) - 2)
    f = x - i
    return tab[i] * (1.0 - f) + tab[i + 1] * f


@numba.njit(cache=True)
def _point_state(p, v, kappa, ax):
    """Axle grips and forces of the car at speed ``v`` on curvature ``kappa`` with longitudinal accel ``ax``.

    Returns (lateral force front, rear; lateral grip front, rear; total normal load), all N.
    """
    m = p[_MASS]
    wheelbase = p[_LF] + p[_LR]
    ay = v * v * abs(kappa)
    downforce = p[_HALF_RHO_CLA] * v * v
    transfer = m * p[_H] / wheelbase * ax
    min_load = 0.05 * m * GRAVITY_MPS2
    fz_f = max(m * GRAVITY_MPS2 * p[_LR] / wheelbase - transfer + p[_DF_FRONT] * downforce, min_load)
    fz_r = max(m * GRAVITY_MPS2 * p[_LF] / wheelbase + transfer + (1.0 - p[_DF_FRONT]) * downforce, min_load)
    lateral_transfer = m * p[_H] / p[_TRACK] * ay
    grip_f = p[_GRIP_SCALE] * _axle_grip_n(fz_f, p[_ROLL_FRONT] * lateral_transfer, p[_MU_F], p[_LS_F], p[_FZ0_F])
    grip_r = p[_GRIP_SCALE] * _axle_grip_n(
        fz_r, (1.0 - p[_ROLL_FRONT]) * lateral_transfer, p[_MU_R], p[_LS_R], p[_FZ0_R]
    )
    fy_f = m * ay * p[_LR] / wheelbase
    fy_r = m * ay * p[_LF] / wheelbase
    return fy_f, fy_r, grip_f, grip_r, fz_f + fz_r


@numba.njit(cache=True)
def _force_limits(p, v, kappa, ax):
    """Largest drive force and largest brake force (both N, >= 0) at ``v`` on ``kappa`` with acceleration ``ax``
    setting the load transfer, and the resistance (N) the car meets there."""
    fy_f, fy_r, grip_f, grip_r, fz = _point_state(p, v, kappa, ax)
    u_f = min(fy_f / grip_f, 1.0)
    u_r = min(fy_r / grip_r, 1.0)
    cap_f = p[_LONG_F] * grip_f * np.sqrt(1.0 - u_f * u_f)
    cap_r = p[_LONG_R] * grip_r * np.sqrt(1.0 - u_r * u_r)
    # Drive force: the engine, then traction of the driven axle(s) under the fixed torque split.
    engine = min(p[_DRIVE_CAP], p[_WHEEL_POWER] / max(v, 1e-3)) * min(max(p[_VMAX] - v, 0.0), 1.0)
    drive = engine
    if p[_DRIVE_FRONT] > 0.0:
        drive = min(drive, cap_f / p[_DRIVE_FRONT])
    if p[_DRIVE_FRONT] < 1.0:
        drive = min(drive, cap_r / (1.0 - p[_DRIVE_FRONT]))
    # Brakes: with the fixed balance the first axle to reach its ellipse sets the total (braking harder would
    # take that axle's lateral force away: a spin if it is the rear).
    brake = p[_BRAKE]
    if p[_BRAKE_FRONT] > 0.0:
        brake = min(brake, cap_f / p[_BRAKE_FRONT])
    if p[_BRAKE_FRONT] < 1.0:
        brake = min(brake, cap_r / (1.0 - p[_BRAKE_FRONT]))
    return drive, brake, fy_f, fy_r, grip_f, grip_r, fz


@numba.njit(cache=True)
def _net_accel(p, v, kappa, ax, slip_f, slip_r, braking):
    drive, brake, fy_f, fy_r, grip_f, grip_r, fz = _force_limits(p, v, kappa, ax)
    resist = (
        p[_HALF_RHO_CDA] * v * v
        + p[_CRR] * fz
        + fy_f * _table(slip_f, fy_f / grip_f)
        + fy_r * _table(slip_r, fy_r / grip_r)
    )
    if braking:
        return -(brake + resist) / p[_MASS]
    return (drive - resist) / p[_MASS]


@numba.njit(cache=True)
def _accel_limit(p, v, kappa, slip_f, slip_r, braking):
    """Largest acceleration (or, ``braking``, deceleration: negative) at ``v`` on ``kappa``, m/s^2.

    The limit depends on itself through the longitudinal load transfer; ``a - limit(a)`` is increasing (the
    transfer gain h / L * mu is below 1), so bisection finds the consistent value.
    """
    lo, hi = -60.0, 60.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if _net_accel(p, v, kappa, mid, slip_f, slip_r, braking) > mid:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@numba.njit(cache=True)
def _passes(p, ds, kappa, v_corner, slip_f, slip_r, start):
    """Forward then backward pass from the slowest corner point, repeated until the lap closes on itself."""
    n = len(ds)
    v_fwd = v_corner.copy()
    # Start at the highest speed the car can hold at the slowest corner point (where the cornering drag does not
    # outweigh the drive): a steady corner then closes in one lap, and the laps after can only raise it.
    v_start = v_corner[start]
    if _accel_limit(p, v_start, kappa[start], slip_f, slip_r, False) < 0.0:
        lo, hi = MIN_SPEED_MPS, v_start
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            if _accel_limit(p, mid, kappa[start], slip_f, slip_r, False) >= 0.0:
                lo = mid
            else:
                hi = mid
        v_start = lo
    for _ in range(_MAX_PASS_LAPS):
        v_fwd[start] = v_start
        for k in range(n):
            i = (start + k) % n
            j = (i + 1) % n
            ax_max = _accel_limit(p, v_fwd[i], kappa[i], slip_f, slip_r, False)
            v_next = np.sqrt(max(v_fwd[i] * v_fwd[i] + 2.0 * ax_max * ds[i], MIN_SPEED_MPS**2))
            v_new = min(v_next, v_corner[j])
            if j != start:
                v_fwd[j] = v_new
        done = abs(v_new - v_start) < 1e-9
        v_start = min(v_new, v_corner[start])
        if done:
            break
    v = v_fwd.copy()
    v_start = v[start]
    for _ in range(_MAX_PASS_LAPS):
        v[start] = v_start
        for k in range(n):
            j = (start - k) % n
            i = (j - 1) % n
            ax_min = _accel_limit(p, v[j], kappa[j], slip_f, slip_r, True)
            v_prev = np.sqrt(v[j] * v[j] - 2.0 * ax_min * ds[i])
            v_new = min(v_prev, v_fwd[i])
            if i != start:
                v[i] = v_new
        done = abs(v_new - v_start) < 1e-9
        v_start = min(v_new, v_fwd[start])
        if done:
            break
    return v


def cornering_speed_mps(car: VehicleParams, curvature_1pm: np.ndarray, grip_scale: float = 1.0) -> np.ndarray:
    """Highest steady speed (m/s) on each curvature with no longitudinal force: both axles at their lateral peak.

    Includes downforce, load sensitivity and lateral load transfer; capped at :data:`MAX_SEARCH_SPEED_MPS`.
    Vectorised bisection on speed (feasibility is monotonic: the needed force grows with v^2 faster than grip).
    """
    p = _pack(car, grip_scale)
    kappa = np.abs(np.asarray(curvature_1pm, dtype=np.float64))
    feasible = _feasible_vec(p, np.full(kappa.shape, MAX_SEARCH_SPEED_MPS), kappa)
    lo, hi = np.zeros(kappa.shape), np.full(kappa.shape, MAX_SEARCH_SPEED_MPS)
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        ok = _feasible_vec(p, mid, kappa)
        lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
    return np.where(feasible, MAX_SEARCH_SPEED_MPS, lo)


@numba.njit(cache=True)
def _feasible_vec(p, v, kappa):
    out = np.empty(len(v), dtype=np.bool_)
    for i in range(len(v)):
        fy_f, fy_r, grip_f, grip_r, _ = _point_state(p, v[i], kappa[i], 0.0)
        out[i] = fy_f <= grip_f and fy_r <= grip_r
    return out


@dataclass(frozen=True, eq=False)
class SpeedProfile:
    """The QSS speed along a racing line (arrays over the line's samples)."""

    s_m: np.ndarray
    """Racing-line arc length of each sample, m (from the line)."""
    speed_mps: np.ndarray
    """Limit speed at each sample, m/s."""
    cornering_speed_mps: np.ndarray
    """Cornering-limit speed at each sample (no longitudinal force), m/s."""
    accel_mps2: np.ndarray
    """Longitudinal acceleration from each sample to the next, m/s^2."""
    length_m: float
    """Length of the closed line, m."""

    @property
    def lap_time_s(self) -> float:
        """Time of one flying lap, s (constant acceleration between samples)."""
        ds = np.diff(np.append(self.s_m, self.length_m))
        return float(np.sum(2.0 * ds / (self.speed_mps + np.roll(self.speed_mps, -1))))

    @property
    def max_speed_mps(self) -> float:
        return float(self.speed_mps.max())

    def speed_at(self, line_s_m: np.ndarray) -> np.ndarray:
        """Profile speed (m/s) at racing-line arc length ``line_s_m`` (wrapped, linear interpolation)."""
        s_closed = np.append(self.s_m, self.length_m)
        return np.interp(np.mod(line_s_m, self.length_m), s_closed, np.append(self.speed_mps, self.speed_mps[0]))

    def accel_at(self, line_s_m: np.ndarray) -> np.ndarray:
        """Profile acceleration (m/s^2) of the segment containing ``line_s_m``."""
        idx = np.searchsorted(self.s_m, np.mod(line_s_m, self.length_m), side="right") - 1
        return self.accel_mps2[np.clip(idx, 0, len(self.s_m) - 1)]

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {
            "sp_s_m": self.s_m,
            "sp_speed_mps": self.speed_mps,
            "sp_cornering_speed_mps": self.cornering_speed_mps,
            "sp_accel_mps2": self.accel_mps2,
            "sp_length_m": np.array(self.length_m),
        }

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> SpeedProfile:
        return cls(
            s_m=np.asarray(arrays["sp_s_m"]),
            speed_mps=np.asarray(arrays["sp_speed_mps"]),
            cornering_speed_mps=np.asarray(arrays["sp_cornering_speed_mps"]),
            accel_mps2=np.asarray(arrays["sp_accel_mps2"]),
            length_m=float(arrays["sp_length_m"]),
        )


def speed_profile(
    car: VehicleParams,
    s_m: np.ndarray,
    curvature_1pm: np.ndarray,
    length_m: float,
    grip_scale: float = 1.0,
) -> SpeedProfile:
    """QSS limit speed of ``car`` along a closed path sampled at arc lengths ``s_m`` (m) with ``curvature_1pm``.

    ``length_m`` closes the path (the last sample joins the first). ``grip_scale`` multiplies every tyre's friction
    (1 is the car's own limit). Use :func:`profile_for_line` with a :class:`~vision_rl.sim.racing_line.RacingLine`.
    """
    s = np.asarray(s_m, dtype=np.float64)
    kappa = np.asarray(curvature_1pm, dtype=np.float64)
    if s.ndim != 1 or s.shape != kappa.shape or len(s) < 3:
        raise ValueError("s_m and curvature_1pm must be 1-D arrays of the same length (>= 3)")
    ds = np.diff(np.append(s, length_m))
    if not (np.all(ds > 0) and np.all(np.isfinite(kappa))):
        raise ValueError("s_m must increase strictly below length_m and curvature_1pm must be finite")
    if not grip_scale > 0:
        raise ValueError(f"grip_scale must be positive, got {grip_scale}")
    p = _pack(car, grip_scale)
    v_corner = np.maximum(cornering_speed_mps(car, kappa, grip_scale), MIN_SPEED_MPS)
    start = int(np.argmin(v_corner))
    v = _passes(p, ds, kappa, v_corner, slip_table(car.tyre_front), slip_table(car.tyre_rear), start)
    accel = (np.roll(v, -1) ** 2 - v**2) / (2.0 * ds)
    return SpeedProfile(s_m=s, speed_mps=v, cornering_speed_mps=v_corner, accel_mps2=accel, length_m=float(length_m))


def profile_for_line(car: VehicleParams, line, grip_scale: float = 1.0) -> SpeedProfile:
    """QSS limit speed of ``car`` along a :class:`~vision_rl.sim.racing_line.RacingLine`."""
    return speed_profile(car, line.s_m, line.curvature_1pm, line.length_m, grip_scale)


@numba.njit(cache=True)
def _car_limits_vec(p, v, kappa, slip_f, slip_r):
    n = len(v)
    alpha_f, alpha_r = np.empty(n), np.empty(n)
    drive, brake = np.empty(n), np.empty(n)
    for i in range(n):
        fy_f, fy_r, grip_f, grip_r, _ = _point_state(p, v[i], kappa[i], 0.0)
        alpha_f[i] = np.arcsin(_table(slip_f, fy_f / grip_f))
        alpha_r[i] = np.arcsin(_table(slip_r, fy_r / grip_r))
        a_max = _accel_limit(p, v[i], kappa[i], slip_f, slip_r, False)
        drive[i] = _force_limits(p, v[i], kappa[i], a_max)[0]
        a_min = _accel_limit(p, v[i], kappa[i], slip_f, slip_r, True)
        brake[i] = _force_limits(p, v[i], kappa[i], a_min)[1]
    return alpha_f, alpha_r, drive, brake


#: Grid of the :class:`CarLimits` table: speeds (m/s), and |curvature| as a fraction of the curvature that saturates
#: the first axle at that speed, dense near 1 where the slip angles climb steeply and up to 1.1 (the other axle
#: saturates there), with a few rows beyond.
#: With the saturation on a grid row, bilinear lookups stay close to the exact model (tests/sim/test_speed_profile.py)
#: at about 1/30 of its cost: the exact model was 5 ms of every 50 Hz AI step for 120 cars, most of an overtaking
#: environment's step.
_TABLE_SPEEDS_MPS = np.linspace(0.0, 110.0, 221)
_TABLE_FRACTIONS = np.concatenate(
    [1.0 - (1.0 - np.linspace(0.0, 1.0, 121)) ** 2, np.linspace(1.0, 1.1, 51)[1:], [1.2, 1.5, 3.0, 1e3]]
)

#: Below this speed the saturation is that of this speed (the bisection's curvature bound).
_SATURATION_MIN_SPEED_MPS = 0.5


@numba.njit(cache=True)
def _saturation_curvature(p, speeds):
    """The |curvature| (1/m) at which the first axle's lateral force reaches its grip at each speed (no accel)."""
    out = np.empty(len(speeds))
    for i in range(len(speeds)):
        v = max(speeds[i], _SATURATION_MIN_SPEED_MPS)
        lo, hi = 0.0, 10.0
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            fy_f, fy_r, grip_f, grip_r, _ = _point_state(p, v, mid, 0.0)
            if max(fy_f / grip_f, fy_r / grip_r) < 1.0:
                lo = mid
            else:
                hi = mid
        out[i] = lo
    return out


@functools.lru_cache(maxsize=16)
def _limits_table(car: VehicleParams, grip_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Saturating lateral acceleration ``v^2 kappa_sat`` per grid speed (m/s^2, with v at least
    ``_SATURATION_MIN_SPEED_MPS``) and the exact limits on the grid (4, speeds, fractions)."""
    p = _pack(car, grip_scale)
    kappa_sat = _saturation_curvature(p, _TABLE_SPEEDS_MPS)
    v = np.repeat(_TABLE_SPEEDS_MPS, len(_TABLE_FRACTIONS))
    kappa = (kappa_sat[:, None] * _TABLE_FRACTIONS[None, :]).ravel()
    exact = _car_limits_vec(p, v, kappa, slip_table(car.tyre_front), slip_table(car.tyre_rear))
    lateral_accel_sat = kappa_sat * np.maximum(_TABLE_SPEEDS_MPS, _SATURATION_MIN_SPEED_MPS) ** 2
    return lateral_accel_sat, np.stack(exact).reshape(4, len(_TABLE_SPEEDS_MPS), len(_TABLE_FRACTIONS))


class CarLimits:
    """The QSS model of a car evaluated for many cars at once: steering feedforward and force limits for a driver.

    For speeds (n,) and path curvatures (n,), :meth:`__call__` returns four (n,) arrays:
    the front and rear steady-state slip angles (rad, magnitudes, saturated at the tyres' peak), so that
    ``steer = wheelbase * kappa + sign(kappa) * (alpha_front - alpha_rear)`` holds a steady turn; and the largest
    drive force and brake force (N) that leave every axle inside its friction ellipse. ``grip_scale`` scales every
    tyre's friction (below 1: a reserve). Values are interpolated in a table of the exact model
    (:meth:`exact` evaluates it directly); they depend on |curvature| only.
    """

    def __init__(self, car: VehicleParams, grip_scale: float = 1.0) -> None:
        self._packed = _pack(car, grip_scale)
        self._slip_front = slip_table(car.tyre_front)
        self._slip_rear = slip_table(car.tyre_rear)
        self._table = _limits_table(car, float(grip_scale))

    def __call__(
        self, speed_mps: np.ndarray, curvature_1pm: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        speeds, fractions = _TABLE_SPEEDS_MPS, _TABLE_FRACTIONS
        lateral_accel_sat, t = self._table
        fv = np.clip(np.asarray(speed_mps, dtype=np.float64) / speeds[1], 0.0, len(speeds) - 1.000001)
        i = fv.astype(np.int64)
        wv = fv - i
        # Interpolated as the saturating lateral acceleration, which varies slowly with speed: kappa_sat itself goes
        # as 1/v^2, which a linear interpolation over 0.5 m/s misplaces at low speed by more than the fractions' step.
        v2 = np.maximum(fv * speeds[1], _SATURATION_MIN_SPEED_MPS) ** 2
        fraction = np.abs(curvature_1pm) * v2 / (lateral_accel_sat[i] * (1.0 - wv) + lateral_accel_sat[i + 1] * wv)
        j = np.clip(np.searchsorted(fractions, fraction, side="right") - 1, 0, len(fractions) - 2)
        wk = np.clip((fraction - fractions[j]) / (fractions[j + 1] - fractions[j]), 0.0, 1.0)
        out = (t[:, i, j] * (1.0 - wk) + t[:, i, j + 1] * wk) * (1.0 - wv) + (
            t[:, i + 1, j] * (1.0 - wk) + t[:, i + 1, j + 1] * wk
        ) * wv
        return out[0], out[1], out[2], out[3]

    def exact(
        self, speed_mps: np.ndarray, curvature_1pm: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The model itself, without the table (slower)."""
        v = np.ascontiguousarray(speed_mps, dtype=np.float64)
        kappa = np.ascontiguousarray(np.broadcast_to(curvature_1pm, v.shape), dtype=np.float64)
        return _car_limits_vec(self._packed, v, kappa, self._slip_front, self._slip_rear)
