"""train-policy, evaluate, leaderboard and drive as the CLI builds them: options, text and JSON output."""

from __future__ import annotations

import json

import pytest

from vision_rl.commands.drive import DriveOptions, run_drive
from vision_rl.commands.evaluate import EvaluateOptions, LeaderboardOptions, run_evaluate, run_leaderboard
from vision_rl.commands.options import parse_config
from vision_rl.commands.train_policy import TrainPolicyOptions


def test_options_parse():
    argv = ["--encoder", "ckpt.pt", "--cars", "4", "--preset", "paper", "--no-progress"]
    cfg = parse_config(TrainPolicyOptions, argv)
    assert (cfg.encoder, cfg.cars, cfg.preset, cfg.progress, cfg.steps) == ("ckpt.pt", 4, "paper", False, 1_000_000)
    ev = parse_config(EvaluateOptions, ["--policy", "runs/policy/x", "--laps", "2", "--seeds", "3", "--json"])
    assert (ev.policy, ev.laps, ev.seeds, ev.json) == ("runs/policy/x", 2, 3, True)
    assert parse_config(LeaderboardOptions, ["--track", "technical"]).runs == "runs"


def test_evaluate_and_leaderboard_print(state_run, small_track, capsys):
    out, _ = state_run
    opts = parse_config(EvaluateOptions, ["--policy", str(out), "--seeds", "1", "--time-limit-s", "10", "--no-write"])
    assert run_evaluate(opts) == 0
    text = capsys.readouterr().out
    assert text.startswith("tiny-state (state, stadium, hatchback), protocol v1: best lap 2") and "seed 0:" in text
    with pytest.raises(ValueError, match="--policy"):
        run_evaluate(EvaluateOptions())
    assert run_leaderboard(LeaderboardOptions(track=small_track, runs=str(out.parent.parent), json=True)) == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    assert [r["kind"] for r in rows] == ["ai"]  # the tiny policy was evaluated without writing


def test_drive_runs_the_protocol_and_refuses_other_drivers(small_track, capsys, tmp_path):
    assert run_drive(DriveOptions(track=small_track, seeds=1, laps=1, plot=str(tmp_path / "ai.png"), json=True)) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["protocol"]["version"] == 1 and result["n_finished"] == 1
    assert result["driver"] == {"driver": "built-in AI", "skill": 0.92, "disrupted": False}
    assert (tmp_path / "ai.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(ValueError, match="only 'ai'"):
        run_drive(DriveOptions(driver="human"))
