"""Sections of a recorded lap: a hand-made constant-speed lap, and the AI's protocol lap adding up to its time."""

from __future__ import annotations

import numpy as np
import pytest

from vision_rl.evaluation.protocol import STEP_S, BuiltinAI, LapRecord, LapTiming, SeedRun, time_laps
from vision_rl.evaluation.sections import compare_sections, lap_sections
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import get_preset


def _constant_speed_lap(track, speed_mps: float) -> LapTiming:
    """One lap on the centre line at ``speed_mps`` from the lap line, touching a wall from 100 to 150 m."""
    lap_s = track.length_m / speed_mps
    t = np.arange(1, int(lap_s / STEP_S) + 3) * STEP_S
    s = (speed_mps * t) % track.length_m
    xy = track.position_at(s)
    record = LapRecord(lap_s, 0.0, 0.0, 0.0, 3.6 * speed_mps, track.length_m)
    timing = LapTiming(
        track,
        get_preset("hatchback"),
        1,
        [SeedRun(0, [record], None, track.length_m, lap_s)],
        lap_s,
        3 * lap_s,
        np.array([speed_mps]),
    )
    timing.time_s, timing.x_m, timing.y_m = t, xy[:, :1], xy[:, 1:]
    timing.speed_mps = np.full((len(t), 1), speed_mps)
    timing.wall_contact = ((s >= 100.0) & (s < 150.0))[:, None]
    return timing


def test_a_constant_speed_lap_spends_length_over_speed_in_each_section(small_track):
    track = load_track(small_track)
    sections = lap_sections(_constant_speed_lap(track, 20.0), 0, 50.0)
    n_full = int(track.length_m // 50.0)
    np.testing.assert_allclose(sections["start_m"][:3], [0.0, 50.0, 100.0])
    np.testing.assert_allclose(sections["time_s"][:n_full], 2.5, atol=0.02)  # 50 m at 20 m/s
    assert sections["time_s"].sum() == pytest.approx(track.length_m / 20.0)
    np.testing.assert_allclose(sections["min_speed_kmh"][:n_full], 72.0)
    assert sections["wall_contact_s"][2] == pytest.approx(2.5, abs=STEP_S + 1e-9)
    assert sections["wall_contact_s"].sum() == pytest.approx(sections["wall_contact_s"][2])


def test_the_sections_of_the_ais_protocol_lap_add_up_to_its_lap_time(small_track):
    timing = time_laps(BuiltinAI(), small_track, "hatchback", seeds=(0,), laps=2, record=True)
    sections = lap_sections(timing, 0, 40.0)
    assert sections["time_s"].sum() == pytest.approx(timing.scored(0).lap_time_s, abs=1e-6)
    assert np.all(sections["time_s"] > 0)
    rows = compare_sections(sections, sections)
    assert [r["loss_s"] for r in rows] == [0.0] * len(rows)
    with pytest.raises(ValueError, match="different sections"):
        compare_sections(sections, lap_sections(timing, 0, 60.0))
    with pytest.raises(ValueError, match="record=True"):
        lap_sections(time_laps(BuiltinAI(), small_track, "hatchback", seeds=(0,), laps=1), 0, 40.0)
