"""The built-in AI driver, batched over cars: racing-line following, speed tracking, car following, disruption.

Steering: the line's curvature a short time ahead (actuator lag) as a feedforward, ``wheelbase * kappa`` plus the
steady-state slip-angle difference of the tyres (so the car does not run wide at the limit), plus a feedback that
brings the lateral error back over a preview distance: ``kappa_fb = -2 (e + L_p sin(psi_e)) / L_p^2`` with
``L_p = v * preview_time_s``, a critically damped (zeta = 0.71) path-following law in the distance domain. The
heading error ``psi_e`` is that of the velocity vector, so body slip does not count as an error.

Speed: the QSS limit profile scaled by the driver's ``skill`` in (0, 1], read a little ahead (the throttle/brake
lag), with a force feedforward from the profile's acceleration and a proportional feedback on the speed error.
The profile's braking zones are the braking look-ahead.

Opponent mode: a car that has another car of its collision group ahead of it, overlapping it laterally, slows to
keep a time gap. Disruption (:class:`Disruptor`) adds uniform random offsets to the commands for data collection.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vision_rl.sim.racing_line import RacingLine
from vision_rl.sim.speed_profile import SpeedProfile, CarLimits
from vision_rl.sim.vehicle import GRAVITY_MPS2, VehicleParams

#: Default skill: the profile scaled by this is 8-12 % slower than the limit on every track and preset (measured,
#: see tests/sim/test_ai_driver.py), as GT Sport's built-in AI is about 11 % slower than the best agent.
DEFAULT_SKILL = 0.90

#: Opponent skill range for overtaking scenarios: clearly slower than the default.
OPPONENT_SKILL_RANGE = (0.80, 0.88)


@dataclass(frozen=True)
class AIParams:
    """Gains of the built-in driver (times in s, distances in m)."""

    preview_time_s: float = 0.7
    """Lateral feedback preview: the lateral error decays over about this time (longer: smoother, less precise)."""
    min_preview_m: float = 6.0
    """Lower bound of the preview distance, m (low speeds)."""
    yaw_rate_gain: float = 5.0
    """Counter-steer per path-curvature error (yaw-rate error over speed), as wheelbase * curvature, dimensionless."""
    heading_from_yaw: bool = True
    axle_grip_reserve: float = 0.9
    """Drive and brake forces are capped where an axle would use more than this share of its grip."""
    steer_lead_s: float = 0.06
    """How far ahead the curvature feedforward reads, s: the steering lag (0.05 s) plus half a control step."""
    speed_lead_s: float = 0.15
    """How far ahead the speed target reads, s: the throttle/brake lag (0.1 s) plus half a control step."""
    speed_gain_per_mps: float = 0.3
    """Throttle/brake command per m/s of speed error."""
    follow_time_gap_s: float = 0.6
    """Opponent mode: time gap kept to a car ahead in the same lane, s."""
    follow_min_gap_m: float = 2.0
    """Opponent mode: bumper-to-bumper distance kept at standstill, m."""
    follow_decel_mps2: float = 6.0
    """Opponent mode: deceleration assumed when closing on a car ahead, m/s^2."""


def _wrap_angle(a: np.ndarray) -> np.ndarray:
    return np.mod(a + np.pi, 2.0 * np.pi) - np.pi


class AIDriver:
    """Built-in driver for ``n_cars`` cars of one world; :meth:`act` maps a world state to commands.

    Args:
        car: the cars' parameters (one model per world).
        line: racing line of the world's track.
        profile: QSS limit profile of ``car`` on ``line`` (see :mod:`vision_rl.sim.speed_profile`).
        skill: (n_cars,) or scalar in (0, 1]: the share of the limit profile each car aims for.
        groups: collision group of each car; cars follow only cars of their own group (None: no following).
        params: controller gains.
    """

    def __init__(
        self,
        car: VehicleParams,
        line: RacingLine,
        profile: SpeedProfile,
        n_cars: int,
        skill: float | np.ndarray = DEFAULT_SKILL,
        groups: np.ndarray | None = None,
        params: AIParams | None = None,
    ) -> None:
        skill_arr = np.broadcast_to(np.asarray(skill, dtype=np.float64), (n_cars,)).copy()
        if not np.all((skill_arr > 0.0) & (skill_arr <= 1.0)):
            raise ValueError(f"skill must be in (0, 1], got {skill}")
        self.car = car
        self.line = line
        self.profile = profile
        self.n_cars = n_cars
        self.skill = skill_arr
        self.groups = None if groups is None else np.asarray(groups)
        self.params = params or AIParams()
        self._limits = CarLimits(car)
        self._reserve_limits = CarLimits(car, self.params.axle_grip_reserve)
        # Closed, unwrapped tables of the line so that interpolation never jumps across the wrap.
        self._line_s_closed = np.append(line.s_m, line.length_m)
        self._heading_closed = np.unwrap(np.append(line.heading_rad, line.heading_rad[0]))

    # ------------------------------------------------------------------ helpers
    def _resistance_n(self, speed_mps: np.ndarray) -> np.ndarray:
        car = self.car
        return 0.5 * car.air_density_kgpm3 * car.drag_area_m2 * speed_mps**2 + car.rolling_resistance * (
            car.weight_n + 0.5 * car.air_density_kgpm3 * car.downforce_area_m2 * speed_mps**2
        )

    def _drive_force_n(self, speed_mps: np.ndarray) -> np.ndarray:
        car = self.car
        fade = np.clip(car.max_speed_mps - speed_mps, 0.0, 1.0)
        return np.minimum(car.max_drive_force_n, car.wheel_power_w / np.maximum(speed_mps, 1e-3)) * fade

    def _follow_speed(self, state, speed: np.ndarray) -> np.ndarray:
        """Highest speed that keeps the time gap to the nearest same-group car ahead in the same lane (inf: none)."""
        limit = np.full(self.n_cars, np.inf)
        if self.groups is None or self.n_cars < 2:
            return limit
        p = self.params
        track_length = self.line.track_length_m
        gap = np.mod(state.s_m[None, :] - state.s_m[:, None] + 0.5 * track_length, track_length) - 0.5 * track_length
        same_lane = np.abs(state.lateral_m[None, :] - state.lateral_m[:, None]) < self.car.width_m + 0.5
        relevant = (self.groups[:, None] == self.groups[None, :]) & same_lane & (gap > 0.0)
        np.fill_diagonal(relevant, False)
        clearance = np.where(relevant, gap - self.car.length_m - p.follow_min_gap_m, np.inf)
        ahead = np.argmin(clearance, axis=1)
        free = np.maximum(clearance[np.arange(self.n_cars), ahead], 0.0)
        v_ahead = speed[ahead]
        # Speed from which the car can still slow to the car ahead's speed within the free distance, less the gap.
        v_safe = np.sqrt(v_ahead**2 + 2.0 * p.follow_decel_mps2 * free) - p.follow_decel_mps2 * p.follow_time_gap_s
        return np.where(np.isfinite(free), np.maximum(v_safe, 0.0), np.inf)

    # ------------------------------------------------------------------ control law
    def act(self, state) -> tuple[np.ndarray, np.ndarray]:
        """Commands (steer_cmd_rad (n,), omega_cmd (n,)) for a world state (``vision_rl.sim.world.WorldState``)."""
        p, car, line = self.params, self.car, self.line
        veh = state.vehicle
        speed = np.maximum(np.hypot(veh.vx_mps, veh.vy_mps), 0.0)
        v_ctrl = np.maximum(speed, 1.0)
        line_s = line.line_s_at(state.s_m)

        # Lateral: feedforward on the curvature just ahead, feedback on the lateral and heading errors.
        kappa_ff = line.curvature_at(line_s + v_ctrl * p.steer_lead_s)
        alpha_f, alpha_r, _, _ = self._limits(speed, kappa_ff)
        steer_ff = car.wheelbase_m * kappa_ff + np.sign(kappa_ff) * (alpha_f - alpha_r)
        err_lat = state.lateral_m - line.lateral_at(state.s_m)
        heading_line = np.interp(line_s, self._line_s_closed, self._heading_closed)
        if p.heading_from_yaw:
            kappa_here = line.curvature_at(line_s)
            _, alpha_here_r, _, _ = self._limits(speed, kappa_here)
            beta_ss = car.cg_to_rear_axle_m * kappa_here - np.sign(kappa_here) * alpha_here_r
            err_heading = _wrap_angle(veh.yaw_rad + beta_ss - heading_line)
        else:
            course = veh.yaw_rad + np.arctan2(veh.vy_mps, np.maximum(np.abs(veh.vx_mps), 1.0))
            err_heading = _wrap_angle(course - heading_line)
        preview = np.maximum(v_ctrl * p.preview_time_s, p.min_preview_m)
        kappa_fb = -2.0 * (err_lat + preview * np.sin(err_heading)) / preview**2
        # Inner loop on the yaw rate: counter-steers a car that rotates faster than its path (oversteer under
        # braking), which the course error alone would notice only once the car slides.
        yaw_rate_error = veh.yaw_rate_radps - speed * (line.curvature_at(line_s) + kappa_fb)
        # The gain is on the path-curvature error (yaw-rate error / speed): the loop gain of yaw rate over steering
        # grows with speed (v / wheelbase), so a constant gain in rad per rad/s would oscillate at high speed.
        steer = steer_ff + car.wheelbase_m * (kappa_fb - p.yaw_rate_gain * yaw_rate_error / v_ctrl)
        steer = np.clip(steer, -car.steer_limit_rad, car.steer_limit_rad)

        # Longitudinal: skill-scaled profile ahead, force feedforward, speed feedback, and the axles' limits
        # (braking or driving harder than an axle's ellipse allows would take its lateral force away).
        lead_s = line_s + v_ctrl * p.speed_lead_s
        v_target = np.minimum(self.skill * self.profile.speed_at(lead_s), self._follow_speed(state, speed))
        accel_ff = self.skill**2 * self.profile.accel_at(lead_s)
        kappa_now = line.curvature_at(line_s)
        alpha_now_f, alpha_now_r, _, _ = self._limits(speed, kappa_now)
        _, _, drive_limit, brake_limit = self._reserve_limits(speed, kappa_now)
        wheelbase = car.wheelbase_m
        ay = speed**2 * np.abs(kappa_now)
        cornering_drag = car.mass_kg * ay * (
            car.cg_to_rear_axle_m / wheelbase * np.sin(alpha_now_f)
            + car.cg_to_front_axle_m / wheelbase * np.sin(alpha_now_r)
        )
        force = car.mass_kg * accel_ff + self._resistance_n(speed) + cornering_drag
        engine = np.maximum(self._drive_force_n(v_ctrl), 1.0)
        omega_ff = np.where(force >= 0.0, force / engine, force / car.max_brake_force_n)
        omega = omega_ff + p.speed_gain_per_mps * (v_target - speed)
        omega = np.clip(omega, -brake_limit / car.max_brake_force_n, np.minimum(drive_limit / engine, 1.0))
        return steer, omega


@dataclass(frozen=True)
class DisruptionParams:
    """Uniform random offsets added to the AI's commands for data collection (the vision paper, section 3)."""

    steer_offset_rad: float = 0.08
    """Steering offsets are uniform in +-this, rad."""
    omega_offset: float = 0.5
    """Throttle/brake offsets are uniform in +-this."""
    hold_s: tuple[float, float] = (0.3, 2.0)
    """Each offset pair is held for a duration uniform in this range, s."""
    quiet_probability: float = 0.3
    """Probability that a new period has no offset at all (the AI recovers)."""
    skill: float = 0.75
    """Skill of a disrupted AI: slower, so that large heading errors end in recoveries, not crashes."""
    stuck_after_s: float = 3.0
    """A car that has made less than ``stuck_progress_m`` of progress in this time is put back on track, s."""
    stuck_progress_m: float = 5.0
    """Progress below which a car counts as stuck, m."""


class Disruptor:
    """Per-car random command offsets held for random durations; batched, reproducible from a seed."""

    def __init__(self, n_cars: int, params: DisruptionParams | None = None, seed: int = 0) -> None:
        self.params = params or DisruptionParams()
        self.n_cars = n_cars
        self.rng = np.random.default_rng(seed)
        self.steer_offset_rad = np.zeros(n_cars)
        self.omega_offset = np.zeros(n_cars)
        self.remaining_s = np.zeros(n_cars)

    def __call__(self, steer_rad: np.ndarray, omega: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Commands plus the current offsets; draws new offsets for cars whose hold time ran out."""
        p = self.params
        renew = self.remaining_s <= 0.0
        k = int(renew.sum())
        if k:
            quiet = self.rng.random(k) < p.quiet_probability
            self.steer_offset_rad[renew] = np.where(quiet, 0.0, self.rng.uniform(-1.0, 1.0, k) * p.steer_offset_rad)
            self.omega_offset[renew] = np.where(quiet, 0.0, self.rng.uniform(-1.0, 1.0, k) * p.omega_offset)
            self.remaining_s[renew] = self.rng.uniform(p.hold_s[0], p.hold_s[1], k)
        self.remaining_s -= dt_s
        return steer_rad + self.steer_offset_rad, np.clip(omega + self.omega_offset, -1.0, 1.0)
