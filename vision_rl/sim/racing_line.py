"""Minimum-curvature racing line: lateral offsets of the centre line that minimise the summed squared curvature.

Quadratic programs on the centre line's samples, the offsets bounded by the walls less a margin. The curvature
models (:data:`CURVATURE_MODELS`) and how their lines and laps compare: docs/notes/sim.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from vision_rl.sim.track import Track, TrackError

if TYPE_CHECKING:  # scipy is imported where it is used: --help of every command stays light
    from scipy import sparse

#: Spacing of the optimisation grid. Heilmeier et al. optimise on 3 m steps (their ``stepsize_opt``); the track's own
#: 1 m samples cost 0.3-0.5 s on a 5-7 km track and follow the database's lines a little closer (Catalunya 0.95 m mean
#: distance against 1.01 m at 2 m and 1.11 m at 3 m, where the main straight leaves the objective nearly flat).
DEFAULT_OPT_STEP_M = 1.0

#: QPs solved: 1 is the Heilmeier et al. line; each further one re-linearises about the previous line (the third
#: moves the line by centimetres: 6 QPs change QSS laps by < 0.05 %).
DEFAULT_ITERATIONS = 3

#: How the QPs after the first linearise the curvature (docs/notes/sim.md).
CURVATURE_MODELS = ("iqp", "exact")

#: Interior-point iterations before falling back to OSQP; 20-30 are typical.
_IPM_MAX_ITER = 80


@dataclass(frozen=True, eq=False)
class RacingLine:
    """A closed racing line defined on the track's centre-line samples (all arrays have the track's n points).

    Parametrised by the centre line's arc length: sample i lies at ``track_s_m[i]`` with lateral offset
    ``lateral_m[i]``. ``s_m`` is the line's own arc length at each sample, so the line can be walked in either
    parametrisation (:meth:`line_s_at`, :meth:`track_s_at`).
    """

    track_s_m: np.ndarray
    """Centre-line arc length of each sample (the track's ``s_m``), m."""
    lateral_m: np.ndarray
    """Offset of the line from the centre line, positive to the left, m."""
    xy_m: np.ndarray
    """World position of each sample, (n, 2), m."""
    s_m: np.ndarray
    """Arc length along the racing line at each sample, starting at 0, m."""
    length_m: float
    """Length of the closed racing line, m."""
    curvature_1pm: np.ndarray
    """Curvature of the racing line at each sample, 1/m, positive turning left."""
    heading_rad: np.ndarray
    """Tangent direction of the racing line at each sample, rad, counter-clockwise from +x."""
    track_length_m: float
    """Length of the centre line the line is defined on, m."""
    margin_m: float
    """Distance kept from each wall (car half width plus safety), m."""

    @property
    def n_points(self) -> int:
        return len(self.s_m)

    @cached_property
    def _s_table(self) -> tuple[np.ndarray, np.ndarray]:
        # One extra sample closes the loop so that np.interp maps the last segment too.
        return np.append(self.track_s_m, self.track_length_m), np.append(self.s_m, self.length_m)

    def line_s_at(self, track_s_m: np.ndarray) -> np.ndarray:
        """Racing-line arc length (m, in [0, length_m)) of the line point at centre-line arc length ``track_s_m``."""
        ts, ls = self._s_table
        return np.interp(np.mod(track_s_m, self.track_length_m), ts, ls) % self.length_m

    def track_s_at(self, line_s_m: np.ndarray) -> np.ndarray:
        """Centre-line arc length (m) of the line point at racing-line arc length ``line_s_m`` (wrapped)."""
        ts, ls = self._s_table
        return np.interp(np.mod(line_s_m, self.length_m), ls, ts) % self.track_length_m

    def _interp_line(self, values: np.ndarray, line_s_m: np.ndarray) -> np.ndarray:
        s = np.mod(line_s_m, self.length_m)
        s_closed = np.append(self.s_m, self.length_m)
        if values.ndim == 1:
            return np.interp(s, s_closed, np.append(values, values[0]))
        closed = np.vstack([values, values[:1]])
        return np.stack([np.interp(s, s_closed, closed[:, k]) for k in range(values.shape[1])], axis=-1)

    def position_at(self, line_s_m: np.ndarray) -> np.ndarray:
        """World (x, y) in m, shape (n, 2), of the line at racing-line arc length ``line_s_m``."""
        return self._interp_line(self.xy_m, np.atleast_1d(line_s_m))

    def curvature_at(self, line_s_m: np.ndarray) -> np.ndarray:
        """Racing-line curvature (1/m) at racing-line arc length ``line_s_m``."""
        return self._interp_line(self.curvature_1pm, line_s_m)

    def lateral_at(self, track_s_m: np.ndarray) -> np.ndarray:
        """Offset of the line from the centre line (m, positive left) at centre-line arc length ``track_s_m``."""
        ts, _ = self._s_table
        return np.interp(np.mod(track_s_m, self.track_length_m), ts, np.append(self.lateral_m, self.lateral_m[0]))

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Plain arrays for an ``.npz`` cache (see :meth:`from_arrays`)."""
        return {
            "rl_track_s_m": self.track_s_m,
            "rl_lateral_m": self.lateral_m,
            "rl_xy_m": self.xy_m,
            "rl_s_m": self.s_m,
            "rl_curvature_1pm": self.curvature_1pm,
            "rl_heading_rad": self.heading_rad,
            "rl_scalars": np.array([self.length_m, self.track_length_m, self.margin_m]),
        }

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> RacingLine:
        length_m, track_length_m, margin_m = (float(v) for v in arrays["rl_scalars"])
        return cls(
            track_s_m=np.asarray(arrays["rl_track_s_m"]),
            lateral_m=np.asarray(arrays["rl_lateral_m"]),
            xy_m=np.asarray(arrays["rl_xy_m"]),
            s_m=np.asarray(arrays["rl_s_m"]),
            length_m=length_m,
            curvature_1pm=np.asarray(arrays["rl_curvature_1pm"]),
            heading_rad=np.asarray(arrays["rl_heading_rad"]),
            track_length_m=track_length_m,
            margin_m=margin_m,
        )


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _polyline_normals(track: Track) -> np.ndarray:
    """Left unit normals (n, 2) of the centre polyline from central differences.

    Not ``track.normal_left``: that comes from the spline's heading, which on some built tracks differs from the
    polyline's direction by a few mrad at isolated samples; offsets of several metres along it would put kinks of
    1-2 cm, curvature spikes of several 0.01 /m, into the line. The two normals differ by < 5 mrad, so a line
    point moves < 3 cm against the walls, well inside any margin.
    """
    chord = np.roll(track.centre_xy_m, -1, axis=0) - np.roll(track.centre_xy_m, 1, axis=0)
    chord /= np.hypot(chord[:, 0], chord[:, 1])[:, None]
    return np.stack([-chord[:, 1], chord[:, 0]], axis=1)


def _difference_weights(centre_xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Three-point weights (3, n) of the first and second derivative in arc length on a closed, unevenly spaced
    polyline: ``f'_i = sum_o w1[o, i] f_{i+o-1}``, likewise ``f''``. Exact for quadratics."""
    seg = np.roll(centre_xy_m, -1, axis=0) - centre_xy_m
    h_f = np.hypot(seg[:, 0], seg[:, 1])
    h_b = np.roll(h_f, 1)
    total = h_f + h_b
    w1 = np.stack([-h_f / (h_b * total), (h_f - h_b) / (h_f * h_b), h_b / (h_f * total)])
    w2 = np.stack([2.0 / (h_b * total), -2.0 / (h_f * h_b), 2.0 / (h_f * total)])
    return w1, w2


def _apply(weights: np.ndarray, values: np.ndarray) -> np.ndarray:
    return (
        weights[0][:, None] * np.roll(values, 1, axis=0)
        + weights[1][:, None] * values
        + weights[2][:, None] * np.roll(values, -1, axis=0)
    )


def _curvature_and_jacobian(
    centre_xy_m: np.ndarray,
    normal: np.ndarray,
    lateral_m: np.ndarray,
    held_tangent_xy_m: np.ndarray | None = None,
) -> tuple[np.ndarray, sparse.csc_matrix]:
    """Curvature of the periodic polyline ``p = c + a n`` from finite differences, and its Jacobian in ``a``.

    Derivatives are taken in the centre line's arc length (unevenly spaced samples allowed), so ``p'`` and ``p''``
    are linear in ``a`` and kappa_i depends only on a_{i-1}, a_i, a_{i+1}: the Jacobian is tridiagonal plus two
    corners. With ``held_tangent_xy_m`` the first derivative is held at that polyline's, ``kappa = cross(h', p'') /
    |h'|^3``, which is linear in ``a``: with the centre line, the formulation of Heilmeier et al. (2019), which
    ignores that offsets towards the inside of a corner shorten the path and so favours the inside of long corners;
    with the previous QP's line, the iterative QP.
    """
    from scipy import sparse

    n = len(lateral_m)
    w1, w2 = _difference_weights(centre_xy_m)
    p = centre_xy_m + normal * lateral_m[:, None]
    d2 = _apply(w2, p)
    d1 = _apply(w1, p if held_tangent_xy_m is None else held_tangent_xy_m)
    cross = _cross(d1, d2)
    speed2 = np.einsum("nk,nk->n", d1, d1)
    speed3 = speed2**1.5
    kappa = cross / speed3
    cols, vals = [], []
    for k, offset in enumerate((-1, 0, 1)):
        # Derivatives of p'_i and p''_i with respect to a_{i+offset}.
        n_j = np.roll(normal, -offset, axis=0)
        dd2 = w2[k][:, None] * n_j
        dvals = _cross(d1, dd2) / speed3
        if held_tangent_xy_m is None:
            dd1 = w1[k][:, None] * n_j
            dspeed2 = 2.0 * np.einsum("nk,nk->n", d1, dd1)
            dvals = dvals + _cross(dd1, d2) / speed3 - 1.5 * cross * dspeed2 / (speed3 * speed2)
        vals.append(dvals)
        cols.append((np.arange(n) + offset) % n)
    rows = np.tile(np.arange(n), 3)
    jac = sparse.csc_matrix((np.concatenate(vals), (rows, np.concatenate(cols))), shape=(n, n))
    return kappa, jac


def _max_step(value: np.ndarray, change: np.ndarray) -> float:
    """Largest step in [0, 1] that keeps ``value + step * change`` non-negative."""
    neg = change < 0.0
    with np.errstate(over="ignore"):  # a change of denormal size overflows its ratio to inf, which the min drops
        return float(min(1.0, np.min(-value[neg] / change[neg]))) if neg.any() else 1.0


def _newton_direction(
    lu, residual, slack_lo, slack_up, z_lo, z_up, target, corr_lo, corr_up
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One interior-point direction (dx, dz_lo, dz_up) for the complementarity target ``target`` (+ corrections)."""
    rhs = -residual + (target - corr_lo) / slack_lo - z_lo - (target - corr_up) / slack_up + z_up
    dx = lu.solve(rhs)
    dz_lo = (target - corr_lo - slack_lo * z_lo - z_lo * dx) / slack_lo
    dz_up = (target - corr_up - slack_up * z_up + z_up * dx) / slack_up
    return dx, dz_lo, dz_up


def _box_qp(
    hess: sparse.csc_matrix, grad: np.ndarray, lower: np.ndarray, upper: np.ndarray, tol: float = 1e-10
) -> np.ndarray | None:
    """argmin 0.5 x'Hx + g'x subject to lower < x < upper, by a Mehrotra predictor-corrector interior point.

    Every Newton system is H plus a diagonal, as sparse as H, so each iteration is one sparse LU (about 1 ms for
    3,000 offsets) and 20-30 iterations reach 1e-10. We use it rather than OSQP because minimum-curvature
    Hessians are fourth-difference operators, condition number ~n^4: OSQP 1.1 stalls there (100,000 ADMM
    iterations and no successful polish at 1e-6 on Monza, 2,895 offsets). Returns None when it does not converge.
    Requires lower < upper everywhere.
    """
    from scipy import sparse
    from scipy.sparse.linalg import splu

    n = len(grad)
    x = 0.5 * (lower + upper)
    slack_lo, slack_up = x - lower, upper - x
    z_lo, z_up = np.ones(n), np.ones(n)
    for _ in range(_IPM_MAX_ITER):
        residual = hess @ x + grad - z_lo + z_up
        mu = (slack_lo @ z_lo + slack_up @ z_up) / (2 * n)
        if mu < tol and np.abs(residual).max() < tol:
            return x
        lu = splu((hess + sparse.diags(z_lo / slack_lo + z_up / slack_up)).tocsc())
        state = (lu, residual, slack_lo, slack_up, z_lo, z_up)
        dx, dz_lo, dz_up = _newton_direction(*state, 0.0, 0.0, 0.0)
        a_p = min(_max_step(slack_lo, dx), _max_step(slack_up, -dx))
        a_d = min(_max_step(z_lo, dz_lo), _max_step(z_up, dz_up))
        mu_aff = ((slack_lo + a_p * dx) @ (z_lo + a_d * dz_lo) + (slack_up - a_p * dx) @ (z_up + a_d * dz_up)) / (2 * n)
        sigma = (mu_aff / mu) ** 3
        dx, dz_lo, dz_up = _newton_direction(*state, sigma * mu, dx * dz_lo, -dx * dz_up)
        # Slacks are updated, not recomputed from x: x - lower can round to 0 next to a bound.
        a_p = 0.99 * min(_max_step(slack_lo, dx), _max_step(slack_up, -dx))
        a_d = 0.99 * min(_max_step(z_lo, dz_lo), _max_step(z_up, dz_up))
        x = x + a_p * dx
        slack_lo, slack_up = slack_lo + a_p * dx, slack_up - a_p * dx
        z_lo, z_up = z_lo + a_d * dz_lo, z_up + a_d * dz_up
    return None


def _solve_qp(
    kappa0: np.ndarray, jac: sparse.csc_matrix, a0: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> np.ndarray:
    """argmin_a ||kappa0 + J (a - a0)||^2 subject to lower <= a <= upper (pinned where lower == upper)."""
    hess = (jac.T @ jac).tocsc()
    # Scale so that the Hessian's diagonal is about 1: the solvers' tolerances are absolute.
    scale = 1.0 / max(float(hess.diagonal().max()), 1e-30)
    grad = jac.T @ (kappa0 - jac @ a0) * scale
    hess = hess * scale
    free = upper - lower > 1e-9
    x = lower.copy()
    if not free.any():
        return x
    if free.all():
        sol = _box_qp(hess, grad, lower, upper)
    else:
        grad_free = grad[free] + hess[free][:, ~free] @ x[~free]
        sol = _box_qp(hess[free][:, free].tocsc(), grad_free, lower[free], upper[free])
    if sol is None:
        sol = _osqp(hess, grad, lower, upper)[free] if not free.all() else _osqp(hess, grad, lower, upper)
    x[free] = sol
    return np.clip(x, lower, upper)


def _osqp(hess: sparse.csc_matrix, grad: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Fallback solver: OSQP at a tolerance it reaches in well under a second (lines within a few mm)."""
    import osqp
    from scipy import sparse

    solver = osqp.OSQP()
    solver.setup(
        P=sparse.triu(hess, format="csc"),
        q=grad,
        A=sparse.identity(len(grad), format="csc"),
        l=lower,
        u=upper,
        eps_abs=1e-5,
        eps_rel=1e-5,
        max_iter=50000,
        verbose=False,
    )
    result = solver.solve()
    if result.x is None or not np.all(np.isfinite(result.x)):
        raise TrackError(f"racing line QP failed: {result.info.status}")
    return result.x


def optimise_racing_line(
    track: Track,
    margin_m: float,
    opt_step_m: float = DEFAULT_OPT_STEP_M,
    iterations: int = DEFAULT_ITERATIONS,
    curvature_model: str = "iqp",
) -> RacingLine:
    """Minimum-curvature racing line of ``track`` keeping ``margin_m`` from both walls.

    Where the track is narrower than twice the margin the line runs mid-way between the walls. The QP is solved on
    about every ``opt_step_m`` metres of centre line with bounds that hold over each sample's neighbourhood; the
    offsets are then interpolated onto every track sample by a periodic cubic spline and clipped to the bounds.
    """
    from scipy import interpolate
    from scipy.ndimage import maximum_filter1d, minimum_filter1d

    if margin_m < 0:
        raise ValueError(f"margin_m must be >= 0, got {margin_m}")
    if curvature_model not in CURVATURE_MODELS:
        raise ValueError(f"curvature_model must be one of {CURVATURE_MODELS}, got {curvature_model!r}")
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    lower_full = -track.width_right_m + margin_m
    upper_full = track.width_left_m - margin_m
    narrow = lower_full > upper_full
    mid = 0.5 * (track.width_left_m - track.width_right_m)
    lower_full = np.where(narrow, mid, lower_full)
    upper_full = np.where(narrow, mid, upper_full)

    n_opt = round(track.length_m / opt_step_m)
    if n_opt < 8:
        raise TrackError(f"track {track.name!r} too short for a racing line at {opt_step_m} m steps")
    n_opt = min(n_opt, track.n_points)
    idx = np.round(np.arange(n_opt) * (track.n_points / n_opt)).astype(np.int64) % track.n_points
    # The spline between optimisation samples follows the neighbouring bounds only roughly: make each sample's
    # bounds the tightest over the samples it stands for, so the interpolated line rarely needs clipping (a clip
    # would copy the walls' survey jitter into the line's curvature).
    window = 2 * int(np.ceil(track.n_points / n_opt)) + 1
    lower = np.minimum(maximum_filter1d(lower_full, window, mode="wrap")[idx], mid[idx])
    upper = np.maximum(minimum_filter1d(upper_full, window, mode="wrap")[idx], mid[idx])
    centre = track.centre_xy_m[idx]
    normal = _polyline_normals(track)[idx]
    a = np.clip(np.zeros(n_opt), lower, upper)
    for iteration in range(iterations):
        held = centre if iteration == 0 else None if curvature_model == "exact" else centre + normal * a[:, None]
        kappa0, jac = _curvature_and_jacobian(centre, normal, a, held)
        a = _solve_qp(kappa0, jac, a, lower, upper)

    # Interpolate in the polyline's own arc length, the parameter the offsets were optimised in.
    seg = np.roll(track.centre_xy_m, -1, axis=0) - track.centre_xy_m
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    spline = interpolate.CubicSpline(np.append(arc[idx], arc[-1]), np.append(a, a[0]), bc_type="periodic")
    lateral = np.clip(spline(arc[:-1]), lower_full, upper_full)
    return racing_line_from_offsets(track, lateral, margin_m)


def racing_line_from_offsets(track: Track, lateral_m: np.ndarray, margin_m: float = 0.0) -> RacingLine:
    """A :class:`RacingLine` through ``track.centre_xy_m + lateral_m * n`` (offsets per track sample), where ``n`` is
    the centre polyline's own left normal (see :func:`_polyline_normals`)."""
    lateral = np.asarray(lateral_m, dtype=np.float64)
    xy = track.centre_xy_m + _polyline_normals(track) * lateral[:, None]
    seg = np.roll(xy, -1, axis=0) - xy
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    s = np.concatenate([[0.0], np.cumsum(seg_len)[:-1]])
    d1 = np.roll(xy, -1, axis=0) - np.roll(xy, 1, axis=0)
    # Curvature of the circle through each sample and its neighbours (Menger): exact for any spacing, which a
    # finite difference in the sample index is not where the centre line's samples are unevenly spaced.
    back = np.roll(seg, 1, axis=0)
    kappa = 2.0 * _cross(back, seg) / (np.roll(seg_len, 1) * seg_len * np.hypot(d1[:, 0], d1[:, 1]))
    return RacingLine(
        track_s_m=track.s_m.copy(),
        lateral_m=lateral,
        xy_m=xy,
        s_m=s,
        length_m=float(seg_len.sum()),
        curvature_1pm=kappa,
        heading_rad=np.arctan2(d1[:, 1], d1[:, 0]),
        track_length_m=track.length_m,
        margin_m=float(margin_m),
    )


def lateral_distance_between_lines(ours_xy_m: np.ndarray, theirs_xy_m: np.ndarray) -> np.ndarray:
    """Distance (m) from each point of ``theirs_xy_m`` (k, 2) to the closed polyline ``ours_xy_m`` (n, 2)."""
    from scipy.spatial import cKDTree

    a = np.asarray(ours_xy_m, dtype=np.float64)
    b = np.roll(a, -1, axis=0)
    pts = np.asarray(theirs_xy_m, dtype=np.float64)
    _, nearest = cKDTree(a).query(pts)
    best = np.full(len(pts), np.inf)
    # The closest segment touches the nearest vertex: check the segment before and after it.
    for i0 in (nearest, (nearest - 1) % len(a)):
        seg = b[i0] - a[i0]
        t = np.clip(np.einsum("nk,nk->n", pts - a[i0], seg) / np.einsum("nk,nk->n", seg, seg), 0.0, 1.0)
        foot = a[i0] + seg * t[:, None]
        best = np.minimum(best, np.hypot(*(pts - foot).T))
    return best
