"""Faults of train-overtaking and evaluate-overtaking: bad names, a policy of another observation or track, a run
continued with other settings, a kill mid-stage."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.helpers.overtaking import tiny_overtaking_config
from tests.helpers.processes import kill_and_read
from vision_rl.overtaking.config import TrainOvertakingConfig
from vision_rl.overtaking.curriculum import (
    OvertakingRunError,
    check_config,
    load_overtaking_policy,
    read_overtaking_spec,
    train_overtaking,
)
from vision_rl.overtaking.settings import SettingError, evaluate_overtaking
from vision_rl.training.artifact import PolicyError


@pytest.fixture(scope="module")
def agent1_run(tmp_path_factory, small_track) -> Path:
    out = tmp_path_factory.mktemp("overtaking-faults") / "run"
    train_overtaking(tiny_overtaking_config(small_track, out, agent="1", eval_every_steps=0, stage2_steps=40))
    return out


def test_an_unknown_agent_is_refused(fault):
    with pytest.raises(ValueError) as excinfo:
        check_config(TrainOvertakingConfig(agent="4"))
    assert "--agent must be one of 1, 2, 3, standard" in str(excinfo.value)
    fault.refused("train-overtaking --agent 4", str(excinfo.value))


def test_an_unknown_setting_is_refused(fault):
    with pytest.raises(SettingError) as excinfo:
        evaluate_overtaking([], "C")
    fault.refused("evaluate-overtaking --setting C", str(excinfo.value))


def test_a_time_trial_policy_is_refused_as_an_overtaking_policy(state_run, fault):
    out, _ = state_run
    with pytest.raises(PolicyError) as excinfo:
        load_overtaking_policy(out)
    assert "observes 'state'" in str(excinfo.value)
    fault.refused("evaluate-overtaking --policy of train-policy (38-D state)", str(excinfo.value))


def test_a_policy_of_another_track_is_refused(agent1_run, fault):
    with pytest.raises(PolicyError) as excinfo:
        evaluate_overtaking([str(agent1_run / "stage2")], "A", runs=1, track="expressway")
    assert "evaluate it on its own track" in str(excinfo.value)
    fault.refused("evaluate-overtaking --track other than the policy's", str(excinfo.value))


def test_a_continued_run_with_other_stage_settings_is_refused_and_kept(agent1_run, small_track, fault):
    before = (agent1_run / "run.json").read_text()
    with pytest.raises(OvertakingRunError) as excinfo:
        train_overtaking(
            tiny_overtaking_config(small_track, agent1_run, agent="2", eval_every_steps=0, stage2_steps=80)
        )
    assert "stage2_steps = 40, not 80" in str(excinfo.value)
    assert (agent1_run / "run.json").read_text() == before and not (agent1_run / "agent2-stage3").exists()
    fault.refused("train-overtaking on a run folder with another --stage2-steps", str(excinfo.value))
    # Stage 3's own settings are checked against its stage.json.
    cfg = tiny_overtaking_config(small_track, agent1_run, agent="3", eval_every_steps=0, stage2_steps=40)
    train_overtaking(cfg)
    with pytest.raises(OvertakingRunError) as excinfo:
        train_overtaking(
            tiny_overtaking_config(
                small_track, agent1_run, agent="3", eval_every_steps=0, stage2_steps=40, stage3_steps=60
            )
        )
    assert "steps = 100, not 60" in str(excinfo.value)
    fault.refused("train-overtaking --agent 3 again with another --stage3-steps", str(excinfo.value))


def test_a_damaged_sidecar_is_refused(agent1_run, tmp_path, fault):
    bad = tmp_path / "policy.json"
    bad.write_text("{not json")
    with pytest.raises(PolicyError) as excinfo:
        read_overtaking_spec(bad)
    fault.refused("an overtaking policy.json that is not JSON", str(excinfo.value))


def _train_process(track: str, out: Path) -> subprocess.Popen:
    argv = [
        sys.executable,
        "-m",
        "vision_rl.commands.main",
        "train-overtaking",
        "--agent",
        "1",
        "--track",
        track,
        "--out",
        str(out),
        "--cars",
        "2",
        "--stage1-max-steps",
        "600",
        "--stage2-steps",
        "40",
        "--learning-starts",
        "50",
        "--batch-size",
        "32",
        "--buffer-size",
        "5000",
        "--eval-every-steps",
        "0",
        "--checkpoint-every-steps",
        "0",
        "--checkpoint-every-min",
        "0.002",
        "--device",
        "cpu",
        "--no-progress",
    ]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_a_killed_stage_resumes_from_its_checkpoint(small_track, tmp_path, fault):
    out = tmp_path / "run"
    process = _train_process(small_track, out)
    sidecar = out / "stage1" / "policy.json"
    deadline = time.monotonic() + 120
    steps = 0
    while time.monotonic() < deadline and process.poll() is None and steps < 200:
        try:
            steps = read_overtaking_spec(sidecar).num_timesteps
        except (PolicyError, OSError):
            steps = 0
        time.sleep(0.05)
    assert steps >= 200, kill_and_read(process)
    os.kill(process.pid, signal.SIGKILL)
    process.communicate(timeout=60)
    assert json.loads((out / "stage1" / "stage.json").read_text())["status"] == "running"
    assert (out / "stage1" / "replay_buffer.npz").is_file()  # saved when the stage began
    resumed = _train_process(small_track, out)
    _, stderr = resumed.communicate(timeout=120)
    assert resumed.returncode == 0, stderr
    record = json.loads((out / "stage1" / "stage.json").read_text())
    assert record["status"] == "done" and record["end_steps"] == 600 and record["start_steps"] == 0
    assert json.loads((out / "stage2" / "stage.json").read_text())["end_steps"] == 640
    fault.recovered(
        "SIGKILL to train-overtaking mid-stage 1",
        "the light checkpoint (weights, optimisers, counters) and the buffer saved when the stage began "
        "survive; the same command finishes the stage and goes on to stage 2",
    )


def test_the_analysis_takes_one_policy_and_writes_its_figures(agent1_run, tmp_path, fault):
    from vision_rl.commands.evaluate_overtaking import EvaluateOvertakingOptions, run_evaluate_overtaking

    policy = str(agent1_run / "stage2")
    with pytest.raises(SettingError) as excinfo:
        run_evaluate_overtaking(EvaluateOvertakingOptions(analysis=True, policy=f"{policy},{policy}"))
    assert "--analysis takes one --policy, got 2" in str(excinfo.value)
    fault.refused("evaluate-overtaking --analysis with two policies", str(excinfo.value))
    opts = EvaluateOvertakingOptions(analysis=True, policy=policy, tiny=True, time_limit_s=5.0, out=str(tmp_path))
    assert run_evaluate_overtaking(opts) == 0
    analysis = json.loads((tmp_path / "overtaking_analysis.json").read_text())
    assert analysis["reference"]["name"] == "built-in AI" and analysis["agent"]["run"]["seed"] == analysis["run"]
    assert len(analysis["agent"]["time_s"]) == len(analysis["agent"]["x_m"]) and analysis["agent"]["time_s"][0] == 0
    assert (tmp_path / "overtaking_timeline.png").stat().st_size > 1000
