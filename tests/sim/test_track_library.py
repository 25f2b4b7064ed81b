"""Track library: built-in layouts meet their specs, random tracks are valid and deterministic, CSV files load or
fail with an error naming the file and the line, corners are counted as a driver would count them."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from vision_rl.sim import track_library as tl
from vision_rl.sim.sensors import WallRayCaster
from vision_rl.sim.track import WALL_TRIM_SHARE, Track, TrackError
from vision_rl.sim.track_library import (
    BUILTIN_TRACKS,
    DATABASE_DIR,
    DATABASE_TRACKS,
    DEFAULT_TRACK,
    Layout,
    build_layout,
    count_corners,
    find_crossings,
    left,
    load_track,
    reference_racing_line,
    right,
    straight,
    track_summary,
    validate_track,
)

HEADER = "# x_m,y_m,w_tr_right_m,w_tr_left_m\n"


def real_track_path(name: str) -> Path:
    """A circuit's CSV in the racetrack-database shipped as package data."""
    return DATABASE_DIR / "tracks" / f"{name}.csv"


def hairpin_layout(radius_m: float = 8.0, half_width_m: float = 10.0) -> Layout:
    """A 160 deg left hairpin of ``radius_m`` between two 600 m straights, ``half_width_m`` to each wall: the
    inside wall's offset exceeds the radius, and round the bend the two legs' inside walls would cross."""
    return Layout(
        segments=(straight(600), left(radius_m, 160), straight(600), left(80, 100), straight(66), left(80, 100)),
        width_left_m=half_width_m,
        width_right_m=half_width_m,
        transition_m=4.0,
    )


def wall_fold_ratio(track: Track) -> float:
    """Largest width-on-the-inside / radius: >= 1 is a folded wall."""
    k = track.curvature_1pm
    return float(max((k * track.width_left_m).max(), (-k * track.width_right_m).max()))


def crossing_count(track: Track) -> int:
    centre = tl._segment_crossings([track.centre_xy_m])[0]
    walls = tl._segment_crossings([track.left_wall_xy_m, track.right_wall_xy_m])[0]
    return len(centre) + len(walls)


# ---------------------------------------------------------------------------------------------- built-in tracks

#: name: (length range m, wall-to-wall width range m, tightest radius range m): what each built-in track was
#: designed to.
BUILTIN_SPECS = {
    "expressway": ((4200.0, 4600.0), (10.0, 14.0), (25.0, 40.0)),
    "flowing": ((4000.0, 5000.0), (16.0, 20.0), (80.0, 1e9)),
    "technical": ((2500.0, 3500.0), (9.0, 11.0), (15.0, 20.0)),
}


def test_builtin_names():
    assert set(BUILTIN_TRACKS) == set(BUILTIN_SPECS)
    assert DEFAULT_TRACK == "expressway" and DEFAULT_TRACK in BUILTIN_TRACKS


@pytest.mark.parametrize("name", sorted(BUILTIN_SPECS))
def test_builtin_track_meets_its_spec(name):
    (l_lo, l_hi), (w_lo, w_hi), (r_lo, r_hi) = BUILTIN_SPECS[name]
    track = load_track(name)
    assert track.name == name
    assert l_lo <= track.length_m <= l_hi
    width = track.width_left_m + track.width_right_m
    assert w_lo - 1e-9 <= width.min() and width.max() <= w_hi + 1e-9
    assert r_lo <= 1.0 / np.abs(track.curvature_1pm).max() <= r_hi
    half = np.maximum(track.width_left_m, track.width_right_m)
    assert (np.abs(track.curvature_1pm) * half).max() < 0.7
    assert wall_fold_ratio(track) < 1.0
    assert crossing_count(track) == 0
    validate_track(track)


@pytest.mark.parametrize("name", sorted(BUILTIN_SPECS))
def test_builtin_track_closes_without_a_kink(name):
    layout = tl.LAYOUTS[name]
    track = load_track(name)
    # The turn adds up to one full turn, the traced line closes on its start ...
    assert abs(layout.total_turn_rad) == pytest.approx(2 * np.pi, abs=1e-12)
    n = round(layout.nominal_length_m / 0.25)
    lengths = tl._close_layout(layout, n)
    xy, _, _ = tl._trace_layout(layout, lengths, n)
    assert np.hypot(*(xy[-1] - xy[0])) < 1e-6
    # ... and nowhere, the join included, does curvature jump: each change ramps over the transition length.
    kappa = track.curvature_1pm
    step = np.abs(np.diff(np.append(kappa, kappa[0])))
    layout_kappa = np.array([seg.curvature_1pm for seg in layout.segments])
    largest_change = np.abs(np.diff(np.append(layout_kappa, layout_kappa[0]))).max()
    assert step.max() <= 1.3 * largest_change * track.spacing_m / layout.transition_m
    heading_step = np.abs(np.angle(np.exp(1j * np.diff(np.append(track.heading_rad, track.heading_rad[0])))))
    assert heading_step.max() <= 1.05 * np.abs(kappa).max() * track.spacing_m


def test_builtin_corner_counts_match_their_layouts():
    # Every arc of these two layouts is tighter than 250 m, turns by more than 20 deg and meets a straight or an arc
    # of the other sign, so each is one corner (the expressway's 300 m kinks are below the threshold).
    for name, expected in (("expressway", 11), ("technical", 13)):
        arcs = [
            seg for seg in tl.LAYOUTS[name].segments if abs(seg.curvature_1pm) > 1 / 250 and abs(seg.turn_rad) >= 0.35
        ]
        assert len(arcs) == expected
        assert count_corners(load_track(name)) == expected


def test_expressway_has_a_chicane_and_long_straights():
    layout = tl.LAYOUTS["expressway"]
    segs = layout.segments
    signs = [np.sign(s.curvature_1pm) for s in segs]
    chicanes = [k for k in range(len(segs) - 1) if signs[k] * signs[k + 1] < 0 and segs[k].length_m < 60]
    assert chicanes
    assert max(s.length_m for s in segs if s.curvature_1pm == 0) >= 600


def test_builtin_tracks_are_cached_and_read_only():
    a, b = load_track("expressway"), load_track(" Expressway ")
    assert a is b
    assert load_track("expressway", spacing_m=2.0) is not a
    assert load_track("expressway", spacing_m=2.0).spacing_m == pytest.approx(2.0, rel=0.01)
    with pytest.raises(ValueError):
        a.centre_xy_m[0, 0] = 1.0


def test_geometry_hashes_differ_between_tracks_and_are_stable_across_processes():
    specs = [*BUILTIN_TRACKS, "random:0", "random:1"]
    hashes = [load_track(s).geometry_hash for s in specs]
    assert len(set(hashes)) == len(hashes)
    code = (
        "import json; from vision_rl.sim.track_library import load_track; "
        f"print(json.dumps([load_track(s).geometry_hash for s in {specs!r}]))"
    )
    root = Path(__file__).parents[2]
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True)
    assert json.loads(out.stdout) == hashes


def test_layout_must_turn_once_and_close():
    with pytest.raises(TrackError, match="360"):
        build_layout("bad", Layout((straight(100), left(50, 90), straight(100), left(50, 180)), 5.0, 5.0))
    # The closing solve fixes a layout whose opposite straights differ by 10 m with the least change: 5 m each.
    sloppy = Layout(
        (
            straight(300),
            left(40, 90),
            straight(200),
            left(40, 90),
            straight(310),
            left(40, 90),
            straight(190),
            left(40, 90),
        ),
        5.0,
        5.0,
    )
    lengths = tl._close_layout(sloppy, round(sloppy.nominal_length_m / 0.25))
    np.testing.assert_allclose(lengths[::2], [305.0, 195.0, 305.0, 195.0], atol=1e-3)
    track = build_layout("sloppy", sloppy)
    assert track.length_m == pytest.approx(2 * 305 + 2 * 195 + 2 * np.pi * 40, abs=0.05)


# ---------------------------------------------------------------------------------------------- count_corners


def test_count_corners_on_known_shapes():
    a = np.linspace(0, 2 * np.pi, 300, endpoint=False)
    circle = Track.from_centre_line("circle", 100 * np.stack([np.cos(a), np.sin(a)], axis=1), 5.0, 5.0)
    assert count_corners(circle) == 1

    def corners(gap_m: float, **kwargs) -> int:
        layout = Layout(
            (
                straight(300),
                left(30, 90),  # 1
                straight(200),
                left(30, 45),  # double apex: 2, or 2 and 3 when the gap is long
                straight(gap_m),
                left(30, 45),
                straight(200),
                left(100, 10),  # two kinks of 0.17 rad: below min_turn_rad
                right(100, 10),
                straight(200),
                left(30, 90),  # 3
                straight(150),
                right(30, 40),  # chicane: two corners
                left(30, 40),
                straight(150),
                left(30, 90),  # 6
            ),
            5.0,
            5.0,
            transition_m=4.0,
        )
        return count_corners(build_layout("shape", layout), **kwargs)

    assert corners(10.0) == 6
    assert corners(10.0, max_gap_m=3.0) == 7
    assert corners(40.0) == 7
    assert corners(10.0, min_turn_rad=0.1) == 8  # the kinks now count
    assert corners(10.0, min_curvature_1pm=1 / 20) == 0


def test_track_summary():
    rows = [track_summary(load_track(name)) for name in BUILTIN_TRACKS]
    assert json.loads(json.dumps(rows)) == rows
    for row, name in zip(rows, BUILTIN_TRACKS, strict=True):
        assert set(row) == {"name", "length_m", "min_width_m", "corners", "wall_trim_m"}
        assert row["wall_trim_m"] == 0.0
        assert row["name"] == name
        assert row["length_m"] == pytest.approx(load_track(name).length_m, abs=0.05)
        assert row["min_width_m"] == pytest.approx(load_track(name).min_width_m, abs=0.005)
        assert isinstance(row["corners"], int) and row["corners"] >= 5


# ---------------------------------------------------------------------------------------------- random tracks


@pytest.mark.parametrize("seed", range(20))
def test_random_track_is_valid(seed):
    track = load_track(f"random:{seed}")
    assert track.name == f"random:{seed}"
    assert 2000.0 <= track.length_m <= 6000.0
    width = track.width_left_m + track.width_right_m
    assert 10.0 <= width.min() and width.max() <= 16.0
    kappa = np.abs(track.curvature_1pm)
    assert kappa.max() <= 1 / 12
    assert (kappa * np.maximum(track.width_left_m, track.width_right_m)).max() < 0.7
    assert crossing_count(track) == 0
    validate_track(track)


def test_random_tracks_are_deterministic_and_distinct():
    first = [load_track(f"random:{seed}") for seed in range(5)]
    tl._random_track_cached.cache_clear()
    again = [load_track(f"random:{seed}") for seed in range(5)]
    for a, b in zip(first, again, strict=True):
        assert a is not b
        assert a.geometry_hash == b.geometry_hash
        np.testing.assert_array_equal(a.centre_xy_m, b.centre_xy_m)
    assert len({t.geometry_hash for t in first}) == 5
    assert len({round(t.length_m) for t in first}) == 5


# ---------------------------------------------------------------------------------------------- load_track specs


def test_unknown_specs_fail_clearly(tmp_path):
    with pytest.raises(TrackError) as err:
        load_track("nurburgring")
    for name in BUILTIN_TRACKS:
        assert name in str(err.value)
    assert "random:SEED" in str(err.value)
    for spec in ("random:", "random:abc", "random:-3", "random:1.5"):
        with pytest.raises(TrackError, match="SEED"):
            load_track(spec)
    with pytest.raises(TrackError, match="non-negative"):
        tl.random_track(-1)
    missing = tmp_path / "missing.csv"
    with pytest.raises(TrackError, match=f"{missing}.*no such track file"):
        load_track(missing)
    with pytest.raises(TrackError):
        load_track(12)  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------------- CSV files


def circle_rows(n: int = 40, radius_m: float = 100.0) -> list[str]:
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return [f"{radius_m * math.cos(t):.6f},{radius_m * math.sin(t):.6f},5.0,4.0" for t in a]


def write_csv(tmp_path: Path, rows: list[str], name: str = "track.csv") -> Path:
    path = tmp_path / name
    path.write_text(HEADER + "\n".join(rows) + "\n")
    return path


def test_csv_loads_with_right_width_first(tmp_path):
    track = load_track(str(write_csv(tmp_path, circle_rows(), "ring.csv")))
    assert track.name == "ring"
    assert track.length_m == pytest.approx(2 * np.pi * 100.0, rel=2e-3)
    np.testing.assert_allclose(track.width_right_m, 5.0)
    np.testing.assert_allclose(track.width_left_m, 4.0)
    # The file's points are counter-clockwise: a left-turning track.
    assert np.all(track.curvature_1pm > 0)


def _bad(rows: list[str], k: int, value: str) -> list[str]:
    rows = list(rows)
    rows[k] = value
    return rows


BAD_CSV_CASES = {
    # name: (rows, pattern the message must contain; lines are 1-based and the header is line 1)
    "columns": (lambda r: _bad(r, 6, "1.0,2.0,3.0"), r"line 8: expected 4 comma-separated numbers"),
    "text": (lambda r: _bad(r, 3, "a,b,c,d"), r"line 5: expected 4"),
    "few": (lambda r: r[:9], r"9 points; .* at least 10"),
    "nan": (lambda r: _bad(r, 12, "nan,1.0,5.0,4.0"), r"line 14 \(point 12, 0-based\): .*NaN"),
    "inf": (lambda r: _bad(r, 20, "1.0,inf,5.0,4.0"), r"line 22 \(point 20, 0-based\): .*inf"),
    "width_right": (lambda r: _bad(r, 7, r[7].rsplit(",", 2)[0] + ",0.0,4.0"), r"line 9 \(point 7.*right width 0.0"),
    "width_left": (lambda r: _bad(r, 9, r[9].rsplit(",", 2)[0] + ",5.0,-1.0"), r"line 11 \(point 9.*left width -1.0"),
    "duplicate": (lambda r: [*r[:15], r[14], *r[15:]], r"line 17 \(point 15, 0-based\): duplicate .*line 16"),
    "repeats_first": (lambda r: [*r, r[0]], r"line 42 \(point 40, 0-based\): the last point repeats the first"),
    "gap": (lambda r: r[:10] + r[16:], r"line 12 \(point 10, 0-based\): gap of .* from line 11"),
    "loop": (lambda r: [*r[:10], r[11], r[10], *r[12:]], r"crosses itself .* after line 11 .* after line 13"),
}


@pytest.mark.parametrize("case", sorted(BAD_CSV_CASES))
def test_bad_csv_names_file_and_point(tmp_path, case):
    make_rows, pattern = BAD_CSV_CASES[case]
    path = write_csv(tmp_path, make_rows(circle_rows()), f"bad_{case}.csv")
    with pytest.raises(TrackError) as err:
        load_track(path)
    message = str(err.value)
    assert message.startswith(str(path))
    assert re.search(pattern, message), message


def test_unreadable_csv(tmp_path):
    path = tmp_path / "binary.csv"
    path.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(TrackError, match=f"{path}: cannot read"):
        load_track(path)


def test_csv_wall_fold_is_trimmed(tmp_path):
    # A rounded square with 6 m corners and 12 m to the left wall: the left (inside) wall would fold at each corner.
    pts = []
    for k in range(4):
        c, s = math.cos(k * math.pi / 2), math.sin(k * math.pi / 2)
        local = [(x - 44.0, -50.0) for x in np.arange(0.0, 88.0, 2.0)]
        local += [(44.0 + 6 * math.cos(a), -44.0 + 6 * math.sin(a)) for a in np.linspace(-np.pi / 2, 0, 4, False)]
        pts += [(c * x - s * y, s * x + c * y) for x, y in local]
    path = write_csv(tmp_path, [f"{x:.6f},{y:.6f},3.0,12.0" for x, y in pts], "fold.csv")
    track = load_track(path)
    assert track.wall_trim_m > 1.0  # the corners, smoothed to about 12 m, are still tighter than 12 m + margin
    assert wall_fold_ratio(track) <= WALL_TRIM_SHARE + 1e-9
    assert crossing_count(track) == 0
    # The outside wall and the inside wall along the middle of each side keep their widths.
    np.testing.assert_array_equal(track.width_right_m, 3.0)
    assert np.isclose(track.width_left_m, 12.0).mean() > 0.5
    # A hand-built track is checked as it is: the fold is still reported there.
    n = track.n_points
    raw = Track("fold", track.centre_xy_m, track.heading_rad, track.curvature_1pm, np.full(n, 12.0), np.full(n, 3.0))
    with pytest.raises(TrackError, match=r"s = .*left wall folds: it is 12.00 m from the centre line"):
        validate_track(raw)


def test_csv_overlapping_parts_are_reported(tmp_path):
    # A bow shape pinched in the middle: centre lines 6 m apart with 5 m to each wall, so the walls overlap.
    a = np.linspace(0.0, 2 * np.pi, 120, endpoint=False)
    x = 150.0 * np.cos(a)
    y = np.sin(a) * (3.0 + 77.0 * (1.0 - np.exp(-((x / 60.0) ** 2))))
    path = write_csv(tmp_path, [f"{p:.6f},{q:.6f},5.0,5.0" for p, q in zip(x, y, strict=True)], "pinch.csv")
    with pytest.raises(TrackError, match=r"pinch\.csv: the left wall crosses itself .* between line \d+ .* and line"):
        load_track(path)


def test_csv_figure_eight_is_a_bridge(tmp_path):
    t = np.linspace(0.0, 2 * np.pi, 200, endpoint=False)
    rows = [f"{300 * math.sin(v):.6f},{150 * math.sin(2 * v):.6f},5.0,5.0" for v in t]
    track = load_track(write_csv(tmp_path, rows, "eight.csv"))
    crossings = find_crossings(track)
    assert crossings.shape == (1, 2)
    assert abs(track.progress_delta(crossings[0, 0], crossings[0, 1])) == pytest.approx(track.length_m / 2, rel=0.01)
    # Built-in and random tracks never get this allowance.
    with pytest.raises(TrackError, match="centre line crosses itself"):
        validate_track(track)


# ---------------------------------------------------------------------------------------------- real tracks

#: Lengths of the five real circuits (m): the official lap lengths, which their database centre lines match to 0.5 %.
REAL_LENGTHS_M = {"Catalunya": 4657, "Monza": 5793, "Silverstone": 5891, "Spa": 7004, "Suzuka": 5807}


@pytest.mark.parametrize("name", sorted(REAL_LENGTHS_M))
def test_real_track_loads(name):
    path = real_track_path(name)
    track = load_track(path)
    assert track.name == name
    assert track.length_m == pytest.approx(REAL_LENGTHS_M[name], rel=0.005)
    assert wall_fold_ratio(track) < 0.8
    raw = np.loadtxt(path, delimiter=",")
    # Smoothing moves the centre line by at most 0.3 m RMS ...
    assert np.sqrt(np.mean(track.project(raw[:, :2]).lateral_m ** 2)) < 0.3
    # ... and leaves no radius tighter than a real corner's (the raw line has 5.7 m at Spa).
    assert 1.0 / np.abs(track.curvature_1pm).max() > 11.0
    # Only Suzuka crosses itself, on its bridge.
    assert len(find_crossings(track)) == (1 if name == "Suzuka" else 0)
    summary = track_summary(track)
    assert 10 <= summary["corners"] <= 20


def test_every_database_circuit_loads_by_name():
    assert len(DATABASE_TRACKS) == 25 and "Catalunya" in DATABASE_TRACKS
    assert (DATABASE_DIR / "LICENSE").read_text().startswith("                   GNU LESSER GENERAL PUBLIC LICENSE")
    assert "e59595d1f3573b30d1ded6a08984935b957688e0" in (DATABASE_DIR / "ORIGIN.md").read_text()
    start = time.perf_counter()
    trimmed = {}
    for name in DATABASE_TRACKS:
        track = load_track(name.upper())
        assert track is load_track(name.lower())  # cached, one shared read-only instance
        assert track.name == name and not track.centre_xy_m.flags.writeable
        assert 2000.0 < track.length_m < 7100.0
        assert wall_fold_ratio(track) <= WALL_TRIM_SHARE + 1e-9
        if track.wall_trim_m > 0:
            trimmed[name] = track.wall_trim_m
    assert time.perf_counter() - start < 10.0
    # Two street hairpins are tighter than their inside widths and are trimmed by metres; Austin's tightest corner
    # comes within 10 % of folding and loses under half a metre; no other circuit is touched.
    assert set(trimmed) == {"Austin", "Norisring", "Shanghai"}
    assert trimmed["Austin"] < 0.5 and 1.0 < trimmed["Norisring"] < 3.0 and 1.0 < trimmed["Shanghai"] < 3.0
    # The path form still works and gives the same geometry.
    assert load_track(real_track_path("Monza")).geometry_hash == load_track("Monza").geometry_hash


@pytest.mark.parametrize("name", ["Catalunya", "Norisring"])
def test_reference_racing_line_lies_on_the_track(name):
    line = reference_racing_line(name.lower())
    assert line.shape[1] == 2 and len(line) > 100
    track = load_track(name)
    proj = track.project(line)
    inside = np.where(proj.lateral_m >= 0, track.width_left_at(proj.s_m), track.width_right_at(proj.s_m))
    # The database's line keeps to its own (unsmoothed) borders: within ours but for a few tenths of a metre.
    assert (np.abs(proj.lateral_m) <= inside + 0.5).mean() > 0.99
    with pytest.raises(TrackError, match="not a circuit of the racetrack-database; its circuits are: Austin"):
        reference_racing_line("Nowhere")


def test_hairpin_inner_wall_is_trimmed_and_consistent():
    track = build_layout("hairpin8", hairpin_layout())
    assert 1 / track.curvature_1pm.max() == pytest.approx(8.0, rel=0.02)
    assert 2.0 < track.wall_trim_m < 4.0
    np.testing.assert_array_equal(track.width_right_m, 10.0)  # the outside wall is as given
    assert crossing_count(track) == 0
    apex = int(np.argmax(track.curvature_1pm))
    assert track.width_left_m[apex] == pytest.approx(WALL_TRIM_SHARE * 8.0, rel=0.02)
    # Far from the hairpin (on the other sides of the lap) the inside width is untouched.
    far = np.abs(track.progress_delta(track.s_m[apex], track.s_m)) > 150.0
    np.testing.assert_array_equal(track.width_left_m[far], 10.0)
    trimmed = np.flatnonzero(track.width_left_m < 10.0)
    assert np.ptp(track.s_m[trimmed]) < 120.0
    # The road is the true one (every point within 10 m of the centre line) but for a thin wedge of wall along the
    # medial line between the legs, where the lateral offset the sim works in cannot reach: on a 0.5 m grid round
    # the hairpin, under 30 m^2 of the true road is lost and nothing outside it is added.
    grid = np.mgrid[-60:60:0.5, -60:60:0.5].reshape(2, -1).T + track.centre_xy_m[apex]
    true_road = cKDTree(track.position_at(np.arange(0.0, track.length_m, 0.1))).query(grid)[0] <= 10.0
    proj = track.project(grid)
    ours = np.abs(proj.lateral_m) <= np.where(
        proj.lateral_m >= 0, track.width_left_at(proj.s_m), track.width_right_at(proj.s_m)
    )
    assert 0.25 * (true_road & ~ours).sum() < 30.0
    assert 0.25 * (ours & ~true_road).sum() <= 1.0
    # Sensors, contact and walls agree: a ray from each centre point along its left normal meets the first wall at
    # the (trimmed) width, the lateral offset the contact model stops a car at; no other wall is nearer.
    caster = WallRayCaster(track)
    idx = np.arange(apex - 80, apex + 81) % track.n_points
    angle = (track.heading_rad[idx] + np.pi / 2)[:, None]
    hit = caster.cast(track.centre_xy_m[idx], angle, 30.0)[:, 0]
    np.testing.assert_allclose(hit, track.width_left_m[idx], atol=0.05)


def test_self_intersection_check_is_fast():
    track = load_track(real_track_path("Spa"), spacing_m=7000.0 / 6000.0)
    assert 5900 <= track.n_points <= 6100
    times = []
    for _ in range(3):
        start = time.perf_counter()
        validate_track(track, allow_overpasses=True)
        times.append(time.perf_counter() - start)
    assert np.median(times) < 0.5
