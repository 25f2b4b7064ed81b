"""N cars on one track, stepped together: vehicle physics, wall and car contact, progress and lap timing.

The core is the pure, batched :func:`world_step` (``state, action -> state``, Brax style); :class:`World` holds a
state and the per-car lap-time lists around it. Cars belong to collision groups and touch only cars of their own
group: 20 independent time-trial cars are 20 groups of one, an overtaking scenario is one group of an ego car and
its opponents. Walls touch every car.

Contact model. After every physics substep each car's footprint (its body rectangle, measured across the track at
its heading) is kept between the walls: a car that reaches a wall is moved back onto it and receives a rigid-body
impulse at the touching corner (restitution on the normal velocity, Coulomb friction on the tangential one), so a
shallow hit is a glancing blow that costs speed and yaws the car, not a teleport. Because the check works on the
continuous lateral offset of the car at each 10 ms substep (0.83 m of travel at 300 km/h), a car cannot tunnel
through a wall. Cars are three circles along their axis; overlapping cars of one group are separated and exchange
an impulse at the contact point.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from vision_rl.sim import vehicle as vehicle_model
from vision_rl.sim.track import Track
from vision_rl.sim.vehicle import VehicleParams, VehicleState


@dataclass(frozen=True)
class WorldConfig:
    """Time steps and contact constants of a world."""

    physics_dt_s: float = 0.01
    """Internal physics step (s); 100-200 Hz keeps the explicit tyre model stable and walls untunnelled."""
    control_dt_s: float = 0.1
    """Control step (s), a whole multiple of the physics step; 10 Hz is the papers' SAC rate."""
    wall_restitution: float = 0.1
    """Share of the normal speed into a wall given back after the hit (concrete barriers absorb most of it)."""
    wall_friction: float = 0.4
    """Coulomb friction coefficient between a car body and a wall: how much a scrape slows the car."""
    car_restitution: float = 0.2
    """Share of the normal closing speed between two cars given back after contact."""
    car_friction: float = 0.3
    """Coulomb friction coefficient between two car bodies."""

    def __post_init__(self) -> None:
        if not 1 / 200 - 1e-12 <= self.physics_dt_s <= 1 / 100 + 1e-12:
            raise ValueError(f"physics_dt_s must be within 1/200..1/100 s (100-200 Hz), got {self.physics_dt_s}")
        ratio = self.control_dt_s / self.physics_dt_s
        if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
            raise ValueError(
                f"control_dt_s ({self.control_dt_s}) must be a whole multiple of physics_dt_s ({self.physics_dt_s})"
            )

    @property
    def substeps(self) -> int:
        """Physics substeps per control step."""
        return round(self.control_dt_s / self.physics_dt_s)


class WorldState(NamedTuple):
    """State of every car; each field is an array over cars (n,)."""

    vehicle: VehicleState
    """Pose, body-frame velocities, actuator and body-motion states (see vision_rl.sim.vehicle)."""
    s_m: np.ndarray
    """Arc length of the car's projection on the centre line, in [0, track length)."""
    lateral_m: np.ndarray
    """Signed distance of the car centre to the centre line (m, + left)."""
    unwrapped_s_m: np.ndarray
    """Start arc length plus signed progress since the reset (m); grows past the lap length lap after lap."""
    time_s: np.ndarray
    """Time since the car's reset (s)."""
    wall_contact: np.ndarray
    """True if the car touched a wall during the last control step."""
    wall_contact_time_s: np.ndarray
    """Time spent touching a wall since the reset (s)."""
    car_contact: np.ndarray
    """True if the car touched another car of its group during the last control step."""
    car_contact_time_s: np.ndarray
    """Time spent touching other cars since the reset (s)."""
    laps_completed: np.ndarray
    """Timed laps completed since the reset (int)."""
    line_crossings: np.ndarray
    """Highest multiple of the lap length that unwrapped_s_m has reached (int): a new one is a line crossing."""
    lap_start_time_s: np.ndarray
    """time_s at which the current timed lap began (s); NaN before the first crossing of the start/finish line."""
    last_lap_time_s: np.ndarray
    """Duration of the last completed lap (s); NaN before the first one."""
    prev_steer_cmd_rad: np.ndarray
    """Steering command of the last control step (rad), one of the 11 dedicated features."""


class StepEvents(NamedTuple):
    """What happened during one control step (arrays over cars)."""

    lap_completed: np.ndarray
    """True where the car finished a timed lap in this step."""
    lap_time_s: np.ndarray
    """That lap's time (s) where lap_completed, NaN elsewhere."""


@dataclass(frozen=True, eq=False)
class WorldModel:
    """Everything constant in a world: track, car, groups and the contact pairs they imply."""

    track: Track
    car: VehicleParams
    groups: np.ndarray
    config: WorldConfig

    def __post_init__(self) -> None:
        groups = np.asarray(self.groups, dtype=np.int64)
        same = groups[:, None] == groups[None, :]
        pair_i, pair_j = np.nonzero(np.triu(same, k=1))
        object.__setattr__(self, "groups", groups)
        object.__setattr__(self, "pair_i", pair_i)
        object.__setattr__(self, "pair_j", pair_j)

    @property
    def n_cars(self) -> int:
        return len(self.groups)

    @property
    def circle_radius_m(self) -> float:
        """Radius of the three circles that stand for a car body in car-car contact."""
        return 0.5 * self.car.width_m

    @property
    def circle_offsets_m(self) -> np.ndarray:
        """Body-frame x of the three contact circles (front, middle, rear)."""
        reach = 0.5 * self.car.length_m - self.circle_radius_m
        return np.array([reach, 0.0, -reach])


def _rotate(vx: np.ndarray, vy: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.cos(yaw), np.sin(yaw)
    return c * vx - s * vy, s * vx + c * vy


def place_cars(
    model: WorldModel,
    state: WorldState | None,
    car_ids: np.ndarray,
    s_m: np.ndarray,
    lateral_m: np.ndarray,
    speed_mps: np.ndarray,
    heading_offset_rad: np.ndarray,
) -> WorldState:
    """Reset the cars ``car_ids`` at track coordinates and return the new state (a new state if ``state`` is None).

    Each car is placed at rest in every respect but its forward speed, with its clocks and counters cleared. A car
    placed exactly on the start/finish line (s = 0) starts a timed lap; elsewhere the first crossing starts one.
    """
    track = model.track
    n = model.n_cars
    k = len(car_ids)
    s = track.wrap_s(np.broadcast_to(np.asarray(s_m, dtype=np.float64), (k,)))
    lateral = np.broadcast_to(np.asarray(lateral_m, dtype=np.float64), (k,))
    xy = track.position_at(s, lateral)
    yaw = track.heading_at(s) + np.broadcast_to(np.asarray(heading_offset_rad, dtype=np.float64), (k,))
    fresh_vehicle = vehicle_model.initial_state(k, xy[:, 0], xy[:, 1], yaw, speed_mps)
    if state is None:
        template = vehicle_model.initial_state(n)
        state = WorldState(
            vehicle=template,
            s_m=np.zeros(n),
            lateral_m=np.zeros(n),
            unwrapped_s_m=np.zeros(n),
            time_s=np.zeros(n),
            wall_contact=np.zeros(n, dtype=bool),
            wall_contact_time_s=np.zeros(n),
            car_contact=np.zeros(n, dtype=bool),
            car_contact_time_s=np.zeros(n),
            laps_completed=np.zeros(n, dtype=np.int64),
            line_crossings=np.zeros(n, dtype=np.int64),
            lap_start_time_s=np.full(n, np.nan),
            last_lap_time_s=np.full(n, np.nan),
            prev_steer_cmd_rad=np.zeros(n),
        )

    def put(field: np.ndarray, values) -> np.ndarray:
        out = field.copy()
        out[car_ids] = values
        return out

    vehicle = VehicleState(*(put(old, new) for old, new in zip(state.vehicle, fresh_vehicle, strict=True)))
    on_line = np.isclose(s, 0.0) | np.isclose(s, track.length_m)
    return state._replace(
        vehicle=vehicle,
        s_m=put(state.s_m, s),
        lateral_m=put(state.lateral_m, lateral),
        unwrapped_s_m=put(state.unwrapped_s_m, np.where(on_line, 0.0, s)),
        time_s=put(state.time_s, 0.0),
        wall_contact=put(state.wall_contact, False),
        wall_contact_time_s=put(state.wall_contact_time_s, 0.0),
        car_contact=put(state.car_contact, False),
        car_contact_time_s=put(state.car_contact_time_s, 0.0),
        laps_completed=put(state.laps_completed, 0),
        line_crossings=put(state.line_crossings, 0),
        lap_start_time_s=put(state.lap_start_time_s, np.where(on_line, 0.0, np.nan)),
        last_lap_time_s=put(state.last_lap_time_s, np.nan),
        prev_steer_cmd_rad=put(state.prev_steer_cmd_rad, 0.0),
    )


def _apply_impulse(
    vx_w: np.ndarray,
    vy_w: np.ndarray,
    yaw_rate: np.ndarray,
    r_x: np.ndarray,
    r_y: np.ndarray,
    n_x: np.ndarray,
    n_y: np.ndarray,
    rel_vn: np.ndarray,
    rel_vt: np.ndarray,
    inv_mass_sum: np.ndarray,
    restitution: float,
    friction: float,
    mass_kg: float,
    inertia_kgm2: float,
    active: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Velocity change of one body from a contact impulse along normal n (pointing into the body) at lever r.

    ``rel_vn`` is the approach speed along n (negative when closing), ``rel_vt`` the sliding speed along the tangent
    (n rotated by +90 deg), ``inv_mass_sum`` the effective inverse masses of the contact along n and t summed over
    both bodies (shape (2, k)). Returns the new (vx_world, vy_world, yaw_rate).
    """
    t_x, t_y = -n_y, n_x
    j_n = np.where(active & (rel_vn < 0.0), -(1.0 + restitution) * rel_vn / inv_mass_sum[0], 0.0)
    j_t = np.clip(-rel_vt / inv_mass_sum[1], -friction * j_n, friction * j_n)
    jx = j_n * n_x + j_t * t_x
    jy = j_n * n_y + j_t * t_y
    return vx_w + jx / mass_kg, vy_w + jy / mass_kg, yaw_rate + (r_x * jy - r_y * jx) / inertia_kgm2


def _wall_contact(
    model: WorldModel, vehicle: VehicleState, s_guess_m: np.ndarray
) -> tuple[VehicleState, np.ndarray, np.ndarray, np.ndarray]:
    """Keep every car's footprint between the walls; returns (vehicle, s_m, lateral_m, in_contact)."""
    track, car, cfg = model.track, model.car, model.config
    proj = track.project(np.stack([vehicle.x_m, vehicle.y_m], axis=1), s_guess_m)
    rel_yaw = vehicle.yaw_rad - proj.heading_rad
    half_l, half_w = 0.5 * car.length_m, 0.5 * car.width_m
    half_extent = half_l * np.abs(np.sin(rel_yaw)) + half_w * np.abs(np.cos(rel_yaw))
    pen_left = proj.lateral_m + half_extent - track.width_left_at(proj.s_m)
    pen_right = -proj.lateral_m + half_extent - track.width_right_at(proj.s_m)
    hit_left, hit_right = pen_left > 0.0, pen_right > 0.0
    contact = hit_left | hit_right
    if not contact.any():
        return vehicle, proj.s_m, proj.lateral_m, contact
    # The wall normal points back into the track: towards the right for the left wall and vice versa.
    side = np.where(hit_left, 1.0, -1.0)
    normal_left_x, normal_left_y = -np.sin(proj.heading_rad), np.cos(proj.heading_rad)
    n_x, n_y = -side * normal_left_x, -side * normal_left_y
    push = np.where(hit_left, pen_left, np.where(hit_right, pen_right, 0.0))
    x = vehicle.x_m + n_x * push
    y = vehicle.y_m + n_y * push
    lateral = proj.lateral_m - side * push
    # The touching corner: the body corner furthest towards the wall.
    cos_yaw, sin_yaw = np.cos(vehicle.yaw_rad), np.sin(vehicle.yaw_rad)
    sign_l = -np.sign(cos_yaw * n_x + sin_yaw * n_y + 1e-12)
    sign_w = -np.sign(-sin_yaw * n_x + cos_yaw * n_y + 1e-12)
    r_x = cos_yaw * sign_l * half_l - sin_yaw * sign_w * half_w
    r_y = sin_yaw * sign_l * half_l + cos_yaw * sign_w * half_w
    vx_w, vy_w = _rotate(vehicle.vx_mps, vehicle.vy_mps, vehicle.yaw_rad)
    w = vehicle.yaw_rate_radps
    vc_x, vc_y = vx_w - w * r_y, vy_w + w * r_x
    t_x, t_y = -n_y, n_x
    m, inertia = car.mass_kg, car.yaw_inertia_kgm2
    inv_mass = np.stack([1 / m + (r_x * n_y - r_y * n_x) ** 2 / inertia, 1 / m + (r_x * t_y - r_y * t_x) ** 2 / inertia])
    vx_w2, vy_w2, w2 = _apply_impulse(
        vx_w, vy_w, w, r_x, r_y, n_x, n_y, vc_x * n_x + vc_y * n_y, vc_x * t_x + vc_y * t_y, inv_mass,
        cfg.wall_restitution, cfg.wall_friction, m, inertia, contact,
    )
    vehicle = _with_world_velocity(vehicle, x, y, vx_w, vy_w, vx_w2, vy_w2, w2, cfg.physics_dt_s)
    return vehicle, proj.s_m, lateral, contact


def _with_world_velocity(
    vehicle: VehicleState,
    x: np.ndarray,
    y: np.ndarray,
    vx_w_before: np.ndarray,
    vy_w_before: np.ndarray,
    vx_w: np.ndarray,
    vy_w: np.ndarray,
    yaw_rate: np.ndarray,
    dt_s: float,
) -> VehicleState:
    """Put a contact's new world-frame velocity back into the body frame; the jolt shows in the accelerations."""
    c, s = np.cos(vehicle.yaw_rad), np.sin(vehicle.yaw_rad)
    dvx_w, dvy_w = vx_w - vx_w_before, vy_w - vy_w_before
    return vehicle._replace(
        x_m=x,
        y_m=y,
        vx_mps=c * vx_w + s * vy_w,
        vy_mps=-s * vx_w + c * vy_w,
        yaw_rate_radps=yaw_rate,
        ax_mps2=vehicle.ax_mps2 + (c * dvx_w + s * dvy_w) / dt_s,
        ay_mps2=vehicle.ay_mps2 + (-s * dvx_w + c * dvy_w) / dt_s,
    )


def _car_contact(model: WorldModel, vehicle: VehicleState) -> tuple[VehicleState, np.ndarray]:
    """Separate overlapping cars of the same group and exchange contact impulses; returns (vehicle, in_contact)."""
    n = model.n_cars
    pi, pj = model.pair_i, model.pair_j
    in_contact = np.zeros(n, dtype=bool)
    if len(pi) == 0:
        return vehicle, in_contact
    radius = model.circle_radius_m
    offsets = model.circle_offsets_m
    cos_yaw, sin_yaw = np.cos(vehicle.yaw_rad), np.sin(vehicle.yaw_rad)
    # Circle centres (n, 3) in the world frame.
    cx = vehicle.x_m[:, None] + cos_yaw[:, None] * offsets[None, :]
    cy = vehicle.y_m[:, None] + sin_yaw[:, None] * offsets[None, :]
    dx = cx[pj][:, None, :] - cx[pi][:, :, None]  # (pairs, circle of i, circle of j)
    dy = cy[pj][:, None, :] - cy[pi][:, :, None]
    dist = np.hypot(dx, dy).reshape(len(pi), 9)
    deepest = np.argmin(dist, axis=1)
    rows = np.arange(len(pi))
    d = dist[rows, deepest]
    overlap = 2.0 * radius - d
    touching = overlap > 0.0
    if not touching.any():
        return vehicle, in_contact
    pi, pj, deepest, d, overlap = pi[touching], pj[touching], deepest[touching], d[touching], overlap[touching]
    ci, cj = deepest // 3, deepest % 3
    n_x = (cx[pj, cj] - cx[pi, ci]) / np.maximum(d, 1e-9)
    n_y = (cy[pj, cj] - cy[pi, ci]) / np.maximum(d, 1e-9)
    n_x = np.where(d > 1e-9, n_x, 1.0)
    # Contact point halfway between the circle centres; levers from each car's centre of gravity.
    px = 0.5 * (cx[pi, ci] + cx[pj, cj])
    py = 0.5 * (cy[pi, ci] + cy[pj, cj])
    ri_x, ri_y = px - vehicle.x_m[pi], py - vehicle.y_m[pi]
    rj_x, rj_y = px - vehicle.x_m[pj], py - vehicle.y_m[pj]
    vx_w, vy_w = _rotate(vehicle.vx_mps, vehicle.vy_mps, vehicle.yaw_rad)
    w = vehicle.yaw_rate_radps
    vi_x, vi_y = vx_w[pi] - w[pi] * ri_y, vy_w[pi] + w[pi] * ri_x
    vj_x, vj_y = vx_w[pj] - w[pj] * rj_y, vy_w[pj] + w[pj] * rj_x
    t_x, t_y = -n_y, n_x
    # Relative velocity of j seen from i; j is pushed along +n, i along -n.
    rel_x, rel_y = vj_x - vi_x, vj_y - vi_y
    rel_vn = rel_x * n_x + rel_y * n_y
    rel_vt = rel_x * t_x + rel_y * t_y
    car, cfg = model.car, model.config
    m, inertia = car.mass_kg, car.yaw_inertia_kgm2
    inv_n = 2 / m + ((ri_x * n_y - ri_y * n_x) ** 2 + (rj_x * n_y - rj_y * n_x) ** 2) / inertia
    inv_t = 2 / m + ((ri_x * t_y - ri_y * t_x) ** 2 + (rj_x * t_y - rj_y * t_x) ** 2) / inertia
    j_n = np.where(rel_vn < 0.0, -(1.0 + cfg.car_restitution) * rel_vn / inv_n, 0.0)
    j_t = np.clip(-rel_vt / inv_t, -cfg.car_friction * j_n, cfg.car_friction * j_n)
    jx, jy = j_n * n_x + j_t * t_x, j_n * n_y + j_t * t_y
    dvx, dvy, dw = np.zeros(n), np.zeros(n), np.zeros(n)
    np.add.at(dvx, pj, jx / m)
    np.add.at(dvy, pj, jy / m)
    np.add.at(dw, pj, (rj_x * jy - rj_y * jx) / inertia)
    np.add.at(dvx, pi, -jx / m)
    np.add.at(dvy, pi, -jy / m)
    np.add.at(dw, pi, -(ri_x * jy - ri_y * jx) / inertia)
    # Split the overlap equally so the pair no longer intersects after this substep.
    shift_x, shift_y = np.zeros(n), np.zeros(n)
    np.add.at(shift_x, pj, 0.5 * overlap * n_x)
    np.add.at(shift_y, pj, 0.5 * overlap * n_y)
    np.add.at(shift_x, pi, -0.5 * overlap * n_x)
    np.add.at(shift_y, pi, -0.5 * overlap * n_y)
    in_contact[pi] = True
    in_contact[pj] = True
    vehicle = _with_world_velocity(
        vehicle, vehicle.x_m + shift_x, vehicle.y_m + shift_y, vx_w, vy_w, vx_w + dvx, vy_w + dvy, w + dw,
        cfg.physics_dt_s,
    )
    return vehicle, in_contact


def world_step(
    model: WorldModel, state: WorldState, steer_cmd_rad: np.ndarray, omega_cmd: np.ndarray
) -> tuple[WorldState, StepEvents]:
    """Advance every car by one control step with the given commands; pure: ``state`` is not modified.

    ``steer_cmd_rad`` (n,) is the road-wheel angle command, clipped to +-pi/6 and the car's lock; ``omega_cmd`` (n,)
    is throttle (> 0) / brake (< 0) in [-1, 1]. Non-finite commands are treated as 0.
    """
    cfg, track = model.config, model.track
    dt = cfg.physics_dt_s
    steer = np.clip(np.nan_to_num(np.asarray(steer_cmd_rad, dtype=np.float64)), -np.pi / 6, np.pi / 6)
    omega = np.clip(np.nan_to_num(np.asarray(omega_cmd, dtype=np.float64)), -1.0, 1.0)
    vehicle, s, lateral, unwrapped = state.vehicle, state.s_m, state.lateral_m, state.unwrapped_s_m
    time_s, crossings = state.time_s, state.line_crossings
    lap_start, laps, last_lap = state.lap_start_time_s, state.laps_completed, state.last_lap_time_s
    wall_any = np.zeros(model.n_cars, dtype=bool)
    car_any = np.zeros(model.n_cars, dtype=bool)
    wall_time, car_time = state.wall_contact_time_s, state.car_contact_time_s
    lap_completed = np.zeros(model.n_cars, dtype=bool)
    lap_time = np.full(model.n_cars, np.nan)
    for _ in range(cfg.substeps):
        vehicle = vehicle_model.step(model.car, vehicle, steer, omega, dt)
        vehicle, car_hit = _car_contact(model, vehicle)
        vehicle, s_new, lateral, wall_hit = _wall_contact(model, vehicle, s)
        unwrapped_new = unwrapped + track.progress_delta(s, s_new)
        # A lap line is crossed when the unwrapped arc length reaches a new multiple of the lap length; driving
        # back and forth over the line never counts twice.
        reached = np.floor(unwrapped_new / track.length_m).astype(np.int64)
        crossed = reached > crossings
        if crossed.any():
            frac = (reached * track.length_m - unwrapped) / np.maximum(unwrapped_new - unwrapped, 1e-12)
            t_cross = time_s + dt * np.clip(frac, 0.0, 1.0)
            timed = crossed & ~np.isnan(lap_start)
            lap_completed |= timed
            lap_time = np.where(timed, t_cross - lap_start, lap_time)
            last_lap = np.where(timed, t_cross - lap_start, last_lap)
            laps = laps + timed
            lap_start = np.where(crossed, t_cross, lap_start)
            crossings = np.maximum(crossings, reached)
        s, unwrapped = s_new, unwrapped_new
        time_s = time_s + dt
        wall_any |= wall_hit
        car_any |= car_hit
        wall_time = wall_time + dt * wall_hit
        car_time = car_time + dt * car_hit
    new_state = WorldState(
        vehicle=vehicle,
        s_m=s,
        lateral_m=lateral,
        unwrapped_s_m=unwrapped,
        time_s=time_s,
        wall_contact=wall_any,
        wall_contact_time_s=wall_time,
        car_contact=car_any,
        car_contact_time_s=car_time,
        laps_completed=laps,
        line_crossings=crossings,
        lap_start_time_s=lap_start,
        last_lap_time_s=last_lap,
        prev_steer_cmd_rad=steer,
    )
    return new_state, StepEvents(lap_completed=lap_completed, lap_time_s=lap_time)


class World:
    """A stateful wrapper around :func:`world_step` that also keeps each car's list of lap times.

    Args:
        track: a :class:`Track`, or a spec for :func:`vision_rl.sim.load_track` (built-in name, ``random:SEED``,
            CSV path).
        car: a :class:`VehicleParams` or a preset name (``hatchback``, ``tt_cup``, ``gt3``); one car model per world.
        n_cars: number of cars.
        groups: collision group of each car (n_cars,) ints; default: every car in its own group.
        config: time steps and contact constants.

    The cars start on the start/finish line at rest, one behind the other 10 m apart; :meth:`reset` places them.
    """

    def __init__(
        self,
        track: Track | str,
        car: VehicleParams | str = vehicle_model.DEFAULT_CAR,
        n_cars: int = 1,
        groups: np.ndarray | None = None,
        config: WorldConfig | None = None,
    ) -> None:
        from vision_rl.sim.track_library import load_track

        if n_cars < 1:
            raise ValueError(f"n_cars must be >= 1, got {n_cars}")
        track = track if isinstance(track, Track) else load_track(track)
        car = car if isinstance(car, VehicleParams) else vehicle_model.get_preset(car)
        groups = np.arange(n_cars) if groups is None else np.asarray(groups)
        if groups.shape != (n_cars,):
            raise ValueError(f"groups must have shape ({n_cars},), got {groups.shape}")
        self.model = WorldModel(track=track, car=car, groups=groups, config=config or WorldConfig())
        ids = np.arange(n_cars)
        self.state = place_cars(self.model, None, ids, -10.0 * ids, 0.0, 0.0, 0.0)
        self.lap_times_s: list[list[float]] = [[] for _ in range(n_cars)]

    @property
    def track(self) -> Track:
        return self.model.track

    @property
    def car(self) -> VehicleParams:
        return self.model.car

    @property
    def n_cars(self) -> int:
        return self.model.n_cars

    def reset(
        self,
        s_m: np.ndarray | float,
        lateral_m: np.ndarray | float = 0.0,
        speed_mps: np.ndarray | float = 0.0,
        heading_offset_rad: np.ndarray | float = 0.0,
        car_ids: np.ndarray | None = None,
    ) -> None:
        """Place cars (all, or ``car_ids``) at arc length ``s_m`` and lateral offset ``lateral_m``, heading along the
        centre line plus ``heading_offset_rad``, rolling straight ahead at ``speed_mps``; clears their lap times."""
        ids = np.arange(self.n_cars) if car_ids is None else np.atleast_1d(np.asarray(car_ids, dtype=np.int64))
        self.state = place_cars(self.model, self.state, ids, s_m, lateral_m, speed_mps, heading_offset_rad)
        for i in ids:
            self.lap_times_s[i] = []

    def step(self, steer_cmd_rad: np.ndarray, omega_cmd: np.ndarray) -> StepEvents:
        """Advance one control step (see :func:`world_step`) and record completed laps."""
        self.state, events = world_step(self.model, self.state, steer_cmd_rad, omega_cmd)
        if events.lap_completed.any():
            for i in np.flatnonzero(events.lap_completed):
                self.lap_times_s[i].append(float(events.lap_time_s[i]))
        return events
