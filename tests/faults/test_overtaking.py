"""Faults of train-overtaking and evaluate-overtaking: bad names, a policy of another observation or track, a run
continued with other settings, a kill mid-stage."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.helpers.overtaking import tiny_overtaking_config
from tests.helpers.processes import kill_and_read
from vision_rl.commands.convert_policy import ConvertPolicyOptions, run_convert_policy
from vision_rl.overtaking.config import TrainOvertakingConfig
from vision_rl.overtaking.curriculum import (
    OvertakingRunError,
    check_config,
    convert_overtaking_run,
    learning_curve,
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
    with pytest.raises(SettingError) as excinfo:  # --tiny runs 2
        run_evaluate_overtaking(dataclasses.replace(opts, analysis_run=2))
    assert "--analysis-run must be in 0-1 (of --runs 2), got 2" in str(excinfo.value)
    fault.refused("evaluate-overtaking --analysis-run past the runs", str(excinfo.value))
    assert run_evaluate_overtaking(dataclasses.replace(opts, analysis_run=1)) == 0
    asked = json.loads((tmp_path / "overtaking_analysis.json").read_text())
    assert asked["run"] == 1 and asked["run_choice"] == "asked" and asked["agent"]["run"]["run"] == 1
    assert len(asked["agent"]["driver"]["policy_sha256"]) == 64  # which policy the record is of
    agent = asked["agent"]
    assert len(agent["pedal"]) == len(agent["steer_rad"]) == len(agent["heading_error_rad"]) == len(agent["time_s"])
    assert all(-1.0 <= p <= 1.0 for p in agent["pedal"]) and any(p != 0.0 for p in agent["pedal"])


def _unsealed_copy(run: Path, target: Path) -> Path:
    """``run`` as a trainer before sealed run records wrote it: run.json, stage.json and agent1.json without their
    content hash or version, the stages' policy.json of format 3 (no content hash)."""
    shutil.copytree(run, target)
    for path in [target / "run.json", target / "agent1.json", *target.glob("*/stage.json")]:
        record = json.loads(path.read_text())
        for key in ("content_sha256", "format_version"):
            record.pop(key)
        if path.name == "agent1.json":
            record.pop("format")
        path.write_text(json.dumps(record, indent=2))
    for sidecar in target.glob("*/policy.json"):
        spec = json.loads(sidecar.read_text())
        spec.pop("content_sha256")
        sidecar.write_text(json.dumps({**spec, "format_version": 3}, indent=2))
    return target


def test_unsealed_run_records_are_refused_then_converted(agent1_run, tmp_path, fault):
    old = _unsealed_copy(agent1_run, tmp_path / "old")
    with pytest.raises(OvertakingRunError) as excinfo:
        learning_curve(old, "1")  # Fig. 3 reads where stage 2 began from stage2/stage.json
    message = str(excinfo.value)
    assert "stage2/stage.json" in message and f"vision-rl convert-policy --run {old}`" in message
    fault.refused("a stage.json of format 1 (no content hash), read for Fig. 3", message)
    assert run_convert_policy(ConvertPolicyOptions(run=str(old))) == 0
    stage2 = json.loads((old / "stage2" / "stage.json").read_text())
    assert stage2["format_version"] == 2 and stage2["content_sha256"]
    assert json.loads((old / "agent1.json").read_text())["content_sha256"]
    assert learning_curve(old, "1")["stage_switches"] == learning_curve(agent1_run, "1")["stage_switches"]
    assert convert_overtaking_run(old) == []  # sealed and whole: nothing to write
    fault.recovered("a run folder of format 1 (unsealed records)", "`vision-rl convert-policy --run RUN` seals it")


def test_an_unsealed_stage_record_that_disagrees_with_its_policy_is_not_sealed(agent1_run, tmp_path, fault):
    old = _unsealed_copy(agent1_run, tmp_path / "old")
    path = old / "stage2" / "stage.json"
    record = json.loads(path.read_text())
    path.write_text(json.dumps({**record, "end_steps": record["end_steps"] + 1000}))
    with pytest.raises(OvertakingRunError) as excinfo:
        convert_overtaking_run(old)
    # Stage 2 itself, or a stage 3 (an earlier test may have trained one here) that starts where it did not end.
    assert re.fullmatch(
        rf"{re.escape(str(old))}/[\w-]+/stage\.json: (ends at step|starts at step \d+, not where stage2).*; not sealed",
        str(excinfo.value),
    )
    assert "content_sha256" not in json.loads(path.read_text())
    assert "content_sha256" not in json.loads((old / "run.json").read_text())  # nothing sealed before all is checked
    fault.refused("convert-policy on a stage.json whose end steps are not its policy's", str(excinfo.value))


@pytest.mark.parametrize("name", ["run.json", "stage1/stage.json", "agent1.json"])
def test_an_edited_run_record_is_refused(agent1_run, tmp_path, name, fault):
    run = shutil.copytree(agent1_run, tmp_path / "run")
    path = run / name
    record = json.loads(path.read_text())
    key = {"run.json": "ai_lap_time_s", "stage1/stage.json": "start_steps", "agent1.json": "agent"}[name]
    path.write_text(json.dumps({**record, key: 7}))
    with pytest.raises(OvertakingRunError) as excinfo:
        convert_overtaking_run(run)
    assert str(excinfo.value).startswith(f"{path}: the run record has content SHA-256")
    fault.refused(f"an edited {name} of an overtaking run", str(excinfo.value))
