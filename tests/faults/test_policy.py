"""Policies and replay buffers: files that would run code, tampered or damaged files, a full disk, kills of
train-policy, and out-of-range options."""

from __future__ import annotations

import errno
import json
import os
import pickle
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.helpers.bitflips import check_flips, sample_flips, torch_regions
from tests.helpers.policies import tiny_train_config
from tests.helpers.processes import kill_and_read
from vision_rl.files import CONTENT_KEY, ArtifactWriteError, sealed_record
from vision_rl.phase2_rl.train import train_policy
from vision_rl.training.artifact import PolicyError, PolicySpec, convert_run, convert_sb3_run, load_policy
from vision_rl.training.persist import ArtifactError, file_sha256, read_sb3_zip


class _WritesAMarker:
    """Unpickling this calls ``Path.touch(marker)``: what a crafted file does to whoever loads it with pickle."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


@pytest.fixture
def run_copy(state_run, tmp_path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(state_run[0], out)
    return out


def _rewrite_spec(run: Path, reseal: bool = True, **changes) -> None:
    """Edit policy.json's fields (dotted keys); with ``reseal`` its content hash is made anew, as someone who knows
    the format would, so that what stands behind the hash is tested."""
    data = json.loads((run / "policy.json").read_text())
    for key, value in changes.items():
        target = data
        *parents, leaf = key.split(".")
        for p in parents:
            target = target[p]
        target[leaf] = value
    (run / "policy.json").write_text(json.dumps(sealed_record(data) if reseal else data))


def test_a_crafted_pickle_is_refused_and_never_runs(run_copy, small_track, tmp_path, fault):
    marker = tmp_path / "marker"
    torch.save({"format": "vision_rl.agent", "payload": _WritesAMarker(marker)}, run_copy / "policy.pt")
    _rewrite_spec(run_copy, weights_sha256=file_sha256(run_copy / "policy.pt"))  # even with a matching checksum
    with pytest.raises(PolicyError, match="not a vision_rl agent file") as excinfo:
        load_policy(run_copy)
    assert not marker.exists()
    fault.refused("policy.pt holding a pickled object that runs code (with a matching checksum)", str(excinfo.value))
    with pytest.raises(PolicyError, match="cannot resume") as excinfo:
        train_policy(tiny_train_config(small_track, run_copy, steps=300, resume=True))
    assert not marker.exists()
    fault.refused("--resume from that policy.pt", str(excinfo.value))


def test_a_flipped_byte_in_the_weights_is_refused(run_copy, fault):
    data = bytearray((run_copy / "policy.pt").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (run_copy / "policy.pt").write_bytes(bytes(data))
    with pytest.raises(PolicyError, match="changed after it was written") as excinfo:
        load_policy(run_copy)
    fault.refused("one flipped byte in policy.pt", str(excinfo.value))


def test_a_sidecar_edited_to_another_track_is_refused(run_copy, fault):
    _rewrite_spec(run_copy, **{"racing_config.track": "technical"})
    with pytest.raises(PolicyError, match="track_geometry_hash") as excinfo:
        load_policy(run_copy)
    fault.refused("policy.json's track edited", str(excinfo.value))
    # Editing the recorded geometry hash too is caught by the fingerprint stored inside the weights.
    from vision_rl.sim.track_library import load_track

    _rewrite_spec(run_copy, **{"fingerprint.track_geometry_hash": load_track("technical").geometry_hash})
    with pytest.raises(PolicyError, match=r"policy\.pt was made for track_geometry_hash") as excinfo:
        load_policy(run_copy)
    fault.refused("policy.json's track and fingerprint both edited", str(excinfo.value))
    _rewrite_spec(run_copy, **{"racing_config.car": "gt3"})
    with pytest.raises(PolicyError, match="car") as excinfo:
        load_policy(run_copy)
    fault.refused("policy.json's car edited", str(excinfo.value))


@pytest.mark.parametrize(
    "field, value",
    [
        ("obs_normalizer.offset", "shifted"),
        ("racing_config.steer_action", "rate"),
        ("racing_config.control_dt_s", 0.2),
        ("racing_config.pedal_full_at", 0.5),
        ("num_timesteps", 10**9),
    ],
)
def test_an_edit_of_a_sidecar_field_that_changes_driving_or_a_figure_is_refused(run_copy, field, value, fault):
    if value == "shifted":
        value = [v + 0.5 for v in json.loads((run_copy / "policy.json").read_text())["obs_normalizer"]["offset"]]
    _rewrite_spec(run_copy, reseal=False, **{field: value})
    with pytest.raises(PolicyError, match=r"policy\.json: the policy sidecar has content SHA-256") as excinfo:
        load_policy(run_copy)
    fault.refused(f"policy.json's {field} edited", str(excinfo.value))


@pytest.mark.parametrize(
    "change, message",
    [
        ({"racing_config": None}, "racing_config is None, not of type dict"),
        ({"racing_config.control_dt_s": "0.1"}, "racing_config.control_dt_s is '0.1', not a value like 0.1"),
        ({"racing_config.steer_action": "torque"}, "steer_action must be one of"),
        ({"obs_normalizer.scale": None}, "obs_normalizer needs offset and scale"),
        ({"sac.hidden_units": [256, "x"]}, "sac.hidden_units"),
        ({"model": "../../elsewhere.pt"}, "not a file name beside the sidecar"),
        ({"num_timesteps": "many"}, "num_timesteps is 'many', not of type int"),
        ({"format_version": "4"}, "format_version is '4'"),
    ],
)
def test_a_sealed_sidecar_of_bad_types_is_refused_in_one_line(run_copy, change, message, fault):
    _rewrite_spec(run_copy, **change)  # sealed anew: only the check of the fields stands between it and a traceback
    with pytest.raises(PolicyError, match=re.escape(message)) as excinfo:
        load_policy(run_copy)
    assert "policy.json" in str(excinfo.value)
    fault.refused(f"policy.json (sealed) with {change}", str(excinfo.value))


@pytest.mark.parametrize(
    "text, what",
    [
        ("[" * 100_000 + "]" * 100_000, "nested 100,000 lists deep"),
        ('{"a":' * 50_000 + "1" + "}" * 50_000, "nested 50,000 objects deep"),
        ("[1, 2]", "a JSON list"),
        ("\udcff\x00\xfe", "not UTF-8"),
    ],
)
def test_a_sidecar_that_is_not_a_json_object_is_refused_in_one_line(run_copy, text, what, fault):
    (run_copy / "policy.json").write_bytes(text.encode("utf-8", "surrogateescape"))
    with pytest.raises(PolicyError, match=r"policy\.json") as excinfo:
        load_policy(run_copy)
    fault.refused(f"policy.json {what}", str(excinfo.value))


def test_a_format_3_run_is_refused_until_convert_policy_seals_it(run_copy, small_track, fault):
    data = json.loads((run_copy / "policy.json").read_text())
    data.pop(CONTENT_KEY)
    (run_copy / "policy.json").write_text(json.dumps({**data, "format_version": 3}))
    with pytest.raises(PolicyError, match=r"format 3 has no content hash.*vision-rl convert-policy --run") as excinfo:
        load_policy(run_copy)
    fault.refused("a format-3 policy (no content hash)", str(excinfo.value))
    with pytest.raises(PolicyError, match="vision-rl convert-policy --run") as excinfo:
        train_policy(tiny_train_config(small_track, run_copy, steps=300, resume=True))
    fault.refused("--resume of a format-3 run", str(excinfo.value))
    written = {p.name for p in convert_run(run_copy)}
    assert "policy.json" in written and not convert_run(run_copy)  # sealed once; the second pass writes nothing
    assert load_policy(run_copy).spec == PolicySpec.from_fields({**data, "format_version": 4})
    fault.recovered("a format-3 policy", "vision-rl convert-policy checks its weights' checksum and seals it; it loads")
    (run_copy / "policy.json").write_text(json.dumps({**data, "format_version": 3, "weights_sha256": "0" * 64}))
    with pytest.raises(PolicyError, match="changed after it was written; not sealed") as excinfo:
        convert_run(run_copy)
    fault.refused("convert-policy of a format-3 sidecar whose weights changed", str(excinfo.value))


def test_single_bit_flips_of_a_sidecar_or_its_weights_load_the_same_policy_or_are_refused(run_copy, tmp_path, fault):
    """Seeded single-bit flips of policy.json (all of it is metadata) and of policy.pt (its zip headers and its
    tensors): each loads the same policy or is refused in one line naming the file."""
    spec_path = run_copy / "policy.json"
    original = PolicySpec.read(spec_path)
    kept = tmp_path / "policy.json.orig"
    shutil.copyfile(spec_path, kept)
    flips = sample_flips([range(kept.stat().st_size)], 400, seed=3)
    counts = check_flips(kept, flips, spec_path, PolicySpec.read, original, PolicyError)
    assert counts.refused >= 390
    shutil.copyfile(kept, spec_path)
    weights = tmp_path / "policy.pt.orig"
    shutil.copyfile(run_copy / "policy.pt", weights)
    metadata, data = torch_regions(weights)
    flips = sample_flips(metadata, 30, seed=4) + sample_flips(data, 30, seed=5)
    obs = np.random.default_rng(0).normal(size=(4, 38)).astype(np.float32)
    expected = load_policy(run_copy).act(obs)
    weight_counts = check_flips(
        weights,
        flips,
        run_copy / "policy.pt",
        lambda _: load_policy(run_copy).act(obs),
        expected,
        PolicyError,
        np.array_equal,
    )
    assert weight_counts.refused == len(flips)
    fault.refused(
        f"400 single-bit flips of policy.json: {counts.refused} refused, {counts.unchanged} read the same "
        f"sidecar; 60 of policy.pt (30 over its zip headers and pickled index, 30 over its tensors): all refused",
        f"{counts.example} / {weight_counts.example}",
    )


def test_a_damaged_or_foreign_buffer_stops_resume_with_a_message(run_copy, small_track, fault):
    buffer = run_copy / "replay_buffer.npz"
    original = buffer.read_bytes()
    damaged = bytearray(original)
    damaged[len(damaged) // 2] ^= 0xFF
    buffer.write_bytes(bytes(damaged))
    with pytest.raises(PolicyError, match=r"replay_buffer\.npz") as excinfo:
        train_policy(tiny_train_config(small_track, run_copy, steps=300, resume=True))
    fault.refused("one flipped byte in replay_buffer.npz on --resume", str(excinfo.value))
    buffer.write_bytes(original[: len(original) // 3])
    with pytest.raises(PolicyError, match=r"replay_buffer\.npz") as excinfo:
        train_policy(tiny_train_config(small_track, run_copy, steps=300, resume=True))
    fault.refused("replay_buffer.npz cut short on --resume", str(excinfo.value))
    np.savez(buffer, observations=np.zeros(3))
    with pytest.raises(PolicyError, match=r"replay_buffer\.npz") as excinfo:
        train_policy(tiny_train_config(small_track, run_copy, steps=300, resume=True))
    fault.refused("an .npz that is not a replay buffer on --resume", str(excinfo.value))
    buffer.write_bytes(original)
    with np.load(buffer, allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    np.savez(buffer, **{**arrays, "rewards": arrays["rewards"] * -1000})  # its meta as it was
    with pytest.raises(PolicyError, match=r"replay_buffer\.npz: the array rewards is not the one written") as excinfo:
        train_policy(tiny_train_config(small_track, run_copy, steps=300, resume=True))
    fault.refused("replay_buffer.npz re-saved with its rewards x -1000, on --resume", str(excinfo.value))


def test_a_format_2_policy_is_refused_and_converts_without_unpickling(run_copy, tmp_path, fault):
    """An SB3 zip, as format 2 wrote it: refused until converted, which reads only its tensors and counters."""
    import gymnasium
    from stable_baselines3 import SAC
    from stable_baselines3.common.env_util import make_vec_env

    from vision_rl.envs import racing_env

    class _Env(gymnasium.Env):  # the shape of the state policy's input and the racing action, for SB3
        observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (38,), dtype=np.float32)
        action_space = racing_env.action_space()

        def reset(self, *, seed=None, options=None):
            return np.zeros(38, np.float32), {}

        def step(self, action):
            return np.zeros(38, np.float32), 0.0, False, False, {}

    model = SAC(
        "MlpPolicy",
        make_vec_env(_Env, 1),
        buffer_size=50,
        learning_starts=0,
        policy_kwargs={"net_arch": [256, 256]},
        device="cpu",
    )
    model.learn(20)
    old = tmp_path / "old"
    old.mkdir()
    model.save(old / "policy.zip")
    data = json.loads((run_copy / "policy.json").read_text())
    for key in ("fingerprint", "weights_sha256"):
        data.pop(key)
    (old / "policy.json").write_text(json.dumps({**data, "format_version": 2, "model": "policy.zip"}))
    with pytest.raises(PolicyError, match="convert-policy --run") as excinfo:
        load_policy(old)
    fault.refused("a format-2 policy (Stable-Baselines3 zip, pickled)", str(excinfo.value))
    (old / "checkpoints").mkdir()
    (old / "checkpoints" / "policy_10.zip").write_bytes(b"not a zip")
    with pytest.raises(PolicyError, match="not a Stable-Baselines3 SAC zip") as excinfo:
        convert_sb3_run(old)
    fault.refused("convert-policy of a damaged zip", str(excinfo.value))
    (old / "checkpoints" / "policy_10.zip").unlink()
    (old / "replay_buffer.pkl").write_bytes(pickle.dumps(_WritesAMarker(tmp_path / "marker")))
    written = convert_sb3_run(old)
    assert {p.name for p in written} == {"policy.pt", "policy.json"}
    assert not (tmp_path / "marker").exists()  # neither the zip's pickled parts nor the buffer were unpickled
    loaded = load_policy(old)
    obs = np.random.default_rng(0).normal(size=(4, 38)).astype(np.float32)
    np.testing.assert_allclose(loaded.act(obs), model.predict(obs, deterministic=True)[0], atol=1e-6)
    assert loaded.spec.num_timesteps == 20


def _states_equal(a, b) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_states_equal(a[k], b[k]) for k in a)
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and torch.equal(a, b)
    return a == b


def test_single_bit_flips_of_a_stable_baselines3_zip_read_the_same_tensors_or_are_refused(tmp_path, fault):
    """What convert-policy and evaluate --env-id read of a format-2 or outside agent's zip (deflated members)."""
    import gymnasium
    from stable_baselines3 import SAC

    from vision_rl.envs import racing_env

    class _Env(gymnasium.Env):
        observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (38,), dtype=np.float32)
        action_space = racing_env.action_space()

    model = SAC("MlpPolicy", _Env(), buffer_size=50, policy_kwargs={"net_arch": [8, 8]}, device="cpu")
    original = tmp_path / "original.zip"
    model.save(original)
    flips = sample_flips([range(original.stat().st_size)], 300, seed=7)
    counts = check_flips(
        original, flips, tmp_path / "policy.zip", read_sb3_zip, read_sb3_zip(original), ArtifactError, _states_equal
    )
    assert counts.refused >= 250
    fault.refused(
        f"300 single-bit flips of a Stable-Baselines3 zip read by convert-policy: {counts.refused} refused, "
        f"{counts.unchanged} read the same tensors (the flip in a member never read)",
        counts.example,
    )


def test_a_full_disk_names_the_file_and_keeps_the_previous_one(run_copy, small_track, monkeypatch, fault):
    before = (run_copy / "policy.pt").read_bytes()

    def disk_full(obj, f, *args, **kwargs):  # how torch reports it: a RuntimeError from its zip writer
        Path(f).write_bytes(b"partial")
        raise RuntimeError(
            "[enforce fail at inline_container.cc:664] . PytorchStreamWriter failed writing file "
            "data/0: file write failed: No space left on device"
        )

    monkeypatch.setattr(torch, "save", disk_full)
    with pytest.raises(ArtifactWriteError, match=r"cannot write .*policy\.pt: .*No space left") as excinfo:
        train_policy(tiny_train_config(small_track, run_copy, steps=210, resume=True, eval_every_steps=0))
    assert (run_copy / "policy.pt").read_bytes() == before and not list(run_copy.glob(".*.tmp"))
    assert excinfo.value.errno == errno.ENOSPC and not str(excinfo.value).startswith("[Errno")
    fault.refused("a full disk while saving policy.pt", str(excinfo.value))


@pytest.mark.parametrize(
    "change, message",
    [
        ({"cars": 0}, "--cars 0"),
        ({"cars": 100_000}, "--cars 100000"),
        ({"steps": 0}, "--steps 0"),
        ({"steps": 40, "learning_starts": 50}, "no update"),
        ({"eval_laps": 0}, "--eval-laps 0"),
        ({"episode_s": -1.0}, "--episode-s -1.0"),
        ({"checkpoint_every_min": -5.0}, "--checkpoint-every-min"),
        ({"steer_change_penalty_c_s": -0.5}, "--steer-change-penalty-c-s -0.5"),
        ({"frame_delay_s": 0.067}, "give --encoder"),
        ({"critic_state": True}, "the state observation: give --encoder"),
        ({"frame_delay_s": 2.0}, "--frame-delay-s 2.0"),
        ({"steer_action": "torque"}, "--steer-action must be one of angle, rate"),
        ({"wall_penalty_speed": "start"}, "--wall-penalty-speed must be one of end, impact"),
        ({"steer_change_penalty_scale": "speed"}, "--steer-change-penalty-scale must be one of limit, usable"),
        ({"wall_hit_throttle_cut_s": -1.0}, "--wall-hit-throttle-cut-s -1.0"),
        ({"pedal_full_at": 0.0}, "--pedal-full-at 0.0"),
        ({"pedal_full_at": 1.5}, "--pedal-full-at 1.5"),
        ({"control_dt_s": 0.05}, "--control-dt-s 0.05 is not a whole multiple of the simulator's 0.02 s"),
        ({"control_dt_s": 0.0}, "--control-dt-s 0.0 is out of range"),
        ({"control_dt_s": 1.5}, "--control-dt-s 1.5 is out of range"),
        ({"steer_change_share_of_range": 0.5}, "give --steer-action rate_scaled"),
        ({"restart_before_stuck_share": 0.5}, "give --stuck-ends-episode"),
        ({"restart_before_stuck_share": 1.5, "stuck_ends_episode": True}, "--restart-before-stuck-share 1.5"),
        ({"restart_before_stuck_m": -1.0}, "--restart-before-stuck-m -1.0"),
        ({"guide_bc_weight": 1.0}, "give --guide-steps too"),
        ({"guide_pretrain_steps": 10}, "give --guide-steps too"),
        ({"guide_steps": 100, "guide_bc_weight": -1.0}, "--guide-bc-weight -1.0"),
    ],
)
def test_out_of_range_options_are_refused_before_anything_is_written(small_track, tmp_path, change, message, fault):
    out = tmp_path / "run"
    with pytest.raises(ValueError, match=message) as excinfo:
        train_policy(tiny_train_config(small_track, out, **change))
    assert not out.exists()
    fault.refused(f"train-policy {change}", str(excinfo.value))


def _train_policy_process(track: str, out: Path, steps: int) -> subprocess.Popen:
    argv = [
        sys.executable,
        "-m",
        "vision_rl.commands.main",
        "train-policy",
        "--track",
        track,
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
        "400",
        "--checkpoint-every-min",
        "0.002",
        "--device",
        "cpu",
        "--no-progress",
    ]
    if (out / "policy.json").exists():
        argv.append("--resume")
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_checkpoint(process: subprocess.Popen, spec: Path, at_least_steps: int) -> int:
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        try:
            steps = PolicySpec.read(spec).num_timesteps
        except (PolicyError, OSError):
            steps = 0
        if steps >= at_least_steps:
            return steps
        time.sleep(0.05)
    raise AssertionError(f"no checkpoint of {at_least_steps} steps: {kill_and_read(process)}")


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_a_killed_train_policy_resumes_from_what_it_saved(small_track, tmp_path, sig, fault):
    out = tmp_path / "run"
    process = _train_policy_process(small_track, out, 100_000)
    saved = _wait_for_checkpoint(process, out / "policy.json", 120)
    os.kill(process.pid, sig)
    process.communicate(timeout=60)
    assert process.returncode == (-signal.SIGKILL if sig == signal.SIGKILL else 130)
    spec = PolicySpec.read(out / "policy.json")
    assert spec.num_timesteps >= saved
    load_policy(out)  # the pair on disk is whole: weights match the sidecar's checksum
    target = spec.num_timesteps + 40
    resumed = _train_policy_process(small_track, out, target)
    _, stderr = resumed.communicate(timeout=120)
    assert resumed.returncode == 0, stderr
    assert PolicySpec.read(out / "policy.json").num_timesteps == target
    name = "SIGKILL" if sig == signal.SIGKILL else "SIGTERM"
    how = (
        "the light checkpoint (weights, optimisers, counters) of the last interval survives and --resume continues"
        if sig == signal.SIGKILL
        else "saves weights and buffer, exits 130, --resume continues"
    )
    fault.recovered(f"{name} to train-policy mid-run", how)


def _experiment_process(track: str, out: Path, steps: int) -> subprocess.Popen:
    argv = [
        sys.executable,
        "-m",
        "vision_rl.commands.main",
        "experiment",
        "--training-seeds",
        "0,1",
        "--seeds-at-once",
        "2",
        "--track",
        track,
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
        "10000",
        "--eval-every-steps",
        "0",
        "--eval-seeds",
        "1",
        "--checkpoint-every-steps",
        "0",
        "--checkpoint-every-min",
        "0.005",
        "--device",
        "cpu",
        "--no-progress",
    ]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_a_stopped_experiment_saves_every_seed_running_side_by_side_and_resumes(small_track, tmp_path, fault):
    out = tmp_path / "exp"
    process = _experiment_process(small_track, out, 1_500)
    saved = [_wait_for_checkpoint(process, out / f"seed-{seed}" / "policy.json", 120) for seed in (0, 1)]
    os.kill(process.pid, signal.SIGTERM)
    stdout, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr
    assert "interrupted" in stdout
    for seed, steps in zip((0, 1), saved, strict=True):
        spec = PolicySpec.read(out / f"seed-{seed}" / "policy.json")
        assert steps <= spec.num_timesteps < 1_500
        assert (out / f"seed-{seed}" / "replay_buffer.npz").is_file()  # saved on the stop, for the resume
    resumed = _experiment_process(small_track, out, 1_500)
    _, stderr = resumed.communicate(timeout=300)
    assert resumed.returncode == 0, stderr
    record = json.loads((out / "experiment.json").read_text())
    assert [r["seed"] for r in record["per_seed"]] == [0, 1]
    assert all(PolicySpec.read(out / f"seed-{s}" / "policy.json").num_timesteps == 1_500 for s in (0, 1))
    fault.recovered(
        "SIGTERM to experiment --seeds-at-once 2 mid-run",
        "each seed's process saves its run, exit 130; the same command resumes both",
    )


def test_a_resume_of_a_baseline_run_is_refused(run_copy, small_track, tmp_path, fault):
    """train-policy --resume of a train-baseline folder raised a TypeError traceback (its sac settings are no SAC
    preset's); it is refused, the folder intact."""
    spec = json.loads((run_copy / "policy.json").read_text())
    spec["sac"]["loss"] = "mse of tanh actions in [-1, 1]"  # what a bc run's sidecar holds
    baseline = tmp_path / "bc"
    shutil.copytree(run_copy, baseline)
    (baseline / "policy.json").write_text(json.dumps(sealed_record(spec)))
    before = {p.name: p.read_bytes() for p in baseline.iterdir() if p.is_file()}
    with pytest.raises(PolicyError, match="not a train-policy run") as excinfo:
        train_policy(tiny_train_config(small_track, baseline, steps=300, resume=True))
    assert {p.name: p.read_bytes() for p in baseline.iterdir() if p.is_file()} == before
    fault.refused("train-policy --resume of a train-baseline (bc) run folder", str(excinfo.value))


def test_a_diverged_training_is_one_line_and_keeps_the_folder(small_track, tmp_path, fault):
    """--learning-rate 1e308 turned the actor's outputs to NaN: torch's check printed a multi-line message with the
    tensor. It is one line naming the step."""
    from vision_rl.training.interrupts import TrainingDivergedError

    with pytest.raises(TrainingDivergedError, match="training diverged at step") as excinfo:
        train_policy(tiny_train_config(small_track, tmp_path / "run", learning_rate=1e308))
    assert "\n" not in str(excinfo.value)
    fault.refused("train-policy --learning-rate 1e308 (the policy's outputs become NaN)", str(excinfo.value))


@pytest.mark.parametrize("mode", ["force", "resume"])
def test_a_second_writer_of_a_running_run_is_refused_with_its_files_intact(run_copy, small_track, mode, fault):
    """A second train-policy --force on the folder of a running one deleted its files and wrote its own (the first
    went on and ended with exit 0 over a mixed folder); --resume wrote over it. The running run's lock (held here as
    it holds it) refuses both before anything changes."""
    from vision_rl.files import InUseError, lock_run_folder

    before = {p.name: p.read_bytes() for p in run_copy.iterdir() if p.is_file()}
    held = lock_run_folder(run_copy, "a running train-policy")
    try:
        with pytest.raises(InUseError, match="in use by another process") as excinfo:
            train_policy(tiny_train_config(small_track, run_copy, steps=300, **{mode: True}))
    finally:
        os.close(held)
    assert {p.name: p.read_bytes() for p in run_copy.iterdir() if p.is_file()} == before
    fault.refused(f"train-policy --{mode} on the folder of a running train-policy", str(excinfo.value))


def test_a_full_disk_while_copying_a_snapshot_leaves_no_cut_file(run_copy, small_track, monkeypatch, fault):
    """The snapshot checkpoints/policy_<steps>.pt was copied in place: a disk that filled (a 600 kB tmpfs) left a cut
    copy without its sidecar and a bare "[Errno 28]" line. It is written through a temporary file now."""
    from vision_rl.phase2_rl import train as train_module

    def disk_full(src, dst, *args, **kwargs):
        Path(dst).write_bytes(Path(src).read_bytes()[:100])
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(train_module.shutil, "copyfile", disk_full)
    with pytest.raises(ArtifactWriteError, match=r"cannot write .*policy_\d+\.pt: No space left") as excinfo:
        train_policy(tiny_train_config(small_track, run_copy, steps=300, resume=True, eval_every_steps=0))
    snapshots = {p.name for p in (run_copy / "checkpoints").iterdir()}
    assert all(name.endswith(".json") or name.replace(".pt", ".json") in snapshots for name in snapshots), snapshots
    assert not list((run_copy / "checkpoints").glob(".*.tmp"))
    fault.refused("a full disk while copying a snapshot to checkpoints/", str(excinfo.value))


def test_a_stop_during_set_up_is_one_line_with_exit_130(small_track, tmp_path, monkeypatch, capsys, fault):
    """SIGTERM a few seconds into train-policy (mapped to KeyboardInterrupt, before training had anything to save)
    printed a KeyboardInterrupt traceback. The command says it in one line and exits 130."""
    from vision_rl.commands.main import main
    from vision_rl.phase2_rl import train as train_module

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(train_module, "make_sb3_vec_env", stopped)
    argv = ["--track", small_track, "--steps", "300", "--learning-starts", "50", "--cars", "2", "--device", "cpu"]
    code = main(["train-policy", *argv, "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip()
    assert code == 130 and "Traceback" not in err and len(err.splitlines()) == 1, err
    fault.refused("SIGTERM (or Ctrl-C) to train-policy while it sets up", err)
