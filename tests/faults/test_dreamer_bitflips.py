"""Seeded single-bit flips over a Dreamer baseline's own files (train-baseline --algo dreamer, the Table III PlaNet
row), as its writers leave them: the sequence replay (``replay_buffer.npz``, its headers, meta and arrays) and the
weights (``policy.pt``, read with the SHA-256 its sidecar records; the sidecar is a policy.json, whose flips
tests/faults/test_policy.py tries). Each flip reads what was written or is refused in one line naming the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from tests.helpers.bitflips import check_flips, npz_regions, same_arrays, sample_flips, torch_regions
from vision_rl.overtaking.dreamer import DreamerAgent, DreamerRecipe, SequenceReplay
from vision_rl.overtaking.dreamer_train import load_sequence_replay, save_sequence_replay
from vision_rl.training.persist import ArtifactError, read_agent, write_agent_state

FINGERPRINT = {"observation": "overtaking", "algo": "dreamer", "track_geometry_hash": "ab" * 32}
OBS_DIM, CARS, CAPACITY = 6, 2, 12
TINY = DreamerRecipe(hidden_units=(16, 16), deter_units=16, stoch_units=4)


def _replay() -> SequenceReplay:
    """A replay of 2 cars, one wrapped past its capacity (its oldest rows overwritten), the other not."""
    rng = np.random.default_rng(0)
    replay = SequenceReplay(CAPACITY, CARS, OBS_DIM, 2)
    for step in range(CAPACITY + 5):
        cars = np.arange(CARS) if step < 9 else np.array([0])
        n = len(cars)
        replay.add(
            cars,
            rng.normal(size=(n, OBS_DIM)).astype(np.float32),
            rng.uniform(-1, 1, (n, 2)).astype(np.float32),
            rng.normal(size=n).astype(np.float32),
            np.ones(n, np.float32),
            np.full(n, float(step == 0), np.float32),
        )
    return replay


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path | str]:
    folder = tmp_path_factory.mktemp("dreamer-flips")
    replay_path, weights_path = folder / "replay_buffer.npz", folder / "policy.pt"
    save_sequence_replay(_replay(), replay_path, FINGERPRINT)
    torch.manual_seed(0)
    agent = DreamerAgent(OBS_DIM, 2, TINY, seed=0)
    counters = {"num_timesteps": 17, "n_updates": 0, "episode_num": 0}
    sha = write_agent_state({**agent.state_dict(), "counters": counters}, weights_path, FINGERPRINT)
    return {"replay": replay_path, "weights": weights_path, "sha256": sha}


def test_single_bit_flips_of_the_sequence_replay_load_the_same_rows_or_are_refused(files, tmp_path, fault):
    original = files["replay"]
    metadata, data = npz_regions(original)
    flips = sample_flips(metadata, 150, seed=21) + sample_flips(data, 150, seed=22)

    def load(path: Path) -> dict[str, np.ndarray]:
        replay = SequenceReplay(CAPACITY, CARS, OBS_DIM, 2)
        load_sequence_replay(replay, path, FINGERPRINT)
        return replay.arrays()

    expected = load(original)  # a restore keeps the rows, and counts a wrapped car's writes from them
    assert expected["observations"].shape == (CAPACITY, CARS, OBS_DIM) and expected["rewards"].any()
    counts = check_flips(original, flips, tmp_path / "replay_buffer.npz", load, expected, ArtifactError, same_arrays)
    assert counts.refused >= 250  # a flip in a zip's unused fields (its timestamps) changes no content
    fault.refused(
        f"300 single-bit flips of a Dreamer sequence replay (150 over its zip and .npy headers and meta, 150 over its "
        f"arrays): {counts.refused} refused, {counts.unchanged} load the same rows",
        counts.example,
    )


def test_single_bit_flips_of_the_dreamer_weights_are_refused(files, tmp_path, fault):
    original = files["weights"]
    metadata, data = torch_regions(original)
    flips = sample_flips(metadata, 30, seed=23) + sample_flips(data, 30, seed=24)

    def load(path: Path):  # as load_dreamer and a resumed run read them: with the sidecar's SHA-256
        return read_agent(path, FINGERPRINT, files["sha256"])

    counts = check_flips(original, flips, tmp_path / "policy.pt", load, None, ArtifactError, lambda a, b: False)
    assert counts.refused == len(flips)
    fault.refused(
        "60 single-bit flips of a Dreamer policy.pt (30 over its pickled index and zip, 30 over its tensors): all "
        "refused by the SHA-256 its sidecar records",
        counts.example,
    )
