"""`vision-rl evaluate --python module:function --env-id ...`: an outside agent from the command line, listed by the
leaderboard under its name; what the options cannot mean is refused in one line."""

from __future__ import annotations

import json
import sys

import pytest

from vision_rl.commands.evaluate import EvaluateOptions, LeaderboardOptions, run_evaluate, run_leaderboard
from vision_rl.commands.options import parse_config

ENV_ID = "vision_rl/TimeTrial-v1"
AGENT = '''import numpy as np

CALLS = []


def predict(obs):
    """Straight ahead at half throttle."""
    CALLS.append(obs.shape)
    return np.tile([0.0, 0.5], (len(obs), 1))
'''


def test_a_python_agent_is_timed_from_the_command_line_and_listed_by_its_name(small_track, tmp_path, capsys):
    (tmp_path / "half_throttle.py").write_text(AGENT)
    runs = tmp_path / "runs"
    argv = ["--python", f"{tmp_path / 'half_throttle.py'}:predict", "--env-id", ENV_ID, "--track", small_track]
    argv += ["--name", "half throttle", "--runs", str(runs), "--seeds", "2", "--time-limit-s", "5", "--json"]
    assert run_evaluate(parse_config(EvaluateOptions, argv)) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["name"] == "half throttle" and record["n_seeds"] == 2
    assert record["driver"]["python"].endswith("half_throttle.py:predict")
    assert record["driver"]["remeasure"].startswith(f"vision-rl evaluate --python {tmp_path}/half_throttle.py:predict")
    assert record["evaluation_json"] == str(runs / "half-throttle" / "evaluation.json")
    assert run_leaderboard(LeaderboardOptions(track=small_track, runs=str(runs), json=True)) == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    assert [(r["name"], r["kind"]) for r in rows] == [
        ("built-in AI (default skill)", "ai"),
        ("straight driver (full throttle, no steering)", "straight"),
        ("half throttle", "agent (state)"),
    ]


def test_a_module_on_the_working_folder_is_found_and_named_by_default(small_track, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # the module is found on the working folder, as `python -m` would find it
    monkeypatch.delitem(sys.modules, "outside_agent_mod", raising=False)
    (tmp_path / "outside_agent_mod.py").write_text(AGENT)
    opts = EvaluateOptions(
        python="outside_agent_mod:predict", env_id=ENV_ID, track=small_track, seeds=1, time_limit_s=3
    )
    assert run_evaluate(opts) == 0
    text = capsys.readouterr().out
    assert text.startswith("outside_agent_mod:predict (state, stadium, hatchback), protocol v1")
    assert (tmp_path / "runs" / "outside_agent_mod-predict" / "evaluation.json").is_file()
    assert sys.modules["outside_agent_mod"].CALLS[0] == (3, 38) and str(tmp_path) not in sys.path


def test_options_that_cannot_mean_an_outside_agent_are_refused_in_one_line(small_track, tmp_path):
    (tmp_path / "agent.py").write_text(AGENT)
    (tmp_path / "broken.py").write_text("import no_such_module_here\n")
    (tmp_path / "ppo.zip").write_bytes(b"not a zip")
    agent = f"{tmp_path / 'agent.py'}:predict"
    cases = [
        ({"python": agent}, "--python needs --env-id"),
        ({"python": agent, "env_id": ENV_ID, "policy": "x.zip"}, "give --python module:function or --policy"),
        ({"env_id": ENV_ID}, "give --python module:function or --policy"),
        ({"policy": "runs/policy/x", "env_id": ENV_ID}, "drop --env-id"),
        ({"policy": str(tmp_path / "ppo.zip")}, "is a Stable-Baselines3 zip: give --env-id"),
        ({"policy": str(tmp_path / "ppo.zip"), "env_id": ENV_ID}, "not a Stable-Baselines3 zip"),
        ({"policy": "runs/policy/x", "track": small_track}, "give --env-id"),
        ({"python": "agent", "env_id": ENV_ID}, "module:function"),
        ({"python": "no_such_agent_module:predict", "env_id": ENV_ID}, "cannot import no_such_agent_module"),
        ({"python": f"{tmp_path / 'broken.py'}:predict", "env_id": ENV_ID}, "cannot import"),
        ({"python": f"{tmp_path / 'none.py'}:predict", "env_id": ENV_ID}, "no such file"),
        ({"python": f"{tmp_path / 'agent.py'}:act", "env_id": ENV_ID}, "has no attribute 'act'"),
        ({"python": agent, "env_id": ENV_ID, "env_kwargs": "{track: 1}"}, "--env-kwargs is not JSON"),
        ({"python": agent, "env_id": ENV_ID, "env_kwargs": "[1]"}, "must be a JSON object"),
        ({"python": agent, "env_id": ENV_ID, "env_kwargs": '{"encoder": "c.pt"}'}, "as --encoder"),
        ({"python": agent, "env_id": "vision_rl/Nope-v0"}, "not a registered environment"),
    ]
    for fields, why in cases:
        with pytest.raises(ValueError, match=why) as excinfo:
            run_evaluate(EvaluateOptions(**fields))
        assert "\n" not in str(excinfo.value), why
