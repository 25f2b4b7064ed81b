"""Sensors against hand-computed geometry: a stadium (exact straights), a circle, and brute force on a real track."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from vision_rl.sim import sensors
from vision_rl.sim.sensors import (
    CURVATURE_AHEAD_M,
    DEDICATED_NAMES,
    DEDICATED_UNITS,
    EDGE_RAY_ANGLES_RAD,
    EDGE_RAY_RANGE_M,
    LIDAR_ANGLES_RAD,
    LIDAR_RANGE_M,
    TARGET_NAMES,
    TARGET_UNITS,
    WallRayCaster,
    car_corners,
    curvature_ahead_time,
    dedicated_features,
    environment_targets,
    lidar,
    state_curvature_ahead,
)
from vision_rl.sim.track import Track

TRACKS_DIR = Path(__file__).parents[2].parent / "shared/tracks/racetrack-database"

# Stadium: straights of length 2 * HALF_M along x at y = -R_M (driven +x) and y = +R_M (driven -x), joined by
# semicircles of radius R_M; counter-clockwise, so the left wall is the inner one.
R_M = 50.0
HALF_M = 100.0
WL_M = 5.0
WR_M = 7.0


def _stadium(half_m: float = HALF_M) -> Track:
    pts = []
    xs = np.arange(-half_m, half_m, 2.0)
    pts += [(x, -R_M) for x in xs]
    phi = np.arange(-np.pi / 2, np.pi / 2, 2.0 / R_M)
    pts += [(half_m + R_M * np.cos(p), R_M * np.sin(p)) for p in phi]
    pts += [(-x, R_M) for x in xs]
    pts += [(-half_m - R_M * np.cos(p), -R_M * np.sin(p)) for p in phi]
    return Track.from_centre_line("stadium", np.array(pts), WL_M, WR_M)


def _circle(radius_m: float = 100.0, wl_m: float = 6.0, wr_m: float = 8.0) -> Track:
    phi = np.linspace(0.0, 2.0 * np.pi, 300, endpoint=False)
    return Track.from_centre_line("circle", radius_m * np.stack([np.cos(phi), np.sin(phi)], axis=1), wl_m, wr_m)


@pytest.fixture(scope="module")
def stadium_caster() -> tuple[Track, WallRayCaster]:
    track = _stadium()
    return track, WallRayCaster(track)


@pytest.fixture(scope="module")
def circle_caster() -> tuple[Track, WallRayCaster]:
    track = _circle()
    return track, WallRayCaster(track)


def _brute_force(segs: np.ndarray, origin: np.ndarray, angles: np.ndarray, max_range: float) -> np.ndarray:
    """First hit of every ray on every segment, no grid: the reference for the caster."""
    d = np.stack([np.cos(angles), np.sin(angles)], axis=-1)[:, :, None, :]  # (n, k, 1, 2)
    a = segs[None, None, :, :2]
    e = segs[None, None, :, 2:] - a
    w = a - origin[:, None, None, :]
    denom = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / denom
        u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / denom
    ok = (denom != 0) & (t >= 0) & (u >= -1e-12) & (u <= 1 + 1e-12)
    return np.minimum(np.where(ok, t, np.inf).min(axis=2), max_range)


# ---------------------------------------------------------------------------------------------------- layouts
def test_names_units_and_angles() -> None:
    assert len(TARGET_NAMES) == len(TARGET_UNITS) == 27
    assert len(DEDICATED_NAMES) == len(DEDICATED_UNITS) == 11
    assert len(set(TARGET_NAMES)) == 27 and len(set(DEDICATED_NAMES)) == 11
    assert TARGET_UNITS[:16] == ("m",) * 16 and TARGET_UNITS[16] == "rad" and TARGET_UNITS[17:] == ("1/m",) * 10
    assert TARGET_NAMES[0] == "edge_distance_-90deg" and TARGET_NAMES[12] == "edge_distance_+90deg"
    assert DEDICATED_UNITS[9] == "1" and DEDICATED_UNITS[10] == "rad" and DEDICATED_NAMES[8] == "yaw_rate"
    np.testing.assert_allclose(np.rad2deg(EDGE_RAY_ANGLES_RAD), np.arange(-90, 91, 15))
    assert len(LIDAR_ANGLES_RAD) == 72 and LIDAR_RANGE_M == 20.0
    np.testing.assert_allclose(np.rad2deg(LIDAR_ANGLES_RAD[[0, -1]]), [-108.0, 108.0])
    np.testing.assert_allclose(np.diff(LIDAR_ANGLES_RAD), np.deg2rad(216.0 / 71.0))
    np.testing.assert_allclose(CURVATURE_AHEAD_M[[0, 1, -1]], [40.0, 40.0 + 80.0 / 9.0, 120.0])


def test_car_corners_hand_computed() -> None:
    c = car_corners(np.array([1.0]), np.array([2.0]), np.array([np.pi / 2]), 4.0, 2.0)
    np.testing.assert_allclose(c[0], [[2, 0], [2, 4], [0, 4], [0, 0]], atol=1e-12)
    x, y = c[0, :, 0], c[0, :, 1]
    assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) == pytest.approx(8.0)  # CCW: positive area


# ---------------------------------------------------------------------------------------------------- ray casting
def test_rays_on_straight_hand_computed(stadium_caster) -> None:
    _, caster = stadium_caster
    # Car 1.5 m left of the centre line on the lower straight, heading +x: left wall at y = -45, right at y = -57.
    y0 = -R_M + 1.5
    dist = caster.cast(np.array([[0.0, y0]]), EDGE_RAY_ANGLES_RAD[None, :], EDGE_RAY_RANGE_M)[0]
    assert dist[12] == pytest.approx(WL_M - 1.5, abs=1e-6)
    assert dist[0] == pytest.approx(WR_M + 1.5, abs=1e-6)
    sin = np.sin(EDGE_RAY_ANGLES_RAD)
    for j in [*range(0, 6), *range(7, 13)]:
        expected = (WL_M - 1.5) / sin[j] if sin[j] > 0 else (WR_M + 1.5) / -sin[j]
        assert expected * np.cos(EDGE_RAY_ANGLES_RAD[j]) < HALF_M - 10  # the hit lies on the straight
        assert dist[j] == pytest.approx(expected, abs=1e-6)
    # Straight ahead: the outer (right) wall of the far semicircle, radius R + WR around (HALF_M, 0).
    expected_ahead = HALF_M + np.sqrt((R_M + WR_M) ** 2 - y0**2)
    assert dist[6] == pytest.approx(expected_ahead, abs=0.05)
    # A shorter range caps the same ray.
    assert caster.cast(np.array([[0.0, y0]]), np.zeros((1, 1)), 30.0)[0, 0] == 30.0


def test_ray_beyond_range_reports_range() -> None:
    track = _stadium(half_m=400.0)
    dist = WallRayCaster(track).cast(np.array([[-300.0, -R_M]]), np.zeros((1, 1)), EDGE_RAY_RANGE_M)
    assert dist[0, 0] == EDGE_RAY_RANGE_M


def _circle_hit(p: np.ndarray, u: np.ndarray, radius: float) -> np.ndarray:
    b = np.einsum("nk,nk->n", p, u)
    disc = b**2 - (np.einsum("nk,nk->n", p, p) - radius**2)
    with np.errstate(invalid="ignore"):
        roots = np.stack([-b - np.sqrt(disc), -b + np.sqrt(disc)], axis=1)
    roots[~(roots > 0)] = np.inf
    return roots.min(axis=1)


def test_rays_on_circle_closed_form(circle_caster) -> None:
    _, caster = circle_caster
    inner, outer = 100.0 - 6.0, 100.0 + 8.0
    rng = np.random.default_rng(3)
    n = 40
    phi = rng.uniform(-np.pi, np.pi, n)
    r = rng.uniform(inner + 1.0, outer - 1.0, n)
    yaw = phi + np.pi / 2 + rng.normal(0.0, 0.4, n)
    p = r[:, None] * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    ang = yaw[:, None] + EDGE_RAY_ANGLES_RAD[None, :]
    got = caster.cast(p, ang, EDGE_RAY_RANGE_M)
    pp = np.repeat(p, 13, axis=0)
    uu = np.stack([np.cos(ang), np.sin(ang)], axis=-1).reshape(-1, 2)
    expected = np.minimum(np.minimum(_circle_hit(pp, uu, inner), _circle_hit(pp, uu, outer)), EDGE_RAY_RANGE_M)
    # Rays that graze the inner wall may hit or miss its inscribed polyline: compare only clear cases.
    closest = np.abs(pp[:, 0] * uu[:, 1] - pp[:, 1] * uu[:, 0])
    clear = np.abs(closest - inner) > 0.5
    assert clear.sum() > 400
    np.testing.assert_allclose(got.reshape(-1)[clear], expected[clear], atol=0.05)


@pytest.mark.parametrize("cell_size_m", [0.7, 4.0, 40.0])
def test_grid_matches_brute_force_on_real_track(cell_size_m) -> None:
    path = TRACKS_DIR / "tracks" / "Suzuka.csv"
    if not path.exists():
        pytest.skip(f"{path} not found")
    data = np.loadtxt(path, delimiter=",", comments="#")
    track = Track.from_centre_line("suzuka", data[:, :2], data[:, 3], data[:, 2], smoothing_m=0.05)
    caster = WallRayCaster(track, cell_size_m)
    rng = np.random.default_rng(0)
    s = rng.uniform(0, track.length_m, 25)
    on_track = track.position_at(s, rng.uniform(-3.0, 3.0, 25))
    # Origins outside the grid (its box is the walls' bounding box plus a cell), aimed at points of the track.
    far = track.centre_xy_m.mean(axis=0) + rng.uniform(1500.0, 3000.0, (8, 1)) * np.stack(
        [np.cos(np.arange(8) * np.pi / 4), np.sin(np.arange(8) * np.pi / 4)], axis=1
    )
    origin = np.vstack([on_track, far])
    ang = rng.uniform(-np.pi, np.pi, (len(origin), 24))
    ang[:, 0] = 0.0  # axis-aligned rays exercise the zero-direction branches
    ang[:, 1] = np.pi / 2
    aim = track.centre_xy_m[rng.integers(0, track.n_points, (8, 20))] - far[:, None, :]
    ang[-8:, 4:] = np.arctan2(aim[..., 1], aim[..., 0])
    for max_range in (20.0, 200.0, 1e4):
        got = caster.cast(origin, ang, max_range)
        np.testing.assert_allclose(got, _brute_force(caster.segments_m, origin, ang, max_range), rtol=0, atol=1e-9)
    assert np.all(caster.cast(origin[-8:], ang[-8:, 4:], 1e4) < 1e4)  # aimed at the track from outside: a hit


def test_ray_through_a_wall_vertex_hits_it(circle_caster) -> None:
    # A ray along +x through a vertex of the outer wall meets both adjacent segments exactly at their ends (u = 0
    # and u = 1); it must stop there and not slip through the joint.
    _, caster = circle_caster
    segs = caster.segments_m
    k = len(segs) // 2 + int(np.argmin(np.abs(np.arctan2(segs[len(segs) // 2 :, 1], segs[len(segs) // 2 :, 0]))))
    vx, vy = segs[k, 0], segs[k, 1]
    assert vx > 107.0  # the outer (right) wall of the counter-clockwise circle, near phi = 0
    d = caster.cast(np.array([[100.0, vy]]), np.zeros((1, 1)), 50.0)
    assert d[0, 0] == pytest.approx(vx - 100.0, abs=1e-9)


def test_cars_match_brute_force(circle_caster) -> None:
    _, caster = circle_caster
    rng = np.random.default_rng(7)
    m = 12
    phi = rng.uniform(0.0, 0.6, m)  # a pack on a 60 m arc, so that beams meet cars edge-on and corner-on
    r = rng.uniform(95.5, 106.5, m)
    yaw = phi + np.pi / 2 + rng.normal(0.0, 0.5, m)
    corners = car_corners(r * np.cos(phi), r * np.sin(phi), yaw, 4.5, 1.9)
    group = rng.integers(0, 2, m)
    got = lidar(caster, r * np.cos(phi), r * np.sin(phi), yaw, corners, group)
    ang = yaw[:, None] + LIDAR_ANGLES_RAD[None, :]
    origin = np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)
    expected = _brute_force(caster.segments_m, origin, ang, LIDAR_RANGE_M)
    car_segs = np.concatenate([corners, np.roll(corners, -1, axis=1)], axis=2)  # (m, 4, 4): x0, y0, x1, y1
    for i in range(m):
        others = [c for c in range(m) if c != i and group[c] == group[i]]
        if others:
            segs_i = car_segs[others].reshape(-1, 4)
            expected[i] = np.minimum(expected[i], _brute_force(segs_i, origin[i : i + 1], ang[i : i + 1], 20.0)[0])
    assert (expected < _brute_force(caster.segments_m, origin, ang, LIDAR_RANGE_M)).sum() > 50  # many car hits
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)


def test_wrap_angle_half_open_interval() -> None:
    np.testing.assert_allclose(
        sensors.wrap_angle(np.array([np.pi, -np.pi, 3 * np.pi, 0.5 - 4 * np.pi, -0.5])),
        [np.pi, np.pi, np.pi, 0.5, -0.5],
        atol=1e-12,
    )


def test_bad_input_raises(stadium_caster) -> None:
    track, caster = stadium_caster
    with pytest.raises(ValueError, match="cell_size_m"):
        WallRayCaster(track, 0.0)
    with pytest.raises(ValueError, match="angles_world_rad"):
        caster.cast(np.zeros((2, 2)), np.zeros((3, 4)), 10.0)
    with pytest.raises(ValueError, match="origin_xy_m"):
        caster.cast(np.zeros((2, 3)), np.zeros((2, 4)), 10.0)
    with pytest.raises(ValueError, match="car_corners_xy_m"):
        caster.cast(np.zeros((1, 2)), np.zeros((1, 4)), 10.0, np.zeros((1, 3, 2)))
    with pytest.raises(ValueError, match="ray_car_index"):
        caster.cast(np.zeros((1, 2)), np.zeros((1, 4)), 10.0, np.zeros((1, 4, 2)), ray_car_index=np.array([5]))


# ---------------------------------------------------------------------------------------------------- lidar
def test_lidar_sees_own_group_only_and_never_itself(stadium_caster) -> None:
    _, caster = stadium_caster
    length, width = 4.5, 1.8
    x = np.array([0.0, 10.0])
    y = np.full(2, -R_M)
    yaw = np.zeros(2)
    corners = car_corners(x, y, yaw, length, width)
    walls_only = lidar(caster, x, y, yaw)
    same = lidar(caster, x, y, yaw, corners, np.array([0, 0]))
    other = lidar(caster, x, y, yaw, corners, np.array([0, 1]))
    np.testing.assert_array_equal(other, walls_only)  # another group is invisible, and no car sees itself
    ahead = np.argsort(np.abs(LIDAR_ANGLES_RAD))[:2]  # the two beams at +-1.52 deg
    assert np.all(walls_only[0, ahead] == LIDAR_RANGE_M)
    np.testing.assert_allclose(same[0, ahead], (10.0 - length / 2) / np.cos(LIDAR_ANGLES_RAD[ahead]), atol=1e-9)
    # The car ahead sees the front face of the car behind in its rear-most beams only if they point backwards:
    # +-108 deg beams reach x = -20 cos(72 deg) = -6.2 m at most, so it is hit when within range.
    behind = [0, 71]
    exp_behind = (10.0 - length / 2) / np.abs(np.cos(LIDAR_ANGLES_RAD[behind]))
    hits = exp_behind < walls_only[1, behind]
    np.testing.assert_allclose(same[1, behind], np.where(hits, exp_behind, walls_only[1, behind]), atol=1e-9)
    # Only the beams that point at the other car change.
    changed = same != walls_only
    assert changed[0, ahead].all() and changed.sum() < 30
    # A single car with its own rectangle sees only walls.
    np.testing.assert_array_equal(lidar(caster, x[:1], y[:1], yaw[:1], corners[:1]), walls_only[:1])


def test_cast_ray_without_car_sees_its_group(stadium_caster) -> None:
    _, caster = stadium_caster
    corners = car_corners(np.array([10.0]), np.array([-R_M]), np.zeros(1), 4.0, 2.0)
    origin = np.array([[0.0, -R_M], [0.0, -R_M]])
    d = caster.cast(origin, np.zeros((2, 1)), 50.0, corners, np.array([3]), ray_group=np.array([3, 2]))
    np.testing.assert_allclose(d[:, 0], [8.0, 50.0])
    # A car whose centre is out of range but whose rear is within it is still seen.
    corners = car_corners(np.array([21.5]), np.array([-R_M]), np.zeros(1), 4.0, 2.0)
    assert caster.cast(origin[:1], np.zeros((1, 1)), 20.0, corners)[0, 0] == pytest.approx(19.5)


# ---------------------------------------------------------------------------------------------------- targets
def _targets(track: Track, caster: WallRayCaster, x, y, yaw) -> tuple[np.ndarray, np.ndarray]:
    x, y, yaw = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (x, y, yaw))
    proj = track.project(np.stack([x, y], axis=1))
    return environment_targets(track, caster, x, y, yaw, proj.s_m, proj.lateral_m), proj.lateral_m


def test_targets_on_straight(stadium_caster) -> None:
    track, caster = stadium_caster
    t, lateral = _targets(track, caster, 0.0, -R_M + 1.5, 0.2)
    t = t[0]
    assert t.shape == (27,)
    assert lateral[0] == pytest.approx(1.5, abs=1e-6)
    sin = np.sin(0.2 + EDGE_RAY_ANGLES_RAD)
    for j in range(13):
        expected = (WL_M - 1.5) / sin[j] if sin[j] > 0 else (WR_M + 1.5) / -sin[j]
        if expected * np.cos(0.2 + EDGE_RAY_ANGLES_RAD[j]) < HALF_M - 10:  # hit on the straight
            assert t[j] == pytest.approx(expected, abs=1e-6), TARGET_NAMES[j]
    assert t[13] == pytest.approx(WL_M - 1.5, abs=1e-6)
    assert t[14] == pytest.approx(WR_M + 1.5, abs=1e-6)
    assert t[15] == pytest.approx(1.5, abs=1e-6)
    assert t[16] == pytest.approx(0.2, abs=1e-9)  # yawed left of the tangent: positive
    # Curvature: the straight ends 100 m ahead, then the left semicircle (1/R).
    ahead = CURVATURE_AHEAD_M
    np.testing.assert_allclose(t[17:][ahead < HALF_M - 8], 0.0, atol=1e-4)
    np.testing.assert_allclose(t[17:][ahead > HALF_M + 6], 1.0 / R_M, atol=1e-3)
    # Yawed right: negative heading angle.
    assert _targets(track, caster, 0.0, -R_M, -0.3)[0][0, 16] == pytest.approx(-0.3, abs=1e-9)


def test_min_wall_distances_are_euclidean_outside_the_track(stadium_caster) -> None:
    track, caster = stadium_caster
    # 1 m beyond the left wall: w - d would say -1, the distance is +1.
    t, _ = _targets(track, caster, 20.0, -R_M + WL_M + 1.0, 0.0)
    assert t[0, 13] == pytest.approx(1.0, abs=1e-6)
    assert t[0, 14] == pytest.approx(WL_M + 1.0 + WR_M, abs=1e-6)


def test_targets_on_circle(circle_caster) -> None:
    track, caster = circle_caster
    phi = np.array([0.3, np.pi / 2, -2.0])
    r = np.array([97.0, 100.0, 105.0])
    # At phi = pi/2 the tangent is pi: yaw = -pi + 0.1 must read +0.1, not 0.1 - 2 pi.
    yaw = np.array([0.3 + np.pi / 2 + 0.25 + 2 * np.pi, -np.pi + 0.1, -2.0 + np.pi / 2 - 0.2])
    t, lateral = _targets(track, caster, r * np.cos(phi), r * np.sin(phi), yaw)
    np.testing.assert_allclose(lateral, 100.0 - r, atol=1e-3)
    np.testing.assert_allclose(t[:, 13], r - 94.0, atol=5e-3)
    np.testing.assert_allclose(t[:, 14], 108.0 - r, atol=5e-3)
    np.testing.assert_allclose(t[:, 15], lateral)
    np.testing.assert_allclose(t[:, 16], [0.25, 0.1, -0.2], atol=1e-3)
    np.testing.assert_allclose(t[:, 17:], 1.0 / 100.0, rtol=1e-3)


def test_curvature_ahead_in_time(stadium_caster, circle_caster) -> None:
    track, _ = circle_caster
    np.testing.assert_allclose(state_curvature_ahead(track, np.array([0.0, 300.0]), np.array([30.0, 0.0])), 0.01, 1e-3)
    track, _ = stadium_caster
    s = track.project(np.array([[0.0, -R_M]])).s_m
    k = state_curvature_ahead(track, s, np.array([50.0]))[0]  # 50 .. 140 m ahead; the straight ends at 100 m
    assert k.shape == (10,)
    np.testing.assert_allclose(k[:3], 0.0, atol=1e-4)  # 50, 60, 70 m
    np.testing.assert_allclose(k[-3:], 1.0 / R_M, atol=1e-3)  # 120, 130, 140 m
    np.testing.assert_allclose(state_curvature_ahead(track, s, np.array([-50.0])), 0.0, atol=1e-4)
    k14 = curvature_ahead_time(track, s, np.array([50.0]), sensors.OVERTAKING_CURVATURE_TIMES_S)
    assert k14.shape == (1, 14) and abs(k14[0, 0]) < 1e-4 and k14[0, -1] == pytest.approx(1.0 / R_M, abs=1e-3)


# ---------------------------------------------------------------------------------------------------- dedicated
def test_dedicated_features_copy_fields() -> None:
    state = SimpleNamespace(
        x_m=np.array([9.0, 9.0]),
        y_m=np.array([9.0, 9.0]),
        yaw_rad=np.array([9.0, 9.0]),
        vx_mps=np.array([30.0, -1.0]),
        vy_mps=np.array([-0.5, 0.2]),
        yaw_rate_radps=np.array([0.3, -0.4]),
        steer_rad=np.array([9.0, 9.0]),
        omega=np.array([9.0, 9.0]),
        ax_mps2=np.array([2.0, -8.0]),
        ay_mps2=np.array([-3.0, 4.0]),
        roll_rad=np.array([9.0, 9.0]),
        pitch_rad=np.array([9.0, 9.0]),
        roll_rate_radps=np.array([0.01, -0.02]),
        pitch_rate_radps=np.array([-0.03, 0.04]),
    )
    f = dedicated_features(state, np.array([False, True]), np.array([0.1, -0.2]))
    expected = [
        [30.0, -0.5, 0.0, 2.0, -3.0, 0.0, 0.01, -0.03, 0.3, 0.0, 0.1],
        [-1.0, 0.2, 0.0, -8.0, 4.0, 0.0, -0.02, 0.04, -0.4, 1.0, -0.2],
    ]
    np.testing.assert_array_equal(f, expected)
    # The simulator's own VehicleState carries the same fields.
    from vision_rl.sim.vehicle import VehicleState

    real = VehicleState(**{k: getattr(state, k) for k in VehicleState._fields})
    np.testing.assert_array_equal(dedicated_features(real, np.array([False, True]), np.array([0.1, -0.2])), expected)


def test_bench_smoke() -> None:
    out = sensors.bench_sensors(n_cars=4, seed=1, repeats=2, track=_circle())
    assert out["lidar_ms_4_cars"] > 0 and out["targets_ms_4_cars"] > 0


def test_non_finite_pose_reads_nan_and_returns(stadium_caster) -> None:
    _, caster = stadium_caster
    d = caster.cast(np.array([[np.nan, 0.0], [0.0, -R_M], [0.0, np.inf]]), np.array([[0.0], [np.nan], [1.0]]), 20.0)
    assert np.isnan(d).all()
