"""Seeded single-bit flips over a train-ddpg run's files, as its own writers leave them: the sidecar ``ddpg.json``,
the agent file ``ddpg.pt`` (through its run folder and alone), the replay index and a replay chunk. Each flip either
loads what was written or is refused in one line naming the file (tests/helpers/bitflips.py)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.helpers.bitflips import check_flips, npz_regions, same_arrays, sample_flips, torch_regions
from tests.helpers.ddpg import HW, ddpg_config
from tests.helpers.tracks import STADIUM, stadium_csv
from vision_rl.ddpg.agent import (
    AGENT_NAME,
    REPLAY_DIR,
    SIDECAR_NAME,
    DDPGAgent,
    FrameReplay,
    load_replay,
    read_agent_file,
    read_run_sidecar,
)
from vision_rl.ddpg.config import DDPGError
from vision_rl.ddpg.train import _Run
from vision_rl.training.persist import ArtifactError

REPLAY_ROWS = 20


def _replay(seed: int = 0) -> FrameReplay:
    """A small replay of 2 cars with a few random transitions (the sampler's arrays, frames included)."""
    rng = np.random.default_rng(seed)
    replay = FrameReplay(REPLAY_ROWS, 2, HW)

    def obs() -> dict[str, np.ndarray]:
        return {
            "image": rng.integers(0, 255, (2, *HW, 3), dtype=np.uint8),
            "motion": rng.normal(size=(2, 15)).astype(np.float32),
            "goal": rng.normal(size=(2, 3)).astype(np.float32),
        }

    replay.start(obs())
    for _ in range(6):
        action = rng.uniform(-1, 1, (2, replay.action.shape[-1])).astype(np.float32)
        replay.add(action, rng.normal(size=2), np.zeros(2, bool), obs(), np.zeros(2, bool))
    return replay


@pytest.fixture(scope="module")
def ddpg_run(tmp_path_factory) -> tuple[Path, dict]:
    """A run folder written by train-ddpg's own save (agent, sidecar, replay), untrained: (folder, fingerprint)."""
    torch.manual_seed(0)
    root = tmp_path_factory.mktemp("ddpg-flips")
    track = str(stadium_csv(root / "stadium.csv", *STADIUM))
    run = _Run(ddpg_config(track, root / "run", variant="symmetric", buffer_size=REPLAY_ROWS * 2))
    run.save(DDPGAgent(run.hyper, run.env, n_cars=1), _replay())
    return run.out, run.fingerprint


def _copy(run: Path, target: Path) -> Path:
    return Path(shutil.copytree(run, target))


def _same_state(a, b) -> bool:
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and a.dtype == b.dtype and torch.equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same_state(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(_same_state(x, y) for x, y in zip(a, b, strict=True))
    return a == b and type(a) is type(b)


def test_single_bit_flips_of_the_run_sidecar_read_the_same_or_are_refused(ddpg_run, tmp_path, fault):
    run, _ = ddpg_run
    original = run / SIDECAR_NAME
    flips = sample_flips([range(original.stat().st_size)], 400, seed=11)
    target = tmp_path / SIDECAR_NAME
    expected = json.loads(original.read_text())
    counts = check_flips(original, flips, target, read_run_sidecar, expected, DDPGError)
    assert counts.refused >= 380  # white space of the layout, or 'e' -> 'E' in an exponent, reads the same
    fault.refused(
        f"400 single-bit flips of ddpg.json: {counts.refused} refused, {counts.unchanged} read the same",
        counts.example,
    )


def test_single_bit_flips_of_the_agent_file_are_refused_through_its_run_and_alone(ddpg_run, tmp_path, fault):
    run, _ = ddpg_run
    original = run / AGENT_NAME
    metadata, data = torch_regions(original)
    index_flips, tensor_flips = sample_flips(metadata, 30, seed=12), sample_flips(data, 30, seed=13)
    folder = _copy(run, tmp_path / "run")

    def through_run(path: Path):  # as load_agent reads a run's agent: with the SHA-256 its sidecar records
        return read_agent_file(path, read_run_sidecar(path.with_name(SIDECAR_NAME))["weights_sha256"])

    refusals = (ArtifactError, DDPGError)
    through = check_flips(
        original, index_flips[:10] + tensor_flips[:10], folder / AGENT_NAME, through_run, None, refusals
    )
    assert through.refused == 20
    alone = tmp_path / "alone" / "agent.pt"  # a copy without its sidecar: its own state_sha256 is what is left
    alone.parent.mkdir()
    expected = read_agent_file(original)
    tensors = check_flips(original, tensor_flips, alone, read_agent_file, expected, ArtifactError, _same_state)
    assert tensors.refused == 30  # every weight, optimiser moment and counter is under state_sha256
    index = check_flips(original, index_flips, alone, read_agent_file, expected, ArtifactError, _same_state)
    assert index.refused >= 10  # the zip's unused bytes (timestamps, the padding before each storage) change nothing
    fault.refused(
        f"60 single-bit flips of ddpg.pt (30 over its pickled index and zip, 30 over its tensors): 20 tried through "
        f"the run, all refused by the sidecar's SHA-256; alone, all 30 tensor flips refused by its state_sha256, "
        f"{index.refused} of the index's refused and {index.unchanged} load the same state",
        tensors.example,
    )


def _loaded_replay(folder: Path, fingerprint: dict) -> dict[str, np.ndarray]:
    replay = FrameReplay(REPLAY_ROWS, 2, HW)
    load_replay(replay, folder, fingerprint)
    return {
        "pos": replay.pos.copy(),
        **{name: getattr(replay, name).copy() for name in replay.arrays if getattr(replay, name) is not None},
    }


def test_single_bit_flips_of_the_replay_index_and_a_chunk_load_the_same_or_are_refused(ddpg_run, tmp_path, fault):
    run, fingerprint = ddpg_run
    folder = _copy(run, tmp_path / "run") / REPLAY_DIR
    expected = _loaded_replay(run / REPLAY_DIR, fingerprint)
    assert expected["image"].any()  # frames were written: a flip of them is a flip of data

    def load(path: Path) -> dict[str, np.ndarray]:
        return _loaded_replay(path.parent, fingerprint)

    index = run / REPLAY_DIR / "index.json"
    flips = sample_flips([range(index.stat().st_size)], 300, seed=14)
    counts = check_flips(index, flips, folder / "index.json", load, expected, ArtifactError, same_arrays)
    assert counts.refused >= 285
    shutil.copy(index, folder / "index.json")  # the index whole again: now the chunk's flips
    (chunk,) = (run / REPLAY_DIR).glob("chunk_*.npz")
    metadata, data = npz_regions(chunk)
    chunk_flips = sample_flips(metadata, 40, seed=15) + sample_flips(data, 40, seed=16)
    chunks = check_flips(chunk, chunk_flips, folder / chunk.name, load, expected, ArtifactError, same_arrays)
    assert chunks.refused == len(chunk_flips)  # the index holds each chunk's SHA-256
    fault.refused(
        f"300 single-bit flips of the DDPG replay index: {counts.refused} refused, {counts.unchanged} load the same "
        f"buffer; 80 of a replay chunk (its headers and its arrays): all refused",
        counts.example,
    )
