"""DDPG agents and runs: another variant's checkpoint, frames of another size, a track without a racing line, a
pickle that would run code, a changed replay chunk, a kill after the last checkpoint, runs compare-ddpg cannot
compare."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.helpers.ddpg import hand_made_run, timed_ddpg_config
from tests.helpers.tracks import STADIUM, stadium_csv
from vision_rl.ddpg.agent import (
    DDPGAgent,
    DDPGError,
    DDPGHyper,
    FrameReplay,
    FrameSizeError,
    PixelActor,
    ddpg_fingerprint,
    load_agent,
    load_replay,
    save_agent_file,
    save_replay,
)
from vision_rl.envs.pixel_racing import PixelRacingConfig, PixelRacingError, goal_line
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import get_preset
from vision_rl.training.persist import ArtifactError

HW = (32, 48)


class _WritesAMarker:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


@pytest.fixture(scope="module")
def track(tmp_path_factory) -> str:
    return str(stadium_csv(tmp_path_factory.mktemp("track") / "stadium.csv", *STADIUM))


def _saved(track: str, folder: Path, variant: str) -> Path:
    env = PixelRacingConfig(track=track, image_hw_px=HW, frames=variant != "state-actor")
    agent = DDPGAgent(DDPGHyper(variant=variant), env)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "ddpg.pt"
    save_agent_file(agent, path, ddpg_fingerprint(agent.hyper, env), {"num_steps": 0})
    return path


def test_a_symmetric_checkpoint_loaded_as_asymmetric_is_refused(track, tmp_path, fault):
    path = _saved(track, tmp_path / "sym", "symmetric")
    with pytest.raises(DDPGError, match="variant 'symmetric', not 'asymmetric'") as excinfo:
        load_agent(path, variant="asymmetric")
    fault.refused("a symmetric agent's ddpg.pt loaded as --variant asymmetric", str(excinfo.value))


def test_resuming_a_symmetric_run_as_asymmetric_is_refused(track, tmp_path, fault):
    import json

    from vision_rl.config import from_flat
    from vision_rl.ddpg.train import TrainDDPGConfig, train_ddpg

    out = tmp_path / "run"
    _saved(track, out, "symmetric")
    (out / "ddpg.json").write_text(json.dumps({"format": "vision_rl.ddpg_run", "hyper": {"variant": "symmetric"}}))
    with pytest.raises(DDPGError, match="variant 'symmetric', not 'asymmetric'") as excinfo:
        train_ddpg(from_flat(TrainDDPGConfig, track=track, out=str(out), resume=True, variant="asymmetric"))
    fault.refused("train-ddpg --resume --variant asymmetric of a symmetric run", str(excinfo.value))


def test_frames_of_another_size_are_refused(fault):
    actor = PixelActor(HW).eval()
    with pytest.raises(FrameSizeError, match="built for 32x48x3") as excinfo:
        actor({"image": torch.zeros((2, 89, 120, 3), dtype=torch.uint8)})
    fault.refused("89x120 frames fed to an actor built for 32x48", str(excinfo.value))
    with pytest.raises(FrameSizeError, match="too small") as excinfo:
        PixelActor((16, 16))
    fault.refused("an actor asked for 16x16 frames (too small for four conv + pool stages)", str(excinfo.value))


def test_a_track_without_a_reference_racing_line_is_refused(track, fault):
    with pytest.raises(PixelRacingError, match="no reference racing line") as excinfo:
        goal_line(load_track(track), get_preset("gt3"), "reference", track)
    fault.refused("racing_line='reference' on a track that has none", str(excinfo.value))


def test_a_crafted_pickle_in_ddpg_pt_is_refused_and_never_runs(tmp_path, fault):
    marker = tmp_path / "marker"
    path = tmp_path / "ddpg.pt"
    torch.save({"format": "vision_rl.ddpg_agent", "payload": _WritesAMarker(marker)}, path)
    with pytest.raises(ArtifactError, match="not a DDPG agent file") as excinfo:
        load_agent(path)
    assert not marker.exists()
    fault.refused("ddpg.pt holding a pickled object that runs code", str(excinfo.value))


def _saved_one_frame_replay(folder) -> FrameReplay:
    """A replay of one car holding its first frame, saved to ``folder``; returns it."""
    buf = FrameReplay(20, 1, HW)
    buf.start(
        {
            "image": np.ones((1, *HW, 3), np.uint8),
            "motion": np.zeros((1, 15), np.float32),
            "goal": np.zeros((1, 3), np.float32),
        }
    )
    save_replay(buf, folder, {"variant": "asymmetric"})
    return buf


def test_a_changed_replay_chunk_is_refused(tmp_path, fault):
    _saved_one_frame_replay(tmp_path / "replay")
    chunk = next((tmp_path / "replay").glob("chunk_*.npz"))
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0xFF
    chunk.write_bytes(bytes(data))
    with pytest.raises(ArtifactError, match="changed after it was written") as excinfo:
        load_replay(FrameReplay(20, 1, HW), tmp_path / "replay", {"variant": "asymmetric"})
    fault.refused("one flipped byte in a replay chunk", str(excinfo.value))
    with pytest.raises(ArtifactError, match="variant") as excinfo:
        load_replay(FrameReplay(20, 1, HW), tmp_path / "replay", {"variant": "symmetric"})
    fault.refused("a replay buffer of another variant", str(excinfo.value))


def test_episodes_logged_after_the_last_checkpoint_are_dropped_on_resume(track, tmp_path, fault):
    from vision_rl.ddpg.train import train_ddpg

    run = tmp_path / "run"
    first = train_ddpg(timed_ddpg_config(track, run))
    episodes = tmp_path / "run" / "episodes.jsonl"
    logged = episodes.read_text().splitlines()
    assert len(logged) == first["episodes"] > 0
    # What a kill after the checkpoint leaves: an episode the resume drives again, and a line torn mid-write.
    with open(episodes, "a") as f:
        f.write(json.dumps({"episode": first["episodes"], "num_steps": first["num_steps"]}) + '\n{"episode": 9, "nu')
    second = train_ddpg(timed_ddpg_config(track, run, train_minutes=0.03, resume=True))
    records = [json.loads(line) for line in episodes.read_text().splitlines()]
    assert [r["episode"] for r in records] == list(range(second["episodes"]))  # each episode once, in order
    assert records[: len(logged)] == [json.loads(line) for line in logged]
    fault.recovered(
        "train-ddpg killed after its last checkpoint, then resumed",
        "episodes.jsonl keeps the checkpoint's episodes and drops those driven again and a torn line",
    )


def test_runs_compare_ddpg_cannot_compare_are_refused(tmp_path, fault):
    from vision_rl.ddpg.compare import compare_runs

    a = hand_made_run(tmp_path / "a", "asymmetric", 10.0, [(1, 100, 0)])
    with pytest.raises(DDPGError, match="not a train-ddpg run folder") as excinfo:
        compare_runs([a, tmp_path])
    fault.refused("compare-ddpg given a folder that is not a train-ddpg run", str(excinfo.value))
    with pytest.raises(DDPGError, match="1 names for 2 runs") as excinfo:
        compare_runs([a, a], names=["only one"])
    fault.refused("compare-ddpg with fewer --names than runs", str(excinfo.value))
    other = hand_made_run(tmp_path / "b", "symmetric", 10.0, [(1, 100, 0)], track="Spa")
    with pytest.raises(DDPGError, match="different tracks or cars") as excinfo:
        compare_runs([a, other])
    fault.refused("compare-ddpg of runs on two tracks", str(excinfo.value))
    with open(a / "episodes.jsonl", "a") as f:
        f.write('{"train_time_s": 70.0, "dist')
    with pytest.raises(DDPGError, match="line 2 is not an episode record") as excinfo:
        compare_runs([a])
    fault.refused("compare-ddpg of a run whose episodes.jsonl has a torn line", str(excinfo.value))
    (a / "episodes.jsonl").unlink()
    with pytest.raises(DDPGError, match="has not finished an episode yet") as excinfo:
        compare_runs([a])
    fault.refused("compare-ddpg of a run with no finished episode", str(excinfo.value))


def test_an_edited_replay_index_or_run_sidecar_is_refused_and_format_1_still_reads(track, tmp_path, fault):
    from vision_rl.ddpg.agent import SIDECAR_NAME, read_run_sidecar

    buf = _saved_one_frame_replay(tmp_path / "replay")
    index_path = tmp_path / "replay" / "index.json"
    index = json.loads(index_path.read_text())
    assert index["format_version"] == 2 and "content_sha256" in index
    index_path.write_text(json.dumps({**index, "pos": [7]}))  # where the next transition goes: a changed buffer
    with pytest.raises(ArtifactError, match="the file changed after it was written") as excinfo:
        load_replay(FrameReplay(20, 1, HW), tmp_path / "replay", {"variant": "asymmetric"})
    fault.refused("a replay index whose write position was edited", str(excinfo.value))
    index_path.write_text(json.dumps({**index, "format_version": 0}))  # one bit of the version: the hash still holds
    with pytest.raises(ArtifactError):
        load_replay(FrameReplay(20, 1, HW), tmp_path / "replay", {"variant": "asymmetric"})
    legacy = {k: v for k, v in index.items() if k != "content_sha256"}
    index_path.write_text(json.dumps({**legacy, "format_version": 1}))
    loaded = FrameReplay(20, 1, HW)  # format 1, written before the hash, reads as it was
    load_replay(loaded, tmp_path / "replay", {"variant": "asymmetric"})
    assert loaded.pos.tolist() == index["pos"] and np.array_equal(loaded.image, buf.image)

    from vision_rl.ddpg.train import train_ddpg

    run = tmp_path / "run"
    train_ddpg(timed_ddpg_config(track, run))
    sidecar_path = tmp_path / "run" / SIDECAR_NAME
    sidecar = json.loads(sidecar_path.read_text())
    assert read_run_sidecar(sidecar_path) == sidecar and sidecar["format_version"] == 2
    sidecar_path.write_text(json.dumps({**sidecar, "counters": {**sidecar["counters"], "train_time_s": 1.0}}))
    with pytest.raises(DDPGError, match="the file changed after it was written") as excinfo:
        train_ddpg(timed_ddpg_config(track, run, resume=True))
    fault.refused("a train-ddpg sidecar whose training time was edited, then resumed", str(excinfo.value))
    with pytest.raises(DDPGError, match="the file changed after it was written"):
        load_agent(tmp_path / "run")


def test_a_second_writer_of_a_running_run_is_refused_with_its_files_intact(track, tmp_path, fault):
    """train-ddpg --force on the folder of a running run deleted its files (the first went on, exit 0); the
    running run's lock (held here as it holds it) refuses it before anything changes."""
    import os

    from vision_rl.ddpg.train import train_ddpg
    from vision_rl.files import InUseError, lock_run_folder

    run = _saved(track, tmp_path / "run", "symmetric").parent
    before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    held = lock_run_folder(run, "a running train-ddpg")
    try:
        with pytest.raises(InUseError, match="in use by another process") as excinfo:
            train_ddpg(timed_ddpg_config(track, run, force=True))
    finally:
        os.close(held)
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before
    fault.refused("train-ddpg --force on the folder of a running train-ddpg", str(excinfo.value))
