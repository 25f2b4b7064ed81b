"""train-policy, evaluate, leaderboard and drive as the CLI builds them: options, text and JSON output."""

from __future__ import annotations

import json
import shutil

import pytest

from vision_rl.commands.drive import DriveOptions, run_drive
from vision_rl.commands.evaluate import EvaluateOptions, LeaderboardOptions, run_evaluate, run_leaderboard
from vision_rl.commands.options import parse_config
from vision_rl.commands.train_policy import TrainPolicyOptions


def test_options_parse():
    argv = ["--encoder", "ckpt.pt", "--cars", "4", "--preset", "paper", "--no-progress"]
    cfg = parse_config(TrainPolicyOptions, argv)
    got = (cfg.encoder, cfg.racing.n_groups, cfg.sac.preset, cfg.progress, cfg.steps)
    assert got == ("ckpt.pt", 4, "paper", False, 1_000_000)
    ev = parse_config(EvaluateOptions, ["--policy", "runs/policy/x", "--laps", "2", "--seeds", "3", "--json"])
    assert (ev.policy, ev.laps, ev.seeds, ev.json) == ("runs/policy/x", 2, 3, True)
    assert parse_config(LeaderboardOptions, ["--track", "technical"]).runs == "runs"


def test_evaluate_and_leaderboard_print(state_run, small_track, capsys, tmp_path):
    out = tmp_path / "policy" / "tiny-state"  # a copy without the evaluations other tests write beside the run
    shutil.copytree(state_run[0], out, ignore=shutil.ignore_patterns("evaluation*.json"))
    opts = parse_config(EvaluateOptions, ["--policy", str(out), "--seeds", "1", "--time-limit-s", "10", "--no-write"])
    assert run_evaluate(opts) == 0
    text = capsys.readouterr().out
    assert text.startswith("tiny-state (state, stadium, hatchback), protocol v1: best lap 2") and "seed 0:" in text
    with pytest.raises(ValueError, match="--policy"):
        run_evaluate(EvaluateOptions())
    assert run_leaderboard(LeaderboardOptions(track=small_track, runs=str(out.parent.parent), json=True)) == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    assert sorted(r["kind"] for r in rows) == ["ai", "straight"]  # the tiny policy was evaluated without writing


def test_drive_runs_the_protocol_and_refuses_other_drivers(small_track, capsys, tmp_path):
    assert run_drive(DriveOptions(track=small_track, seeds=1, laps=1, plot=str(tmp_path / "ai.png"), json=True)) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["protocol"]["version"] == 1 and result["n_finished"] == 1
    assert result["driver"] == {"driver": "built-in AI", "skill": 0.92, "disrupted": False}
    assert (tmp_path / "ai.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(ValueError, match="ai or straight"):
        run_drive(DriveOptions(driver="human"))
    with pytest.raises(ValueError, match="the straight driver has neither"):
        run_drive(DriveOptions(driver="straight", skill=0.8))
    assert run_drive(DriveOptions(track=small_track, driver="straight", seeds=1, laps=1, json=True)) == 0
    straight = json.loads(capsys.readouterr().out)
    assert straight["driver"] == {"driver": "straight", "steer_rad": 0.0, "omega": 1.0}
    assert straight["seeds"][0]["distance_m"] > 50.0  # full throttle from the rolling start


def test_an_experiment_prints_its_last_and_its_chosen_weights():
    from vision_rl.commands.experiment import format_experiment

    def summary(mean_s, std_s):
        return {
            "n_training_seeds": 2,
            "n_training_seeds_finished": 2,
            "lap_time_mean_s": mean_s,
            "lap_time_std_s": std_s,
            "best_lap_time_s": mean_s - std_s,
            "finished": "6/6",
        }

    rows = [
        {"seed": 0, "lap_time_s": 130.5, "finished": "3/3", "wall_contact_s": 0.0},
        {"seed": 1, "lap_time_s": 131.5, "finished": "3/3", "wall_contact_s": None},
    ]
    result = {
        "name": "tt",
        "observation": "state",
        "steps": 1000,
        "track": "expressway",
        "car": "hatchback",
        "summary": summary(131.0, 0.71),
        "per_seed": rows,
        "experiment_json": "exp/experiment.json",
        "selected": {
            "summary": summary(130.2, 0.28),
            "per_seed": [{**rows[0], "lap_time_s": 130.0, "kept_at_steps": 600000}, {**rows[1], "kept_at_steps": None}],
        },
    }
    text = "\n".join(format_experiment(result))
    assert "last weights: lap 2 mean 2:11.000 +- 0.71 s" in text
    assert "weights chosen by the held-out starts: lap 2 mean 2:10.200 +- 0.28 s" in text
    assert "seed 0: 2:10.000 (3/3 finished, wall contact 0.00 s, kept at 600000 steps)" in text
    assert "seed 1: 2:11.500 (3/3 finished, wall contact -, no held-out evaluation clean: last weights)" in text
    assert "kept at" not in format_experiment({**result, "selected": None})[2]
