"""`evaluate` of a trained policy through the protocol; the summary's statistics; the outputs."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers.drivers import CentreLineFollower
from tests.helpers.rendering import renderer_available
from vision_rl.evaluation.outputs import TRACE_COLUMNS, format_lap_time, plot_trajectory, write_trace, write_video
from vision_rl.evaluation.protocol import LapRecord, LapTiming, SeedRun, time_laps
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import get_preset
from vision_rl.training.evaluate import evaluate_policy


def _timing(lap_times, dnf=None):
    runs = [
        SeedRun(k, [LapRecord(t, 0.5 * (i + 1), 0.0, 0.0, 100.0, 1000.0) for i, t in enumerate(times)], None, 0.0, 1.0)
        for k, times in enumerate(lap_times)
    ]
    return LapTiming(load_track("technical"), get_preset("hatchback"), 2, runs, 90.0, 300.0, np.zeros(len(runs)))


def test_summary_best_median_and_dnf():
    s = _timing([[50.0, 40.0], [52.0, 41.0, 39.0], [55.0]]).summary()
    assert [x["lap_time_s"] for x in s["seeds"]] == [40.0, 41.0, None]  # lap 2, not a later faster one
    assert s["best_lap_time_s"] == 40.0 and s["best_seed"] == 0
    assert s["median_lap_time_s"] == 41.0  # of 40, 41 and a DNF counted as infinitely slow
    assert s["n_finished"] == 2
    assert s["best_lap"]["wall_contact_s"] == 1.0 and not s["clean"]  # 1.0 s > 0.5 s of wall contact
    assert _timing([[50.0, 40.0], [55.0], [56.0]]).summary()["median_lap_time_s"] is None


def test_format_lap_time():
    assert format_lap_time(102.717) == "1:42.717"
    assert format_lap_time(59.9996) == "1:00.000"
    assert format_lap_time(None) == "DNF" and format_lap_time(float("inf")) == "DNF"


def test_evaluate_is_deterministic_for_a_seed(state_run, tmp_path):
    out, _ = state_run
    a = evaluate_policy(out, laps=2, seeds=2, seed=5, time_limit_s=15.0, write=False, trace=str(tmp_path / "t.csv"))
    b = evaluate_policy(out, laps=2, seeds=2, seed=5, time_limit_s=15.0, write=False)
    c = evaluate_policy(out, laps=2, seeds=2, seed=7, time_limit_s=15.0, write=False)
    assert a["seeds"] == b["seeds"] and a["protocol"] == b["protocol"]
    assert [s["seed"] for s in a["seeds"]] == [5, 6]
    assert a["seeds"][0]["distance_m"] != c["seeds"][0]["distance_m"]
    assert a["driver"]["driver"] == "policy" and len(a["driver"]["policy_sha256"]) == 64
    trace = np.loadtxt(a["trace"], delimiter=",", skiprows=1)
    assert set(trace[:, 0]) == {5, 6} and trace[:, 1].max() <= 15.0 + 1e-6 and b["trace"] is None


def test_plot_and_video(small_track, tmp_path):
    timing = time_laps(CentreLineFollower(), small_track, "hatchback", seeds=[0], laps=1, record=True)
    png = plot_trajectory(timing, 0, tmp_path / "traj.png", "follower")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    reason = renderer_available()
    if reason:
        pytest.skip(reason)
    pytest.importorskip("imageio_ffmpeg", reason="the mp4 writer needs imageio[ffmpeg]")
    timing = time_laps(CentreLineFollower(), small_track, "hatchback", seeds=[0], laps=1, time_limit_s=3.0, record=True)
    mp4 = write_video(timing, 0, tmp_path / "drive.mp4", image_hw_px=(64, 96), map_size_px=40)
    assert mp4.stat().st_size > 1000 and mp4.read_bytes()[4:8] == b"ftyp"
    import imageio.v2 as imageio

    frames = imageio.mimread(str(mp4))
    assert len(frames) == len(timing.time_s) == 30 and frames[0].shape == (64, 96, 3)


class OneCarBrakes(CentreLineFollower):
    """The follower, 1 m left of the centre line, except that the second car brakes to a stop (a DNF: stuck)."""

    def __init__(self) -> None:
        super().__init__(target_lateral=lambda s: 1.0 + 0.0 * s)

    def act(self, state):
        action = super().act(state)
        action[1:] = (0.0, -1.0)
        return action


def test_trace_places_every_step_on_the_track_and_ends_each_run_at_its_finish_or_dnf(small_track, tmp_path):
    timing = time_laps(OneCarBrakes(), small_track, "hatchback", seeds=[3, 4], laps=1, record=True)
    follower, braked = timing.runs
    assert follower.dnf_reason is None and braked.dnf_reason.startswith("stuck")
    path = write_trace(timing, tmp_path / "trace.csv")
    assert path.read_text().splitlines()[0] == ",".join(TRACE_COLUMNS)
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    col = {name: table[:, k] for k, name in enumerate(TRACE_COLUMNS)}
    for i, run in enumerate(timing.runs):
        rows = col["seed"] == run.seed
        steps = timing.time_s <= run.time_s + 1e-9
        # One row per recorded step up to the run's end, the braked car's rows ending at its DNF.
        assert rows.sum() == steps.sum() and col["time_s"][rows][-1] == pytest.approx(run.time_s)
        np.testing.assert_allclose(col["speed_kmh"][rows], 3.6 * timing.speed_mps[steps, i], atol=0.01)
        # Arc length and lateral offset give back the pose (to the CSV's mm).
        xy = timing.track.position_at(col["s_m"][rows], col["lateral_m"][rows])
        np.testing.assert_allclose(xy, np.stack([col["x_m"][rows], col["y_m"][rows]], axis=1), atol=0.02)
    assert braked.time_s < follower.time_s - 10.0
    settled = (col["seed"] == 3) & (col["time_s"] > 10.0)
    # The follower holds 1 m to the left (+), along the track (heading error near 0).
    np.testing.assert_allclose(col["lateral_m"][settled], 1.0, atol=0.25)
    assert np.abs(col["heading_error_deg"][settled]).max() < 5.0
    assert col["speed_kmh"][col["seed"] == 4][-1] < 1.0 and col["pedal"][col["seed"] == 4][-1] < -0.9
    untimed = time_laps(OneCarBrakes(), small_track, "hatchback", seeds=[3], laps=1, time_limit_s=1.0)
    with pytest.raises(ValueError, match="record=True"):
        write_trace(untimed, tmp_path / "none.csv")


def test_evaluate_sections_say_when_no_lap_finished_and_refuse_bad_options(state_run):
    from vision_rl.commands.evaluate import format_timing

    out, _ = state_run
    result = evaluate_policy(out, laps=1, seeds=1, time_limit_s=3.0, write=False, sections_m=50.0)
    assert result["n_finished"] == 0 and result["sections"]["rows"] is None
    assert "sections: no seed finished its scored lap" in format_timing(result)
    for bad in ({"sections_m": -1.0}, {"sections_m": 50.0, "reference_skill": 0.0}):
        with pytest.raises(ValueError, match="--sections-m must be >= 0"):
            evaluate_policy(out, write=False, **bad)


def test_evaluate_sections_print_how_the_best_lap_drives_at_speed_beside_the_ai(state_run):
    from vision_rl.commands.evaluate import format_timing

    out, _ = state_run
    result = evaluate_policy(out, laps=1, seeds=1, time_limit_s=3.0, write=False)
    row = {
        "start_m": 0.0,
        "time_s": 3.5,
        "reference_time_s": 3.4,
        "loss_s": 0.1,
        "min_speed_kmh": 96.0,
        "reference_min_speed_kmh": 99.0,
        "wall_contact_s": 0.0,
    }
    controls = {
        "fast_above_kmh": 127.7,
        "steps": 600,
        "full_throttle_share": 0.002,
        "range_end_share": 0.16,
        "steer_sign_change_share": 0.36,
    }
    reference = {**controls, "full_throttle_share": 0.87, "range_end_share": 0.0, "steer_sign_change_share": 0.03}
    result["sections"] = {
        "section_m": 100.0,
        "reference": {"skill": 1.0, "lap_time_s": 128.655},
        "rows": [row],
        "controls": {"lap": controls, "reference": reference},
    }
    assert format_timing(result)[-1] == (
        "above 128 km/h (the best lap / the AI's): full throttle 0% / 87% of the steps, the wheel at the end of its "
        "usable angle 16% / 0%, changing side 36% / 3%"
    )


def test_an_output_file_that_is_a_folder_is_refused_before_the_evaluation(state_run, tmp_path):
    out, _ = state_run
    for option in ("plot", "video", "trace"):
        with pytest.raises(ValueError, match=f"--{option} .* is a folder"):
            evaluate_policy(out, seeds=1, write=False, **{option: str(tmp_path)})


def test_encoder_error_is_refused_for_a_state_policy(state_run):
    out, _ = state_run
    with pytest.raises(ValueError, match="this policy observes the state"):
        evaluate_policy(out, write=False, encoder_error=True)
