"""Faults of record-demos, train-baseline and table3: demonstrations of another track or car, damaged, edited or of
the wrong shape; a policy of another algorithm, network or observation; a continued run with other settings; a
run stopped mid-training."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.helpers.overtaking import tiny_baseline_config
from vision_rl.config import replace_flat
from vision_rl.files import sealed_record
from vision_rl.overtaking.baseline_run import BaselineError, RunFolder, check_config
from vision_rl.overtaking.baselines import load_baseline, train_baseline
from vision_rl.overtaking.config import RecordDemosConfig, Table3Config, TrainBaselineConfig
from vision_rl.overtaking.demos import DemoError, load_demos, load_demos_for, record_demos, write_demos
from vision_rl.overtaking.table3 import table3
from vision_rl.training.artifact import PolicyError, PolicySpec, sac_policy
from vision_rl.training.persist import write_agent_state


@pytest.fixture(scope="module")
def runs(tmp_path_factory, small_track, small_demos):
    demos, _ = small_demos
    root = tmp_path_factory.mktemp("baseline-faults")
    for algo in ("bc", "td3"):
        train_baseline(tiny_baseline_config(small_track, demos, root / algo, algo=algo, eval_every_steps=0))
    return root


def test_an_unknown_algorithm_is_refused(fault):
    with pytest.raises(ValueError) as excinfo:
        check_config(TrainBaselineConfig(algo="planet"))
    assert "--algo must be one of bc, gail, td3, sac, dreamer" in str(excinfo.value)
    fault.refused("train-baseline --algo planet", str(excinfo.value))


def test_demonstrations_of_another_track_or_car_are_refused(small_demos, small_track, tmp_path, fault):
    demos, _ = small_demos
    with pytest.raises(DemoError) as excinfo:
        train_baseline(tiny_baseline_config("expressway", demos, tmp_path / "bc", algo="bc"))
    assert "was made for track_geometry_hash" in str(excinfo.value) and not (tmp_path / "bc").exists()
    fault.refused("train-baseline --algo bc on expressway with demonstrations of another track", str(excinfo.value))
    with pytest.raises(DemoError) as excinfo:
        load_demos_for(demos, small_track, "hatchback")
    assert "car = 'tt_cup', not 'hatchback'" in str(excinfo.value)
    fault.refused("demonstrations of the tt_cup used for the hatchback", str(excinfo.value))


def test_a_damaged_demonstrations_file_is_refused(small_demos, tmp_path, fault):
    demos, _ = small_demos
    bad = tmp_path / "cut.npz"
    bad.write_bytes(demos.read_bytes()[: demos.stat().st_size // 2])
    with pytest.raises(DemoError) as excinfo:
        load_demos(bad)
    assert "damaged demonstrations file" in str(excinfo.value)
    fault.refused("a demonstrations file cut in half", str(excinfo.value))
    flipped = bytearray(demos.read_bytes())
    flipped[len(flipped) // 2] ^= 0xFF  # one byte inside an array: the zip's CRC-32 or the arrays' SHA-256
    (tmp_path / "flipped.npz").write_bytes(bytes(flipped))
    with pytest.raises(DemoError) as excinfo:
        load_demos(tmp_path / "flipped.npz")
    fault.refused("a demonstrations file with one byte flipped", str(excinfo.value))


def test_record_demos_refuses_a_damaged_file_to_extend_before_it_drives(small_demos, small_track, tmp_path, fault):
    demos, _ = small_demos
    bad = tmp_path / "cut.npz"
    bad.write_bytes(demos.read_bytes()[: demos.stat().st_size // 2])
    out = tmp_path / "dagger.npz"
    cfg = RecordDemosConfig(track=small_track, car="tt_cup", laps=0.1, cars=1, include=str(bad), out=str(out))
    with pytest.raises(DemoError) as excinfo:
        record_demos(cfg)
    assert "damaged demonstrations file" in str(excinfo.value) and not out.exists()
    fault.refused("record-demos --include a demonstrations file cut in half", str(excinfo.value))


def test_an_edited_demonstrations_file_is_refused(small_demos, tmp_path, fault):
    demos, _ = small_demos
    with np.load(demos, allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    arrays["actions"][5, 1] = -1.0  # brake where the AI did not, saved again with the same meta record
    edited = tmp_path / "edited.npz"
    with open(edited, "wb") as f:
        np.savez(f, **arrays)
    with pytest.raises(DemoError) as excinfo:
        load_demos(edited)
    assert "do not match their recorded SHA-256" in str(excinfo.value)
    fault.refused("a demonstrations file whose actions were edited and saved again", str(excinfo.value))


def test_demonstrations_of_the_wrong_shape_are_refused(small_demos, tmp_path, fault):
    demos, _ = small_demos
    good = load_demos(demos)
    arrays = {
        "observations": good.observations[:, :38],
        "actions": good.actions,
        "rewards": good.rewards,
        "expert_actions": good.expert_actions,
        "episode_starts": good.episode_starts,
    }
    write_demos(tmp_path / "state.npz", arrays, {"fingerprint": good.fingerprint})
    with pytest.raises(DemoError) as excinfo:
        load_demos(tmp_path / "state.npz")
    assert "observations has shape" in str(excinfo.value)
    fault.refused("demonstrations with 38-D observations", str(excinfo.value))
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(DemoError) as excinfo:
        load_demos(tmp_path / "other.npz")
    fault.refused("an .npz that is not a demonstrations file", str(excinfo.value))


def test_a_policy_of_another_algorithm_is_refused(runs, fault):
    with pytest.raises(BaselineError) as excinfo:
        load_baseline(runs / "td3", "bc")
    assert "a td3 policy, not a bc one" in str(excinfo.value)
    fault.refused("a td3 policy loaded as bc", str(excinfo.value))


def test_a_policy_of_another_network_shape_is_refused(runs, tmp_path, fault):
    other = tmp_path / "bc-64"
    shutil.copytree(runs / "bc", other)
    spec = PolicySpec.read(other / "policy.json")
    state = {
        "policy": sac_policy(96, [64, 64]).state_dict(),
        "optimizers": {},
        "counters": {"num_timesteps": 0, "n_updates": 0, "episode_num": 0},
    }
    sha = write_agent_state(state, other / "policy.pt", spec.fingerprint)  # a whole file, checksum and fingerprint
    data = json.loads((other / "policy.json").read_text())
    (other / "policy.json").write_text(json.dumps(sealed_record({**data, "weights_sha256": sha})))
    with pytest.raises(PolicyError) as excinfo:
        load_baseline(other)
    assert "do not fit a [256, 256] network" in str(excinfo.value)
    fault.refused("a bc policy file of a 64 x 64 network under a 256 x 256 sidecar", str(excinfo.value))
    edited = {**data, "weights_sha256": sha, "sac": {"hidden_units": [64, 64]}}
    (other / "policy.json").write_text(json.dumps(sealed_record(edited)))
    with pytest.raises(BaselineError) as excinfo:
        load_baseline(other)
    assert "not the paper's [256, 256]" in str(excinfo.value)
    fault.refused("a baseline policy of 64 x 64 hidden units", str(excinfo.value))


def test_a_policy_of_another_observation_is_refused(state_run, fault):
    out, _ = state_run
    with pytest.raises(BaselineError) as excinfo:
        load_baseline(out)
    assert "observes 'state'" in str(excinfo.value)
    fault.refused("table3 --runs with a train-policy (38-D state) policy", str(excinfo.value))


def test_table3_refuses_a_given_run_of_another_track(runs, fault):
    with pytest.raises(BaselineError) as excinfo:
        table3(Table3Config(runs=str(runs / "bc"), seeds=1, laps=1))
    assert "not 'expressway'" in str(excinfo.value)
    fault.refused("table3 --runs with a run of another track", str(excinfo.value))


def test_a_continued_run_with_other_settings_is_refused_and_kept(runs, small_track, small_demos, fault):
    demos, _ = small_demos
    before = (runs / "td3" / "baseline.json").read_text()
    with pytest.raises(BaselineError) as excinfo:
        train_baseline(
            tiny_baseline_config(small_track, demos, runs / "td3", algo="td3", eval_every_steps=0, td3_noise=0.3)
        )
    assert "td3_noise = 0.1, not 0.3" in str(excinfo.value)
    assert (runs / "td3" / "baseline.json").read_text() == before
    fault.refused("train-baseline --algo td3 on its run folder with another --td3-noise", str(excinfo.value))


def _train_process(track: str, demos: Path, out: Path, steps: int) -> subprocess.Popen:
    argv = [
        sys.executable,
        "-m",
        "vision_rl.commands.main",
        "train-baseline",
        "--algo",
        "sac",
        "--track",
        track,
        "--demos",
        str(demos),
        "--out",
        str(out),
        "--cars",
        "2",
        "--steps",
        str(steps),
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
        "0",
        "--device",
        "cpu",
        "--no-progress",
        "--json",
    ]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_a_stopped_run_saves_and_continues(small_track, small_demos, tmp_path, fault):
    demos, _ = small_demos
    out = tmp_path / "sac"
    process = _train_process(small_track, demos, out, 100_000)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None and not (out / "policy.json").is_file():
        time.sleep(0.1)
    time.sleep(3.0)  # some training after the first save
    process.send_signal(signal.SIGTERM)
    stdout, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr
    stopped = json.loads(stdout)
    assert stopped["status"] == "interrupted" and stopped["num_timesteps"] > 0
    assert (out / "replay_buffer.npz").is_file()
    resumed = _train_process(small_track, demos, out, stopped["num_timesteps"] + 100)
    stdout, stderr = resumed.communicate(timeout=120)
    assert resumed.returncode == 0, stderr
    done = json.loads(stdout)
    assert done["status"] == "done" and done["num_timesteps"] == stopped["num_timesteps"] + 100
    assert done["buffer_restored"] == stopped["num_timesteps"]
    fault.recovered(
        "SIGTERM to train-baseline --algo sac mid-training",
        "weights, optimisers, counters and the replay buffer are saved; the same command with the run's "
        "settings continues from them",
    )


def test_an_edited_baseline_record_is_refused_and_one_of_format_1_still_reads(
    runs, small_track, small_demos, tmp_path, fault
):
    demos, _ = small_demos
    run = Path(shutil.copytree(runs / "td3", tmp_path / "td3"))
    cfg = tiny_baseline_config(small_track, demos, run, algo="td3", eval_every_steps=0)
    path = run / "baseline.json"
    record = json.loads(path.read_text())
    assert record["content_sha256"] == sealed_record(record)["content_sha256"]
    path.write_text(json.dumps({**record, "settings": {**record["settings"], "td3_noise": 0.3}}))
    with pytest.raises(BaselineError) as excinfo:
        RunFolder(replace_flat(cfg, td3_noise=0.3), None)  # the edit would let a resume change its noise
    assert str(excinfo.value).startswith(f"{path}: the run record has content SHA-256")
    fault.refused("a baseline.json whose settings were edited, then resumed", str(excinfo.value))
    path.write_text(
        json.dumps({k: v for k, v in record.items() if k != "content_sha256"})
    )  # before records were sealed
    assert RunFolder(cfg, None).record["settings"] == record["settings"]


def test_a_second_writer_of_a_running_run_is_refused_with_its_files_intact(runs, small_track, small_demos, fault):
    """train-baseline --force on the folder of a running run deleted its files; the running run's lock (held here
    as it holds it) refuses it before anything changes."""
    import os

    from vision_rl.files import InUseError, lock_run_folder

    demos, _ = small_demos
    run = runs / "td3"
    before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    held = lock_run_folder(run, "a running train-baseline")
    try:
        with pytest.raises(InUseError, match="in use by another process") as excinfo:
            train_baseline(tiny_baseline_config(small_track, demos, run, algo="td3", force=True))
    finally:
        os.close(held)
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before
    fault.refused("train-baseline --force on the folder of a running train-baseline", str(excinfo.value))
