"""Sharded capture: shards equal single-process captures of their seeds, the manifest presents them as one dataset,
the plan of seeds and laps, and the option checks (a local Ray cluster of 2 CPUs, the ``ray_local`` fixture)."""

from __future__ import annotations

import dataclasses
import json
import sys

import numpy as np
import pytest

from vision_rl.capture.h5format import open_capture
from vision_rl.capture.sharded import (
    RayMissingError,
    ShardedCaptureConfig,
    capture_sharded,
    import_ray,
    open_manifest,
    plan_shards,
    shard_seed,
    shards_dir,
)
from vision_rl.capture.sim_capture import capture_sim
from vision_rl.datasets.capture_dataset import CaptureDataset, FrameCatalogue, expand_paths


def _circle_csv(path) -> str:
    a = np.linspace(0.0, 2 * np.pi, 120, endpoint=False)
    rows = np.stack([40 * np.cos(a), 40 * np.sin(a), np.full(120, 6.0), np.full(120, 6.0)], axis=1)
    np.savetxt(path, rows, delimiter=",", header="x_m,y_m,w_tr_right_m,w_tr_left_m")
    return str(path)


def _config(tmp_path, **kw) -> ShardedCaptureConfig:
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


def test_shards_have_their_own_seeds_and_share_the_laps(tmp_path):
    cfg = _config(tmp_path, laps=5, max_frames=7)
    shards = plan_shards(cfg)
    assert [s.laps for s in shards] == [3, 2] and [s.max_frames for s in shards] == [4, 3]
    assert len({s.seed for s in shards}) == 2 and all(s.seed != cfg.seed for s in shards)
    assert [s.seed for s in shards] == [shard_seed(3, 0), shard_seed(3, 1)]
    # No shard of one run repeats a shard of the run seeded one higher.
    assert not {shard_seed(3, i) for i in range(8)} & {shard_seed(4, i) for i in range(8)}
    assert shards[1].out == str((shards_dir(cfg.out) / "shard_001.h5").resolve())
    assert all(s.resume and not s.force for s in shards)  # a rerun of a task continues its file


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"workers": 0}, "--workers must be >= 1"),
        ({"laps": 1, "workers": 2}, "every shard needs at least one lap"),
        ({"out": "cap.h5"}, "give --out PATH.json"),
        ({"max_frames": 1}, "every shard needs at least one frame"),
    ],
)
def test_bad_shard_options_are_refused_naming_them(tmp_path, change, words):
    with pytest.raises(ValueError, match=words):
        _config(tmp_path, **change)


def test_without_ray_the_error_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    with pytest.raises(RayMissingError, match=r"capture --workers needs Ray: pip install 'vision_rl\[ray\]'"):
        import_ray("capture --workers")


def test_sharded_capture_equals_single_process_captures_and_reads_as_one_dataset(gl_available, ray_local, tmp_path):
    cfg = _config(tmp_path)
    result = capture_sharded(cfg)
    assert result["complete"] and result["failed_shards"] == [] and result["workers"] == 2
    assert [s["status"] for s in result["shards"]] == ["captured", "captured"]
    assert result["cpu_s_per_frame"] > 0 and result["frames_written"] == result["frames_in_file"]
    manifest = json.loads((tmp_path / "cap.json").read_text())
    assert [s["path"] for s in manifest["shards"]] == ["cap.shards/shard_000.h5", "cap.shards/shard_001.h5"]

    # Each shard holds exactly the frames a single-process capture of its seed and laps makes.
    for i, shard in enumerate(plan_shards(cfg)):
        alone = tmp_path / f"alone_{i}.h5"
        capture_sim(dataclasses.replace(shard, out=str(alone), resume=False))
        with open_capture(shard.out) as a, open_capture(alone) as b:
            assert a.complete and a.n_frames == b.n_frames > 0
            assert a.attrs["seed"] == shard.seed
            for name in ("targets", "dedicated", "pose", "time_s", "lap", "car_id"):
                np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
            idx = np.arange(0, a.n_frames, 7)
            np.testing.assert_array_equal(a.read_images(idx), b.read_images(idx))

    # The manifest is one dataset over both shards.
    paths = expand_paths(str(tmp_path / "cap.json"))
    assert [p.name for p in paths] == ["shard_000.h5", "shard_001.h5"]
    catalogue = FrameCatalogue.open(str(tmp_path / "cap.json"))
    assert len(catalogue) == result["frames_in_file"]
    assert set(np.unique(catalogue.file_index)) == {0, 1}
    dataset = CaptureDataset(catalogue)
    rows = [0, len(catalogue) - 1]  # the first frame of shard 0, the last of shard 1
    batch = dataset.__getitems__(rows)
    with open_capture(paths[0]) as a, open_capture(paths[1]) as b:
        np.testing.assert_array_equal(batch.images[0].numpy(), a.read_image(0))
        np.testing.assert_array_equal(batch.images[1].numpy(), b.read_image(b.n_frames - 1))
        np.testing.assert_array_equal(batch.targets[1].numpy(), b.targets[-1])
    dataset.close()
    assert open_manifest(tmp_path / "cap.json") == paths
