"""A closed, walled race track: centre line, widths, walls and batched geometric queries.

Conventions: arc length ``s`` grows in the driving direction, lateral offset ``d`` is
positive to the left, curvature is positive in a left turn. The centre line is a periodic smooth spline
resampled at a fixed spacing; every query below works on that resampled polyline and is batched over cars.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numba
import numpy as np

from vision_rl.budget import require_memory

if TYPE_CHECKING:  # scipy is imported where it is used: --help of every command stays light
    from scipy.spatial import cKDTree

#: Default spacing of the resampled centre line: 1 m keeps polyline errors
#: (kappa * ds^2 / 8) below 3 mm even in a 40 m hairpin.
DEFAULT_SPACING_M = 1.0

#: Half-width, in samples, of the window first searched around a start sample; beyond it the search walks downhill
#: in distance, so a poor guess costs a few more steps, never a wrong answer on a smooth track.
_SEARCH_WINDOW_SAMPLES = 3

#: The kerb or shoulder band between each painted edge line and its wall takes this share of the half width, at
#: most SHOULDER_MAX_WIDTH_M: a car whose centre is on it has more than half its body over the line (off track).
SHOULDER_SHARE = 0.15
SHOULDER_MAX_WIDTH_M = 1.0

#: Where a wall would fold (its offset larger than the local radius, or reaching past the line midway to another
#: part of the same bend), its width is cut to this share of the distance to that midway line (the medial axis).
#: Below 1 so that the two sides of a trimmed bend never touch and the lateral offset stays clear of the centre
#: of curvature, where the (s, d) frame of the contact model and the racing line is singular.
WALL_TRIM_SHARE = 0.9
#: Parts of the track at most this far apart along it are the two sides of one bend, whose walls are trimmed where
#: they would overlap; parts farther apart that overlap are an error of the track file (or a bridge).
WALL_TRIM_MAX_ARC_M = 200.0


class TrackError(ValueError):
    """A track that cannot be built: the message names the source and, where it applies, the point."""


@dataclass(frozen=True, eq=False)
class Projection:
    """Where points lie relative to the centre line, batched over cars (all arrays shape (n,))."""

    s_m: np.ndarray
    """Arc length of the closest centre-line point, in [0, length_m)."""
    lateral_m: np.ndarray
    """Signed distance to the centre line, positive to the left."""
    heading_rad: np.ndarray
    """Centre-line tangent direction at s_m, counter-clockwise from +x, in (-pi, pi]."""


class Track:
    """A closed centre line resampled every ``spacing_m`` metres, with widths and walls on both edges.

    Build one with :meth:`from_centre_line` (any closed point sequence) or :func:`vision_rl.sim.load_track`
    (a built-in name, ``random:SEED`` or a racetrack-database CSV path).

    Attributes (arrays over the n resampled points):
        centre_xy_m (n, 2), s_m (n,), heading_rad (n,), curvature_1pm (n,), width_left_m (n,), width_right_m (n,),
        tangent (n, 2), normal_left (n, 2), left_wall_xy_m (n, 2), right_wall_xy_m (n, 2).
    """

    def __init__(
        self,
        name: str,
        centre_xy_m: np.ndarray,
        heading_rad: np.ndarray,
        curvature_1pm: np.ndarray,
        width_left_m: np.ndarray,
        width_right_m: np.ndarray,
    ) -> None:
        self.name = name
        self.centre_xy_m = np.ascontiguousarray(centre_xy_m, dtype=np.float64)
        self.heading_rad = np.asarray(heading_rad, dtype=np.float64)
        self.curvature_1pm = np.asarray(curvature_1pm, dtype=np.float64)
        self.width_left_m = np.asarray(width_left_m, dtype=np.float64)
        self.width_right_m = np.asarray(width_right_m, dtype=np.float64)
        n = len(self.centre_xy_m)
        seg = np.roll(self.centre_xy_m, -1, axis=0) - self.centre_xy_m
        self.length_m = float(np.hypot(seg[:, 0], seg[:, 1]).sum())
        self.spacing_m = self.length_m / n
        self.s_m = np.arange(n) * self.spacing_m
        self.tangent = np.stack([np.cos(self.heading_rad), np.sin(self.heading_rad)], axis=1)
        self.normal_left = np.stack([-self.tangent[:, 1], self.tangent[:, 0]], axis=1)
        self.left_wall_xy_m = self.centre_xy_m + self.normal_left * self.width_left_m[:, None]
        self.right_wall_xy_m = self.centre_xy_m - self.normal_left * self.width_right_m[:, None]
        #: Largest cut (m) that :meth:`with_trimmed_walls` made to a width; 0 for a track built as given.
        self.wall_trim_m = 0.0
        # Heading unwrapped along s so that linear interpolation between samples never jumps by 2 pi.
        self._heading_unwrapped = np.unwrap(np.append(self.heading_rad, self.heading_rad[0]))

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_centre_line(
        cls,
        name: str,
        xy_m: np.ndarray,
        width_left_m: np.ndarray | float,
        width_right_m: np.ndarray | float,
        spacing_m: float = DEFAULT_SPACING_M,
        smoothing_m: float = 0.0,
    ) -> Track:
        """Fit a periodic cubic spline through a closed point sequence and resample it every ~``spacing_m``.

        ``xy_m`` (k, 2) must not repeat its first point at the end. Widths are per input point or scalars.
        ``smoothing_m`` is the RMS distance the spline may keep from the input points (0 interpolates them);
        a few centimetres remove the jitter of surveyed centre lines without moving the track.
        """
        from scipy import interpolate

        xy = np.asarray(xy_m, dtype=np.float64)
        k = len(xy)
        w_left = np.broadcast_to(np.asarray(width_left_m, dtype=np.float64), (k,))
        w_right = np.broadcast_to(np.asarray(width_right_m, dtype=np.float64), (k,))
        closed = np.vstack([xy, xy[:1]])
        chord = np.hypot(*np.diff(closed, axis=0).T)
        require_track_memory(name, float(chord.sum()), spacing_m, float(max(w_left.max(), w_right.max())))
        u = np.concatenate([[0.0], np.cumsum(chord)])
        tck, _ = interpolate.splprep([closed[:, 0], closed[:, 1]], u=u, s=k * smoothing_m**2, per=1, k=3, quiet=2)
        # Arc length of the spline by dense quadrature, then uniform resampling in arc length.
        u_dense = np.linspace(0.0, u[-1], 20 * k + 1)
        dx, dy = interpolate.splev(u_dense, tck, der=1)
        speed = np.hypot(dx, dy)
        arc = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(u_dense))])
        n = max(round(float(arc[-1]) / spacing_m), 8)
        s_uniform = np.arange(n) * (arc[-1] / n)
        u_uniform = np.interp(s_uniform, arc, u_dense)
        x, y = interpolate.splev(u_uniform, tck)
        dx, dy = interpolate.splev(u_uniform, tck, der=1)
        ddx, ddy = interpolate.splev(u_uniform, tck, der=2)
        curvature = (dx * ddy - dy * ddx) / np.hypot(dx, dy) ** 3
        wl = np.interp(u_uniform, u, np.append(w_left, w_left[0]))
        wr = np.interp(u_uniform, u, np.append(w_right, w_right[0]))
        return cls(name, np.stack([x, y], axis=1), np.arctan2(dy, dx), curvature, wl, wr)

    def with_trimmed_walls(self, share: float = WALL_TRIM_SHARE, max_arc_m: float = WALL_TRIM_MAX_ARC_M) -> Track:
        """This track with each wall cut back where it would fold; ``self`` when nothing needs cutting.

        A wall on the inside of a bend tighter than its offset (a street hairpin) folds into a loop (the offset
        curve's swallow tail) and, round the bend, crosses the wall of the other leg. The road there is the set of
        points within the width of the centre line, whose inner edge is the offset curve without that loop. Each
        width is cut to ``share`` of its distance along the normal to the medial axis (the points as far from this
        centre point as from another one within ``max_arc_m`` along the track), counting another point only where
        the two walls facing each other would overlap (their widths add up to more than twice that distance).
        The walls then follow the true inner edge up to where the two legs' walls meet and, beyond it, a thin
        wedge of wall along the medial axis towards the bend's centre: the part of the road past the centre of
        curvature cannot be described by a lateral offset, which the contact model, the racing line and the
        renderer all use. Every consumer reads the cut widths, so walls, wall distances, contact and the drawn
        track agree.
        """
        left, right = trimmed_widths(
            self.centre_xy_m,
            self.normal_left,
            self.curvature_1pm,
            self.s_m,
            self.length_m,
            self.width_left_m,
            self.width_right_m,
            share,
            max_arc_m,
        )
        cut = max(float((self.width_left_m - left).max()), float((self.width_right_m - right).max()))
        if cut <= 0.0:
            return self
        track = Track(self.name, self.centre_xy_m, self.heading_rad, self.curvature_1pm, left, right)
        track.wall_trim_m = cut
        return track

    # ------------------------------------------------------------------ derived properties
    @cached_property
    def geometry_hash(self) -> str:
        """Hex digest of the resampled geometry (centre line and widths): a cache key and a dataset attribute."""
        h = hashlib.sha256()
        for a in (self.centre_xy_m, self.width_left_m, self.width_right_m):
            h.update(np.round(a, 6).tobytes())
        return h.hexdigest()[:16]

    @property
    def n_points(self) -> int:
        return len(self.s_m)

    @property
    def min_width_m(self) -> float:
        """Narrowest wall-to-wall width."""
        return float((self.width_left_m + self.width_right_m).min())

    @cached_property
    def _kdtree(self) -> cKDTree:
        from scipy.spatial import cKDTree

        return cKDTree(self.centre_xy_m)

    def wall_segments(self) -> np.ndarray:
        """All wall segments as (2n, 4) rows ``x0, y0, x1, y1``: the left wall's n, then the right wall's n."""
        segs = []
        for wall in (self.left_wall_xy_m, self.right_wall_xy_m):
            segs.append(np.hstack([wall, np.roll(wall, -1, axis=0)]))
        return np.ascontiguousarray(np.vstack(segs))

    # ------------------------------------------------------------------ batched queries
    def wrap_s(self, s_m: np.ndarray) -> np.ndarray:
        """Arc length wrapped into [0, length_m)."""
        return np.mod(s_m, self.length_m)

    def _interp_index(self, s_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pos = self.wrap_s(np.asarray(s_m, dtype=np.float64)) / self.spacing_m
        i0 = np.floor(pos).astype(np.int64)
        frac = pos - i0
        return i0 % self.n_points, frac

    def _interp(self, values: np.ndarray, s_m: np.ndarray) -> np.ndarray:
        i0, frac = self._interp_index(s_m)
        i1 = (i0 + 1) % self.n_points
        return values[i0] * (1.0 - frac) + values[i1] * frac

    def curvature_at(self, s_m: np.ndarray) -> np.ndarray:
        """Centre-line curvature (1/m, positive turning left) at any arc length, wrapped."""
        return self._interp(self.curvature_1pm, s_m)

    def heading_at(self, s_m: np.ndarray) -> np.ndarray:
        """Centre-line tangent direction (rad, in (-pi, pi]) at any arc length, wrapped."""
        i0, frac = self._interp_index(s_m)
        h = self._heading_unwrapped[i0] * (1.0 - frac) + self._heading_unwrapped[i0 + 1] * frac
        return np.angle(np.exp(1j * h))

    def position_at(self, s_m: np.ndarray, lateral_m: np.ndarray | float = 0.0) -> np.ndarray:
        """World (x, y) in m, shape (n, 2), of the point at arc length ``s_m`` and lateral offset ``lateral_m``."""
        s_m = np.atleast_1d(np.asarray(s_m, dtype=np.float64))
        i0, frac = self._interp_index(s_m)
        i1 = (i0 + 1) % self.n_points
        centre = self.centre_xy_m[i0] * (1.0 - frac)[:, None] + self.centre_xy_m[i1] * frac[:, None]
        heading = self.heading_at(s_m)
        normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
        return centre + normal * np.asarray(lateral_m, dtype=np.float64)[..., None]

    def width_left_at(self, s_m: np.ndarray) -> np.ndarray:
        """Distance from the centre line to the left wall (m) at any arc length."""
        return self._interp(self.width_left_m, s_m)

    def width_right_at(self, s_m: np.ndarray) -> np.ndarray:
        """Distance from the centre line to the right wall (m) at any arc length."""
        return self._interp(self.width_right_m, s_m)

    def beyond_edge_line(self, s_m: np.ndarray, lateral_m: np.ndarray) -> np.ndarray:
        """True where a point (arc length, lateral offset) lies outside the painted edge lines, on the kerb or
        shoulder band that runs along each wall (``SHOULDER_SHARE`` of the half width, at most
        ``SHOULDER_MAX_WIDTH_M``; the renderer draws the same band)."""
        lateral = np.asarray(lateral_m, dtype=np.float64)
        side = np.where(lateral >= 0.0, self.width_left_at(s_m), self.width_right_at(s_m))
        return np.abs(lateral) > side - np.minimum(SHOULDER_MAX_WIDTH_M, SHOULDER_SHARE * side)

    def project(self, xy_m: np.ndarray, s_guess_m: np.ndarray | float | None = None) -> Projection:
        """Project points (n, 2) onto the centre line.

        With ``s_guess_m`` (the previous step's s; a scalar broadcasts) the search starts at the guess and
        descends to the nearest local minimum of the distance, so the cost per car is O(1) and a car never jumps
        to a neighbouring part of the track that happens to be close (the far side of a hairpin). Without a guess
        the globally nearest sample is the start.
        """
        xy = np.atleast_2d(np.asarray(xy_m, dtype=np.float64))
        if s_guess_m is None:
            _, nearest = self._kdtree.query(xy)
            start = np.asarray(nearest, dtype=np.int64)
        else:
            guess = np.broadcast_to(np.asarray(s_guess_m, dtype=np.float64), (len(xy),))
            start = np.rint(self.wrap_s(guess) / self.spacing_m).astype(np.int64) % self.n_points
        s, lateral, heading = _project_points(self.kernel_arrays, self.spacing_m, xy, start)
        return Projection(s_m=s, lateral_m=lateral, heading_rad=heading)

    @cached_property
    def kernel_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The arrays the numba kernels read: (centre_xy_m, tangent, heading unwrapped (n + 1), width_left_m,
        width_right_m); the spacing follows from them."""
        return (
            self.centre_xy_m,
            np.ascontiguousarray(self.tangent),
            self._heading_unwrapped,
            self.width_left_m,
            self.width_right_m,
        )

    def progress_delta(self, s_prev_m: np.ndarray, s_now_m: np.ndarray) -> np.ndarray:
        """Signed arc length driven from ``s_prev_m`` to ``s_now_m`` (m), wrapped to half a lap.

        Crossing the start/finish line forwards gives a small positive value, driving backwards a negative one.
        """
        half = 0.5 * self.length_m
        return np.mod(np.asarray(s_now_m) - np.asarray(s_prev_m) + half, self.length_m) - half

    def __repr__(self) -> str:
        return f"Track({self.name!r}, length_m={self.length_m:.1f}, n_points={self.n_points})"


#: Memory a resampled point costs while a track is built and used, bytes: its arrays, k-d tree, racing line and
#: renderer mesh (loading alone peaked at 2.5 KB a point for a 126 km circle).
TRACK_POINT_BYTES = 10_000
#: Memory a pair of nearby points costs in :func:`trimmed_widths`, bytes (indices, gaps, offsets, masks).
TRIM_PAIR_BYTES = 128


def require_track_memory(where: str, length_m: float, spacing_m: float, max_width_m: float) -> None:
    """Refuse a track whose extent, resolution or width would need more memory than the budget, before it is
    resampled: ``where`` names the file or track in the one-line message."""
    points = length_m / spacing_m
    require_memory(
        f"{where}: a track of {length_m / 1000:,.1f} km at {spacing_m:g} m spacing", points * TRACK_POINT_BYTES
    )
    neighbours = min(points, 4.0 * (2.0 * max_width_m / WALL_TRIM_SHARE) / spacing_m)  # within the trim's reach
    require_memory(f"{where}: track widths up to {max_width_m:,.0f} m", points * neighbours * TRIM_PAIR_BYTES)


def trimmed_widths(
    centre_xy_m: np.ndarray,
    normal_left: np.ndarray,
    curvature_1pm: np.ndarray,
    s_m: np.ndarray,
    length_m: float,
    width_left_m: np.ndarray,
    width_right_m: np.ndarray,
    share: float = WALL_TRIM_SHARE,
    max_arc_m: float = WALL_TRIM_MAX_ARC_M,
) -> tuple[np.ndarray, np.ndarray]:
    """Widths (left, right) cut where the walls would fold; see :meth:`Track.with_trimmed_walls`.

    Point i's wall on side n (the unit normal towards it) reaches the medial axis between centre points i and j at
    ``t = |d|^2 / (2 d.n)``, d = c_j - c_i (d.n > 0); where the two facing widths add up to more than
    ``2 share t``, the width is cut to ``share t``. For j a neighbour round a bend t is about the radius of curvature,
    and the sampled curvature itself bounds the width on the inside to ``share / |kappa|``, so a cut width never
    folds (``|kappa| w <= share``) and a width already within both bounds is kept exactly. Only pairs closer than
    twice the widest width can cut (``share t < w`` needs ``|d| < 2 w / share``); a k-d tree finds them, so the cost
    is O(n log n) and vectorised.
    """
    from scipy.spatial import cKDTree

    kappa = np.asarray(curvature_1pm, dtype=np.float64)
    with np.errstate(divide="ignore"):
        left = np.minimum(width_left_m, np.where(kappa > 0.0, share / kappa, np.inf))
        right = np.minimum(width_right_m, np.where(kappa < 0.0, -share / kappa, np.inf))
    reach = 2.0 * float(max(left.max(), right.max())) / share
    pairs = cKDTree(centre_xy_m).query_pairs(reach, output_type="ndarray")
    if len(pairs) == 0:
        return left, right
    # Both orders of every pair: i is the point whose width is cut, j the one it is measured against.
    i = np.concatenate([pairs[:, 0], pairs[:, 1]])
    j = np.concatenate([pairs[:, 1], pairs[:, 0]])
    gap = np.abs(np.mod(s_m[j] - s_m[i] + 0.5 * length_m, length_m) - 0.5 * length_m)
    near = gap <= max_arc_m
    i, j = i[near], j[near]
    d = centre_xy_m[j] - centre_xy_m[i]
    d2 = np.einsum("nk,nk->n", d, d)
    dn = np.einsum("nk,nk->n", d, normal_left[i])
    for width, sign in ((left, 1.0), (right, -1.0)):
        facing = sign * dn > 0.0
        with np.errstate(divide="ignore"):
            t = np.where(facing, d2 / (2.0 * np.abs(dn)), np.inf)
        overlap = facing & (width[i] + width[j] > 2.0 * share * t)
        limit = np.full(len(width), np.inf)
        np.minimum.at(limit, i[overlap], share * t[overlap])
        np.minimum(width, limit, out=width)
    return left, right


# ---------------------------------------------------------------------------------------------- numba kernels
# Projection runs for every car at every 10 ms physics substep inside the world kernel; numpy's per-call overhead at
# 20 cars made it ~150 us a call, the scalar kernel below is ~0.1 us per car. Track.project uses the same code.


@numba.njit(cache=True, inline="always")
def _dist2(centre, i, px, py):
    dx = centre[i, 0] - px
    dy = centre[i, 1] - py
    return dx * dx + dy * dy


@numba.njit(cache=True)
def project_point(centre, tangent, heading_unwrapped, spacing, px, py, start):
    """Project one point onto the closed polyline ``centre`` (samples ``spacing`` m apart) starting the search at
    sample ``start``.

    Returns (s_m, lateral_m, heading_rad, nearest sample). The nearest sample is the best of a small window around
    ``start``, then followed downhill while a neighbour is closer.
    """
    n = centre.shape[0]
    best = start % n
    best_d = _dist2(centre, best, px, py)
    for o in range(-_SEARCH_WINDOW_SAMPLES, _SEARCH_WINDOW_SAMPLES + 1):
        j = (start + o) % n
        d = _dist2(centre, j, px, py)
        if d < best_d:
            best, best_d = j, d
    for _ in range(n):
        ahead = (best + 1) % n
        behind = (best - 1) % n
        d_ahead = _dist2(centre, ahead, px, py)
        d_behind = _dist2(centre, behind, px, py)
        if d_ahead < best_d and d_ahead <= d_behind:
            best, best_d = ahead, d_ahead
        elif d_behind < best_d:
            best, best_d = behind, d_behind
        else:
            break
    # Refine on the polyline segment on the side of the nearest sample that the point lies on.
    rx = px - centre[best, 0]
    ry = py - centre[best, 1]
    i0 = best if rx * tangent[best, 0] + ry * tangent[best, 1] >= 0.0 else (best - 1) % n
    i1 = (i0 + 1) % n
    sx = centre[i1, 0] - centre[i0, 0]
    sy = centre[i1, 1] - centre[i0, 1]
    seg_len2 = sx * sx + sy * sy
    t = ((px - centre[i0, 0]) * sx + (py - centre[i0, 1]) * sy) / seg_len2
    t = min(max(t, 0.0), 1.0)
    heading = heading_unwrapped[i0] * (1.0 - t) + heading_unwrapped[i0 + 1] * t
    heading = heading - 2.0 * np.pi * np.floor((heading + np.pi) / (2.0 * np.pi))
    ox = px - (centre[i0, 0] + sx * t)
    oy = py - (centre[i0, 1] + sy * t)
    lateral = -np.sin(heading) * ox + np.cos(heading) * oy
    s = (i0 + t) * spacing
    if s >= n * spacing:
        s -= n * spacing
    return s, lateral, heading, best


@numba.njit(cache=True)
def _project_points(arrays, spacing, xy, start):
    centre, tangent, heading_unwrapped = arrays[0], arrays[1], arrays[2]
    m = xy.shape[0]
    s = np.empty(m)
    lateral = np.empty(m)
    heading = np.empty(m)
    for k in range(m):
        s[k], lateral[k], heading[k], _ = project_point(
            centre, tangent, heading_unwrapped, spacing, xy[k, 0], xy[k, 1], start[k]
        )
    return s, lateral, heading
