"""Faults of the sharded capture: a worker killed mid-shard (with and without Ray's rerun), a manifest whose shard is
missing, changed or another run's, an edited manifest, a resume with other settings, bad --workers, no Ray."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import signal
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.helpers.captures import ATTRS, write_synthetic_capture
from vision_rl.capture.h5format import CaptureFormatError, open_capture
from vision_rl.capture.sharded import (
    ManifestError,
    ShardedCaptureConfig,
    capture_sharded,
    open_manifest,
    plan_shards,
    shards_dir,
    write_manifest,
)
from vision_rl.commands.main import main
from vision_rl.datasets.capture_dataset import FrameCatalogue


def _circle_csv(path: Path) -> str:
    a = np.linspace(0.0, 2 * np.pi, 120, endpoint=False)
    rows = np.stack([40 * np.cos(a), 40 * np.sin(a), np.full(120, 6.0), np.full(120, 6.0)], axis=1)
    np.savetxt(path, rows, delimiter=",", header="x_m,y_m,w_tr_right_m,w_tr_left_m")
    return str(path)


def _config(tmp_path: Path, **kw) -> ShardedCaptureConfig:
    base = dict(
        out=str(tmp_path / "cap.json"),
        track=_circle_csv(tmp_path / "circle.csv"),
        laps=2,
        cars=2,
        fps=5,
        image_hw_px=(32, 48),
        seed=3,
        workers=2,
    )
    return ShardedCaptureConfig(**{**base, **kw})


def _sha(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@pytest.fixture
def synthetic_run(tmp_path) -> tuple[ShardedCaptureConfig, list[Path]]:
    """A manifest over two small synthetic shards (no renderer, no Ray): what the manifest checks act on."""
    cfg = _config(tmp_path)
    shards = plan_shards(cfg)
    for i, shard in enumerate(shards):
        write_synthetic_capture(Path(shard.out), seed=i)
    write_manifest(cfg, shards, {"seed": cfg.seed})
    return cfg, [Path(s.out) for s in shards]


def _refused(path, fault, what: str, *words: str) -> str:
    with pytest.raises(CaptureFormatError) as info:
        FrameCatalogue.open(str(path))
    message = str(info.value)
    assert len(message.splitlines()) == 1 and all(w in message for w in words), message
    fault.refused(what, message)
    return message


def test_a_missing_shard_is_refused_naming_it(synthetic_run, fault):
    cfg, paths = synthetic_run
    assert len(FrameCatalogue.open(cfg.out)) == 2 * 16  # the intact run opens
    paths[1].unlink()
    _refused(
        cfg.out, fault, "a manifest whose shard file is missing", "shard cap.shards/shard_001.h5 is missing", "--resume"
    )


def test_a_changed_shard_is_refused_naming_it(synthetic_run, fault):
    cfg, paths = synthetic_run
    paths[0].unlink()
    write_synthetic_capture(paths[0], seed=5, n_laps=3)  # same settings, other frames
    message = _refused(
        cfg.out,
        fault,
        "a manifest whose shard was replaced by other frames of the same settings",
        "shard cap.shards/shard_000.h5 changed since the manifest was written",
    )
    assert "shard_001" not in message  # the intact shard is not blamed


def test_a_foreign_shard_is_refused_naming_the_field(synthetic_run, tmp_path, fault):
    from vision_rl.capture.h5format import CaptureWriter
    from vision_rl.sim import sensors

    cfg, paths = synthetic_run
    paths[1].unlink()
    with CaptureWriter(
        paths[1],
        image_hw_px=(64, 96),
        target_names=sensors.TARGET_NAMES,
        target_units=sensors.TARGET_UNITS,
        dedicated_names=sensors.DEDICATED_NAMES,
        dedicated_units=sensors.DEDICATED_UNITS,
        attrs={**ATTRS, "car_preset": "gt3"},
    ) as w:
        w.close(complete=True)
    message = _refused(
        cfg.out,
        fault,
        "a manifest whose shard is another run's capture",
        "shard cap.shards/shard_001.h5 is not this run's shard",
        "car_preset is 'gt3'",
    )
    assert "shard_000" not in message  # the intact shard is not blamed


def test_an_edited_manifest_is_refused(synthetic_run, fault):
    cfg, _ = synthetic_run
    body = json.loads(Path(cfg.out).read_text())
    body["shards"][0]["n_frames"] = 8
    Path(cfg.out).write_text(json.dumps(body))
    edited = _refused(cfg.out, fault, "a manifest edited by hand", "does not match its manifest_sha256")
    Path(cfg.out).write_text("{not json")
    garbled = _refused(cfg.out, fault, "a manifest that is not JSON", "not a capture manifest")
    assert all(str(cfg.out) in m for m in (edited, garbled))  # both name the manifest


def test_a_resume_with_other_settings_is_refused_naming_the_option(synthetic_run, fault):
    cfg, _ = synthetic_run
    from vision_rl.capture.sharded import _settings
    from vision_rl.sim.track_library import load_track

    write_manifest(cfg, plan_shards(cfg), _settings(cfg, load_track(cfg.track).geometry_hash))
    with pytest.raises(ManifestError) as info:
        capture_sharded(dataclasses.replace(cfg, seed=4, resume=True))
    message = str(info.value)
    assert "cannot resume: settings.seed was 3, now 4 (--seed)" in message and len(message.splitlines()) == 1
    fault.refused("capture --workers 2 --resume with another --seed", message)
    other = r"settings\.disrupt_steer_offset_rad was 0\.3, now 0\.6 \(--disrupt-steer-offset-rad\)"
    with pytest.raises(ManifestError, match=other):
        capture_sharded(dataclasses.replace(cfg, disrupt_steer_offset_rad=0.6, resume=True))


@pytest.mark.parametrize("argv", [["--workers", "0"], ["--workers", "2", "--laps", "1"], ["--address", "auto"]])
def test_bad_worker_options_are_one_line(tmp_path, argv, capsys, fault):
    out = tmp_path / "cap.json"
    assert main(["capture", "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and argv[0] in err, err
    assert not out.exists()
    fault.refused(f"capture {' '.join(argv)}", err.split("error: ", 1)[1])


def test_without_ray_capture_workers_says_which_extra(tmp_path, capsys, monkeypatch, fault):
    monkeypatch.setitem(sys.modules, "ray", None)
    out = tmp_path / "cap.json"
    argv = ["capture", "--out", str(out), "--track", _circle_csv(tmp_path / "c.csv"), "--workers", "2", "--laps", "2"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("capture --workers needs Ray: pip install 'vision_rl[ray]'") and len(err.splitlines()) == 1
    fault.refused("capture --workers 2 without Ray installed", err.split("error: ", 1)[1])


def test_more_workers_than_cpus_is_refused(ray_local, tmp_path, fault):
    cfg = _config(tmp_path, laps=3, workers=3)
    with pytest.raises(ValueError) as info:
        capture_sharded(cfg)
    assert "--workers 3 but the Ray cluster has 2 CPUs" in str(info.value)
    assert not Path(cfg.out).exists() and not shards_dir(cfg.out).exists()  # refused before touching the disk
    fault.refused("capture --workers 3 on a Ray cluster of 2 CPUs", str(info.value))


def _kill_shard_once(index: int, after_frames: int):
    killed: dict[str, int] = {}

    def on_shards(reports: dict[int, tuple[int, int, int]]) -> None:
        laps_frames_pid = reports.get(index)
        if not killed and laps_frames_pid and laps_frames_pid[1] >= after_frames:
            os.kill(laps_frames_pid[2], signal.SIGKILL)
            killed["pid"], killed["frames"] = laps_frames_pid[2], laps_frames_pid[1]

    return on_shards, killed


def test_a_worker_killed_mid_shard_fails_only_its_shard_and_resume_redoes_only_it(
    gl_available, ray_local, tmp_path, fault
):
    # Six laps a shard (about 1,200 frames), every batch flushed: the kill lands mid-shard with frames on disk (with
    # two laps, an idle machine finished the shard within one report interval, before the kill).
    cfg = _config(tmp_path, laps=12, task_retries=0, flush_interval_s=0.0)
    on_shards, killed = _kill_shard_once(1, after_frames=20)
    first = capture_sharded(cfg, on_shards=on_shards)
    assert killed, "the shard finished before it could be killed"
    assert first["failed_shards"] == [1] and not first["complete"]
    assert "WorkerCrashedError" in first["shards"][1]["error"] or "died" in first["shards"][1]["error"]
    shards = plan_shards(cfg)
    with open_capture(shards[0].out) as a, open_capture(shards[1].out) as b:
        assert a.complete and not b.complete
        kept_frames = b.n_frames
    kept = _sha(shards[0].out)
    assert len(FrameCatalogue.open(cfg.out)) == first["frames_in_file"]  # the partial run opens, verified

    second = capture_sharded(dataclasses.replace(cfg, resume=True))
    assert [s["status"] for s in second["shards"]] == ["kept", "captured"]
    assert second["complete"] and second["failed_shards"] == []
    assert _sha(shards[0].out) == kept  # the finished shard was not touched
    with open_capture(shards[1].out) as b:
        assert b.complete and b.n_frames > kept_frames
        b.read_images(np.arange(b.n_frames))  # every frame passes its checksum
    assert len(FrameCatalogue.open(cfg.out)) == second["frames_in_file"]
    fault.recovered(
        f"capture --workers 2: the worker of shard 1 killed (SIGKILL) after {killed['frames']} frames",
        f"shard 0 finished and kept ({first['shards'][0]['frames_in_file']} frames), shard 1 kept {kept_frames} "
        "frames; --resume captured only shard 1, continuing its file",
    )


def test_a_killed_worker_is_rerun_by_ray_and_continues_its_shard(gl_available, ray_local, tmp_path, fault):
    cfg = _config(tmp_path, laps=4, task_retries=1, flush_interval_s=0.0)
    on_shards, killed = _kill_shard_once(0, after_frames=20)
    result = capture_sharded(cfg, on_shards=on_shards)
    assert killed and result["complete"] and result["failed_shards"] == []
    with open_capture(plan_shards(cfg)[0].out) as a:
        assert a.complete and a.n_frames > killed["frames"]
    assert open_manifest(cfg.out)
    fault.recovered(
        f"capture --workers 2: the worker of shard 0 killed (SIGKILL) after {killed['frames']} frames",
        "Ray reran the task, which resumed the shard's file; the run completed",
    )
