"""Batched sensors: wall/car ray casting, the 27 Phase-1 targets, the 11 dedicated features and the 72-beam lidar.

Layouts and names are the papers' observations (see :data:`TARGET_NAMES`). Every function takes arrays over cars
and returns ``(n_cars, ...)`` float64 arrays.

Ray casting runs in numba over a uniform grid of the wall segments (a cell holds the segments whose bounding box
overlaps it, stored as CSR arrays). A ray walks the cells it crosses in order (Amanatides & Woo, "A fast voxel
traversal algorithm for ray tracing", Eurographics 1987) and stops as soon as its nearest hit lies before the exit
of the current cell: any closer hit would lie in a cell already visited. Cars are rectangles of 4 segments, tested
only against rays of their own collision group and never against the ray's own car.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from numba import njit

from vision_rl.sim.track import Track

# ---------------------------------------------------------------------------------------------------- constants
#: Body-frame directions of the 13 edge rays, -90..+90 deg every 15 deg (0 ahead, + left): Fuchs et al.'s
#: rangefinders as described in the vision paper, section 3 ("15-degree increments over a range of 180 degrees").
EDGE_RAY_ANGLES_RAD = np.deg2rad(np.arange(-90.0, 90.0 + 1e-9, 15.0))

#: Length of an edge ray; a ray that hits no wall within it reports this value. Neither paper gives a range. 200 m
#: exceeds the hatchback's braking distance from its 178 km/h top speed (about 140 m at 0.9 g) and the 120 m reach of
#: the curvature targets, so a wall farther away does not bear on the next decision, while a finite cap keeps the
#: regression targets bounded before they are standardised (vision paper, section 3).
EDGE_RAY_RANGE_M = 200.0

#: Distances ahead along the centre line (m) of the 10 curvature targets (vision paper, section 4: "10 points 40 to
#: 120 m ahead", chosen there from the Demio's approximate top speed).
CURVATURE_AHEAD_M = np.linspace(40.0, 120.0, 10)

#: Look-ahead times (s) of the privileged `state` observation's curvature (Fuchs et al., quoted in the vision paper,
#: section 4: "the position of the car after 1.0 to 2.8 seconds").
STATE_CURVATURE_TIMES_S = np.linspace(1.0, 2.8, 10)

#: Look-ahead times (s) of the overtaking observation's curvature: 14 points from 0.2 s to 3.0 s.
OVERTAKING_CURVATURE_TIMES_S = np.linspace(0.2, 3.0, 14)

#: 72 lidar beams evenly over -108..+108 deg inclusive, body frame (overtaking paper, section III: "72 equally
#: spaced Lidar beams with a maximum detection range of 20 m arranged between -108 and 108 deg").
LIDAR_ANGLES_RAD = np.deg2rad(np.linspace(-108.0, 108.0, 72))
LIDAR_RANGE_M = 20.0

_EDGE_DEG = np.rint(np.rad2deg(EDGE_RAY_ANGLES_RAD)).astype(int)

#: The 27 Phase-1 targets: 13 edge rays, the two minimum edge distances, centre-line offset, heading angle and 10
#: curvatures ahead. Capture files, checkpoints and policies store them in this order.
TARGET_NAMES: tuple[str, ...] = (
    *(f"edge_distance_{d:+03d}deg" for d in _EDGE_DEG),
    "min_distance_left_edge",
    "min_distance_right_edge",
    "centre_line_offset",
    "heading_angle_to_centre_line",
    *(f"curvature_{d:.1f}m_ahead" for d in CURVATURE_AHEAD_M),
)
TARGET_UNITS: tuple[str, ...] = ("m",) * 13 + ("m", "m", "m", "rad") + ("1/m",) * 10

#: The 11 dedicated features, in the order observations stack them (body frame: x forward, y left, z up).
DEDICATED_NAMES: tuple[str, ...] = (
    "velocity_body_x",
    "velocity_body_y",
    "velocity_body_z",
    "acceleration_body_x",
    "acceleration_body_y",
    "acceleration_body_z",
    "roll_rate",
    "pitch_rate",
    "yaw_rate",
    "wall_contact",
    "previous_steering_command",
)
DEDICATED_UNITS: tuple[str, ...] = ("m/s",) * 3 + ("m/s^2",) * 3 + ("rad/s",) * 3 + ("1", "rad")

#: Half-width (m) of the stretch of wall searched around a car's s for its minimum wall distance. The nearest wall
#: point lies on the car's own normal to the centre line for any smooth track, so a short window suffices; 20 m
#: covers width changes and the folded inner wall of a corner tighter than the track is wide.
_WALL_WINDOW_M = 20.0

#: Default grid cell (m): about a third of a 10-14 m wide track, so a lidar beam crosses few cells while a cell
#: holds only a handful of 1 m wall segments. bench_sensors on expressway and Suzuka: 2-5 m within noise of each
#: other (lidar 0.33-0.40 ms), 8 m about 25 % slower.
DEFAULT_CELL_SIZE_M = 4.0


# ---------------------------------------------------------------------------------------------------- numba kernels
@njit(cache=True)
def _build_grid(segs, x0, y0, cell, nx, ny):
    """CSR cell -> segment lists: every segment is listed in each cell its bounding box overlaps."""
    n_seg = segs.shape[0]
    bounds = np.empty((n_seg, 4), dtype=np.int64)
    counts = np.zeros(nx * ny, dtype=np.int64)
    for k in range(n_seg):
        bounds[k, 0] = max(int((min(segs[k, 0], segs[k, 2]) - x0) / cell), 0)
        bounds[k, 1] = min(int((max(segs[k, 0], segs[k, 2]) - x0) / cell), nx - 1)
        bounds[k, 2] = max(int((min(segs[k, 1], segs[k, 3]) - y0) / cell), 0)
        bounds[k, 3] = min(int((max(segs[k, 1], segs[k, 3]) - y0) / cell), ny - 1)
        for ix in range(bounds[k, 0], bounds[k, 1] + 1):
            for iy in range(bounds[k, 2], bounds[k, 3] + 1):
                counts[iy * nx + ix] += 1
    start = np.zeros(nx * ny + 1, dtype=np.int64)
    for c in range(nx * ny):
        start[c + 1] = start[c] + counts[c]
    fill = start[:-1].copy()
    items = np.empty(start[-1], dtype=np.int64)
    for k in range(n_seg):
        for ix in range(bounds[k, 0], bounds[k, 1] + 1):
            for iy in range(bounds[k, 2], bounds[k, 3] + 1):
                c = iy * nx + ix
                items[fill[c]] = k
                fill[c] += 1
    return start, items


@njit(cache=True, inline="always")
def _hit_segment(px, py, dx, dy, ax, ay, bx, by):
    """Distance along the ray (p, unit d) to segment a-b, or inf when it misses."""
    ex = bx - ax
    ey = by - ay
    denom = dx * ey - dy * ex
    if denom == 0.0:
        return np.inf
    wx = ax - px
    wy = ay - py
    t = (wx * ey - wy * ex) / denom
    u = (wx * dy - wy * dx) / denom
    # A hair of slack on u so that a ray through the joint of two segments cannot slip between them.
    if t >= 0.0 and -1e-12 <= u <= 1.0 + 1e-12:
        return t
    return np.inf


@njit(cache=True, inline="always")
def _slab(t0, t1, origin, direction, lo, hi):
    """The ray parameters (t0, t1) clipped to the slab lo..hi of one axis; t1 = -1 when the ray runs outside it."""
    if direction != 0.0:
        ta = (lo - origin) / direction
        tb = (hi - origin) / direction
        t0 = max(t0, min(ta, tb))
        t1 = min(t1, max(ta, tb))
    elif not (lo <= origin <= hi):
        t1 = -1.0
    return t0, t1


@njit(cache=True, inline="always")
def _axis_start(t0, p, d, cell, index):
    """One axis of the voxel walk from grid position ``p`` (in cell ``index``) along ``d``: (step between cells,
    ray parameter of the next cell boundary, ray parameter between two boundaries)."""
    if d > 0.0:
        return 1, t0 + ((index + 1) * cell - p) / d, cell / d
    if d < 0.0:
        return -1, t0 + (index * cell - p) / d, -cell / d
    return 0, np.inf, np.inf


@njit(cache=True)
def _cast_walls(ox, oy, ang, max_range, segs, x0, y0, cell, nx, ny, start, items, out):
    """``out[i, j]``: the distance from origin i along world angle ``ang[i, j]`` to the nearest wall."""
    n, k = ang.shape
    gx1 = x0 + nx * cell
    gy1 = y0 + ny * cell
    for i in range(n):
        for j in range(k):
            dx = np.cos(ang[i, j])
            dy = np.sin(ang[i, j])
            # A NaN pose (a blown-up car) would never leave the cell loop; it reads NaN instead.
            if not (np.isfinite(dx) and np.isfinite(ox[i]) and np.isfinite(oy[i])):
                out[i, j] = np.nan
                continue
            best = max_range
            # Clip the ray to the grid box (slab test) so an origin outside the grid still finds the walls.
            t0, t1 = _slab(0.0, max_range, ox[i], dx, x0, gx1)
            t0, t1 = _slab(t0, t1, oy[i], dy, y0, gy1)
            if t0 > t1:
                out[i, j] = best
                continue
            px = ox[i] + dx * t0 - x0
            py = oy[i] + dy * t0 - y0
            ix = min(max(int(px / cell), 0), nx - 1)
            iy = min(max(int(py / cell), 0), ny - 1)
            step_x, t_max_x, t_delta_x = _axis_start(t0, px, dx, cell, ix)
            step_y, t_max_y, t_delta_y = _axis_start(t0, py, dy, cell, iy)
            while True:
                c = iy * nx + ix
                for q in range(start[c], start[c + 1]):
                    s = items[q]
                    t = _hit_segment(ox[i], oy[i], dx, dy, segs[s, 0], segs[s, 1], segs[s, 2], segs[s, 3])
                    if t < best:
                        best = t
                t_exit = min(t_max_x, t_max_y)
                if best <= t_exit or t_exit >= max_range:
                    break
                if t_max_x < t_max_y:
                    ix += step_x
                    if ix < 0 or ix >= nx:
                        break
                    t_max_x += t_delta_x
                else:
                    iy += step_y
                    if iy < 0 or iy >= ny:
                        break
                    t_max_y += t_delta_y
            out[i, j] = best


@njit(cache=True)
def _cast_cars(ox, oy, ang, max_range, corners, car_group, ray_group, ray_car, out):
    """Lower ``out`` (the wall distances) to the nearest hit on a car of the ray's group other than its own."""
    n, k = ang.shape
    m = corners.shape[0]
    cx = np.empty(m)
    cy = np.empty(m)
    rad = np.empty(m)
    for c in range(m):
        cx[c] = 0.25 * (corners[c, 0, 0] + corners[c, 1, 0] + corners[c, 2, 0] + corners[c, 3, 0])
        cy[c] = 0.25 * (corners[c, 0, 1] + corners[c, 1, 1] + corners[c, 2, 1] + corners[c, 3, 1])
        r2 = 0.0
        for v in range(4):
            r2 = max(r2, (corners[c, v, 0] - cx[c]) ** 2 + (corners[c, v, 1] - cy[c]) ** 2)
        rad[c] = np.sqrt(r2)
    cand = np.empty(m, dtype=np.int64)
    for i in range(n):
        # Candidate cars for this origin: same group, not its own car, bounding circle within range.
        n_cand = 0
        for c in range(m):
            if car_group[c] != ray_group[i] or c == ray_car[i]:
                continue
            if np.hypot(cx[c] - ox[i], cy[c] - oy[i]) - rad[c] <= max_range:
                cand[n_cand] = c
                n_cand += 1
        if n_cand == 0:
            continue
        for j in range(k):
            dx = np.cos(ang[i, j])
            dy = np.sin(ang[i, j])
            best = out[i, j]
            for q in range(n_cand):
                c = cand[q]
                rx = cx[c] - ox[i]
                ry = cy[c] - oy[i]
                along = rx * dx + ry * dy
                # Bounding-circle rejection: behind the ray, beyond the current best, or off to the side.
                if along + rad[c] < 0.0 or along - rad[c] > best or abs(rx * dy - ry * dx) > rad[c]:
                    continue
                for v in range(4):
                    w = (v + 1) % 4
                    t = _hit_segment(
                        ox[i], oy[i], dx, dy, corners[c, v, 0], corners[c, v, 1], corners[c, w, 0], corners[c, w, 1]
                    )
                    if t < best:
                        best = t
            out[i, j] = best


# ---------------------------------------------------------------------------------------------------- ray caster
class WallRayCaster:
    """Casts batches of rays against a track's walls (a uniform grid over ``track.wall_segments()``) and cars.

    ``cell_size_m`` is the grid cell edge (m). The grid covers the walls' bounding box plus one cell; rays leave it
    where no wall remains.
    """

    def __init__(self, track: Track, cell_size_m: float = DEFAULT_CELL_SIZE_M) -> None:
        if not np.isfinite(cell_size_m) or cell_size_m <= 0.0:
            raise ValueError(f"cell_size_m must be a positive number of metres, got {cell_size_m}")
        self.track = track
        self.cell_size_m = float(cell_size_m)
        self.segments_m = np.ascontiguousarray(track.wall_segments(), dtype=np.float64)
        pts = self.segments_m.reshape(-1, 2)
        lo = pts.min(axis=0) - self.cell_size_m
        hi = pts.max(axis=0) + self.cell_size_m
        self.grid_origin_m = lo
        self.nx = int(np.ceil((hi[0] - lo[0]) / self.cell_size_m))
        self.ny = int(np.ceil((hi[1] - lo[1]) / self.cell_size_m))
        self.cell_start, self.cell_items = _build_grid(
            self.segments_m, float(lo[0]), float(lo[1]), self.cell_size_m, self.nx, self.ny
        )

    def cast(
        self,
        origin_xy_m: np.ndarray,
        angles_world_rad: np.ndarray,
        max_range_m: float,
        car_corners_xy_m: np.ndarray | None = None,
        car_group: np.ndarray | None = None,
        ray_group: np.ndarray | None = None,
        ray_car_index: np.ndarray | None = None,
    ) -> np.ndarray:
        """Distance (m) from each origin along each world-frame angle to the first wall or car, capped at range.

        Args:
            origin_xy_m: (n, 2) ray origins.
            angles_world_rad: (n, k) ray directions, counter-clockwise from +x.
            max_range_m: rays that hit nothing within it report it.
            car_corners_xy_m: (m, 4, 2) car rectangles (see :func:`car_corners`); without it only walls are hit.
            car_group: (m,) int collision group of each car (default: all in group 0).
            ray_group: (n,) int group of each origin; default: the group of ``ray_car_index``'s car, else 0.
            ray_car_index: (n,) int row of the origin's own car in ``car_corners_xy_m`` (never hit), -1 for none.

        Returns:
            (n, k) float64 distances in [0, max_range_m].
        """
        origin = np.ascontiguousarray(origin_xy_m, dtype=np.float64)
        ang = np.ascontiguousarray(angles_world_rad, dtype=np.float64)
        if origin.ndim != 2 or origin.shape[1] != 2:
            raise ValueError(f"origin_xy_m must have shape (n, 2), got {origin.shape}")
        if ang.ndim != 2 or ang.shape[0] != origin.shape[0]:
            raise ValueError(f"angles_world_rad must have shape (n, k) with n = {origin.shape[0]}, got {ang.shape}")
        if not max_range_m > 0.0:
            raise ValueError(f"max_range_m must be positive, got {max_range_m}")
        ox = np.ascontiguousarray(origin[:, 0])
        oy = np.ascontiguousarray(origin[:, 1])
        out = np.empty(ang.shape, dtype=np.float64)
        x0, y0 = self.grid_origin_m
        _cast_walls(
            ox,
            oy,
            ang,
            float(max_range_m),
            self.segments_m,
            float(x0),
            float(y0),
            self.cell_size_m,
            self.nx,
            self.ny,
            self.cell_start,
            self.cell_items,
            out,
        )
        if car_corners_xy_m is None:
            return out
        corners = np.ascontiguousarray(car_corners_xy_m, dtype=np.float64)
        if corners.ndim != 3 or corners.shape[1:] != (4, 2):
            raise ValueError(f"car_corners_xy_m must have shape (m, 4, 2), got {corners.shape}")
        n, m = origin.shape[0], corners.shape[0]
        cgroup = _int_array(car_group, m, 0, "car_group")
        rcar = _int_array(ray_car_index, n, -1, "ray_car_index")
        if np.any(rcar >= m) or np.any(rcar < -1):
            raise ValueError(f"ray_car_index must be -1 or a row of car_corners_xy_m (0..{m - 1})")
        if ray_group is None:
            rgroup = np.where(rcar >= 0, cgroup[np.maximum(rcar, 0)] if m else 0, 0).astype(np.int64)
        else:
            rgroup = _int_array(ray_group, n, 0, "ray_group")
        _cast_cars(ox, oy, ang, float(max_range_m), corners, cgroup, rgroup, rcar, out)
        return out


def _int_array(a: np.ndarray | None, n: int, default: int, name: str) -> np.ndarray:
    if a is None:
        return np.full(n, default, dtype=np.int64)
    arr = np.ascontiguousarray(a, dtype=np.int64)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
    return arr


def car_corners(x_m: np.ndarray, y_m: np.ndarray, yaw_rad: np.ndarray, length_m: float, width_m: float) -> np.ndarray:
    """Corners (n, 4, 2) of each car's body rectangle, counter-clockwise from the rear right corner."""
    x = np.asarray(x_m, dtype=np.float64)
    y = np.asarray(y_m, dtype=np.float64)
    c = np.cos(yaw_rad)[:, None]
    s = np.sin(yaw_rad)[:, None]
    bx = np.array([-0.5, 0.5, 0.5, -0.5]) * length_m
    by = np.array([-0.5, -0.5, 0.5, 0.5]) * width_m
    return np.stack([x[:, None] + c * bx - s * by, y[:, None] + s * bx + c * by], axis=2)


# ---------------------------------------------------------------------------------------------------- observations
def wrap_angle(angle_rad: np.ndarray) -> np.ndarray:
    """Angle wrapped to (-pi, pi]."""
    return np.pi - np.mod(np.pi - np.asarray(angle_rad, dtype=np.float64), 2.0 * np.pi)


def _min_wall_distances(track: Track, xy_m: np.ndarray, s_m: np.ndarray) -> np.ndarray:
    """Euclidean distances (n, 2) from points to the left and right wall polylines, within _WALL_WINDOW_M of s."""
    n_pts = track.n_points
    half = int(np.ceil(_WALL_WINDOW_M / track.spacing_m))
    centre = np.rint(track.wrap_s(s_m) / track.spacing_m).astype(np.int64)
    i0 = (centre[:, None] + np.arange(-half, half + 1)[None, :]) % n_pts  # (n, w)
    walls = np.stack([track.left_wall_xy_m, track.right_wall_xy_m])  # (2, n_pts, 2)
    a = walls[:, i0]  # (2, n, w, 2)
    e = walls[:, (i0 + 1) % n_pts] - a
    w = xy_m[None, :, None, :] - a
    ex, ey, wx, wy = e[..., 0], e[..., 1], w[..., 0], w[..., 1]
    t = np.clip((wx * ex + wy * ey) / np.maximum(ex * ex + ey * ey, 1e-18), 0.0, 1.0)
    rx = wx - ex * t
    ry = wy - ey * t
    return np.sqrt((rx * rx + ry * ry).min(axis=2)).T


def environment_targets(
    track: Track,
    caster: WallRayCaster,
    x_m: np.ndarray,
    y_m: np.ndarray,
    yaw_rad: np.ndarray,
    s_m: np.ndarray,
    lateral_m: np.ndarray,
) -> np.ndarray:
    """The 27 Phase-1 targets (n, 27) in TARGET_NAMES order; ``s_m``/``lateral_m`` are the cars' projection.

    Edge rays hit walls only (the vision paper's targets describe the track, not traffic). The minimum edge
    distances are Euclidean distances to the wall polylines, so they stay positive for a car outside the walls.
    """
    x = np.asarray(x_m, dtype=np.float64)
    y = np.asarray(y_m, dtype=np.float64)
    yaw = np.asarray(yaw_rad, dtype=np.float64)
    s = np.asarray(s_m, dtype=np.float64)
    xy = np.stack([x, y], axis=1)
    out = np.empty((len(x), 27), dtype=np.float64)
    out[:, :13] = caster.cast(xy, yaw[:, None] + EDGE_RAY_ANGLES_RAD[None, :], EDGE_RAY_RANGE_M)
    out[:, 13:15] = _min_wall_distances(track, xy, s)
    out[:, 15] = lateral_m
    out[:, 16] = wrap_angle(yaw - track.heading_at(s))
    out[:, 17:] = track.curvature_at(s[:, None] + CURVATURE_AHEAD_M[None, :])
    return out


def curvature_ahead_time(track: Track, s_m: np.ndarray, speed_mps: np.ndarray, times_s: np.ndarray) -> np.ndarray:
    """Centre-line curvature (n, len(times_s)) where each car will be after ``times_s`` at its current speed.

    Negative speeds count as 0 (a reversing car samples its own position), so the look-ahead never points behind.
    """
    s = np.asarray(s_m, dtype=np.float64)
    v = np.maximum(np.asarray(speed_mps, dtype=np.float64), 0.0)
    return track.curvature_at(s[:, None] + v[:, None] * np.asarray(times_s, dtype=np.float64)[None, :])


def state_curvature_ahead(track: Track, s_m: np.ndarray, speed_mps: np.ndarray) -> np.ndarray:
    """Curvature (n, 10) 1.0..2.8 s ahead at the current speed: the privileged `state` observation's version."""
    return curvature_ahead_time(track, s_m, speed_mps, STATE_CURVATURE_TIMES_S)


def dedicated_features(vehicle_state: Any, wall_contact: np.ndarray, prev_steer_cmd_rad: np.ndarray) -> np.ndarray:
    """The 11 dedicated features (n, 11) in DEDICATED_NAMES order.

    Reads ``vx_mps, vy_mps, ax_mps2, ay_mps2, roll_rate_radps, pitch_rate_radps, yaw_rate_radps`` of a
    VehicleState (body-frame velocity and acceleration, gravity excluded). The planar model has no heave, so
    the z components are 0.
    """
    vx = np.asarray(vehicle_state.vx_mps, dtype=np.float64)
    out = np.zeros((len(vx), 11), dtype=np.float64)
    out[:, 0] = vx
    out[:, 1] = vehicle_state.vy_mps
    out[:, 3] = vehicle_state.ax_mps2
    out[:, 4] = vehicle_state.ay_mps2
    out[:, 6] = vehicle_state.roll_rate_radps
    out[:, 7] = vehicle_state.pitch_rate_radps
    out[:, 8] = vehicle_state.yaw_rate_radps
    out[:, 9] = np.asarray(wall_contact, dtype=bool)
    out[:, 10] = prev_steer_cmd_rad
    return out


def lidar(
    caster: WallRayCaster,
    x_m: np.ndarray,
    y_m: np.ndarray,
    yaw_rad: np.ndarray,
    car_corners_xy_m: np.ndarray | None = None,
    car_group: np.ndarray | None = None,
    car_index: np.ndarray | None = None,
) -> np.ndarray:
    """72-beam lidar (n, 72) over LIDAR_ANGLES_RAD with LIDAR_RANGE_M range: walls, and cars of the same group.

    ``car_corners_xy_m`` (m, 4, 2) and ``car_group`` (m,) describe all cars; ``car_index`` (n,) is the row of each
    lidar car among them (default: the cars are the same, ``arange(n)``, so m must equal n). A car never sees itself.
    """
    x = np.asarray(x_m, dtype=np.float64)
    yaw = np.asarray(yaw_rad, dtype=np.float64)
    xy = np.stack([x, np.asarray(y_m, dtype=np.float64)], axis=1)
    angles = yaw[:, None] + LIDAR_ANGLES_RAD[None, :]
    if car_corners_xy_m is None:
        return caster.cast(xy, angles, LIDAR_RANGE_M)
    if car_index is None:
        if len(car_corners_xy_m) != len(x):
            raise ValueError("without car_index, car_corners_xy_m must hold one rectangle per lidar car")
        car_index = np.arange(len(x))
    return caster.cast(xy, angles, LIDAR_RANGE_M, car_corners_xy_m, car_group, ray_car_index=car_index)


# ---------------------------------------------------------------------------------------------------- benchmark
def _bench_track() -> Track:
    """The built-in default track (expressway)."""
    from vision_rl.sim.track_library import load_track

    return load_track("expressway")


def bench_sensors(
    n_cars: int = 20, seed: int = 0, repeats: int = 200, track: Track | None = None, cell_size_m: float | None = None
) -> dict:
    """Median wall-clock times (ms) of the sensors for ``n_cars`` cars packed within 150 m of track, one group.

    Returns ``{"lidar_ms_<n>_cars": 72-beam lidar against walls and cars, "targets_ms_<n>_cars": the 27 targets}``.

    The pack puts the cars within each other's 20 m lidar range, the costly case of the overtaking scenario.
    Numba kernels are compiled (or loaded from cache) and warmed before timing.
    """
    track = track if track is not None else _bench_track()
    rng = np.random.default_rng(seed)
    caster = WallRayCaster(track) if cell_size_m is None else WallRayCaster(track, cell_size_m)
    s = track.wrap_s(rng.uniform(0.0, track.length_m) + rng.uniform(0.0, 150.0, n_cars))
    half_w = np.minimum(track.width_left_at(s), track.width_right_at(s)) - 1.5
    lateral = rng.uniform(-1.0, 1.0, n_cars) * np.maximum(half_w, 0.0)
    xy = track.position_at(s, lateral)
    x, y = xy[:, 0], xy[:, 1]
    yaw = track.heading_at(s) + rng.normal(0.0, 0.1, n_cars)
    # Body size of a GT3 car (911 GT3 R: 4.6 m x 2.0 m); the exact figure barely moves the timing.
    corners = car_corners(x, y, yaw, 4.6, 2.0)
    group = np.zeros(n_cars, dtype=np.int64)

    def time_ms(fn) -> float:
        for _ in range(3):
            fn()
        samples = np.empty(repeats)
        for r in range(repeats):
            t0 = time.perf_counter()
            fn()
            samples[r] = time.perf_counter() - t0
        return float(np.median(samples) * 1e3)

    lidar_ms = time_ms(lambda: lidar(caster, x, y, yaw, corners, group))
    targets_ms = time_ms(lambda: environment_targets(track, caster, x, y, yaw, s, lateral))
    return {
        f"lidar_ms_{n_cars}_cars": lidar_ms,
        f"targets_ms_{n_cars}_cars": targets_ms,
    }
