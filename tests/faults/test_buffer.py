"""Replay-buffer files: a buffer re-saved with other rewards, non-finite rewards, a buffer of format 1 (no content
hash), and seeded single-bit flips over the file's metadata and its arrays."""

from __future__ import annotations

import json

import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer

from tests.helpers.bitflips import check_flips, npz_regions, same_arrays, sample_flips
from vision_rl.files import CONTENT_KEY, content_sha256, json_text
from vision_rl.training.persist import ArtifactError, array_sha256, load_buffer, save_buffer, seal_buffer_file

FINGERPRINT = {"track_geometry_hash": "0123456789abcdef", "car": "hatchback", "observation": "state", "obs_dim": 38}


def _buffer(filled: int = 40) -> ReplayBuffer:
    space = spaces.Box(-np.inf, np.inf, (38,), dtype=np.float32)
    buffer = ReplayBuffer(100, space, spaces.Box(-1, 1, (2,), dtype=np.float32), device="cpu", n_envs=2)
    rng = np.random.default_rng(0)
    for _ in range(filled):
        obs = rng.normal(size=(2, 38)).astype(np.float32)
        buffer.add(obs, obs + 1, rng.uniform(-1, 1, (2, 2)), rng.normal(size=2), np.zeros(2), [{}, {}])
    return buffer


def _arrays(buffer: ReplayBuffer) -> dict[str, np.ndarray]:
    n = buffer.buffer_size if buffer.full else buffer.pos
    names = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")
    return {name: getattr(buffer, name)[:n].copy() for name in names}


def _resave(path, meta: dict, arrays: dict, reseal: bool = False) -> None:
    """What someone who edits a buffer with numpy does: the same meta (or one sealed anew), other arrays."""
    if reseal:
        meta = {**meta, "arrays_sha256": {k: array_sha256(v) for k, v in arrays.items()}}
        meta[CONTENT_KEY] = content_sha256(meta)
    with open(path, "wb") as f:
        np.savez(f, meta=np.array(json_text(meta)), **arrays)


def _meta(path) -> dict:
    with np.load(path, allow_pickle=False) as data:
        return json.loads(str(data["meta"]))


def test_a_buffer_resaved_with_other_rewards_is_refused(tmp_path, fault):
    path = tmp_path / "replay_buffer.npz"
    save_buffer(_buffer(), path, FINGERPRINT)
    arrays = _arrays(_buffer())
    _resave(path, _meta(path), {**arrays, "rewards": arrays["rewards"] * -1000})
    with pytest.raises(ArtifactError, match=r"replay_buffer\.npz: the array rewards is not the one written") as exc:
        load_buffer(_buffer(0), path, FINGERPRINT)
    fault.refused("replay_buffer.npz re-saved with its rewards x -1000", str(exc.value))


def test_non_finite_rewards_are_refused_naming_the_buffer(tmp_path, fault):
    path = tmp_path / "replay_buffer.npz"
    arrays = _arrays(_buffer())
    rewards = arrays["rewards"].copy()
    rewards[3, 1] = np.nan
    save_buffer(_buffer(), path, FINGERPRINT)
    _resave(path, _meta(path), {**arrays, "rewards": rewards}, reseal=True)  # even with its hashes made anew
    with pytest.raises(ArtifactError, match=r"replay_buffer\.npz: the array rewards holds non-finite") as exc:
        load_buffer(_buffer(0), path, FINGERPRINT)
    fault.refused("replay_buffer.npz with a NaN reward (its hashes made anew)", str(exc.value))


def test_a_buffer_of_format_1_is_refused_with_the_command_that_seals_it(tmp_path, fault):
    path = tmp_path / "run" / "replay_buffer.npz"
    path.parent.mkdir()
    save_buffer(_buffer(), path, FINGERPRINT)
    meta = {k: v for k, v in _meta(path).items() if k not in ("arrays_sha256", CONTENT_KEY)}
    _resave(path, {**meta, "format_version": 1}, _arrays(_buffer()))
    with pytest.raises(ArtifactError, match=r"format 1 has no content hash.*vision-rl convert-policy --run") as exc:
        load_buffer(_buffer(0), path, FINGERPRINT)
    fault.refused("replay_buffer.npz of format 1 (before content hashes)", str(exc.value))
    assert seal_buffer_file(path) and not seal_buffer_file(path)
    restored = _buffer(0)
    assert load_buffer(restored, path, FINGERPRINT) == 40
    np.testing.assert_array_equal(restored.rewards[:40], _buffer().rewards[:40])
    fault.recovered("replay_buffer.npz of format 1", "vision-rl convert-policy seals it in place and it loads")


def test_single_bit_flips_of_a_buffer_load_the_same_arrays_or_are_refused(tmp_path, fault):
    original = tmp_path / "original.npz"
    save_buffer(_buffer(), original, FINGERPRINT)
    metadata, data = npz_regions(original)
    flips = sample_flips(metadata, 150, seed=1) + sample_flips(data, 150, seed=2)
    expected = _arrays(_buffer())

    def load(path):
        buffer = _buffer(0)
        load_buffer(buffer, path, FINGERPRINT)
        return _arrays(buffer)

    counts = check_flips(original, flips, tmp_path / "replay_buffer.npz", load, expected, ArtifactError, same_arrays)
    assert counts.refused >= 250  # a flip in a zip's unused fields (its timestamps) changes no content
    fault.refused(
        f"{len(flips)} single-bit flips of replay_buffer.npz (150 over its zip and .npy headers and meta, 150 over "
        f"its arrays): {counts.refused} refused, {counts.unchanged} load the same arrays",
        counts.example,
    )
