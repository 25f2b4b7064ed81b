"""Batched vehicle dynamics: a dynamic single-track (bicycle) model with Pacejka Magic Formula tyres.

The physics is one element-wise function, :func:`_car_step`, that runs on whole arrays (numpy) and, compiled by
numba, on one car's floats in a loop over cars and substeps (:func:`step`, :func:`advance`): one source for both
paths. Signs: world x, y on the ground, z up, yaw counter-clockwise from +x; body x forward, y left, z up.
The model term by term, the roll and pitch signs and the two paths' speed: docs/notes/sim.md.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, fields
from functools import cached_property
from typing import NamedTuple

import numba
import numpy as np
from numba.extending import register_jitable

#: Standard gravity, m/s^2.
GRAVITY_MPS2 = 9.80665

#: Steering action limit of every environment, rad (the papers' action: delta in [-pi/6, pi/6]).
ACTION_STEER_LIMIT_RAD = math.pi / 6.0

#: Default internal step, s: a fixed step of 100 Hz, fine enough for the tyre and actuator dynamics.
DEFAULT_DT_S = 0.01

_DRIVES = ("fwd", "rwd", "awd")


@dataclass(frozen=True)
class TyreParams:
    """Magic Formula coefficients of one axle's lumped tyre (both wheels of the axle use it).

    Lateral force of one wheel: ``Fy = D sin(C atan(B a - E (B a - atan(B a))))`` with the slip angle ``a`` in rad and
    ``D = mu(Fz) Fz``, where ``mu(Fz) = peak_mu (1 + load_sensitivity (Fz - nominal_load_n) / nominal_load_n)``
    (floored at 0.2 peak_mu). The longitudinal capacity is ``long_to_lat_mu_ratio * D``.
    """

    stiffness_b_per_rad: float
    """B, 1/rad."""
    shape_c: float
    """C, dimensionless."""
    curvature_e: float
    """E, dimensionless (<= 1)."""
    peak_mu: float
    """Peak lateral friction coefficient at the nominal load, dimensionless."""
    load_sensitivity: float
    """Fractional change of mu per nominal load of extra load, dimensionless (negative: grip saturates)."""
    nominal_load_n: float
    """Wheel load Fz0 at which mu = peak_mu, N."""
    long_to_lat_mu_ratio: float = 1.0
    """Longitudinal over lateral peak friction, dimensionless."""

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not math.isfinite(v):
                raise ValueError(f"TyreParams.{f.name} must be finite, got {v}")
        if self.stiffness_b_per_rad <= 0 or self.shape_c <= 0 or self.peak_mu <= 0 or self.nominal_load_n <= 0:
            raise ValueError("TyreParams: B, C, peak_mu and nominal_load_n must be positive")
        if self.curvature_e > 1.0:
            raise ValueError(f"TyreParams.curvature_e must be <= 1 (else the curve folds back), got {self.curvature_e}")
        if self.long_to_lat_mu_ratio <= 0:
            raise ValueError("TyreParams.long_to_lat_mu_ratio must be positive")

    @property
    def peak_slip_angle_rad(self) -> float:
        """Slip angle of the peak lateral force, rad (solves C atan(x - E (x - atan x)) = pi/2 for x = B a)."""
        target = math.tan(math.pi / (2.0 * self.shape_c)) if self.shape_c > 1.0 else math.inf
        if not math.isfinite(target):
            return math.inf
        lo, hi = 0.0, 1.0e3
        for _ in range(100):
            mid = 0.5 * (lo + hi)
            if mid - self.curvature_e * (mid - math.atan(mid)) < target:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi) / self.stiffness_b_per_rad

    def cornering_stiffness_npr(self, load_n: float) -> float:
        """Slope dFy/da at a = 0 of one wheel carrying ``load_n``, N/rad (B C D)."""
        return self.stiffness_b_per_rad * self.shape_c * self.mu_at(load_n) * load_n

    def mu_at(self, load_n: float) -> float:
        """Peak friction coefficient at wheel load ``load_n`` (N), dimensionless."""
        scale = 1.0 + self.load_sensitivity * (load_n - self.nominal_load_n) / self.nominal_load_n
        return self.peak_mu * max(scale, 0.2)


# Dry-asphalt road tyre: B, C, E are the Magic Formula "dry tarmac" row (B 10, C 1.9, D 1, E 0.97) of MathWorks'
# Tire-Road Interaction (Magic Formula) block (mathworks.com/help/sdl/ref/tireroadinteractionmagicformula.html, after
# Pacejka, Tyre and Vehicle Dynamics), given there for longitudinal slip and used here for the slip angle: it peaks
# near 10 deg with B C = 19 /rad, the cornering-stiffness coefficient of passenger-car tyres (15-20 /rad). mu 1.0 is a
# typical dry-road peak; -0.1 load sensitivity (10 % less mu per extra nominal load) and the 4 kN nominal
# load (about 80 % of a load index 88 tyre's 5.6 kN) are textbook-typical estimates.
ROAD_TYRE = TyreParams(
    stiffness_b_per_rad=10.0,
    shape_c=1.9,
    curvature_e=0.97,
    peak_mu=1.0,
    load_sensitivity=-0.1,
    nominal_load_n=4000.0,
)

# A road car's front axle is effectively softer in cornering than its tyres: steering compliance, roll steer and
# the heavier (stiffness-saturated) front wheels of a front-heavy car. A lower front B lumps these, as single-track
# models identified from tests do with axle cornering stiffnesses. With it the hatchback's understeer gradient is
# about 1 deg/g in the linear range (0.1-0.5 g on a 50 m skidpad; with equal axles it would be 0.16 deg/g); road
# cars have about 1-4 deg/g (Milliken & Milliken, Race Car Vehicle Dynamics).
ROAD_TYRE_SOFT_AXLE = TyreParams(
    stiffness_b_per_rad=8.0,
    shape_c=1.9,
    curvature_e=0.97,
    peak_mu=1.0,
    load_sensitivity=-0.1,
    nominal_load_n=4000.0,
)

# Racing slick (estimates): peak mu about 1.6 at nominal load and a sharper peak (about 7 deg) than a road tyre;
# slicks lose more mu with load (-0.15 per nominal load), which is why aero load adds less grip than weight would.
SLICK_TYRE = TyreParams(
    stiffness_b_per_rad=14.0,
    shape_c=1.9,
    curvature_e=0.97,
    peak_mu=1.6,
    load_sensitivity=-0.15,
    nominal_load_n=4000.0,
)


@dataclass(frozen=True)
class VehicleParams:
    """One car's parameters; every field carries its unit in the name or docstring. Presets: :data:`PRESETS`."""

    name: str
    mass_kg: float
    """Total mass incl. driver, kg."""
    yaw_inertia_kgm2: float
    """Yaw moment of inertia about the centre of gravity, kg m^2."""
    cg_to_front_axle_m: float
    cg_to_rear_axle_m: float
    cg_height_m: float
    length_m: float
    """Body length, m (collisions, rendering)."""
    width_m: float
    """Body width, m (collisions, rendering)."""
    max_steer_rad: float
    """Road-wheel angle limit, rad; the action is clipped to min(pi/6, this)."""
    track_width_m: float
    """Distance between left and right wheel centres (mean of the axles), m."""
    tyre_front: TyreParams
    tyre_rear: TyreParams
    max_power_w: float
    """Peak engine power, W."""
    max_drive_force_n: float
    """Low-speed cap on the total tractive force (engine torque through first gear), N."""
    drive: str
    """'fwd', 'rwd' or 'awd'."""
    max_brake_force_n: float
    """Total brake force at full pedal, N (above the tyres' capacity: the tyres, not the brakes, limit a stop)."""
    brake_front_share: float
    """Front share of the brake force, dimensionless."""
    drag_area_m2: float
    """Drag coefficient times frontal area, Cd*A, m^2."""
    rolling_resistance: float
    """Rolling-resistance coefficient, dimensionless (force = coefficient * total normal load)."""
    max_speed_mps: float = math.inf
    """Rev limit in top gear, m/s: drive force fades to 0 over the last 1 m/s below it (inf: none)."""
    drivetrain_efficiency: float = 0.9
    """Wheel power over engine power, dimensionless."""
    downforce_area_m2: float = 0.0
    """Lift coefficient times reference area, Cl*A, m^2, positive for downforce."""
    downforce_front_share: float = 0.5
    """Share of the downforce on the front axle, dimensionless."""
    air_density_kgpm3: float = 1.204
    """Air density, kg/m^3 (ISA at 20 deg C, sea level)."""
    roll_stiffness_front_share: float = 0.55
    """Front share of the total roll stiffness (and so of the lateral load transfer), dimensionless."""
    max_steer_rate_radps: float = 1.5
    """Road-wheel steering rate limit, rad/s."""
    steer_lag_s: float = 0.05
    """Time constant of the first-order steering actuator lag, s (short: 0.05 s is an estimate for a power-steering
    rack)."""
    omega_lag_s: float = 0.1
    """Time constant of the first-order throttle/brake lag (engine response, brake pressure build-up, typically
    0.1-0.2 s), s."""
    roll_gradient_radpmps2: float = 0.0089
    """Steady-state body roll per lateral acceleration, rad per m/s^2 (0.0089 = 5 deg/g)."""
    pitch_gradient_radpmps2: float = 0.0036
    """Steady-state body pitch per longitudinal acceleration, rad per m/s^2 (0.0036 = 2 deg/g)."""
    body_motion_lag_s: float = 0.15
    """Time constant of the roll/pitch response, s (estimate: a damped body mode of about 1-2 Hz)."""
    kinematic_below_mps: float = 2.0
    """Speed below which the lateral/yaw states follow the kinematic model, m/s. With ``dynamic_above_mps`` chosen
    so that the explicit 10 ms step is stable for the presets' cornering stiffnesses (the tests check it)."""
    dynamic_above_mps: float = 5.0
    """Speed above which the dynamic model alone is used, m/s (linear blend in between)."""
    source: str = field(default="", compare=False)
    """Free text: what the preset models."""

    def __post_init__(self) -> None:
        if self.drive not in _DRIVES:
            raise ValueError(f"VehicleParams.drive must be one of {_DRIVES}, got {self.drive!r}")
        positive = (
            "mass_kg yaw_inertia_kgm2 cg_to_front_axle_m cg_to_rear_axle_m cg_height_m length_m width_m max_steer_rad "
            "track_width_m max_power_w max_drive_force_n max_brake_force_n max_speed_mps drivetrain_efficiency "
            "air_density_kgpm3 max_steer_rate_radps steer_lag_s omega_lag_s body_motion_lag_s dynamic_above_mps"
        ).split()
        for name in positive:
            v = getattr(self, name)
            if not v > 0 or math.isnan(v):
                raise ValueError(f"VehicleParams.{name} must be positive, got {v}")
        non_negative = (
            "drag_area_m2 rolling_resistance downforce_area_m2 roll_gradient_radpmps2 pitch_gradient_radpmps2 "
            "kinematic_below_mps"
        ).split()
        for name in non_negative:
            v = getattr(self, name)
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"VehicleParams.{name} must be finite and >= 0, got {v}")
        for name in ("brake_front_share", "downforce_front_share", "roll_stiffness_front_share"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"VehicleParams.{name} must be in [0, 1], got {v}")
        if self.drivetrain_efficiency > 1.0:
            raise ValueError("VehicleParams.drivetrain_efficiency must be <= 1")
        if min(self.cg_to_front_axle_m, self.cg_to_rear_axle_m) < 0.1 * self.wheelbase_m:
            raise ValueError("VehicleParams: the centre of gravity must lie well between the axles (>= 10 % of L)")
        if not self.dynamic_above_mps > self.kinematic_below_mps:
            raise ValueError("VehicleParams.dynamic_above_mps must exceed kinematic_below_mps")

    # ------------------------------------------------------------------ derived values
    @property
    def wheelbase_m(self) -> float:
        return self.cg_to_front_axle_m + self.cg_to_rear_axle_m

    @property
    def steer_limit_rad(self) -> float:
        """Largest road-wheel angle an action can ask for, rad: min(pi/6, max_steer_rad)."""
        return min(ACTION_STEER_LIMIT_RAD, self.max_steer_rad)

    @property
    def drive_front_share(self) -> float:
        """Front share of the tractive force: 1 (FWD), 0 (RWD). AWD splits in proportion to the axles' current
        longitudinal grip; for it this returns the static weight share lr / L (its value at rest with equal tyres
        and no load sensitivity)."""
        if self.drive == "awd":
            return self.cg_to_rear_axle_m / self.wheelbase_m
        return 1.0 if self.drive == "fwd" else 0.0

    @property
    def weight_n(self) -> float:
        return self.mass_kg * GRAVITY_MPS2

    @property
    def static_front_load_n(self) -> float:
        """Front axle load at rest, N: m g lr / L."""
        return self.weight_n * self.cg_to_rear_axle_m / self.wheelbase_m

    @property
    def static_rear_load_n(self) -> float:
        """Rear axle load at rest, N: m g lf / L."""
        return self.weight_n * self.cg_to_front_axle_m / self.wheelbase_m

    @property
    def wheel_power_w(self) -> float:
        """Power at the driven wheels, W."""
        return self.max_power_w * self.drivetrain_efficiency

    @cached_property
    def _packed(self) -> np.ndarray:
        """The floats :func:`_car_step` needs, in the order of the ``_P_*`` indices (cached: frozen)."""
        values = {
            _P_MASS: self.mass_kg,
            _P_IZ: self.yaw_inertia_kgm2,
            _P_LF: self.cg_to_front_axle_m,
            _P_LR: self.cg_to_rear_axle_m,
            _P_H: self.cg_height_m,
            _P_TRACK: self.track_width_m,
            _P_STEER_LIM: self.steer_limit_rad,
            _P_STEER_RATE: self.max_steer_rate_radps,
            _P_STEER_LAG: self.steer_lag_s,
            _P_OMEGA_LAG: self.omega_lag_s,
            _P_WHEEL_POWER: self.wheel_power_w,
            _P_DRIVE_CAP: self.max_drive_force_n,
            _P_DRIVE_FRONT: -1.0 if self.drive == "awd" else self.drive_front_share,  # < 0: split by grip
            _P_VMAX: self.max_speed_mps,
            _P_BRAKE: self.max_brake_force_n,
            _P_BRAKE_FRONT: self.brake_front_share,
            _P_HALF_RHO_CDA: 0.5 * self.air_density_kgpm3 * self.drag_area_m2,
            _P_HALF_RHO_CLA: 0.5 * self.air_density_kgpm3 * self.downforce_area_m2,
            _P_DF_FRONT: self.downforce_front_share,
            _P_CRR: self.rolling_resistance,
            _P_ROLL_FRONT: self.roll_stiffness_front_share,
            _P_ROLL_GRAD: self.roll_gradient_radpmps2,
            _P_PITCH_GRAD: self.pitch_gradient_radpmps2,
            _P_BODY_LAG: self.body_motion_lag_s,
            _P_V_KIN: self.kinematic_below_mps,
            _P_V_DYN: self.dynamic_above_mps,
        }
        for base, tyre in ((_P_TYRE_F, self.tyre_front), (_P_TYRE_R, self.tyre_rear)):
            values[base + 0] = tyre.stiffness_b_per_rad
            values[base + 1] = tyre.shape_c
            values[base + 2] = tyre.curvature_e
            values[base + 3] = tyre.peak_mu
            values[base + 4] = tyre.load_sensitivity
            values[base + 5] = tyre.nominal_load_n
            values[base + 6] = tyre.long_to_lat_mu_ratio
        packed = np.array([values[i] for i in range(_N_PACKED)], dtype=np.float64)
        packed.setflags(write=False)
        return packed


# Indices into VehicleParams._packed (module constants: numba folds them into the compiled code).
(
    _P_MASS,
    _P_IZ,
    _P_LF,
    _P_LR,
    _P_H,
    _P_TRACK,
    _P_STEER_LIM,
    _P_STEER_RATE,
    _P_STEER_LAG,
    _P_OMEGA_LAG,
    _P_WHEEL_POWER,
    _P_DRIVE_CAP,
    _P_DRIVE_FRONT,
    _P_VMAX,
    _P_BRAKE,
    _P_BRAKE_FRONT,
    _P_HALF_RHO_CDA,
    _P_HALF_RHO_CLA,
    _P_DF_FRONT,
    _P_CRR,
    _P_ROLL_FRONT,
    _P_ROLL_GRAD,
    _P_PITCH_GRAD,
    _P_BODY_LAG,
    _P_V_KIN,
    _P_V_DYN,
) = range(26)
_P_TYRE_F = 26  # 7 tyre floats: B, C, E, mu, load sensitivity, nominal load, long/lat mu ratio
_P_TYRE_R = 33
_N_PACKED = 40


class VehicleState(NamedTuple):
    """State of n cars; every field is a float64 array of shape (n_cars,). Signs: docs/notes/sim.md (vehicle.py)."""

    x_m: np.ndarray
    y_m: np.ndarray
    yaw_rad: np.ndarray
    """Heading, counter-clockwise from world +x, wrapped to [-pi, pi)."""
    vx_mps: np.ndarray
    """Body-frame forward velocity."""
    vy_mps: np.ndarray
    """Body-frame leftward velocity."""
    yaw_rate_radps: np.ndarray
    steer_rad: np.ndarray
    """Actual road-wheel angle (after lag and rate limit), positive to the left."""
    omega: np.ndarray
    """Lagged throttle (> 0) / brake (< 0) command in [-1, 1]."""
    ax_mps2: np.ndarray
    """Body-frame longitudinal acceleration without gravity over the last substep."""
    ay_mps2: np.ndarray
    """Body-frame lateral acceleration without gravity over the last substep."""
    roll_rad: np.ndarray
    pitch_rad: np.ndarray
    roll_rate_radps: np.ndarray
    pitch_rate_radps: np.ndarray


def initial_state(
    n_cars: int,
    x_m: float | np.ndarray = 0.0,
    y_m: float | np.ndarray = 0.0,
    yaw_rad: float | np.ndarray = 0.0,
    speed_mps: float | np.ndarray = 0.0,
) -> VehicleState:
    """Cars at the given poses moving straight ahead at ``speed_mps``; scalars and (n_cars,) arrays broadcast."""
    if n_cars < 0:
        raise ValueError(f"n_cars must be >= 0, got {n_cars}")

    def full(v: float | np.ndarray) -> np.ndarray:
        return np.array(np.broadcast_to(np.asarray(v, dtype=np.float64), (n_cars,)))

    zeros = [np.zeros(n_cars) for _ in range(10)]
    yaw = full(yaw_rad)
    yaw = yaw - 2.0 * np.pi * np.floor((yaw + np.pi) / (2.0 * np.pi))
    return VehicleState(full(x_m), full(y_m), yaw, full(speed_mps), *zeros)


# ---------------------------------------------------------------------------------------------------- physics
@register_jitable
def _clean_command(cmd, limit):
    """Clip to [-limit, limit]; NaN becomes 0 (fmax alone would turn it into -limit).

    Multiplying by a mask instead of ``np.where``, which numba types as a 0-d array on floats."""
    return np.fmin(np.fmax(cmd, -limit), limit) * np.logical_not(np.isnan(cmd)) + 0.0


@register_jitable
def _magic_formula(b, c, e, slip):
    """Normalised Magic Formula, F / D, for slip in rad."""
    bs = b * slip
    return np.sin(c * np.arctan(bs - e * (bs - np.arctan(bs))))


@register_jitable
def _axle_grip_n(fz_axle, transfer_n, mu0, load_sens, fz0):
    """Peak force of an axle's two wheels, N, with ``transfer_n`` moved from the inner to the outer wheel."""
    f_out = 0.5 * fz_axle + transfer_n
    f_in = 0.5 * fz_axle - transfer_n
    mu_out = mu0 * np.maximum(1.0 + load_sens * (f_out - fz0) / fz0, 0.2)
    mu_in = mu0 * np.maximum(1.0 + load_sens * (f_in - fz0) / fz0, 0.2)
    return mu_out * f_out + mu_in * f_in


@register_jitable
def _flush(value):
    """0 for |value| < 1e-100. The lags and the stable modes decay geometrically; without this a car on a straight
    ends up computing with subnormal floats (and their squares), which makes a substep about twice as slow."""
    return value * (np.abs(value) >= 1e-100)


@register_jitable
def _axle_loads(p, vx, ax):
    """Front and rear axle loads, N: static split, longitudinal transfer m ax h / L, downforce. The transfer is
    capped so that each axle keeps 5 % of the weight: the grip terms divide by the load, and a wall or car contact
    can write an impulsive acceleration of hundreds of m/s^2 into ``ax``."""
    m = p[_P_MASS]
    wheelbase = p[_P_LF] + p[_P_LR]
    static_f = m * GRAVITY_MPS2 * p[_P_LR] / wheelbase
    static_r = m * GRAVITY_MPS2 * p[_P_LF] / wheelbase
    min_load = 0.05 * m * GRAVITY_MPS2
    transfer = np.minimum(np.maximum(m * p[_P_H] / wheelbase * ax, min_load - static_r), static_f - min_load)
    downforce = p[_P_HALF_RHO_CLA] * vx * vx
    return static_f - transfer + p[_P_DF_FRONT] * downforce, static_r + transfer + (1.0 - p[_P_DF_FRONT]) * downforce


def axle_loads_n(
    params: VehicleParams, vx_mps: float | np.ndarray, ax_mps2: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Front and rear axle normal loads (N) the model uses at forward speed ``vx_mps`` and body acceleration
    ``ax_mps2`` (the previous substep's, in :func:`step`)."""
    vx = np.asarray(vx_mps, dtype=np.float64)
    ax = np.asarray(ax_mps2, dtype=np.float64)
    return _axle_loads(params._packed, vx, ax)


@register_jitable
def _actuators(p, steer, omega, steer_cmd, omega_cmd, dt):
    """New road-wheel angle (rad) and pedal: exact discretisation of the first-order lags (stable for any dt), then
    the steering's rate limit."""
    steer_target = _clean_command(steer_cmd, p[_P_STEER_LIM])
    omega_target = _clean_command(omega_cmd, 1.0)
    steer_gain = 1.0 - math.exp(-dt / p[_P_STEER_LAG])
    omega_gain = 1.0 - math.exp(-dt / p[_P_OMEGA_LAG])
    max_dsteer = p[_P_STEER_RATE] * dt
    steer_n = steer + np.minimum(np.maximum(steer_gain * (steer_target - steer), -max_dsteer), max_dsteer)
    steer_n = np.minimum(np.maximum(steer_n, -p[_P_STEER_LIM]), p[_P_STEER_LIM])  # also for a bad initial state
    omega_n = omega + omega_gain * (omega_target - omega)
    return steer_n, omega_n


@register_jitable
def _grips_n(p, vx, ax, ay):
    """Axle loads and each axle's lateral and longitudinal grip, N: (fz_f, fz_r, grip_f, grip_r, grip_long_f,
    grip_long_r). Last substep's acceleration closes the load-transfer loop one step late (gain h/L * mu < 1)."""
    fz_f, fz_r = _axle_loads(p, vx, ax)
    lateral_transfer = p[_P_MASS] * p[_P_H] / p[_P_TRACK] * np.abs(ay)
    grip_f = _axle_grip_n(
        fz_f,
        np.minimum(p[_P_ROLL_FRONT] * lateral_transfer, 0.5 * fz_f),
        p[_P_TYRE_F + 3],
        p[_P_TYRE_F + 4],
        p[_P_TYRE_F + 5],
    )
    grip_r = _axle_grip_n(
        fz_r,
        np.minimum((1.0 - p[_P_ROLL_FRONT]) * lateral_transfer, 0.5 * fz_r),
        p[_P_TYRE_R + 3],
        p[_P_TYRE_R + 4],
        p[_P_TYRE_R + 5],
    )
    return fz_f, fz_r, grip_f, grip_r, p[_P_TYRE_F + 6] * grip_f, p[_P_TYRE_R + 6] * grip_r


@register_jitable
def _lateral_forces_n(p, vx, vy, r, cos_d, sin_d, grip_f, grip_r):
    """Pure lateral forces of the front and rear axle, N; slip angles in each wheel's frame (valid reversing and
    sliding sideways)."""
    vy_front = vy + p[_P_LF] * r
    u_front = vx * cos_d + vy_front * sin_d
    w_front = vy_front * cos_d - vx * sin_d
    slip_f = -np.arctan2(w_front, np.abs(u_front))
    slip_r = -np.arctan2(vy - p[_P_LR] * r, np.abs(vx))
    fy_f0 = grip_f * _magic_formula(p[_P_TYRE_F], p[_P_TYRE_F + 1], p[_P_TYRE_F + 2], slip_f)
    fy_r0 = grip_r * _magic_formula(p[_P_TYRE_R], p[_P_TYRE_R + 1], p[_P_TYRE_R + 2], slip_r)
    return fy_f0, fy_r0


@register_jitable
def _longitudinal_demand_n(p, vx, vy, omega_n, grip_long_f, grip_long_r):
    """(throttle, front and rear force demand in N, speed in m/s, direction): the engine (power and force caps, rev
    limit) and the brakes opposing the motion; ``direction`` is the forward share of the motion."""
    throttle = np.maximum(omega_n, 0.0)
    brake = np.maximum(-omega_n, 0.0)
    rev_fade = np.minimum(np.maximum(p[_P_VMAX] - vx, 0.0), 1.0)
    f_drive = throttle * np.minimum(p[_P_DRIVE_CAP], p[_P_WHEEL_POWER] / np.maximum(vx, 1e-3)) * rev_fade
    # Brakes and rolling resistance act along the wheels: a car sliding sideways (vx ~ 0, |vy| large) gets little
    # longitudinal force from them, so their sign cannot chatter while vx crosses 0; below 0.1 m/s they taper off.
    speed = np.sqrt(vx * vx + vy * vy)
    direction = vx / np.maximum(speed, 0.1)
    f_brake = brake * p[_P_BRAKE] * direction
    drive_front = p[_P_DRIVE_FRONT]
    if drive_front < 0.0:  # AWD: an active centre differential sends the torque to where the grip is
        drive_front = grip_long_f / (grip_long_f + grip_long_r)
    fx_f_demand = drive_front * f_drive - p[_P_BRAKE_FRONT] * f_brake
    fx_r_demand = (1.0 - drive_front) * f_drive - (1.0 - p[_P_BRAKE_FRONT]) * f_brake
    return throttle, fx_f_demand, fx_r_demand, speed, direction


@register_jitable
def _friction_ellipse(fx_demand, fy0, grip_long, grip):
    """Combined slip: an axle's (Fx, Fy) pair scaled back onto its friction ellipse, N."""
    scale = 1.0 / np.maximum(np.sqrt((fx_demand / grip_long) ** 2 + (fy0 / grip) ** 2), 1.0)
    return fx_demand * scale, fy0 * scale


@register_jitable
def _dynamic_velocities(p, vx, vy, r, cos_d, sin_d, fx_f, fy_f, fx_r, fy_r, f_resist, dt):
    """The dynamic model's new body-frame velocities (m/s) and yaw rate (rad/s)."""
    m = p[_P_MASS]
    fy_front_body = fx_f * sin_d + fy_f * cos_d
    dvx_dyn = (fx_f * cos_d - fy_f * sin_d + fx_r + f_resist) / m
    dvy_dyn = (fy_front_body + fy_r) / m
    # The body frame turns by r dt during the step: rotating the velocity exactly instead of adding the explicit
    # Euler terms (r vy, -r vx) keeps a spinning car from gaining speed: at 18 rad/s, the Euler terms grew |v| by
    # 1.6 % per 10 ms step and a car spun by a wall impact accelerated without bound.
    turn_c = np.cos(r * dt)
    turn_s = np.sin(r * dt)
    vx_turned = vx * turn_c + vy * turn_s
    vy_turned = vy * turn_c - vx * turn_s
    dr_dyn = (p[_P_LF] * fy_front_body - p[_P_LR] * fy_r) / p[_P_IZ]
    return vx_turned + dt * dvx_dyn, vy_turned + dt * dvy_dyn, r + dt * dr_dyn


@register_jitable
def _kinematic_dvx(p, cos_d, fx_f_demand, fx_r_demand, grip_long_f, grip_long_r, f_resist):
    """The kinematic model's forward acceleration, m/s^2: no slip, only longitudinal forces, each within its axle's
    capacity."""
    fx_f_kin = np.minimum(np.maximum(fx_f_demand, -grip_long_f), grip_long_f)
    fx_r_kin = np.minimum(np.maximum(fx_r_demand, -grip_long_r), grip_long_r)
    return (fx_f_kin * cos_d + fx_r_kin + f_resist) / p[_P_MASS]


@register_jitable
def _blended_velocities(p, vx, vy, r, speed, throttle, cos_d, sin_d, grip_f, grip_r, dvx_kin, dyn, dt):
    """New (vx, vy, yaw rate): the kinematic model's below ``_P_V_KIN``, the dynamic model's ``dyn`` (vx, vy, r)
    above ``_P_V_DYN``, blended linearly in between."""
    vx_dyn, vy_dyn, r_dyn = dyn
    lf = p[_P_LF]
    lr = p[_P_LR]
    w_dyn = np.minimum(np.maximum((speed - p[_P_V_KIN]) / (p[_P_V_DYN] - p[_P_V_KIN]), 0.0), 1.0)
    vx_n = vx + dt * dvx_kin + w_dyn * (vx_dyn - vx - dt * dvx_kin)
    # In the kinematic regime brakes and rolling resistance stop a car but never reverse it, and a creep below
    # 1 mm/s is a stop (else it decays geometrically into subnormal floats). At speed a sign change of vx is real:
    # a spinning car.
    stopped = (speed < p[_P_V_KIN]) & (throttle <= 0.0) & ((vx * vx_n <= 0.0) | (np.abs(vx_n) < 1e-3))
    vx_n = vx_n * np.logical_not(stopped) + 0.0  # + 0.0 turns -0.0 into 0.0
    # The kinematic model's no-slip values, approached as fast as the tyres' grip allows: rolling cars follow them
    # exactly, a car still sliding when it slows down keeps sliding at the friction limit instead of snapping.
    yaw_rate_kin = vx_n * (sin_d / cos_d) / (lf + lr)
    max_dvy = dt * (grip_f + grip_r) / p[_P_MASS]
    max_dr = dt * (lf * grip_f + lr * grip_r) / p[_P_IZ]
    vy_kin = vy + np.minimum(np.maximum(lr * yaw_rate_kin - vy, -max_dvy), max_dvy)
    r_kin = r + np.minimum(np.maximum(yaw_rate_kin - r, -max_dr), max_dr)
    vy_n = vy_kin + w_dyn * (vy_dyn - vy_kin)
    r_n = r_kin + w_dyn * (r_dyn - r_kin)
    return vx_n, vy_n, r_n


@register_jitable
def _pose(x, y, yaw, vx_n, vy_n, r_n, dt):
    """New (x, y, yaw): semi-implicit (the new velocities), yaw wrapped to [-pi, pi)."""
    yaw_n = yaw + dt * r_n
    yaw_n = yaw_n - 2.0 * np.pi * np.floor((yaw_n + np.pi) / (2.0 * np.pi))
    cos_y = np.cos(yaw_n)
    sin_y = np.sin(yaw_n)
    return x + dt * (vx_n * cos_y - vy_n * sin_y), y + dt * (vx_n * sin_y + vy_n * cos_y), yaw_n


@register_jitable
def _body_motion(p, vx, vy, r, vx_n, vy_n, roll, pitch, dt):
    """The accelerometer (dv/dt + omega x v) and the lagged quasi-static body roll and pitch: (ax, ay, roll, pitch,
    roll rate, pitch rate)."""
    ax_n = (vx_n - vx) / dt - r * vy
    ay_n = (vy_n - vy) / dt + r * vx
    body_gain = 1.0 - math.exp(-dt / p[_P_BODY_LAG])
    roll_n = roll + body_gain * (p[_P_ROLL_GRAD] * ay_n - roll)
    pitch_n = pitch + body_gain * (-p[_P_PITCH_GRAD] * ax_n - pitch)
    return ax_n, ay_n, roll_n, pitch_n, (roll_n - roll) / dt, (pitch_n - pitch) / dt


@register_jitable
def _car_step(
    p, x, y, yaw, vx, vy, r, steer, omega, ax, ay, roll, pitch, roll_rate, pitch_rate, steer_cmd, omega_cmd, dt
):
    """One substep, element-wise: every argument but ``p`` (``VehicleParams._packed``) and ``dt`` (s) is either an
    (n,) array (the numpy path) or one car's float (the numba path, :func:`_step_jit`): one source for both.

    Returns the 14 new state values in :class:`VehicleState` order.
    """
    steer_n, omega_n = _actuators(p, steer, omega, steer_cmd, omega_cmd, dt)
    fz_f, fz_r, grip_f, grip_r, grip_long_f, grip_long_r = _grips_n(p, vx, ax, ay)
    cos_d = np.cos(steer_n)
    sin_d = np.sin(steer_n)
    fy_f0, fy_r0 = _lateral_forces_n(p, vx, vy, r, cos_d, sin_d, grip_f, grip_r)
    throttle, fx_f_demand, fx_r_demand, speed, direction = _longitudinal_demand_n(
        p, vx, vy, omega_n, grip_long_f, grip_long_r
    )
    fx_f, fy_f = _friction_ellipse(fx_f_demand, fy_f0, grip_long_f, grip_f)
    fx_r, fy_r = _friction_ellipse(fx_r_demand, fy_r0, grip_long_r, grip_r)
    f_resist = -p[_P_HALF_RHO_CDA] * vx * np.abs(vx) - p[_P_CRR] * (fz_f + fz_r) * direction
    dyn = _dynamic_velocities(p, vx, vy, r, cos_d, sin_d, fx_f, fy_f, fx_r, fy_r, f_resist, dt)
    dvx_kin = _kinematic_dvx(p, cos_d, fx_f_demand, fx_r_demand, grip_long_f, grip_long_r, f_resist)
    vx_n, vy_n, r_n = _blended_velocities(p, vx, vy, r, speed, throttle, cos_d, sin_d, grip_f, grip_r, dvx_kin, dyn, dt)
    x_n, y_n, yaw_n = _pose(x, y, yaw, vx_n, vy_n, r_n, dt)
    ax_n, ay_n, roll_n, pitch_n, roll_rate_n, pitch_rate_n = _body_motion(p, vx, vy, r, vx_n, vy_n, roll, pitch, dt)
    return (
        x_n,
        y_n,
        yaw_n,
        vx_n,
        _flush(vy_n),
        _flush(r_n),
        _flush(steer_n),
        _flush(omega_n),
        _flush(ax_n),
        _flush(ay_n),
        _flush(roll_n),
        _flush(pitch_n),
        _flush(roll_rate_n),
        _flush(pitch_rate_n),
    )


def _step_numpy(p, state_arrays, steer_cmd, omega_cmd, dt):
    """The numpy path: :func:`_car_step` on whole arrays (kept for the agreement test and for reading)."""
    return _car_step(p, *state_arrays, steer_cmd, omega_cmd, dt)


@numba.njit(cache=True, error_model="numpy")
def _step_jit(p, s, steer_cmd, omega_cmd, dt, n_substeps):
    """The numba path: ``n_substeps`` of :func:`_car_step` per car, the car's state kept in registers in between.

    ``s`` is a (14, n) array (one row per :class:`VehicleState` field); returns a new (14, n) array.
    """
    out = np.empty_like(s)
    for i in range(s.shape[1]):
        c = (
            s[0, i],
            s[1, i],
            s[2, i],
            s[3, i],
            s[4, i],
            s[5, i],
            s[6, i],
            s[7, i],
            s[8, i],
            s[9, i],
            s[10, i],
            s[11, i],
            s[12, i],
            s[13, i],
        )
        for _ in range(n_substeps):
            c = _car_step(p, *c, steer_cmd[i], omega_cmd[i], dt)
        for k in range(14):
            out[k, i] = c[k]
    return out


def _command(value: float | np.ndarray, n_cars: int) -> np.ndarray:
    """A writable C-contiguous float64 (n_cars,) array: numba compiles (and caches) one specialisation per array
    type, and read-only or strided inputs would each cost a fresh compilation."""
    a = np.asarray(value, dtype=np.float64)
    if a.shape == (n_cars,) and a.flags.c_contiguous and a.flags.writeable:
        return a
    return np.array(np.broadcast_to(a, (n_cars,)))


def _check_dt(dt_s: float) -> float:
    dt = float(dt_s)
    if not (dt > 0.0 and math.isfinite(dt)):
        raise ValueError(f"dt_s must be positive and finite, got {dt_s}")
    return dt


def advance(
    params: VehicleParams,
    state: VehicleState,
    steer_cmd_rad: float | np.ndarray,
    omega_cmd: float | np.ndarray,
    dt_s: float = DEFAULT_DT_S,
    n_substeps: int = 1,
) -> VehicleState:
    """``n_substeps`` physics substeps of ``dt_s`` seconds with the same command, for all cars; pure.

    ``steer_cmd_rad`` (road-wheel angle, + left) and ``omega_cmd`` (throttle > 0, brake < 0) are (n_cars,) arrays or
    scalars; out-of-range values are clipped and NaN counts as 0. The new state's arrays are rows of one (14, n)
    block: fresh memory, never the input's.
    """
    if n_substeps < 0:
        raise ValueError(f"n_substeps must be >= 0, got {n_substeps}")
    n = len(state.x_m)
    try:
        block = np.array(state, dtype=np.float64)  # a copy: the numba loop reads one (14, n) block
    except ValueError:
        block = None
    if block is None or block.shape != (len(VehicleState._fields), n):
        raise ValueError(f"every VehicleState field must have shape ({n},), got {[np.shape(a) for a in state]}")
    out = _step_jit(
        params._packed, block, _command(steer_cmd_rad, n), _command(omega_cmd, n), _check_dt(dt_s), int(n_substeps)
    )
    return VehicleState(*out)


def step(
    params: VehicleParams,
    state: VehicleState,
    steer_cmd_rad: float | np.ndarray,
    omega_cmd: float | np.ndarray,
    dt_s: float = DEFAULT_DT_S,
) -> VehicleState:
    """One physics substep of ``dt_s`` seconds for all cars (see :func:`advance`); pure."""
    return advance(params, state, steer_cmd_rad, omega_cmd, dt_s, 1)


# ---------------------------------------------------------------------------------------------------- presets
PRESETS: dict[str, VehicleParams] = {
    # Mazda Demio XD Touring '15 (Mazda2 1.5 SKYACTIV-D, 6MT), the car of the GT Sport vision paper.
    "hatchback": VehicleParams(
        name="hatchback",
        source="Mazda Demio XD Touring '15 (Mazda2 DJ 1.5 SKYACTIV-D)",
        # Mass, yaw inertia and CG position as identified inside GT Sport; Mazda's kerb mass is about
        # 1,130 kg plus a 75 kg driver, GT Sport's car is heavier.
        mass_kg=1355.0,
        yaw_inertia_kgm2=2064.0,
        cg_to_front_axle_m=0.946,
        cg_to_rear_axle_m=1.620,  # 2.566 m wheelbase; Mazda's spec sheet: 2,570 mm
        cg_height_m=0.55,  # estimate for a B-segment hatchback (1,500 mm tall)
        length_m=4.06,  # Mazda2 DJ spec sheet: 4,060 x 1,695 mm
        width_m=1.695,
        max_steer_rad=0.55,  # 9.8 m kerb-to-kerb turning circle: asin(2.566 / 4.9) = 0.55 rad
        track_width_m=1.49,  # spec sheet: 1,495 mm front, 1,480 mm rear
        tyre_front=ROAD_TYRE_SOFT_AXLE,
        tyre_rear=ROAD_TYRE,
        max_power_w=77_000.0,  # 105 PS at 4,000 rpm (spec sheet)
        # 250 Nm x about 12.5 overall first-gear ratio x 0.9 / 0.30 m rolling radius (estimate); the front tyres
        # limit the launch anyway.
        max_drive_force_n=9_400.0,
        drive="fwd",
        # Manual transaxle, typically 85-92 %; the low end also stands for the gear-shift time a gearless model
        # leaves out (0-100 km/h: 9.9 s, about the real car's 10 s).
        drivetrain_efficiency=0.85,
        # Published top speed 178 km/h; the constant-power model with this car's drag would reach about 190 km/h,
        # because the overdrive sixth gear keeps the real engine below its power peak there.
        max_speed_mps=178.0 / 3.6,
        max_brake_force_n=17_000.0,  # about 1.3 g: road-car brakes can lock all four wheels
        brake_front_share=0.7,  # typical front bias of a front-heavy hatchback
        drag_area_m2=0.30 * 2.2,  # Cd about 0.30, frontal area about 2.2 m^2 (estimates for the class)
        rolling_resistance=0.012,  # passenger-car tyres on asphalt, 0.010-0.015
        downforce_area_m2=0.0,  # road hatchbacks make little lift or downforce
        roll_stiffness_front_share=0.6,  # FWD hatchbacks are set up stiffer in front (understeer), estimate
        max_steer_rate_radps=1.2,  # about 1,000 deg/s at the wheel through a 15:1 rack (fast human driver)
        roll_gradient_radpmps2=math.radians(5.0) / GRAVITY_MPS2,  # 5 deg/g, a soft road car
        pitch_gradient_radpmps2=math.radians(2.0) / GRAVITY_MPS2,  # 2 deg/g
        body_motion_lag_s=0.15,
    ),
    # Audi TT Cup (2015-2018 one-make series car), the car of the GT Sport overtaking paper.
    "tt_cup": VehicleParams(
        name="tt_cup",
        source="Audi TT Cup (Audi Sport TT Cup 2015)",
        mass_kg=1195.0,  # GT Sport identified; Audi's figure is 1,125 kg without driver
        yaw_inertia_kgm2=1185.0,  # GT Sport identified
        cg_to_front_axle_m=1.020,  # GT Sport identified; 2.504 m wheelbase (TT Mk3: 2,505 mm)
        cg_to_rear_axle_m=1.484,
        cg_height_m=0.45,  # estimate: lowered touring car
        length_m=4.18,  # TT Mk3 coupe: 4,177 x 1,832 mm
        width_m=1.83,
        max_steer_rad=0.45,  # estimate: race car rack with less lock than the road car
        track_width_m=1.60,  # TT Mk3 about 1,570 mm, the Cup car runs wider wheels (estimate)
        tyre_front=SLICK_TYRE,
        tyre_rear=SLICK_TYRE,
        max_power_w=228_000.0,  # 310 PS (Audi Sport)
        max_drive_force_n=14_000.0,  # 380 Nm x about 12 overall first gear x 0.9 / 0.32 m (estimate)
        drive="fwd",
        drivetrain_efficiency=0.9,  # DSG transaxle, typical
        max_brake_force_n=23_000.0,  # about 2 g: race brakes, above the slicks' capacity at low speed
        brake_front_share=0.7,  # front-heavy FWD car (estimate)
        drag_area_m2=0.72,  # TT coupe Cd 0.30 x 2.1 m^2 plus the Cup car's rear wing (estimate)
        rolling_resistance=0.015,  # racing slicks (estimate)
        downforce_area_m2=0.6,  # small rear wing and splitter (estimate)
        downforce_front_share=0.3,  # rear wing: aero balance behind the weight balance, stable at speed (estimate)
        roll_stiffness_front_share=0.55,  # estimate
        max_steer_rate_radps=1.5,  # quicker race rack (about 12:1, estimate)
        roll_gradient_radpmps2=math.radians(1.5) / GRAVITY_MPS2,  # stiff race suspension, 1.5 deg/g
        pitch_gradient_radpmps2=math.radians(0.7) / GRAVITY_MPS2,
        body_motion_lag_s=0.08,
    ),
    # Porsche 911 GT3 R (991.2, 2019): rear-engined RWD GT3 race car with real downforce.
    "gt3": VehicleParams(
        name="gt3",
        source="Porsche 911 GT3 R (991.2)",
        mass_kg=1325.0,  # about 1,250 kg race weight (class minimum, BoP dependent) plus a 75 kg driver
        yaw_inertia_kgm2=1900.0,  # estimate: m lf lr (dynamic index 1) = 1,325 x 1.48 x 0.98
        cg_to_front_axle_m=1.48,  # 2,459 mm wheelbase with about 40 % of the weight on the front axle (rear engine)
        cg_to_rear_axle_m=0.98,
        cg_height_m=0.38,  # estimate for a GT3 car
        length_m=4.63,  # Porsche Motorsport: 4,629 x 2,002 mm
        width_m=2.00,
        max_steer_rad=0.45,  # estimate: race car rack
        track_width_m=1.65,  # estimate from the 2.0 m body width
        tyre_front=SLICK_TYRE,
        tyre_rear=SLICK_TYRE,
        max_power_w=370_000.0,  # about 500 PS, BoP dependent (Porsche Motorsport)
        max_drive_force_n=16_000.0,  # 470 Nm x about 12 overall first gear x 0.9 / 0.34 m (estimate)
        drive="rwd",
        drivetrain_efficiency=0.9,  # sequential race gearbox, typical
        max_brake_force_n=32_000.0,  # about 2.5 g: above the tyres' capacity with full downforce
        brake_front_share=0.6,  # rear-engined car: less front bias than a front-engined one (estimate)
        drag_area_m2=0.90,  # estimate: GT3 cars run Cd about 0.45 on about 2.0 m^2, top speed about 300 km/h
        rolling_resistance=0.015,  # racing slicks (estimate)
        downforce_area_m2=2.5,  # estimate: lift/drag about 2.8, about 470 kg of downforce at 200 km/h
        downforce_front_share=0.40,  # aero balance near the weight balance, slightly rearward (estimate)
        roll_stiffness_front_share=0.55,  # estimate
        max_steer_rate_radps=1.5,  # race rack (estimate)
        roll_gradient_radpmps2=math.radians(1.0) / GRAVITY_MPS2,  # GT3 race suspension, about 1 deg/g
        pitch_gradient_radpmps2=math.radians(0.5) / GRAVITY_MPS2,
        body_motion_lag_s=0.08,
    ),
}

DEFAULT_CAR = "hatchback"


def get_preset(name: str) -> VehicleParams:
    """The preset called ``name``; ValueError listing the presets for any other name."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown car preset {name!r}; presets: {', '.join(sorted(PRESETS))}") from None


# ---------------------------------------------------------------------------------------------------- benchmark
def bench_physics(n_cars: int = 1000, n_substeps: int = 100, seed: int = 0, repeats: int = 7) -> dict:
    """Physics throughput of :func:`advance` on the default car with random actions at random speeds.

    Returns ``{"physics_car_substeps_per_s": median over repeats, ...}``; compiles (or loads the cache) first.
    """
    rng = np.random.default_rng(seed)
    params = get_preset(DEFAULT_CAR)
    state = initial_state(n_cars, yaw_rad=rng.uniform(-np.pi, np.pi, n_cars), speed_mps=rng.uniform(0, 50, n_cars))
    steer = rng.uniform(-params.steer_limit_rad, params.steer_limit_rad, n_cars)
    omega = rng.uniform(-1.0, 1.0, n_cars)
    advance(params, state, steer, omega, DEFAULT_DT_S, 2)  # compile or load the numba cache outside the timing
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        state = advance(params, state, steer, omega, DEFAULT_DT_S, n_substeps)
        rates.append(n_cars * n_substeps / (time.perf_counter() - t0))
    return {
        "physics_car_substeps_per_s": float(np.median(rates)),
        "n_cars": n_cars,
        "n_substeps": n_substeps,
        "repeats": repeats,
    }
