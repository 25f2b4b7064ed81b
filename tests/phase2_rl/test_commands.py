"""The three commands as the CLI builds them: options from the config dataclasses, text and JSON output."""

from __future__ import annotations

import argparse
import json

import pytest

from vision_rl.config import add_config_arguments, config_from_args
from vision_rl.phase2_rl import leaderboard as lb
from vision_rl.phase2_rl.evaluate import EvaluateConfig, run_evaluate
from vision_rl.phase2_rl.leaderboard import LeaderboardConfig, run_leaderboard
from vision_rl.phase2_rl.train import TrainPolicyConfig


def _parse(config_cls, argv):
    parser = argparse.ArgumentParser()
    add_config_arguments(parser, config_cls)  # raises TypeError for a field the CLI cannot express
    return config_from_args(config_cls, parser.parse_args(argv))


def test_options_parse():
    cfg = _parse(TrainPolicyConfig, ["--encoder", "ckpt.pt", "--cars", "4", "--preset", "paper", "--no-progress"])
    assert (cfg.encoder, cfg.cars, cfg.preset, cfg.progress, cfg.steps) == ("ckpt.pt", 4, "paper", False, 1_000_000)
    ev = _parse(EvaluateConfig, ["--policy", "runs/policy/x", "--laps", "2", "--seeds", "3", "--json"])
    assert (ev.policy, ev.laps, ev.seeds, ev.json, ev.start) == ("runs/policy/x", 2, 3, True, "rolling")
    assert _parse(LeaderboardConfig, ["--track", "technical"]).runs == "runs"


def test_evaluate_and_leaderboard_print(state_run, small_track, capsys, monkeypatch):
    out, _ = state_run
    assert run_evaluate(_parse(EvaluateConfig, ["--policy", str(out), "--seeds", "1", "--time-limit-s", "10",
                                                "--no-write"])) == 0  # fmt: skip
    text = capsys.readouterr().out
    assert text.startswith("tiny-state (state, stadium, hatchback): best lap 2") and "seed 0:" in text
    with pytest.raises(ValueError, match="--policy"):
        run_evaluate(EvaluateConfig())
    monkeypatch.setattr(lb, "reference_lap_times",
                        lambda track, car: {"limit_lap_time_s": 25.0, "ai_lap_time_s": 28.0, "source": "test"})
    assert run_leaderboard(LeaderboardConfig(track=small_track, runs=str(out.parent.parent), json=True)) == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    assert [r["name"] for r in rows][:2] == ["physical limit (QSS)", "built-in AI (default skill)"]
