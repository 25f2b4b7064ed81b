"""Track faults: walls that would fold round a hairpin are trimmed and the track is driven and drawn; tracks that are
truly broken (a centre line that crosses itself without a bridge, widths that are not positive, overlapping parts,
unknown names) are refused with a message that names the file, the point or the name."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vision_rl.evaluation.protocol import BuiltinAI, time_laps
from vision_rl.sim.track import WALL_TRIM_SHARE, TrackError
from vision_rl.sim.track_library import Layout, build_layout, left, load_track, straight

HEADER = "# x_m,y_m,w_tr_right_m,w_tr_left_m\n"


def hairpin_track():
    """A 160 deg left hairpin of radius 8 m with 10 m from the centre line to each wall, between 600 m legs."""
    layout = Layout(
        segments=(straight(600), left(8, 160), straight(600), left(80, 100), straight(66), left(80, 100)),
        width_left_m=10.0,
        width_right_m=10.0,
        transition_m=4.0,
    )
    return build_layout("hairpin", layout)


def circle_rows(n: int = 40, radius_m: float = 100.0) -> list[str]:
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return [f"{radius_m * math.cos(t):.6f},{radius_m * math.sin(t):.6f},5.0,4.0" for t in a]


def write_csv(tmp_path, rows: list[str], name: str):
    path = tmp_path / name
    path.write_text(HEADER + "\n".join(rows) + "\n")
    return path


def test_hairpin_tighter_than_its_width_is_trimmed_and_driven(fault):
    track = hairpin_track()
    apex = int(np.argmax(track.curvature_1pm))
    assert 1.0 / track.curvature_1pm[apex] == pytest.approx(8.0, rel=0.02)
    assert track.wall_trim_m > 2.0 and track.width_left_m[apex] <= WALL_TRIM_SHARE * 8.0 + 0.1
    timing = time_laps(BuiltinAI(), track, "hatchback", seeds=(0,), laps=1)
    lap = timing.scored(0)
    assert timing.runs[0].dnf_reason is None and lap is not None, timing.runs[0].dnf_reason
    assert lap.lap_time_s < 1.3 * timing.limit_lap_time_s
    fault.recovered(
        "a hairpin of radius 8 m with 10 m to the inside wall (the wall would fold past the bend's centre)",
        f"inside wall trimmed by {track.wall_trim_m:.1f} m to the true inner edge; the built-in AI laps it in "
        f"{lap.lap_time_s:.1f} s ({lap.wall_contact_s:.1f} s of wall contact)",
    )


@pytest.mark.parametrize("name", ["Norisring", "Shanghai"])
def test_database_hairpins_that_used_to_fold_load(fault, name):
    track = load_track(name)
    assert 1.0 < track.wall_trim_m < 3.0
    fault.recovered(
        f"{name} (racetrack-database): its tightest hairpin is narrower than the inside width",
        f"loads, inside wall trimmed by {track.wall_trim_m:.2f} m where it would fold",
    )


def test_hairpin_track_renders(fault, gl_available):
    from vision_rl.render import Renderer
    from vision_rl.render.scene import Label

    track = hairpin_track()
    apex = int(np.argmax(track.curvature_1pm))
    # Cars 25 m before the apex and at it, on the inside half of the road, looking along the track.
    s = track.s_m[apex] + np.array([-25.0, 0.0])
    xy = track.position_at(s, 0.5 * track.width_left_at(s))
    with Renderer(track) as renderer:
        labels = renderer.render_labels(xy[:, 0], xy[:, 1], track.heading_at(s))
    for view in labels:
        assert (view == Label.ROAD).mean() > 0.05 and (view == Label.WALL).mean() > 0.01
    fault.recovered("the trimmed hairpin drawn by the renderer", "renders: road and walls in view at the apex")


def test_centre_line_crossing_itself_is_refused(fault, tmp_path):
    rows = circle_rows()
    rows = [*rows[:10], rows[11], rows[10], *rows[12:]]
    path = write_csv(tmp_path, rows, "knot.csv")
    with pytest.raises(TrackError) as err:
        load_track(path)
    assert "centre line crosses itself" in str(err.value) and str(path) in str(err.value)
    fault.refused("a CSV centre line that crosses itself in a knot (no bridge)", str(err.value))


@pytest.mark.parametrize("width", ["0.0", "-2.5"])
def test_non_positive_width_is_refused(fault, tmp_path, width):
    rows = circle_rows()
    rows[7] = rows[7].rsplit(",", 2)[0] + f",{width},4.0"
    path = write_csv(tmp_path, rows, "narrow.csv")
    with pytest.raises(TrackError) as err:
        load_track(path)
    assert f"right width {float(width)} m is not > 0" in str(err.value) and "line 9" in str(err.value)
    fault.refused(f"a CSV right width of {width} m", str(err.value))


def test_overlapping_distant_parts_are_refused(fault, tmp_path):
    # A bow pinched in the middle: parts half a lap apart run 6 m apart with 5 m to each wall. Not one bend, so
    # not trimmed: the walls of two different parts of the track overlap.
    a = np.linspace(0.0, 2 * np.pi, 120, endpoint=False)
    x = 150.0 * np.cos(a)
    y = np.sin(a) * (3.0 + 77.0 * (1.0 - np.exp(-((x / 60.0) ** 2))))
    path = write_csv(tmp_path, [f"{p:.6f},{q:.6f},5.0,5.0" for p, q in zip(x, y, strict=True)], "pinch.csv")
    with pytest.raises(TrackError) as err:
        load_track(path)
    assert "two parts of the track overlap" in str(err.value)
    fault.refused("a CSV whose two halves run 6 m apart with 10 m wide roads", str(err.value))


def test_unknown_track_name_is_refused(fault):
    with pytest.raises(TrackError) as err:
        load_track("Catalunia")
    assert "unknown track 'Catalunia'" in str(err.value) and "Catalunya" in str(err.value)
    fault.refused("a misspelt circuit name (Catalunia)", str(err.value))


def test_non_finite_csv_value_is_refused(fault, tmp_path):
    rows = circle_rows()
    rows[12] = "nan,1.0,5.0,4.0"
    path = write_csv(tmp_path, rows, "nan.csv")
    with pytest.raises(TrackError) as err:
        load_track(path)
    assert "line 14" in str(err.value) and "not a finite number" in str(err.value)
    fault.refused("a NaN coordinate in a track CSV", str(err.value))
