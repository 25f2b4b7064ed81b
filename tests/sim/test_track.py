"""The Track class against hand-computed geometry: circles, a stadium, a hairpin with a wide and a narrow side."""

from __future__ import annotations

import numpy as np
import pytest

from vision_rl.sim.track import Track


def circle_track(radius_m: float = 100.0, clockwise: bool = False, width_m: float = 5.0) -> Track:
    """A circle about the origin starting at (R, 0): s = 0 there, heading +y (ccw) or -y (cw)."""
    a = np.linspace(0.0, 2 * np.pi, 360, endpoint=False)
    a = -a if clockwise else a
    return Track.from_centre_line("circle", radius_m * np.stack([np.cos(a), np.sin(a)], axis=1), width_m, width_m)


def wobbly_track() -> Track:
    """A closed curve with bends of both signs and radii down to about 25 m, 6 m to each wall."""
    a = np.linspace(0.0, 2 * np.pi, 900, endpoint=False)
    r = 300.0 + 60.0 * np.cos(3 * a) + 25.0 * np.sin(7 * a)
    return Track.from_centre_line("wobbly", np.stack([r * np.cos(a), r * np.sin(a)], axis=1), 6.0, 6.0)


def hairpin_track() -> tuple[Track, float]:
    """Clockwise paperclip: upper straight along +x at y = 0, hairpins of radius 10 m, lower straight at y = -20.

    The upper straight's right side (towards the lower straight) is 12 m wide in its middle and tapers to 4 m
    before the hairpins; everything else is 4 m. A car 11 m right of the upper straight is inside its own walls
    but 9 m from the lower straight's centre line. Returns the track and the s of the upper straight's middle.
    """
    straight_m, radius_m, step_m = 300.0, 10.0, 1.0
    x = np.arange(0.0, straight_m, step_m)
    upper = np.stack([x, np.zeros_like(x)], axis=1)
    a = np.linspace(np.pi / 2, -np.pi / 2, int(np.pi * radius_m / step_m), endpoint=False)
    bend_right = np.stack([straight_m + radius_m * np.cos(a), -radius_m + radius_m * np.sin(a)], axis=1)
    lower = np.stack([straight_m - x, np.full_like(x, -2 * radius_m)], axis=1)
    bend_left = np.stack([radius_m * np.cos(a + np.pi), -radius_m + radius_m * np.sin(a + np.pi)], axis=1)
    xy = np.vstack([upper, bend_right, lower, bend_left])
    taper = np.clip((np.minimum(x, straight_m - x) - 40.0) / 60.0, 0.0, 1.0)
    width_right = np.concatenate([4.0 + 8.0 * taper, np.full(len(xy) - len(x), 4.0)])
    return Track.from_centre_line("hairpin", xy, 4.0, width_right), straight_m / 2


# ---------------------------------------------------------------------------------------------- construction


def test_circle_length_and_curvature_signs():
    ccw, cw = circle_track(), circle_track(clockwise=True)
    for track in (ccw, cw):
        assert track.length_m == pytest.approx(2 * np.pi * 100.0, rel=1e-4)
        assert track.spacing_m == pytest.approx(1.0, rel=0.01)
    # Left-turning circle: +1/R everywhere; clockwise: -1/R.
    np.testing.assert_allclose(ccw.curvature_1pm, 0.01, rtol=1e-3)
    np.testing.assert_allclose(cw.curvature_1pm, -0.01, rtol=1e-3)
    np.testing.assert_allclose(ccw.curvature_at(np.array([-5.0, 0.0, 123.4, 1e4])), 0.01, rtol=1e-3)
    # s = 0 at the first input point, heading +y there for the ccw circle.
    np.testing.assert_allclose(ccw.centre_xy_m[0], [100.0, 0.0], atol=1e-9)
    assert ccw.heading_rad[0] == pytest.approx(np.pi / 2, abs=1e-4)
    assert cw.heading_rad[0] == pytest.approx(-np.pi / 2, abs=1e-4)


def test_walls_offset_along_left_normal():
    track = circle_track(width_m=5.0)
    # Left of a ccw circle is its inside: the left wall is at radius 95 m, the right one at 105 m.
    np.testing.assert_allclose(np.hypot(*track.left_wall_xy_m.T), 95.0, atol=1e-3)
    np.testing.assert_allclose(np.hypot(*track.right_wall_xy_m.T), 105.0, atol=1e-3)
    cross = track.tangent[:, 0] * track.normal_left[:, 1] - track.tangent[:, 1] * track.normal_left[:, 0]
    np.testing.assert_allclose(cross, 1.0)
    segs = track.wall_segments()
    assert segs.shape == (2 * track.n_points, 4)
    np.testing.assert_allclose(segs[: track.n_points, 2:], np.roll(track.left_wall_xy_m, -1, axis=0))
    np.testing.assert_allclose(segs[track.n_points :, :2], track.right_wall_xy_m)
    assert track.min_width_m == pytest.approx(10.0)


def test_widths_interpolate_per_input_point():
    track, s_mid = hairpin_track()
    assert track.width_right_at(np.array([s_mid]))[0] == pytest.approx(12.0, abs=1e-6)
    assert track.width_right_at(np.array([5.0, 400.0]))[0] == pytest.approx(4.0, abs=1e-6)
    np.testing.assert_allclose(track.width_left_at(np.array([0.0, s_mid, 500.0])), 4.0)


def test_geometry_hash_is_stable_and_sees_widths():
    assert circle_track().geometry_hash == circle_track().geometry_hash
    assert circle_track(width_m=5.0).geometry_hash != circle_track(width_m=5.5).geometry_hash
    assert circle_track().geometry_hash != circle_track(clockwise=True).geometry_hash


# ---------------------------------------------------------------------------------------------- projection


def test_projection_on_circle_signs():
    track = circle_track()
    # A point 2 m inside a ccw circle is 2 m to the left; outside is to the right.
    angle = np.array([0.3, 2.0, 4.0])
    xy_in = 98.0 * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    xy_out = 103.0 * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    p_in, p_out = track.project(xy_in), track.project(xy_out)
    np.testing.assert_allclose(p_in.lateral_m, 2.0, atol=2e-3)
    np.testing.assert_allclose(p_out.lateral_m, -3.0, atol=2e-3)
    np.testing.assert_allclose(p_in.s_m, 100.0 * angle, atol=0.02)
    np.testing.assert_allclose(np.angle(np.exp(1j * (p_in.heading_rad - angle - np.pi / 2))), 0.0, atol=1e-3)


@pytest.mark.parametrize("warm", [False, True])
def test_projection_and_progress_across_the_line(warm):
    track = circle_track()
    length = track.length_m
    before = 100.0 * np.array([[np.cos(-0.005), np.sin(-0.005)]])  # 0.5 m before the line
    after = 100.0 * np.array([[np.cos(0.005), np.sin(0.005)]])  # 0.5 m after it
    p_before = track.project(before, np.array([length - 0.6]) if warm else None)
    p_after = track.project(after, np.array([length - 0.5]) if warm else None)
    assert p_before.s_m[0] == pytest.approx(length - 0.5, abs=0.01)
    assert p_after.s_m[0] == pytest.approx(0.5, abs=0.01)
    # Forwards across the line: +1 m, not -(L - 1); backwards: -1 m.
    assert track.progress_delta(p_before.s_m, p_after.s_m)[0] == pytest.approx(1.0, abs=0.02)
    assert track.progress_delta(p_after.s_m, p_before.s_m)[0] == pytest.approx(-1.0, abs=0.02)
    # Driving backwards across the line, warm-started from the far side.
    p_back = track.project(before, np.array([0.5]) if warm else None)
    assert p_back.s_m[0] == pytest.approx(length - 0.5, abs=0.01)
    assert 0.0 <= p_back.s_m[0] < length


def test_progress_delta_wraps_to_half_a_lap():
    track = circle_track()
    length = track.length_m
    s_prev = np.array([length - 3.0, 2.0, 10.0, 10.0, 0.0])
    s_now = np.array([4.0, length - 1.0, 10.0 + 0.4 * length, 10.0 - 0.4 * length, 0.0])
    np.testing.assert_allclose(track.progress_delta(s_prev, s_now), [7.0, -3.0, 0.4 * length, -0.4 * length, 0.0])


def test_driving_a_lap_sums_to_its_length():
    track = wobbly_track()
    s = np.arange(0.0, 2 * track.length_m, 2.7)
    xy = track.position_at(s, 1.5 * np.sin(s / 40.0))
    s_proj, total = np.array([0.0]), 0.0
    for p in xy:
        new = track.project(p[None, :], s_proj).s_m
        total += track.progress_delta(s_proj, new)[0]
        s_proj = new
    assert total == pytest.approx(s[-1], abs=0.2)
    # Backwards is negative by the same amount.
    total_back = 0.0
    for p in xy[::-1]:
        new = track.project(p[None, :], s_proj).s_m
        total_back += track.progress_delta(s_proj, new)[0]
        s_proj = new
    assert total_back == pytest.approx(-s[-1], abs=0.2)


def test_position_project_round_trip():
    track = wobbly_track()
    rng = np.random.default_rng(7)
    s = rng.uniform(-100.0, track.length_m + 100.0, 5000)
    lateral = rng.uniform(-6.0, 6.0, s.size)
    xy = track.position_at(s, lateral)
    kappa = np.abs(track.curvature_at(s))
    # position_at offsets along the interpolated normal, project drops a perpendicular to the chord: they agree
    # to |d| |kappa| ds / 2 in s (the normals' spread over one sample) and to millimetres in d.
    s_tol = 0.6 * np.abs(lateral) * kappa * track.spacing_m + 1e-3
    for guess in (None, s + rng.uniform(-4.0, 4.0, s.size)):
        p = track.project(xy, guess)
        assert np.all(np.abs(track.progress_delta(s, p.s_m)) <= s_tol)
        np.testing.assert_allclose(p.lateral_m, lateral, atol=3e-3)
        assert np.all((p.s_m >= 0) & (p.s_m < track.length_m))
    # On a straight both are exact.
    track, s_mid = hairpin_track()
    s = s_mid + rng.uniform(-40.0, 40.0, 100)
    p = track.project(track.position_at(s, rng.uniform(-10.0, 3.0, 100)), s)
    np.testing.assert_allclose(p.s_m, s, atol=1e-6)


def test_position_at_broadcasts_scalar_lateral():
    track = circle_track()
    xy = track.position_at(np.array([0.0, 100.0 * np.pi / 2]), 2.0)
    np.testing.assert_allclose(xy, [[98.0, 0.0], [0.0, 98.0]], atol=1e-3)


def test_heading_is_continuous_across_the_line():
    track = circle_track()
    h = track.heading_at(np.array([track.length_m - 1e-6, 0.0, 1e-6, track.length_m]))
    np.testing.assert_allclose(np.angle(np.exp(1j * (h - np.pi / 2))), 0.0, atol=1e-4)
    assert np.all((h > -np.pi) & (h <= np.pi))


def test_warm_start_stays_on_its_own_side_of_a_hairpin():
    track, s_mid = hairpin_track()
    # 11 m right of the upper straight's middle: inside its 12 m, but only 9 m from the lower straight's centre.
    car = np.array([[s_mid, -11.0]])
    cold = track.project(car)
    assert cold.s_m[0] > track.length_m / 2  # global nearest point is on the lower straight ...
    assert cold.lateral_m[0] == pytest.approx(-9.0, abs=1e-6)
    warm = track.project(car, np.array([s_mid - 3.0]))
    assert warm.s_m[0] == pytest.approx(s_mid, abs=0.02)  # ... the warm start keeps the car on the upper one
    assert warm.lateral_m[0] == pytest.approx(-11.0, abs=1e-6)
    # A car driving along there, projected step by step, never jumps across.
    xs = np.arange(s_mid - 50.0, s_mid + 50.0, 0.8)
    s_guess = np.array([xs[0]])
    for x in xs:
        p = track.project(np.array([[x, -11.0]]), s_guess)
        assert p.s_m[0] == pytest.approx(x, abs=0.02)
        s_guess = p.s_m
    # A scalar guess broadcasts over the points.
    p = track.project(np.array([[s_mid, -11.0], [s_mid + 1.0, -11.0]]), s_mid)
    np.testing.assert_allclose(p.s_m, [s_mid, s_mid + 1.0], atol=0.02)


def test_bad_warm_start_still_finds_the_nearest_point():
    track = circle_track()
    xy = 100.0 * np.array([[np.cos(1.0), np.sin(1.0)], [np.cos(4.0), np.sin(4.0)]])
    p = track.project(xy, np.array([300.0, 10.0]))  # both guesses 200 m or more off, on a track with one minimum
    np.testing.assert_allclose(p.s_m, [100.0, 400.0], atol=0.02)
