"""Settings A/B and the learning curves: the start geometry, the metrics of a scripted driver, the summary, the
curves over seeds with the stage switch, and the files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vision_rl.commands.evaluate_overtaking import EvaluateOvertakingOptions
from vision_rl.evaluation.protocol import BuiltinAI
from vision_rl.evaluation.report import record_damage
from vision_rl.overtaking.curriculum import agent_record_path, write_run_record
from vision_rl.overtaking.settings import (
    SETTINGS,
    TRACE_DT_S,
    RunTrace,
    SettingError,
    contact_intervals,
    fastest_run,
    learning_curves,
    overtake_moments,
    run_setting,
    summarise_runs,
    write_analysis_outputs,
    write_learning_curves,
    write_setting_outputs,
)
from vision_rl.sim.ai_driver import OPPONENT_SKILL_RANGE
from vision_rl.sim.track_library import load_track


class Scripted:
    """A driver with fixed commands that records where every car of the world started."""

    control_dt_s = 0.1

    def __init__(self, steer_rad: float, omega: float) -> None:
        self.command = (steer_rad, omega)

    def reset(self, world, car_ids) -> None:
        self.ids = np.asarray(car_ids)
        self.start_s_m = world.state.s_m.copy()
        self.groups = world.model.groups.copy()

    def act(self, state) -> np.ndarray:
        return np.tile(self.command, (len(self.ids), 1))


@pytest.mark.parametrize("setting", ["A", "B"])
def test_opponents_start_ahead_along_the_centre_line(small_track, setting):
    driver = Scripted(0.0, 0.0)
    run_setting(driver, small_track, "tt_cup", setting, runs=2, time_limit_s=0.02)
    length_m = load_track(small_track).length_m
    s = driver.start_s_m.reshape(2, 6)
    gaps = np.mod(s[:, 1:] - s[:, :1], length_m)
    expected = np.mod(np.arange(1, 6) * SETTINGS[setting], length_m)
    np.testing.assert_allclose(gaps, np.tile(expected, (2, 1)), atol=1e-6)
    assert driver.ids.tolist() == [0, 6] and driver.groups.tolist() == [0] * 6 + [1] * 6  # a group per run


def test_a_braking_driver_is_stuck_with_no_contact_and_nobody_passed(small_track):
    runs, _ = run_setting(Scripted(0.0, -1.0), small_track, "tt_cup", "A", runs=2, time_limit_s=30.0)
    for run in runs:
        assert run["end"].startswith("stuck") and run["overtaken"] == 0 and not run["all_overtaken"]
        assert 5.0 <= run["travel_time_s"] < 15.0  # stopped within seconds, then the 5 s stuck window
        assert run["car_contact_s"] == 0.0 and run["wall_contact_s"] == 0.0
        assert 20.0 < run["travel_distance_m"] < 200.0  # braking from ~30 m/s on the straight
    assert runs[0]["opponent_skills"] != runs[1]["opponent_skills"]  # drawn per run seed
    again, _ = run_setting(Scripted(0.0, -1.0), small_track, "tt_cup", "A", runs=2, time_limit_s=30.0)
    assert again == runs  # the same seeds, the same runs


def test_opponents_drive_at_the_asked_skill_and_a_bad_range_is_refused(small_track):
    runs, _ = run_setting(Scripted(0.0, 0.0), small_track, "tt_cup", "A", runs=2, time_limit_s=0.02)
    assert all(0.80 <= k <= 0.88 for run in runs for k in run["opponent_skills"])  # the default range
    runs, _ = run_setting(
        Scripted(0.0, 0.0), small_track, "tt_cup", "A", runs=2, time_limit_s=0.02, opponent_skill=(0.92, 0.92)
    )
    assert [run["opponent_skills"] for run in runs] == [[0.92] * 5] * 2
    for bad in ((0.9, 0.8), (0.0, 0.5), (0.9, 1.2), (float("nan"), 0.9)):
        with pytest.raises(SettingError, match="--opponent-skill"):
            run_setting(Scripted(0.0, 0.0), small_track, "tt_cup", "A", runs=1, opponent_skill=bad)
    assert EvaluateOvertakingOptions().opponent_skill == OPPONENT_SKILL_RANGE  # the option's default is the library's


def test_the_built_in_ai_follows_and_the_outputs_are_written(small_track, tmp_path):
    runs, traces = run_setting(BuiltinAI(), small_track, "tt_cup", "A", runs=1, time_limit_s=15.0)
    assert runs[0]["end"] == "time limit" and runs[0]["travel_time_s"] == pytest.approx(15.0)
    trace = traces[0]  # sampled every 0.1 s from the start to the end, the metrics' final values included
    np.testing.assert_allclose(trace.time_s, np.arange(151) * TRACE_DT_S, atol=1e-9)
    np.testing.assert_allclose(trace.gap_m[0], [50.0, 100.0, 150.0, 200.0, 250.0], atol=1e-6)
    assert trace.x_m.shape == (151, 6) and np.all(trace.gap_m > 0.0) and overtake_moments(trace) == []
    assert trace.wall_contact_s[-1] == runs[0]["wall_contact_s"] and trace.car_contact_s[-1] == 0.0
    assert np.sum(np.hypot(np.diff(trace.x_m[:, 0]), np.diff(trace.y_m[:, 0]))) == pytest.approx(
        runs[0]["travel_distance_m"], rel=0.01
    )
    assert runs[0]["wall_contact_s"] == 0.0 and runs[0]["travel_distance_m"] > 300.0
    result = {
        "setting": "A",
        "separation_m": 50.0,
        "track_name": "stadium",
        "car": "tt_cup",
        "drivers": [{"name": "built-in AI", "reference": True, "runs": runs, "summary": summarise_runs(runs)}],
    }
    files = write_setting_outputs(result, tmp_path)
    written = json.loads(Path(files["json"]).read_text())
    assert Path(files["png"]).stat().st_size > 1000 and record_damage(written) is None  # sealed as written
    assert {k: v for k, v in written.items() if k != "content_sha256"} == result


def test_summary_mean_spread_best():
    runs = [
        {
            "travel_time_s": t,
            "travel_distance_m": 100.0 * t,
            "car_contact_s": c,
            "wall_contact_s": 0.0,
            "overtaken": o,
            "all_overtaken": o == 5,
        }
        for t, c, o in ((10.0, 1.0, 5), (20.0, 0.0, 3))
    ]
    s = summarise_runs(runs)
    assert s["travel_time_s"] == {"mean": 15.0, "std": 5.0, "best": 10.0}
    assert s["car_contact_s"]["best"] == 0.0 and s["all_overtaken_runs"] == 1
    assert s["fastest_all_five_s"] == 10.0  # the 20 s run passed three
    assert summarise_runs(runs[1:])["fastest_all_five_s"] is None
    assert s["overtaken"] == {"mean": 4.0, "min": 3, "max": 5}
    with pytest.raises(SettingError, match="--setting must be one of A, B"):
        run_setting(BuiltinAI(), "expressway", "tt_cup", "C")


def _fake_run(root: Path, seed: int, switch: int) -> Path:
    """A run folder with stage-1/2 and standard metrics: returns rise by 1 per 100 steps (curriculum from 10)."""
    for name, start, end, base in (
        ("stage1", 0, switch, 10.0),
        ("stage2", switch, 600, 10.0),
        ("standard", 0, 600, 0.0),
    ):
        folder = root / f"s{seed}" / name
        folder.mkdir(parents=True)
        write_run_record(folder / "stage.json", {"start_steps": start, "end_steps": end})
        lines = [
            json.dumps(
                {"stage": name, "num_timesteps": n, "train_time_s": n / 10, "overtaking_return": base + n / 100 + seed}
            )
            for n in range(start + 100, end + 1, 100)
        ]
        (folder / "metrics.jsonl").write_text("\n".join(lines) + "\n")
    for agent in ("1", "standard"):  # as a finished training writes them
        write_run_record(agent_record_path(root / f"s{seed}", agent), {"agent": agent})
    return root / f"s{seed}"


def test_learning_curves_over_seeds_with_the_stage_switch(tmp_path):
    runs = [_fake_run(tmp_path, 0, 200), _fake_run(tmp_path, 2, 300)]
    result = learning_curves(runs, "1")
    cur = result["curriculum"]
    assert cur["x"] == [100, 200, 300, 400, 500, 600] and cur["seeds_with_data"] == 2
    assert cur["mean"][0] == pytest.approx(12.0) and cur["std"][0] == pytest.approx(1.0)
    assert [s[0]["num_timesteps"] for s in cur["stage_switches"]] == [200, 300]
    assert result["standard_final_return"] == pytest.approx(7.0)
    assert result["curriculum_steps_to_standard_final"] == 100
    assert result["share_of_standard_steps"] == pytest.approx(1 / 6)
    # Read at 80 % (5.6): standard SAC's mean (2..7) at 500 steps, its seeds (1..6, 3..8) at 600 and 400.
    eighty = result["reach"][0]
    assert (eighty["share"], eighty["level"]) == (0.8, pytest.approx(5.6))
    assert eighty["standard"] == {"mean_x": 500, "per_seed_x": [600, 400]}
    assert eighty["curriculum"] == {"mean_x": 100, "per_seed_x": [100, 100]}
    assert result["reach"][-1]["standard"]["mean_x"] == 600 and result["reach"][-1]["share"] == 1.0
    files = write_learning_curves(result, tmp_path / "fig")
    assert Path(files["png"]).stat().st_size > 1000
    assert json.loads(Path(files["json"]).read_text())["curriculum"]["x"] == cur["x"]
    assert record_damage(json.loads(Path(files["json"]).read_text())) is None  # sealed: `vision-rl report` reads it
    assert result["complete"] and cur["n_seeds"] == [2] * 6 and cur["per_seed"][1][0] == pytest.approx(13.0)
    by_time = learning_curves(runs, "1", axis="train_time_s")
    assert by_time["curriculum"]["x"][-1] == 60.0


def test_a_seed_still_training_counts_only_where_every_seed_has_a_point(tmp_path):
    runs = [_fake_run(tmp_path, 0, 200), _fake_run(tmp_path, 2, 300)]
    for name in ("stage2", "standard"):  # seed 2 has trained to 400 steps only
        metrics = runs[1] / name / "metrics.jsonl"
        metrics.write_text(
            "".join(
                line + "\n" for line in metrics.read_text().splitlines() if json.loads(line)["num_timesteps"] <= 400
            )
        )
    for agent in ("1", "standard"):
        agent_record_path(runs[1], agent).unlink()
    result = learning_curves(runs, "1")
    assert result["standard"]["n_seeds"] == [2, 2, 2, 2, 1, 1] and not result["complete"]
    # Standard SAC's mean at 400 (both seeds: 4 and 6), not at 600 where only seed 0 is: 5.0.
    assert (result["standard_final_x"], result["standard_final_return"]) == (400, pytest.approx(5.0))
    assert result["curriculum_steps_to_standard_final"] == 100 and result["share_of_standard_steps"] == 0.25
    assert Path(write_learning_curves(result, tmp_path / "fig")["png"]).stat().st_size > 1000
    agent_record_path(runs[1], "1").write_text(agent_record_path(runs[0], "1").read_text())
    agent_record_path(runs[1], "standard").write_text(agent_record_path(runs[0], "standard").read_text())
    # Both finished, seed 2 sooner (as a curriculum whose stage 1 ended sooner): complete, still read at 400.
    result = learning_curves(runs, "1")
    assert result["complete"] and (result["standard_final_x"], result["standard_final_return"]) == (400, 5.0)


def test_the_curriculum_is_timed_against_standard_sacs_first_arrival_at_its_final_return(tmp_path):
    """Standard SAC at 5 from 200 steps on, dipping to 4 at 400: its final return (5) is first reached at 200, not at
    its last step (600), so the curriculum's arrival at 100 is half of standard SAC's steps, not a sixth."""
    runs = [_fake_run(tmp_path, 0, 200), _fake_run(tmp_path, 2, 300)]
    for run in runs:
        returns = dict(zip(range(100, 601, 100), (1.0, 5.0, 5.0, 4.0, 5.0, 5.0), strict=True))
        metrics = run / "standard" / "metrics.jsonl"
        lines = [json.loads(line) for line in metrics.read_text().splitlines()]
        metrics.write_text(
            "".join(json.dumps({**r, "overtaking_return": returns[r["num_timesteps"]]}) + "\n" for r in lines)
        )
    result = learning_curves(runs, "1")
    assert (result["standard_final_x"], result["standard_final_return"]) == (600, 5.0)
    assert result["standard_steps_to_final"] == 200 and result["curriculum_steps_to_standard_final"] == 100
    assert result["share_of_standard_steps"] == 0.5


def _trace(track, gaps: np.ndarray, car_contact_s: np.ndarray) -> RunTrace:
    """A hand-made trace: the agent on the centre line from s = 0 at 40 m/s, opponent j ``gaps[:, j-1]`` ahead."""
    t = np.arange(len(gaps)) * TRACE_DT_S
    s = np.column_stack([40.0 * t, 40.0 * t[:, None] + gaps]) % track.length_m
    xy = track.position_at(s.ravel()).reshape(*s.shape, 2)
    yaw = track.heading_at(s.ravel()).reshape(s.shape)
    zeros = np.zeros(len(t))
    return RunTrace(t, xy[..., 0], xy[..., 1], yaw, np.full(len(t), 40.0), gaps, car_contact_s, *[zeros] * 4)


def test_passes_that_stood_contacts_and_the_fastest_run():
    gaps = np.full((10, 5), 30.0)
    gaps[:, 0] = [5, 3, 1, -1, -2, 1, -1, -3, -4, -5]  # passed at sample 3, re-passed, passed again at 6
    gaps[:, 2] = -8.0  # behind the agent from the start
    t = np.arange(10) * TRACE_DT_S
    trace = RunTrace(
        t,
        np.zeros((10, 6)),
        np.zeros((10, 6)),
        np.zeros((10, 6)),
        np.full(10, 25.0),
        gaps,
        np.array([0, 0, 0.02, 0.04, 0.04, 0.04, 0.06, 0.06, 0.06, 0.06]),
        *[np.zeros(10)] * 4,
    )
    moments = overtake_moments(trace)
    assert [(m["opponent"], m["sample"]) for m in moments] == [(3, 0), (1, 6)]
    assert [m["approach_sample"] for m in moments] == [0, 6]  # never 10 m ahead: the pass itself
    assert moments[1]["time_s"] == pytest.approx(0.6) and moments[1]["speed_kmh"] == pytest.approx(90.0)
    assert contact_intervals(t, trace.car_contact_s) == [
        (pytest.approx(0.1), pytest.approx(0.3)),
        (pytest.approx(0.5), pytest.approx(0.6)),
    ]
    assert contact_intervals(t, trace.wall_contact_s) == []
    runs = [
        {"all_overtaken": False, "overtaken": 4, "travel_time_s": 50.0},
        {"all_overtaken": True, "overtaken": 5, "travel_time_s": 90.0},
        {"all_overtaken": True, "overtaken": 5, "travel_time_s": 80.0},
    ]
    assert fastest_run(runs) == 2 and fastest_run(runs[:1]) == 0


def test_analysis_figures_and_the_driver_view_at_each_pass(small_track, tmp_path):
    track = load_track(small_track)
    gaps = np.tile(np.arange(1, 6) * 10.0, (40, 1)) - 5.0 * np.arange(40)[:, None]  # one pass each 0.2 s
    trace = _trace(track, gaps, np.zeros(40))
    record = {
        "name": "agent",
        "run": {"run": 0, "seed": 0, "overtaken": 5, "travel_time_s": 3.9, "car_contact_s": 0.0, "wall_contact_s": 0.0},
        "time_s": trace.time_s.tolist(),
        "overtaken": np.sum(gaps < 0, axis=1).tolist(),
        "moments": overtake_moments(trace),
        "car_contacts": [],
        "wall_contacts": [(1.0, 1.2)],
        "speed_kmh": (3.6 * trace.speed_mps).tolist(),
        "pedal": np.linspace(1.0, -1.0, 40).tolist(),
        "heading_error_rad": trace.heading_error_rad.tolist(),
    }
    analysis = {"setting": "A", "track_name": track.name, "car": "tt_cup", "agent": record, "reference": record}
    files = write_analysis_outputs(analysis, trace, track, tmp_path)
    assert [m["opponent"] for m in record["moments"]] == [1, 2, 3, 4, 5]
    # car j leads by 10 j - 5 k m at sample k: 10 m ahead at k = 2j - 2, passed (lead < 0) at k = 2j + 1
    assert [(m["approach_sample"], m["sample"]) for m in record["moments"]] == [(0, 3), (2, 5), (4, 7), (6, 9), (8, 11)]
    assert Path(files["timeline"]).stat().st_size > 1000 and Path(files["paths"]).stat().st_size > 1000
    assert len(files["frames"]) == 5
    from PIL import Image

    view = np.asarray(Image.open(files["frames"][0]))
    assert view.shape == (280, 470, 3) and view.std() > 10.0  # a rendered scene, not a blank image
    assert json.loads(Path(files["json"]).read_text())["agent"]["moments"] == record["moments"]


class BrakingInTurn:
    """The built-in AI in every run, except that run r >= 1 brakes to a stop from r x 0.33 s on: the runs get stuck
    one by one, between trace samples, while run 0 drives to the time limit."""

    def __init__(self) -> None:
        self.ai = BuiltinAI()
        self.control_dt_s = self.ai.control_dt_s

    def reset(self, world, car_ids) -> None:
        self.ai.reset(world, car_ids)
        self.ids = np.asarray(car_ids)

    def act(self, state) -> np.ndarray:
        action = np.array(self.ai.act(state), dtype=np.float64)
        braking = state.time_s[self.ids] >= 0.33 * np.arange(len(self.ids))
        braking[0] = False
        action[braking] = (0.0, -1.0)
        return action


def test_runs_that_end_between_trace_samples_leave_the_others_traces_whole(small_track):
    runs, traces = run_setting(BrakingInTurn(), small_track, "tt_cup", "A", runs=5, time_limit_s=12.0)
    assert runs[0]["end"] == "time limit" and all(run["end"].startswith("stuck") for run in runs[1:])
    ends = [run["travel_time_s"] for run in runs[1:]]
    assert len(set(ends)) == 4  # four separate end events
    for run, trace in zip(runs, traces, strict=True):
        assert trace.time_s[-1] == pytest.approx(run["travel_time_s"])  # each trace ends where its run ended
        assert np.all(np.diff(trace.time_s) > 0.0) and np.all(np.diff(trace.time_s) <= TRACE_DT_S + 1e-9)


def test_the_trace_holds_each_agents_commands_and_heading_against_the_track(small_track):
    _, traces = run_setting(BrakingInTurn(), small_track, "tt_cup", "A", runs=3, time_limit_s=4.0)
    braking = traces[2]  # full brake, wheels straight from 0.66 s on
    late = braking.time_s > 0.8
    assert np.all(braking.pedal[late] == -1.0) and np.all(braking.steer_rad[late] == 0.0)
    assert np.any(traces[0].pedal[traces[0].time_s > 0.8] != -1.0)  # run 0 is the AI throughout
    assert all(abs(trace.heading_error_rad[0]) < 0.05 for trace in traces)  # every car starts along the track
    assert np.all(np.abs(traces[0].heading_error_rad) < 0.5)  # the AI follows it
    assert abs(braking.heading_error_rad[-1]) > 0.5  # wheels straight through a turn: across the track at the end
