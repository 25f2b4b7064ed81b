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

import math
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np
from numba.extending import register_jitable

from vision_rl.sim import vehicle as vehicle_model
from vision_rl.sim.track import Track, project_point
from vision_rl.sim.vehicle import VehicleParams, VehicleState, _car_step

# Rows of the (14, n) vehicle block, in VehicleState order.
_X, _Y, _YAW, _VX, _VY, _R = 0, 1, 2, 3, 4, 5
_AX, _AY = 8, 9
#: WorldState fields the kernel updates in place, in its argument order.
_KERNEL_FIELDS = (
    "s_m",
    "lateral_m",
    "unwrapped_s_m",
    "time_s",
    "line_crossings",
    "lap_start_time_s",
    "laps_completed",
    "last_lap_time_s",
    "wall_contact_time_s",
    "car_contact_time_s",
)


#: Largest forward speed (either sign) a car may be placed at: beyond every car preset's top speed, so a larger one is
#: a unit slip (km/h for m/s) or garbage, not a start.
MAX_PLACE_SPEED_MPS = 150.0


class WorldInputError(ValueError):
    """A pose, speed, command or car id given to the world that it cannot use: the message names the argument,
    the car and the value."""


class NonFiniteInputError(WorldInputError):
    """A NaN or infinite value given to the world (a trainer tells a diverged policy's actions by it)."""


def _per_car(name: str, value, k: int) -> np.ndarray:
    """``value`` as a finite (k,) float64 array (a scalar or a length-1 array broadcasts), or a WorldInputError."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise WorldInputError(f"{name} must be a number or an array of numbers, got {value!r:.80}") from None
    if a.ndim > 1 or (a.ndim == 1 and a.shape[0] not in (1, k)):
        raise WorldInputError(f"{name} must be a number or an array of shape ({k},), one per car, got shape {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a.reshape(-1)))
    if len(bad):
        i = int(bad[0])
        where = f"{name}[{i}]" if a.ndim else name
        raise NonFiniteInputError(
            f"{where} = {a.reshape(-1)[i]} is not a finite number; pass a finite value for every car"
        )
    return np.broadcast_to(a, (k,))


def _car_ids(car_ids, n: int) -> np.ndarray:
    """``car_ids`` as distinct int64 indices in [0, n), or a WorldInputError."""
    ids = np.asarray(car_ids)
    if ids.ndim == 0:
        ids = ids.reshape(1)
    if ids.ndim != 1 or (ids.size and (ids.dtype.kind not in "iu")):
        raise WorldInputError(f"car_ids must be a 1-D array of integer car indices, got {car_ids!r:.80}")
    ids = ids.astype(np.int64)
    bad = np.flatnonzero((ids < 0) | (ids >= n))
    if len(bad):
        raise WorldInputError(f"car_ids[{bad[0]}] = {ids[bad[0]]} is not a car of this world (0..{n - 1})")
    if len(np.unique(ids)) != len(ids):
        raise WorldInputError(f"car_ids lists a car twice: {ids.tolist()[:20]}")
    return ids


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


def _checked_placement(
    track: Track, n: int, car_ids, s_m, lateral_m, speed_mps, heading_offset_rad
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(car ids, s, lateral, speed, heading offset) as (k,) arrays, or a :class:`WorldInputError` naming the
    argument, the car and the value (see :func:`place_cars`)."""
    car_ids = _car_ids(car_ids, n)
    k = len(car_ids)
    s = track.wrap_s(_per_car("s_m", s_m, k))
    lateral = _per_car("lateral_m", lateral_m, k)
    speed_mps = _per_car("speed_mps", speed_mps, k)
    heading_offset_rad = _per_car("heading_offset_rad", heading_offset_rad, k)
    wall = np.where(lateral >= 0.0, track.width_left_at(s), track.width_right_at(s))
    outside = np.flatnonzero(np.abs(lateral) > wall)
    if len(outside):
        i = int(outside[0])
        side = "left" if lateral[i] >= 0 else "right"
        raise WorldInputError(
            f"lateral_m[{i}] = {lateral[i]:.2f} m puts car {car_ids[i]} outside the {side} wall, {wall[i]:.2f} m from "
            f"the centre line at s = {s[i]:.1f} m"
        )
    fast = np.flatnonzero(np.abs(speed_mps) > MAX_PLACE_SPEED_MPS)
    if len(fast):
        i = int(fast[0])
        raise WorldInputError(
            f"speed_mps[{i}] = {speed_mps[i]:g} is beyond +-{MAX_PLACE_SPEED_MPS:g} m/s (speeds are in m/s)"
        )
    return car_ids, s, lateral, speed_mps, heading_offset_rad


def _empty_state(n: int) -> WorldState:
    """n cars at the origin, at rest, with clocks and counters cleared: what :func:`place_cars` places cars into."""
    return WorldState(
        vehicle=vehicle_model.initial_state(n),
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
    Raises :class:`WorldInputError` for a car id out of range or listed twice, a value that is not finite or of the
    wrong shape, a car centre outside the walls or a speed beyond :data:`MAX_PLACE_SPEED_MPS`.
    """
    track = model.track
    car_ids, s, lateral, speed_mps, heading_offset_rad = _checked_placement(
        track, model.n_cars, car_ids, s_m, lateral_m, speed_mps, heading_offset_rad
    )
    xy = track.position_at(s, lateral)
    yaw = track.heading_at(s) + heading_offset_rad
    fresh_vehicle = vehicle_model.initial_state(len(car_ids), xy[:, 0], xy[:, 1], yaw, speed_mps)
    if state is None:
        state = _empty_state(model.n_cars)

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


# ------------------------------------------------------------------------------------------------ numba kernel
# The whole substep loop (vehicle, car contact, walls, progress, laps) runs in one numba kernel: with numpy, the
# per-call overhead of ~200 small array operations per substep held a 20-car control step to ~3,000 car-steps/s;
# the vehicle physics itself is the element-wise `_car_step` of vision_rl.sim.vehicle, one source for both paths.


@register_jitable
def _impulse(vx_w, vy_w, w, r_x, r_y, n_x, n_y, rel_vn, rel_vt, inv_n, inv_t, restitution, friction, mass, inertia):
    """Velocity change of a body hit along normal n (into the body) at lever r from its centre of gravity.

    ``rel_vn`` is the approach speed along n (negative when closing), ``rel_vt`` the sliding speed along the tangent
    (n turned +90 deg), ``inv_n``/``inv_t`` the contact's effective inverse masses along n and t (both bodies).
    Returns (impulse x, impulse y) in N s and the body's new (vx_world, vy_world, yaw rate).
    """
    if rel_vn >= 0.0:
        return 0.0, 0.0, vx_w, vy_w, w
    j_n = -(1.0 + restitution) * rel_vn / inv_n
    j_t = min(max(-rel_vt / inv_t, -friction * j_n), friction * j_n)
    jx = j_n * n_x - j_t * n_y
    jy = j_n * n_y + j_t * n_x
    return jx, jy, vx_w + jx / mass, vy_w + jy / mass, w + (r_x * jy - r_y * jx) / inertia


@register_jitable
def _set_world_velocity(veh, i, vx_w, vy_w, w, dt):
    """Write a contact's new world-frame velocity back in the body frame; the jolt shows in the accelerometer."""
    c, s = math.cos(veh[_YAW, i]), math.sin(veh[_YAW, i])
    vx_b = c * vx_w + s * vy_w
    vy_b = -s * vx_w + c * vy_w
    veh[_AX, i] += (vx_b - veh[_VX, i]) / dt
    veh[_AY, i] += (vy_b - veh[_VY, i]) / dt
    veh[_VX, i] = vx_b
    veh[_VY, i] = vy_b
    veh[_R, i] = w


@register_jitable
def _world_velocity(veh, i):
    c, s = math.cos(veh[_YAW, i]), math.sin(veh[_YAW, i])
    return c * veh[_VX, i] - s * veh[_VY, i], s * veh[_VX, i] + c * veh[_VY, i]


@register_jitable
def _car_contacts(veh, pair_i, pair_j, offsets, radius, mass, inertia, restitution, friction, dt, car_hit):
    """Separate overlapping pairs (three circles per car) and exchange impulses, pair after pair."""
    for k in range(pair_i.shape[0]):
        i, j = pair_i[k], pair_j[k]
        ci, si = math.cos(veh[_YAW, i]), math.sin(veh[_YAW, i])
        cj, sj = math.cos(veh[_YAW, j]), math.sin(veh[_YAW, j])
        best, bix, biy, bjx, bjy = np.inf, 0.0, 0.0, 0.0, 0.0
        for a in range(3):
            ax_ = veh[_X, i] + ci * offsets[a]
            ay_ = veh[_Y, i] + si * offsets[a]
            for b in range(3):
                bx_ = veh[_X, j] + cj * offsets[b]
                by_ = veh[_Y, j] + sj * offsets[b]
                d = math.hypot(bx_ - ax_, by_ - ay_)
                if d < best:
                    best, bix, biy, bjx, bjy = d, ax_, ay_, bx_, by_
        overlap = 2.0 * radius - best
        if overlap <= 0.0:
            continue
        car_hit[i] = True
        car_hit[j] = True
        if best > 1e-9:
            n_x, n_y = (bjx - bix) / best, (bjy - biy) / best
        else:
            n_x, n_y = ci, si
        # Split the overlap so the pair no longer intersects; the contact point lies halfway between the circles.
        veh[_X, i] -= 0.5 * overlap * n_x
        veh[_Y, i] -= 0.5 * overlap * n_y
        veh[_X, j] += 0.5 * overlap * n_x
        veh[_Y, j] += 0.5 * overlap * n_y
        px, py = 0.5 * (bix + bjx), 0.5 * (biy + bjy)
        ri_x, ri_y = px - veh[_X, i], py - veh[_Y, i]
        rj_x, rj_y = px - veh[_X, j], py - veh[_Y, j]
        vix, viy = _world_velocity(veh, i)
        vjx, vjy = _world_velocity(veh, j)
        wi, wj = veh[_R, i], veh[_R, j]
        rel_x = (vjx - wj * rj_y) - (vix - wi * ri_y)
        rel_y = (vjy + wj * rj_x) - (viy + wi * ri_x)
        t_x, t_y = -n_y, n_x
        inv_n = 2.0 / mass + ((ri_x * n_y - ri_y * n_x) ** 2 + (rj_x * n_y - rj_y * n_x) ** 2) / inertia
        inv_t = 2.0 / mass + ((ri_x * t_y - ri_y * t_x) ** 2 + (rj_x * t_y - rj_y * t_x) ** 2) / inertia
        jx, jy, vjx2, vjy2, wj2 = _impulse(
            vjx,
            vjy,
            wj,
            rj_x,
            rj_y,
            n_x,
            n_y,
            rel_x * n_x + rel_y * n_y,
            rel_x * t_x + rel_y * t_y,
            inv_n,
            inv_t,
            restitution,
            friction,
            mass,
            inertia,
        )
        _set_world_velocity(veh, j, vjx2, vjy2, wj2, dt)
        _set_world_velocity(veh, i, vix - jx / mass, viy - jy / mass, wi - (ri_x * jy - ri_y * jx) / inertia, dt)


@register_jitable
def _wall_contact(veh, i, lateral, heading, width_left, width_right, half_l, half_w, mass, inertia, e, mu, dt):
    """Keep car i's footprint between the walls; returns (new lateral offset, in contact)."""
    rel_yaw = veh[_YAW, i] - heading
    half_extent = half_l * abs(math.sin(rel_yaw)) + half_w * abs(math.cos(rel_yaw))
    pen_left = lateral + half_extent - width_left
    pen_right = -lateral + half_extent - width_right
    if pen_left <= 0.0 and pen_right <= 0.0:
        return lateral, False
    side, push = (1.0, pen_left) if pen_left >= pen_right else (-1.0, pen_right)
    # The wall normal points back into the track: to the right for the left wall and vice versa.
    n_x, n_y = side * math.sin(heading), -side * math.cos(heading)
    veh[_X, i] += n_x * push
    veh[_Y, i] += n_y * push
    # The touching corner is the body corner furthest towards the wall.
    c, s = math.cos(veh[_YAW, i]), math.sin(veh[_YAW, i])
    sign_l = -math.copysign(1.0, c * n_x + s * n_y)
    sign_w = -math.copysign(1.0, -s * n_x + c * n_y)
    r_x = c * sign_l * half_l - s * sign_w * half_w
    r_y = s * sign_l * half_l + c * sign_w * half_w
    vx_w, vy_w = _world_velocity(veh, i)
    w = veh[_R, i]
    vc_x, vc_y = vx_w - w * r_y, vy_w + w * r_x
    t_x, t_y = -n_y, n_x
    inv_n = 1.0 / mass + (r_x * n_y - r_y * n_x) ** 2 / inertia
    inv_t = 1.0 / mass + (r_x * t_y - r_y * t_x) ** 2 / inertia
    _, _, vx_w2, vy_w2, w2 = _impulse(
        vx_w,
        vy_w,
        w,
        r_x,
        r_y,
        n_x,
        n_y,
        vc_x * n_x + vc_y * n_y,
        vc_x * t_x + vc_y * t_y,
        inv_n,
        inv_t,
        e,
        mu,
        mass,
        inertia,
    )
    _set_world_velocity(veh, i, vx_w2, vy_w2, w2, dt)
    return lateral - side * push, True


@register_jitable
def _step_vehicles(p, veh, steer, omega, dt):
    """One physics substep of every car's own dynamics (:func:`_car_step`), in place in the (14, n) block."""
    for i in range(veh.shape[1]):
        c = (
            veh[0, i],
            veh[1, i],
            veh[2, i],
            veh[3, i],
            veh[4, i],
            veh[5, i],
            veh[6, i],
            veh[7, i],
            veh[8, i],
            veh[9, i],
            veh[10, i],
            veh[11, i],
            veh[12, i],
            veh[13, i],
        )
        c = _car_step(p, *c, steer[i], omega[i], dt)
        for k in range(14):
            veh[k, i] = c[k]


@register_jitable
def _keep_within_walls(veh, s, walls, body, dt, s_new, lat_new, hit):
    """Every car's new arc length and lateral offset (into ``s_new``, ``lat_new``) once the walls have kept it on the
    track, and whether it touched one (``hit``). Each projection starts from the car's previous arc length in ``s``;
    ``walls`` and ``body`` are the kernel's track arrays and the car's contact constants, in its argument order."""
    centre, tangent, heading_unwrapped, width_left, width_right, spacing = walls
    half_l, half_w, mass, inertia, wall_e, wall_mu = body
    n_points = centre.shape[0]
    for i in range(veh.shape[1]):
        start = int(round(s[i] / spacing)) % n_points  # noqa: RUF046 (numba's round needs the int)
        s_i, lat, heading, _ = project_point(centre, tangent, heading_unwrapped, spacing, veh[_X, i], veh[_Y, i], start)
        pos = s_i / spacing
        i0 = int(pos) % n_points
        frac = pos - int(pos)
        i1 = (i0 + 1) % n_points
        wl = width_left[i0] * (1.0 - frac) + width_left[i1] * frac
        wr = width_right[i0] * (1.0 - frac) + width_right[i1] * frac
        lat_new[i], hit[i] = _wall_contact(
            veh, i, lat, heading, wl, wr, half_l, half_w, mass, inertia, wall_e, wall_mu, dt
        )
        s_new[i] = s_i


@register_jitable
def _count_laps(s_new, length, dt, s, unwrapped, time_s, lap_arrays):
    """Every car's unwrapped arc length moved on to ``s_new``; a crossing of the lap line starts a timed lap and ends
    the one under way (``lap_arrays``: the kernel's crossings, lap start, laps, last lap, lap completed and lap time).

    Signed progress is wrapped to half a lap; a lap line is crossed when the unwrapped arc length reaches a new
    multiple of the lap length, so driving back and forth over the line never counts twice."""
    crossings, lap_start, laps, last_lap, lap_completed, lap_time = lap_arrays
    for i in range(s.shape[0]):
        ds = (s_new[i] - s[i] + 0.5 * length) % length - 0.5 * length
        u_new = unwrapped[i] + ds
        reached = math.floor(u_new / length)
        if reached > crossings[i]:
            frac_t = min(max((reached * length - unwrapped[i]) / max(ds, 1e-12), 0.0), 1.0)
            t_cross = time_s[i] + dt * frac_t
            if not math.isnan(lap_start[i]):
                laps[i] += 1
                last_lap[i] = t_cross - lap_start[i]
                lap_completed[i] = True
                lap_time[i] = last_lap[i]
            lap_start[i] = t_cross
            crossings[i] = reached
        unwrapped[i] = u_new


@numba.njit(cache=True, error_model="numpy")
def _world_substeps(
    p,
    veh,
    steer,
    omega,
    dt,
    n_substeps,
    centre,
    tangent,
    heading_unwrapped,
    width_left,
    width_right,
    spacing,
    half_l,
    half_w,
    mass,
    inertia,
    wall_e,
    wall_mu,
    pair_i,
    pair_j,
    offsets,
    radius,
    car_e,
    car_mu,
    s,
    lateral,
    unwrapped,
    time_s,
    crossings,
    lap_start,
    laps,
    last_lap,
    wall_time,
    car_time,
    wall_any,
    car_any,
    lap_completed,
    lap_time,
):
    """``n_substeps`` physics substeps for every car; updates all the array arguments after ``n_substeps`` in place."""
    n = veh.shape[1]
    length = centre.shape[0] * spacing
    walls = (centre, tangent, heading_unwrapped, width_left, width_right, spacing)
    body = (half_l, half_w, mass, inertia, wall_e, wall_mu)
    lap_arrays = (crossings, lap_start, laps, last_lap, lap_completed, lap_time)
    car_hit = np.zeros(n, dtype=np.bool_)
    # Each substep's new arc lengths, lateral offsets and wall hits: computed for every car before any is written.
    s_new, lat_new, wall_hit = np.empty(n), np.empty(n), np.zeros(n, dtype=np.bool_)
    for _ in range(n_substeps):
        _step_vehicles(p, veh, steer, omega, dt)
        car_hit[:] = False
        if pair_i.shape[0] > 0:
            _car_contacts(veh, pair_i, pair_j, offsets, radius, mass, inertia, car_e, car_mu, dt, car_hit)
        _keep_within_walls(veh, s, walls, body, dt, s_new, lat_new, wall_hit)
        _count_laps(s_new, length, dt, s, unwrapped, time_s, lap_arrays)
        for i in range(n):
            s[i] = s_new[i]
            lateral[i] = lat_new[i]
            time_s[i] += dt
            if wall_hit[i]:
                wall_any[i] = True
                wall_time[i] += dt
            if car_hit[i]:
                car_any[i] = True
                car_time[i] += dt


def _clean_command(name: str, cmd: np.ndarray | float, limit: float, n: int) -> np.ndarray:
    """A fresh (n,) float64 array clipped to +-limit; a NaN or inf command (a diverged policy) is refused, naming
    the car, rather than driven as something it did not say."""
    return np.ascontiguousarray(np.clip(_per_car(name, cmd, n), -limit, limit))


def world_step(
    model: WorldModel,
    state: WorldState,
    steer_cmd_rad: np.ndarray,
    omega_cmd: np.ndarray,
    control_steps: int = 1,
) -> tuple[WorldState, StepEvents]:
    """Advance every car by ``control_steps`` control steps with the given commands held; pure: ``state`` is not
    modified. Holding commands over k steps is the same physics as k calls, in one kernel call; the contact flags
    then cover all k steps.

    ``steer_cmd_rad`` (n,) is the road-wheel angle command, clipped to +-pi/6 and the car's lock; ``omega_cmd`` (n,)
    is throttle (> 0) / brake (< 0) in [-1, 1]; larger commands are clipped. A command that is not finite, an array
    of another shape or ``control_steps`` < 1 raises :class:`WorldInputError`.
    """
    n, cfg, track, car = model.n_cars, model.config, model.track, model.car
    if isinstance(control_steps, bool) or not isinstance(control_steps, (int, np.integer)) or control_steps < 1:
        raise WorldInputError(f"control_steps must be an integer >= 1, got {control_steps!r}")
    steer = _clean_command("steer_cmd_rad", steer_cmd_rad, vehicle_model.ACTION_STEER_LIMIT_RAD, n)
    omega = _clean_command("omega_cmd", omega_cmd, 1.0, n)
    veh = np.array(state.vehicle, dtype=np.float64)
    out = {f: np.array(getattr(state, f)) for f in _KERNEL_FIELDS}
    wall_any, car_any = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    lap_completed, lap_time = np.zeros(n, dtype=bool), np.full(n, np.nan)
    centre, tangent, heading_unwrapped, width_left, width_right = track.kernel_arrays
    _world_substeps(
        car._packed,
        veh,
        steer,
        omega,
        cfg.physics_dt_s,
        cfg.substeps * control_steps,
        centre,
        tangent,
        heading_unwrapped,
        width_left,
        width_right,
        track.spacing_m,
        0.5 * car.length_m,
        0.5 * car.width_m,
        car.mass_kg,
        car.yaw_inertia_kgm2,
        cfg.wall_restitution,
        cfg.wall_friction,
        model.pair_i,
        model.pair_j,
        model.circle_offsets_m,
        model.circle_radius_m,
        cfg.car_restitution,
        cfg.car_friction,
        *(out[f] for f in _KERNEL_FIELDS),
        wall_any,
        car_any,
        lap_completed,
        lap_time,
    )
    new_state = state._replace(
        vehicle=VehicleState(*veh), wall_contact=wall_any, car_contact=car_any, prev_steer_cmd_rad=steer, **out
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
        ids = np.arange(self.n_cars) if car_ids is None else _car_ids(car_ids, self.n_cars)
        self.state = place_cars(self.model, self.state, ids, s_m, lateral_m, speed_mps, heading_offset_rad)
        for i in ids:
            self.lap_times_s[i] = []

    def step(self, steer_cmd_rad: np.ndarray, omega_cmd: np.ndarray, control_steps: int = 1) -> StepEvents:
        """Advance ``control_steps`` control steps with held commands (see :func:`world_step`) and record completed
        laps."""
        self.state, events = world_step(self.model, self.state, steer_cmd_rad, omega_cmd, control_steps)
        if events.lap_completed.any():
            for i in np.flatnonzero(events.lap_completed):
                self.lap_times_s[i].append(float(events.lap_time_s[i]))
        return events
