import dataclasses

import numpy as np
import pytest

from vision_rl.sim import driving, racing_line
from vision_rl.sim.speed_profile import profile_for_line
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import get_preset


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("VISION_RL_CACHE", str(tmp_path / "cache"))


def _cache_files(tmp_path):
    return sorted((tmp_path / "cache" / "lines").glob("*.npz"))


def test_line_and_profile_are_cached_and_the_key_follows_the_preset(tmp_path):
    track, car = load_track("technical"), get_preset("hatchback")
    line, profile = driving.line_and_profile(track, car)
    assert len(_cache_files(tmp_path)) == 1
    line2, profile2 = driving.line_and_profile(track, car)
    np.testing.assert_array_equal(line.lateral_m, line2.lateral_m)
    assert profile2.lap_time_s == profile.lap_time_s
    # A heavier car is another preset: another key, another (slower) profile.
    heavier = dataclasses.replace(car, mass_kg=car.mass_kg + 300.0)
    _, profile3 = driving.line_and_profile(track, heavier)
    assert len(_cache_files(tmp_path)) == 2
    assert profile3.lap_time_s > profile.lap_time_s


@pytest.mark.parametrize("spec", ["expressway", "technical"])
def test_the_exact_line_is_taken_only_when_clearly_faster(spec):
    # On the expressway's long arcs the exact minimum-curvature line is the faster (hatchback: 1.0 %), on the
    # technical track the iterative QP's (0.3 %).
    track, car = load_track(spec), get_preset("hatchback")
    line, profile = driving.line_and_profile(track, car)
    laps = {}
    for model in racing_line.CURVATURE_MODELS:
        candidate = racing_line.optimise_racing_line(track, margin_m=line.margin_m, curvature_model=model)
        laps[model] = profile_for_line(car, candidate).lap_time_s
    exact_wins = laps["exact"] < (1.0 - driving.EXACT_LINE_MIN_GAIN) * laps["iqp"]
    assert exact_wins == (spec == "expressway")
    assert profile.lap_time_s == pytest.approx(laps["exact" if exact_wins else "iqp"], rel=1e-9)


def test_a_corrupt_cache_file_is_recomputed(tmp_path):
    track, car = load_track("technical"), get_preset("hatchback")
    _, profile = driving.line_and_profile(track, car)
    (path,) = _cache_files(tmp_path)
    path.write_bytes(b"not an npz")
    _, again = driving.line_and_profile(track, car)
    assert again.lap_time_s == pytest.approx(profile.lap_time_s)
