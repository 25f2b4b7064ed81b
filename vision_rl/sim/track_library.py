"""Where tracks come from: built-in circuits, the 25 real circuits of the racetrack-database, procedural
``random:SEED`` tracks and CSV files.

:func:`load_track` is the one entry point every command and constructor uses; it accepts a built-in name
(:data:`BUILTIN_TRACKS`), the name of a circuit of the TUMFTM racetrack-database shipped with the package
(:data:`DATABASE_TRACKS`, any case: ``Catalunya``), ``random:SEED`` or a path to a CSV file in that database's format
(``# x_m,y_m,w_tr_right_m,w_tr_left_m``). Every track it returns has been checked: no wall fold (a wall on the inside
of a bend tighter than its offset is trimmed to the true inner edge, see :meth:`Track.with_trimmed_walls`), and
neither the centre line nor the walls cross themselves or each other, except at a grade-separated crossing of a real
circuit (Suzuka's bridge), see :func:`find_crossings`.

Built-in circuits are written as a list of straights and constant-radius arcs (:class:`Layout`), joined by linear
curvature ramps (clothoids, as road builders use) and closed exactly by a least-norm change of the straights' lengths.
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vision_rl.sim.track import DEFAULT_SPACING_M, Track, TrackError, require_track_memory

__all__ = [
    "BUILTIN_TRACKS",
    "CSV_SMOOTHING_LENGTH_M",
    "DATABASE_DIR",
    "DATABASE_TRACKS",
    "DEFAULT_TRACK",
    "LAYOUTS",
    "Layout",
    "Segment",
    "build_layout",
    "count_corners",
    "find_crossings",
    "left",
    "load_csv_track",
    "load_track",
    "random_track",
    "reference_racing_line",
    "right",
    "straight",
    "track_summary",
    "validate_track",
]

DEFAULT_TRACK = "expressway"

#: The TUMFTM racetrack-database (LGPL-3.0) shipped as package data: ``tracks/NAME.csv`` (centre line and widths),
#: ``racelines/NAME.csv`` (the database's minimum-curvature race line), its LICENSE and ORIGIN.md (commit, format).
DATABASE_DIR = Path(__file__).resolve().parent.parent / "data" / "racetrack_database"
#: The database's circuits, by their file names (``load_track`` takes them in any case).
DATABASE_TRACKS: tuple[str, ...] = tuple(sorted(p.stem for p in (DATABASE_DIR / "tracks").glob("*.csv")))
_DATABASE_BY_KEY = {name.lower(): name for name in DATABASE_TRACKS}

#: Fewest points a CSV centre line may have: a periodic cubic spline through fewer is a blob, not a circuit.
MIN_CSV_POINTS = 10
#: A gap between consecutive CSV points larger than this multiple of the median spacing is a hole in the survey.
MAX_SPACING_RATIO = 5.0
#: Consecutive CSV points closer than this are the same point written twice.
DUPLICATE_TOLERANCE_M = 1e-3

#: Smoothing length of CSV centre lines: the cut-off of a periodic second-order Whittaker (penalised least squares)
#: filter, lambda = (length / spacing)^4. The racetrack-database lines are GPS-derived with 5 m spacing; unsmoothed,
#: their curvature has spikes down to a 5.7 m radius (Spa, where the inside wall then folds). FITPACK's own
#: smoothing (``Track.from_centre_line(smoothing_m=...)``) was tried first and is worse: its knot placement leaves
#: 7 m radii at Monza at 0.1 m RMS. With 9 m the five real tracks move by 0.15-0.23 m RMS (at most 2.5 m, in
#: Monza's first chicane) and their tightest radii become 12-18 m, with no wall fold (largest inside width / radius
#: 0.57). Monza keeps 12 m in the first chicane: the database's line has 8.8 m there and its race line 18 m;
#: 15 m would need 0.42 m RMS, which moves the chicane itself. Widths are kept as given.
CSV_SMOOTHING_LENGTH_M = 9.0

#: Least crossing angle of a grade-separated crossing (a bridge): two branches crossing at a shallower angle are
#: an error in the file, not a figure-eight circuit. Suzuka's crossing is at 60 deg.
MIN_OVERPASS_ANGLE_RAD = math.radians(30.0)
#: Least arc length between the two branches of a grade-separated crossing; a shorter loop is a knot in the line.
MIN_OVERPASS_SEPARATION_M = 300.0

# ---------------------------------------------------------------------------------------------- geometry checks


def _segment_crossings(rings: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All touching or crossing pairs among the segments of closed polylines, excluding neighbours on one ring.

    ``rings`` are (k, 2) closed point sequences (the last point joins the first). Returns segment indices ``i < j``
    into the rings' concatenated segments and the crossing points (m, 2). Candidates come from a k-d tree over the
    segment midpoints: two segments of length <= L that touch have midpoints at most L apart, so the search is
    O(n log n) and vectorised.
    """
    from scipy.spatial import cKDTree

    starts = np.vstack(rings)
    ends = np.vstack([np.roll(r, -1, axis=0) for r in rings])
    ring_len = np.concatenate([np.full(len(r), len(r)) for r in rings])
    local = np.concatenate([np.arange(len(r)) for r in rings])
    ring_id = np.concatenate([np.full(len(r), k) for k, r in enumerate(rings)])
    d = ends - starts
    max_len = float(np.hypot(d[:, 0], d[:, 1]).max())
    pairs = cKDTree(0.5 * (starts + ends)).query_pairs(max_len * (1 + 1e-9) + 1e-9, output_type="ndarray")
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)))
    if len(pairs) == 0:
        return empty
    i, j = pairs.min(axis=1), pairs.max(axis=1)
    gap = np.abs(local[i] - local[j])
    neighbours = (ring_id[i] == ring_id[j]) & ((gap == 1) | (gap == ring_len[i] - 1))
    i, j = i[~neighbours], j[~neighbours]
    d1, d2, r = d[i], d[j], starts[j] - starts[i]
    den = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    r_x_d2 = r[:, 0] * d2[:, 1] - r[:, 1] * d2[:, 0]
    r_x_d1 = r[:, 0] * d1[:, 1] - r[:, 1] * d1[:, 0]
    len1_sq = np.einsum("nk,nk->n", d1, d1)
    scale = np.sqrt(len1_sq * np.einsum("nk,nk->n", d2, d2))
    parallel = np.abs(den) <= 1e-12 * scale
    with np.errstate(divide="ignore", invalid="ignore"):
        t = r_x_d2 / den
        u = r_x_d1 / den
    hit = ~parallel & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    # Collinear segments touch when they lie on one line and their extents along it overlap.
    collinear = parallel & (np.abs(r_x_d1) <= 1e-9 * np.sqrt(len1_sq) * (1.0 + np.hypot(r[:, 0], r[:, 1])))
    t0 = np.einsum("nk,nk->n", r, d1) / len1_sq
    t1 = t0 + np.einsum("nk,nk->n", d2, d1) / len1_sq
    overlap = collinear & (np.maximum(t0, t1) >= 0) & (np.minimum(t0, t1) <= 1)
    t = np.where(overlap, np.clip(np.minimum(t0, t1), 0, 1), t)
    hit |= overlap
    i, j, t = i[hit], j[hit], t[hit]
    order = np.lexsort((j, i))
    i, j, t = i[order], j[order], t[order]
    return i, j, starts[i] + d[i] * t[:, None]


def _crossing_angle_rad(d1: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """Unsigned angle between the lines of direction vectors d1 and d2 (n, 2), in [0, pi/2]."""
    cross = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    dot = np.abs(np.einsum("nk,nk->n", d1, d2))
    return np.arctan2(cross, dot)


def find_crossings(track: Track) -> np.ndarray:
    """Where the centre line crosses itself: (k, 2) arc lengths (m) of the two branches at each crossing.

    A real circuit may cross itself on a bridge (Suzuka); the simulator is flat, so a sensor or a contact model
    that looks up walls by position sees both levels there and should keep to the walls near the car's own ``s``.
    """
    i, j, _ = _segment_crossings([track.centre_xy_m])
    return np.stack([track.s_m[i], track.s_m[j]], axis=1) if len(i) else np.zeros((0, 2))


def _arc_separation_m(track: Track, s_a: np.ndarray, s_b: np.ndarray) -> np.ndarray:
    return np.abs(track.progress_delta(s_a, s_b))


def validate_track(
    track: Track,
    source: str | None = None,
    allow_overpasses: bool = False,
    where: Callable[[float], str] | None = None,
) -> None:
    """Raise :class:`TrackError` unless the track's walls are drivable.

    Checks, in order: every width > 0; no wall fold (``width * |kappa| < 1`` on the inside of every bend); the
    centre line does not cross itself and no wall crosses itself or the other wall. With ``allow_overpasses`` a
    crossing of the centre line at more than :data:`MIN_OVERPASS_ANGLE_RAD` between branches at least
    :data:`MIN_OVERPASS_SEPARATION_M` apart is a bridge, and the wall crossings around it are allowed.
    ``where(s_m) -> str`` names the place of an arc length in messages (CSV tracks name the file's line).
    """
    source = source or track.name
    if where is None:

        def where(s_m: float) -> str:
            return f"s = {s_m:.1f} m"

    for side, width in (("left", track.width_left_m), ("right", track.width_right_m)):
        bad = np.flatnonzero(~(width > 0))
        if len(bad):
            raise TrackError(f"{source}: {where(track.s_m[bad[0]])}: {side} width {width[bad[0]]:.3f} m is not > 0")
    kappa = track.curvature_1pm
    fold_left = kappa * track.width_left_m
    fold_right = -kappa * track.width_right_m
    for side, fold, width in (("left", fold_left, track.width_left_m), ("right", fold_right, track.width_right_m)):
        k = int(np.argmax(fold))
        if fold[k] >= 1.0:
            raise TrackError(
                f"{source}: {where(track.s_m[k])}: the {side} wall folds: it is {width[k]:.2f} m from the centre line "
                f"on the inside of a bend of radius {1 / abs(kappa[k]):.2f} m (the centre line is too tight here)"
            )

    overpasses = np.zeros((0, 2))
    i, j, points = _segment_crossings([track.centre_xy_m])
    if len(i):
        s_i, s_j = track.s_m[i], track.s_m[j]
        tangent = track.tangent
        angle = _crossing_angle_rad(tangent[i], tangent[j])
        bridge = (angle >= MIN_OVERPASS_ANGLE_RAD) & (_arc_separation_m(track, s_i, s_j) >= MIN_OVERPASS_SEPARATION_M)
        bad = np.flatnonzero(~bridge) if allow_overpasses else np.arange(len(i))
        if len(bad):
            b = bad[0]
            raise TrackError(
                f"{source}: the centre line crosses itself at ({points[b, 0]:.1f}, {points[b, 1]:.1f}) m, between "
                f"{where(s_i[b])} and {where(s_j[b])}"
            )
        overpasses = np.column_stack([points, angle])

    n = track.n_points
    i, j, points = _segment_crossings([track.left_wall_xy_m, track.right_wall_xy_m])
    if len(i) and len(overpasses):
        # Around a bridge the walls of the two levels cross; a wall crossing is excused when it lies within the
        # footprint of the crossing of two strips of the widest width at the bridge's angle.
        reach = 2.0 * float((track.width_left_m + track.width_right_m).max()) / np.sin(overpasses[:, 2])
        dist = np.hypot(*(points[:, None, :] - overpasses[None, :, :2]).transpose(2, 0, 1))
        keep = ~(dist <= reach[None, :]).any(axis=1)
        i, j, points = i[keep], j[keep], points[keep]
    if len(i):
        name = ("left", "right")
        wall_i, wall_j = name[i[0] // n], name[j[0] // n]
        what = f"the {wall_i} wall crosses itself" if wall_i == wall_j else "the left and right walls cross"
        raise TrackError(
            f"{source}: {what} at ({points[0, 0]:.1f}, {points[0, 1]:.1f}) m, between {where(track.s_m[i[0] % n])} "
            f"and {where(track.s_m[j[0] % n])} (two parts of the track overlap)"
        )


# ---------------------------------------------------------------------------------------------- CSV files


def _read_csv_points(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Rows (k, 4) ``x_m, y_m, w_tr_right_m, w_tr_left_m`` and their 1-based line numbers in the file."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise TrackError(f"{path}: cannot read the track file ({exc})") from exc
    rows, lines = [], []
    for line_no, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.split(",")
        try:
            if len(fields) != 4:
                raise ValueError
            rows.append([float(f) for f in fields])
        except ValueError:
            raise TrackError(
                f"{path}: line {line_no}: expected 4 comma-separated numbers x_m,y_m,w_tr_right_m,w_tr_left_m, "
                f"got {line[:80]!r}"
            ) from None
        lines.append(line_no)
    return np.array(rows, dtype=np.float64).reshape(-1, 4), np.array(lines, dtype=np.int64)


def _check_csv_points(path: Path, rows: np.ndarray, lines: np.ndarray) -> None:
    def at(k: int) -> str:
        return f"line {lines[k]} (point {k}, 0-based)"

    if len(rows) < MIN_CSV_POINTS:
        raise TrackError(f"{path}: {len(rows)} points; a closed centre line needs at least {MIN_CSV_POINTS}")
    bad = np.flatnonzero(~np.isfinite(rows).all(axis=1))
    if len(bad):
        raise TrackError(f"{path}: {at(bad[0])}: value is not a finite number (NaN or inf)")
    for col, side in ((2, "right"), (3, "left")):
        bad = np.flatnonzero(rows[:, col] <= 0)
        if len(bad):
            raise TrackError(f"{path}: {at(bad[0])}: {side} width {rows[bad[0], col]} m is not > 0")
    xy = rows[:, :2]
    gap = np.hypot(*(np.roll(xy, -1, axis=0) - xy).T)
    dup = np.flatnonzero(gap < DUPLICATE_TOLERANCE_M)
    if len(dup):
        k = int(dup[0])
        if k == len(xy) - 1:
            raise TrackError(
                f"{path}: {at(k)}: the last point repeats the first ({at(0)}); the file's closed centre line must "
                "not repeat its first point"
            )
        raise TrackError(f"{path}: {at(k + 1)}: duplicate of the point before it ({at(k)})")
    median = float(np.median(gap))
    jump = np.flatnonzero(gap > MAX_SPACING_RATIO * median)
    if len(jump):
        k = int(jump[0])
        k1 = (k + 1) % len(xy)
        raise TrackError(
            f"{path}: {at(k1)}: gap of {gap[k]:.1f} m from {at(k)} is more than {MAX_SPACING_RATIO:g} x the median "
            f"spacing ({median:.2f} m)"
        )
    i, j, points = _segment_crossings([xy])
    if len(i):
        cum = np.concatenate([[0.0], np.cumsum(gap)])
        sep = np.abs(cum[j] - cum[i])
        sep = np.minimum(sep, cum[-1] - sep)
        angle = _crossing_angle_rad(np.roll(xy, -1, axis=0)[i] - xy[i], np.roll(xy, -1, axis=0)[j] - xy[j])
        bad = np.flatnonzero((angle < MIN_OVERPASS_ANGLE_RAD) | (sep < MIN_OVERPASS_SEPARATION_M))
        if len(bad):
            b = bad[0]
            raise TrackError(
                f"{path}: the centre line crosses itself at ({points[b, 0]:.1f}, {points[b, 1]:.1f}) m, on the "
                f"segment after {at(i[b])} and the segment after {at(j[b])}"
            )


def _smooth_closed(xy: np.ndarray, smoothing_length_m: float) -> np.ndarray:
    """Periodic second-order Whittaker smoother of a closed, roughly evenly spaced point sequence (k, 2)."""
    if smoothing_length_m <= 0:
        return xy
    spacing = float(np.hypot(*(np.roll(xy, -1, axis=0) - xy).T).mean())
    lam = (smoothing_length_m / spacing) ** 4
    omega = 2 * np.pi * np.fft.rfftfreq(len(xy))
    gain = 1.0 / (1.0 + lam * (2.0 - 2.0 * np.cos(omega)) ** 2)
    return np.fft.irfft(np.fft.rfft(xy, axis=0) * gain[:, None], n=len(xy), axis=0)


def load_csv_track(
    path: str | os.PathLike,
    spacing_m: float = DEFAULT_SPACING_M,
    smoothing_length_m: float = CSV_SMOOTHING_LENGTH_M,
) -> Track:
    """Load and check a racetrack-database CSV (``x_m,y_m,w_tr_right_m,w_tr_left_m``; the right width first).

    The track is named after the file's stem. Errors name the file and the point as its 1-based line in the file
    and its 0-based point index. A grade-separated crossing (a bridge, as at Suzuka) is accepted; see
    :func:`find_crossings`.
    """
    path = Path(path)
    if not path.is_file():
        raise TrackError(f"{path}: no such track file")
    rows, lines = _read_csv_points(path)
    _check_csv_points(path, rows, lines)
    length_m = float(np.hypot(*(np.roll(rows[:, :2], -1, axis=0) - rows[:, :2]).T).sum())
    require_track_memory(str(path), length_m, spacing_m, float(rows[:, 2:].max()))
    xy = _smooth_closed(rows[:, :2], smoothing_length_m)
    track = Track.from_centre_line(path.stem, xy, rows[:, 3], rows[:, 2], spacing_m=spacing_m).with_trimmed_walls()
    # Messages about the resampled track name the file line whose point lies nearest along the track.
    raw_s = track.project(rows[:, :2]).s_m

    def where(s_m: float) -> str:
        k = int(np.argmin(np.abs(track.progress_delta(raw_s, s_m))))
        return f"line {lines[k]} (point {k}, 0-based; s = {s_m:.1f} m)"

    validate_track(track, str(path), allow_overpasses=True, where=where)
    return track


# ---------------------------------------------------------------------------------------------- built-in layouts


@dataclass(frozen=True)
class Segment:
    """A piece of a layout: a straight (``curvature_1pm == 0``) or a constant-radius arc."""

    length_m: float
    """Arc length of the piece (m)."""
    curvature_1pm: float = 0.0
    """1 / radius (1/m), positive turning left."""
    width_left_m: float | None = None
    """Distance centre line to left wall (m) from this piece on; None keeps the previous piece's."""
    width_right_m: float | None = None
    """Distance centre line to right wall (m) from this piece on; None keeps the previous piece's."""

    @property
    def turn_rad(self) -> float:
        return self.length_m * self.curvature_1pm


def straight(length_m: float, width_m: tuple[float, float] | None = None) -> Segment:
    """A straight of ``length_m``; ``width_m = (left, right)`` changes the widths from here on."""
    wl, wr = width_m if width_m is not None else (None, None)
    return Segment(length_m, 0.0, wl, wr)


def left(radius_m: float, turn_deg: float, width_m: tuple[float, float] | None = None) -> Segment:
    """A left-hand arc of ``radius_m`` turning by ``turn_deg``."""
    wl, wr = width_m if width_m is not None else (None, None)
    return Segment(radius_m * math.radians(turn_deg), 1.0 / radius_m, wl, wr)


def right(radius_m: float, turn_deg: float, width_m: tuple[float, float] | None = None) -> Segment:
    """A right-hand arc of ``radius_m`` turning by ``turn_deg``."""
    wl, wr = width_m if width_m is not None else (None, None)
    return Segment(radius_m * math.radians(turn_deg), -1.0 / radius_m, wl, wr)


@dataclass(frozen=True)
class Layout:
    """A circuit written as straights and arcs whose turns add up to one full turn (+-360 deg)."""

    segments: tuple[Segment, ...]
    width_left_m: float
    """Initial distance centre line to left wall (m)."""
    width_right_m: float
    """Initial distance centre line to right wall (m)."""
    transition_m: float = 20.0
    """Length (m) of the linear curvature ramp (clothoid) that replaces each jump of curvature."""
    width_transition_m: float = 60.0
    """Length (m) over which a change of width is blended."""
    description: str = ""

    @property
    def nominal_length_m(self) -> float:
        return float(sum(seg.length_m for seg in self.segments))

    @property
    def total_turn_rad(self) -> float:
        return float(sum(seg.turn_rad for seg in self.segments))


def _box_filter_periodic(values: np.ndarray, width_samples: int) -> np.ndarray:
    """Periodic moving average over an odd number of samples; preserves the sum exactly."""
    w = max(1, width_samples | 1)
    if w == 1:
        return values
    half = w // 2
    padded = np.concatenate([values[-half:], values, values[:half]])
    c = np.concatenate([[0.0], np.cumsum(padded)])
    return (c[w:] - c[:-w]) / w


def _trace_layout(layout: Layout, lengths_m: np.ndarray, n: int) -> tuple[np.ndarray, float, np.ndarray]:
    """Centre line (n + 1, 2) traced in n even steps from the origin, heading +x, for segments of ``lengths_m``.

    Returns the points, the step (m) and the segments' boundaries in arc length (m). The last point lands on the
    first only if the lengths close the layout (see :func:`_close_layout`).
    """
    total = float(lengths_m.sum())
    ds = total / n
    bounds = np.concatenate([[0.0], np.cumsum(lengths_m)])
    turn_at_bounds = np.concatenate([[0.0], np.cumsum(lengths_m * [seg.curvature_1pm for seg in layout.segments])])
    # Cell-averaged curvature from the exact, piecewise-linear turn angle: the lap's total turn is kept exactly.
    grid = np.linspace(0.0, total, n + 1)
    turn = np.interp(grid, bounds, turn_at_bounds)
    # A moving average over the transition length turns each jump of curvature into a linear ramp centred on it.
    kappa = _box_filter_periodic(np.diff(turn) / ds, round(layout.transition_m / ds))
    heading_edges = np.concatenate([[0.0], np.cumsum(kappa * ds)])
    heading_mid = 0.5 * (heading_edges[:-1] + heading_edges[1:])
    steps = ds * np.stack([np.cos(heading_mid), np.sin(heading_mid)], axis=1)
    xy = np.concatenate([[[0.0, 0.0]], np.cumsum(steps, axis=0)])
    return xy, ds, bounds


def _close_layout(layout: Layout, n: int) -> np.ndarray:
    """Segment lengths, with the straights changed by the least-norm amount that makes the lap close exactly."""
    lengths = np.array([seg.length_m for seg in layout.segments], dtype=np.float64)
    is_straight = np.array([seg.curvature_1pm == 0.0 for seg in layout.segments])
    idx = np.flatnonzero(is_straight)
    for _ in range(8):
        xy, _, bounds = _trace_layout(layout, lengths, n)
        gap = xy[-1] - xy[0]
        if np.hypot(*gap) < 1e-9:
            break
        # Lengthening straight k by 1 m moves the end point by its unit direction (exactly, away from the ramps).
        starts = np.searchsorted(np.linspace(0, lengths.sum(), n + 1), bounds[idx] + 0.5 * lengths[idx])
        direction = np.diff(xy, axis=0)[np.minimum(starts, n - 1)]
        direction /= np.hypot(direction[:, 0], direction[:, 1])[:, None]
        jac = direction.T  # (2, n_straights)
        lengths[idx] -= jac.T @ np.linalg.solve(jac @ jac.T, gap)
    return lengths


def build_layout(name: str, layout: Layout, spacing_m: float = DEFAULT_SPACING_M) -> Track:
    """Trace, close, resample and check a :class:`Layout`; raises :class:`TrackError` if it is not drivable."""
    if len(layout.segments) < 3 or not math.isclose(abs(layout.total_turn_rad), 2 * math.pi, abs_tol=1e-9):
        raise TrackError(
            f"{name}: the layout's turns add up to {math.degrees(layout.total_turn_rad):.6f} deg, not +-360 deg"
        )
    n_straights = sum(seg.curvature_1pm == 0.0 for seg in layout.segments)
    if n_straights < 2:
        raise TrackError(f"{name}: a layout needs at least two straights to be closed")
    step_m = 0.25
    n = round(layout.nominal_length_m / step_m)
    lengths = _close_layout(layout, n)
    short = [k for k, seg in enumerate(layout.segments) if seg.curvature_1pm == 0.0 and lengths[k] < 0]
    if short:
        raise TrackError(f"{name}: closing the layout needs a negative length for straight {short[0]}")
    xy, ds, bounds = _trace_layout(layout, lengths, n)
    # Widths: piecewise constant per segment (held until changed), blended over width_transition_m.
    wl, wr = [], []
    cur_l, cur_r = layout.width_left_m, layout.width_right_m
    for seg in layout.segments:
        cur_l = seg.width_left_m if seg.width_left_m is not None else cur_l
        cur_r = seg.width_right_m if seg.width_right_m is not None else cur_r
        wl.append(cur_l)
        wr.append(cur_r)
    cell = np.clip(np.searchsorted(bounds, (np.arange(n) + 0.5) * ds, side="right") - 1, 0, len(wl) - 1)
    blend = round(layout.width_transition_m / ds)
    width_left = _box_filter_periodic(np.asarray(wl)[cell], blend)
    width_right = _box_filter_periodic(np.asarray(wr)[cell], blend)
    # Hand the spline points 2 m apart: the traced curve has continuous curvature, so the interpolating spline
    # follows it to within a millimetre (0.6 mm in the technical track's hairpins).
    stride = max(1, round(2.0 / ds))
    pts = xy[:-1][::stride]
    track = Track.from_centre_line(name, pts, width_left[::stride], width_right[::stride], spacing_m=spacing_m)
    track = track.with_trimmed_walls()
    validate_track(track, name)
    return track


EXPRESSWAY = Layout(
    description=(
        "An original walled city-expressway loop in the spirit of GT Sport's Tokyo Expressway Central Outer Loop: "
        "driven clockwise, long elevated straights, tight 90-degree junction corners, a chicane and fast sweepers."
    ),
    width_left_m=6.0,
    width_right_m=6.0,
    transition_m=18.0,
    segments=(
        straight(865),  # main straight, east
        right(32, 90),  # tight junction corner
        straight(140),
        left(45, 90),
        straight(165),
        right(40, 90, width_m=(6.5, 6.5)),
        straight(265),
        left(300, 20),  # fast kink
        right(300, 20),
        straight(135),
        right(140, 90),  # long sweeper
        straight(695, width_m=(6.0, 6.0)),  # back straight, west
        left(30, 35, width_m=(5.5, 5.5)),  # chicane
        right(30, 70),
        left(30, 35),
        straight(315, width_m=(6.0, 6.0)),
        right(35, 90),
        straight(415),
        left(200, 30),  # sweepers
        right(200, 30),
        straight(315),
        right(30, 90),
        straight(95),
    ),
)

FLOWING = Layout(
    description="A wide, fast, flowing circuit of big-radius sweepers and esses, driven counter-clockwise.",
    width_left_m=9.0,
    width_right_m=9.0,
    transition_m=60.0,
    segments=(
        straight(848),  # main straight, east
        left(180, 80),
        straight(133),
        right(350, 40),  # esses
        left(250, 70),
        straight(313),
        left(120, 90, width_m=(10.0, 10.0)),  # the slowest corner
        straight(369, width_m=(9.0, 9.0)),
        right(300, 50),
        left(200, 80),
        straight(479, width_m=(8.0, 8.0)),
        left(150, 60),
        right(250, 40),
        left(220, 110, width_m=(9.0, 9.0)),
    ),
)

TECHNICAL = Layout(
    description="A tight, technical circuit: two hairpins, chicanes and short straights, driven clockwise.",
    width_left_m=5.0,
    width_right_m=5.0,
    transition_m=12.0,
    segments=(
        straight(478),  # main straight, east
        right(17, 180),  # hairpin
        straight(322),
        left(35, 90),
        straight(176),
        right(25, 90),
        straight(172),
        right(20, 40),  # chicane
        left(20, 40),
        straight(222),
        right(40, 90),
        straight(174),
        left(18, 45),  # chicane
        right(18, 90),
        left(18, 45),
        straight(224),
        right(16, 180, width_m=(5.5, 5.5)),  # hairpin
        straight(226, width_m=(5.0, 5.0)),
        left(30, 90),
        straight(128),
        left(25, 60),  # esses
        right(30, 60),
        straight(128),
    ),
)

#: The built-in circuits' descriptions, by name.
LAYOUTS: dict[str, Layout] = {"expressway": EXPRESSWAY, "flowing": FLOWING, "technical": TECHNICAL}
BUILTIN_TRACKS: tuple[str, ...] = tuple(LAYOUTS)


@functools.lru_cache(maxsize=32)
def _builtin_track(name: str, spacing_m: float) -> Track:
    return _freeze(build_layout(name, LAYOUTS[name], spacing_m))


# ---------------------------------------------------------------------------------------------- random tracks

#: Bounds every ``random:SEED`` track meets: lengths and widths of real circuits, no corner tighter than 12 m.
RANDOM_LENGTH_M = (2000.0, 6000.0)
RANDOM_WIDTH_M = (10.0, 16.0)
RANDOM_MAX_CURVATURE_1PM = 1.0 / 12.0
RANDOM_MAX_FOLD_RATIO = 0.7
#: Least gap (m) between the walls of two different parts of a random track, so that no two parts touch.
RANDOM_MIN_WALL_GAP_M = 8.0
#: Fewest corners (:func:`count_corners`) of a random track: fewer makes a featureless oval.
RANDOM_MIN_CORNERS = 5
_RANDOM_MAX_ATTEMPTS = 500


def _random_candidate(rng: np.random.Generator, name: str, spacing_m: float) -> Track:
    """Perturbed polar control points through a periodic spline: a low-order shape plus per-point jitter."""
    n_ctrl = int(rng.integers(12, 25))
    theta = (np.arange(n_ctrl) + rng.uniform(-0.3, 0.3, n_ctrl)) * (2 * np.pi / n_ctrl)
    radius = np.ones(n_ctrl)
    for order in (2, 3, 4):
        radius += rng.uniform(0.0, 0.2) * np.cos(order * theta + rng.uniform(0, 2 * np.pi))
    radius += rng.uniform(-0.3, 0.3, n_ctrl)
    xy = np.stack([radius * np.cos(theta), radius * np.sin(theta)], axis=1)
    perimeter = float(np.hypot(*(np.roll(xy, -1, axis=0) - xy).T).sum())
    target_length_m = rng.uniform(2400.0, 5600.0)
    xy *= target_length_m / perimeter
    total_width = rng.uniform(*RANDOM_WIDTH_M)
    # Each side's width varies slowly by up to 4 % of the total around half of it; the total stays constant.
    offset = rng.uniform(-0.08, 0.08, n_ctrl) * total_width
    width_left = 0.5 * total_width + 0.5 * offset
    width_right = 0.5 * total_width - 0.5 * offset
    return Track.from_centre_line(name, xy, width_left, width_right, spacing_m=spacing_m)


def _random_track_ok(track: Track) -> bool:
    from scipy.spatial import cKDTree

    total = track.width_left_m + track.width_right_m
    half = np.maximum(track.width_left_m, track.width_right_m)
    kappa = np.abs(track.curvature_1pm)
    if not RANDOM_LENGTH_M[0] <= track.length_m <= RANDOM_LENGTH_M[1]:
        return False
    if total.min() < RANDOM_WIDTH_M[0] or total.max() > RANDOM_WIDTH_M[1]:
        return False
    if kappa.max() > RANDOM_MAX_CURVATURE_1PM or (kappa * half).max() >= RANDOM_MAX_FOLD_RATIO:
        return False
    # Two parts of the track closer than the wall gap: points nearer than that in space but farther apart along
    # the track than the way round a half circle of that size.
    reach = float(total.max()) + RANDOM_MIN_WALL_GAP_M
    pairs = cKDTree(track.centre_xy_m).query_pairs(reach, output_type="ndarray")
    if len(pairs) and (_arc_separation_m(track, track.s_m[pairs[:, 0]], track.s_m[pairs[:, 1]]) > np.pi * reach).any():
        return False
    if count_corners(track) < RANDOM_MIN_CORNERS:
        return False
    try:
        validate_track(track)
    except TrackError:
        return False
    return True


@functools.lru_cache(maxsize=64)
def _random_track_cached(seed: int, spacing_m: float) -> Track:
    # A generator of its own per seed, derived with a fixed tag so that other users of the seed never collide.
    rng = np.random.default_rng(np.random.SeedSequence([0x7261636B, seed]))
    name = f"random:{seed}"
    for _ in range(_RANDOM_MAX_ATTEMPTS):
        track = _random_candidate(rng, name, spacing_m)
        if _random_track_ok(track):
            return _freeze(track)
    raise TrackError(f"{name}: no valid track in {_RANDOM_MAX_ATTEMPTS} attempts")  # pragma: no cover


def random_track(seed: int, spacing_m: float = DEFAULT_SPACING_M) -> Track:
    """The procedural track of ``seed`` (>= 0): deterministic, valid, 2-6 km long and 10-16 m wide."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise TrackError(f"random track seed must be a non-negative integer, got {seed!r}")
    return _random_track_cached(int(seed), float(spacing_m))


# ---------------------------------------------------------------------------------------------- the database


def _database_name(name: str) -> str:
    canonical = _DATABASE_BY_KEY.get(name.strip().lower())
    if canonical is None:
        raise TrackError(
            f"{name!r} is not a circuit of the racetrack-database; its circuits are: {', '.join(DATABASE_TRACKS)}"
        )
    return canonical


@functools.lru_cache(maxsize=32)
def _database_track(name: str, spacing_m: float) -> Track:
    return _freeze(load_csv_track(DATABASE_DIR / "tracks" / f"{name}.csv", spacing_m))


def reference_racing_line(name: str) -> np.ndarray:
    """The racetrack-database's own minimum-curvature race line of circuit ``name`` (any case): (k, 2) x, y in m,
    closed (the last point does not repeat the first), in the frame of the circuit's centre line."""
    path = DATABASE_DIR / "racelines" / f"{_database_name(name)}.csv"
    rows = np.loadtxt(path, delimiter=",", comments="#", dtype=np.float64, ndmin=2)
    if rows.shape[1] != 2 or not np.isfinite(rows).all():
        raise TrackError(f"{path}: expected rows of 2 finite numbers x_m,y_m")
    return rows


# ---------------------------------------------------------------------------------------------- entry point


def _freeze(track: Track) -> Track:
    """Make a cached track's arrays read-only: one instance is shared by every caller."""
    for value in vars(track).values():
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
    return track


def load_track(spec: str | os.PathLike, spacing_m: float = DEFAULT_SPACING_M) -> Track:
    """A track from a built-in name (:data:`BUILTIN_TRACKS`), a racetrack-database circuit (:data:`DATABASE_TRACKS`,
    any case), ``random:SEED`` or a racetrack-database CSV path.

    Built-in, database and random tracks are cached (the same object is returned for the same spec and spacing; its
    arrays are read-only). CSV paths are read every time.
    """
    if isinstance(spec, os.PathLike):
        return load_csv_track(spec, spacing_m)
    if not isinstance(spec, str):
        raise TrackError(f"a track is a name, 'random:SEED' or a CSV path, got {type(spec).__name__}")
    key = spec.strip()
    if key.lower() in LAYOUTS:
        return _builtin_track(key.lower(), float(spacing_m))
    if key.lower().startswith("random:"):
        text = key.split(":", 1)[1].strip()
        if not text.isdigit():
            raise TrackError(f"{spec!r}: SEED in 'random:SEED' must be a non-negative integer")
        return random_track(int(text), spacing_m)
    if key.lower() in _DATABASE_BY_KEY:
        return _database_track(_DATABASE_BY_KEY[key.lower()], float(spacing_m))
    if key.lower().endswith(".csv") or os.sep in key or Path(key).is_file():
        return load_csv_track(key, spacing_m)
    raise TrackError(
        f"unknown track {spec!r}: use a built-in track ({', '.join(BUILTIN_TRACKS)}), a racetrack-database circuit "
        f"({', '.join(DATABASE_TRACKS)}), 'random:SEED' or the path of a racetrack-database CSV file"
    )


# ---------------------------------------------------------------------------------------------- summaries


def count_corners(
    track: Track, min_curvature_1pm: float = 1 / 250, min_turn_rad: float = 0.35, max_gap_m: float = 15.0
) -> int:
    """Number of corners: runs of one sign of curvature above ``min_curvature_1pm`` turning by ``min_turn_rad``.

    Runs of one sign separated by less than ``max_gap_m`` of straighter track are one corner (a double apex); a
    change of sign always starts a new corner, so a chicane counts as its parts.
    """
    kappa = track.curvature_1pm
    sign = np.where(kappa > min_curvature_1pm, 1, np.where(kappa < -min_curvature_1pm, -1, 0))
    change = np.flatnonzero(sign != np.roll(sign, 1))
    if len(change) == 0:
        return int(sign[0] != 0 and abs(kappa.sum() * track.spacing_m) >= min_turn_rad)
    # Runs [sign, length in m, turn in rad], listed from a change of sign on so that none wraps round the lap.
    order = np.roll(np.arange(len(kappa)), -change[0])
    edges = np.append(change - change[0], len(kappa))
    turns = np.add.reduceat(kappa[order], edges[:-1]) * track.spacing_m
    runs = [
        [int(sign[order[a]]), (b - a) * track.spacing_m, float(t)]
        for a, b, t in zip(edges[:-1], edges[1:], turns, strict=True)
    ]
    # Fold "corner, short gap, corner of the same sign" into one corner (cyclically) until none is left.
    k = 0
    while k < len(runs) and len(runs) >= 3:
        before, gap, after = runs[k - 1], runs[k], runs[(k + 1) % len(runs)]
        if gap[0] == 0 and gap[1] < max_gap_m and before[0] != 0 and before[0] == after[0]:
            before[1] += gap[1] + after[1]
            before[2] += gap[2] + after[2]
            for r in sorted({k, (k + 1) % len(runs)}, reverse=True):
                runs.pop(r)
            k = 0
        else:
            k += 1
    return sum(1 for sgn, _, turn in runs if sgn != 0 and abs(turn) >= min_turn_rad)


def track_summary(track: Track) -> dict:
    """Figures for ``vision-rl tracks --json``: name, length_m, min_width_m (wall to wall), corners and
    wall_trim_m (the largest cut of a wall that would have folded, 0 for none)."""
    return {
        "name": track.name,
        "length_m": round(float(track.length_m), 1),
        "min_width_m": round(float(track.min_width_m), 2),
        "corners": count_corners(track),
        "wall_trim_m": round(float(track.wall_trim_m), 2),
    }
