"""The policy sidecar: round trips, path resolution, and the encoder-hash check. (Tampered and foreign policy files
are in tests/faults/test_policy.py.)"""

from __future__ import annotations

import json
import shutil

import pytest

from vision_rl.envs import RacingConfig
from vision_rl.phase1_repr import file_sha256
from vision_rl.training.artifact import (
    PolicyError,
    PolicySpec,
    load_checked_encoder,
    load_policy,
    racing_config_from_dict,
    racing_config_to_dict,
    resolve_policy_paths,
)


def _vision_spec(encoder_path, sha) -> PolicySpec:
    cfg = RacingConfig(track="technical", observation="vision", n_groups=3, image_hw_px=(64, 96))
    return PolicySpec(
        observation="vision",
        racing_config=racing_config_to_dict(cfg),
        obs_normalizer={"offset": [0.0] * 75, "scale": [1.0] * 75},
        fingerprint={},
        weights_sha256="",
        encoder={"path": str(encoder_path), "sha256": sha, "rep_dim": 64, "input_hw_px": [64, 96]},
    )


def _state_spec(**kw) -> PolicySpec:
    return PolicySpec(
        observation="state",
        racing_config=racing_config_to_dict(RacingConfig()),
        obs_normalizer={"offset": [0.0] * 38, "scale": [1.0] * 38},
        fingerprint={},
        weights_sha256="",
        **kw,
    )


def test_racing_config_round_trips_through_json():
    cfg = RacingConfig(track="flowing", car="gt3", n_groups=7, image_hw_px=(64, 96), terminate_when_stuck=True)
    back = racing_config_from_dict(json.loads(json.dumps(racing_config_to_dict(cfg))))
    assert back == cfg
    assert back.image_hw_px == (64, 96) and isinstance(back.opponent_skill, tuple)
    with pytest.raises(PolicyError, match="unknown fields"):
        racing_config_from_dict({**racing_config_to_dict(cfg), "warp_drive": True})


def test_spec_round_trip_and_bad_sidecars(tmp_path, tiny_encoders):
    spec = _vision_spec(tiny_encoders[0], "ab" * 32)
    path = spec.write(tmp_path / "policy.json")
    assert PolicySpec.read(path) == spec
    assert PolicySpec.read(path).config.image_hw_px == (64, 96)
    (tmp_path / "other.json").write_text(json.dumps({"format": "something.else"}))
    with pytest.raises(PolicyError, match="not a vision_rl policy"):
        PolicySpec.read(tmp_path / "other.json")
    (tmp_path / "broken.json").write_text("{not json")
    with pytest.raises(PolicyError, match="not valid JSON"):
        PolicySpec.read(tmp_path / "broken.json")
    with pytest.raises(PolicyError, match="must record its encoder"):
        PolicySpec(observation="vision", racing_config={}, obs_normalizer={}, fingerprint={}, weights_sha256="")


def test_encoder_hash_mismatch_is_refused(tmp_path, tiny_encoders):
    enc_a, enc_b = tiny_encoders
    sha_a = file_sha256(enc_a)
    assert sha_a != file_sha256(enc_b)
    spec = _vision_spec(enc_a, sha_a)
    loaded = load_checked_encoder(spec, enc_a)
    assert loaded.path == enc_a and loaded.sha256 == sha_a
    assert load_checked_encoder(spec).path == enc_a  # no --encoder: the recorded checkpoint, checked again
    with pytest.raises(PolicyError, match="trained with encoder sha256"):
        load_checked_encoder(spec, enc_b)
    # The recorded file was replaced by other weights: refused even without --encoder.
    moved = tmp_path / "ckpt.pt"
    shutil.copyfile(enc_b, moved)
    with pytest.raises(PolicyError, match="trained with encoder sha256"):
        load_checked_encoder(_vision_spec(moved, sha_a))
    with pytest.raises(PolicyError, match="--encoder"):
        load_checked_encoder(_vision_spec(tmp_path / "gone.pt", sha_a))
    with pytest.raises(PolicyError, match="takes no encoder"):
        load_checked_encoder(_state_spec(), enc_a)


def test_policy_paths_resolve_from_folder_weights_and_snapshot(tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    for name in ("policy.pt", "checkpoints/policy_100.pt"):
        (run / name).write_bytes(b"weights")
    with pytest.raises(PolicyError, match=r"no sidecar \(policy\.json\)"):
        resolve_policy_paths(run)
    _state_spec().write(run / "policy.json")
    _state_spec(model="policy_100.pt").write(run / "checkpoints" / "policy_100.json")
    assert resolve_policy_paths(run) == (run / "policy.pt", run / "policy.json")
    assert resolve_policy_paths(run / "policy.pt") == (run / "policy.pt", run / "policy.json")
    snapshot = run / "checkpoints" / "policy_100.pt"
    assert resolve_policy_paths(snapshot) == (snapshot, snapshot.with_suffix(".json"))
    with pytest.raises(PolicyError, match="no such policy"):
        resolve_policy_paths(tmp_path / "nothing")
    (run / "policy.pt").unlink()
    with pytest.raises(PolicyError, match="no policy weights here"):
        resolve_policy_paths(run)


def test_bad_encoder_runtime_is_refused_before_loading(tmp_path):
    with pytest.raises(ValueError, match="encoder runtime must be one of"):
        load_policy(tmp_path / "nothing", encoder_runtime="tensorrt")  # before the missing policy is noticed


def test_a_kill_between_the_weights_and_their_sidecar_reads_the_previous_pair(tmp_path):
    import torch

    from vision_rl.training.persist import ArtifactError, previous_weights_path, read_agent, write_agent_state

    path = tmp_path / "policy.pt"
    fingerprint = {"observation": "state"}
    sha_a = write_agent_state({"policy": {"w": torch.zeros(3)}}, path, fingerprint)
    sha_b = write_agent_state({"policy": {"w": torch.ones(3)}}, path, fingerprint)  # the sidecar still says sha_a
    assert previous_weights_path(path).is_file()
    assert read_agent(path, fingerprint, sha_a)["policy"]["w"].sum() == 0  # the pair the sidecar describes
    assert read_agent(path, fingerprint, sha_b)["policy"]["w"].sum() == 3
    with pytest.raises(ArtifactError, match="the file changed after it was written"):
        read_agent(path, fingerprint, "0" * 64)
