"""Capture files as a dataset: catalogue over shards, split by lap, standardisation, workers, DataModule."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from tests.helpers.captures import write_synthetic_capture
from vision_rl.capture.h5format import CaptureFormatError
from vision_rl.datasets import (
    CaptureDataset,
    FrameBatch,
    FrameCatalogue,
    TargetStandardiser,
    collate_frames,
    expand_paths,
    split_by_lap,
)
from vision_rl.datasets.datamodule import CaptureDataModule


@pytest.fixture(scope="module")
def shards(tmp_path_factory) -> tuple[list[Path], list[dict]]:
    root = tmp_path_factory.mktemp("shards")
    paths, written = [], []
    for i, cars in enumerate([(0, 1), (0, 2, 5)]):
        path = root / f"shard_{i}.h5"
        written.append(write_synthetic_capture(path, n_laps=3, frames_per_lap=3, car_ids=cars, seed=10 + i))
        paths.append(path)
    return paths, written


def test_catalogue_joins_shards_in_order(shards) -> None:
    paths, written = shards
    cat = FrameCatalogue.open([str(p) for p in paths])
    assert len(cat) == 18 + 27
    np.testing.assert_array_equal(cat.targets, np.concatenate([w["targets"] for w in written]))
    np.testing.assert_array_equal(cat.file_index, np.repeat([0, 1], [18, 27]))
    np.testing.assert_array_equal(cat.frame_index[18:], np.arange(27))
    assert cat.image_hw_px == (64, 96) and len(cat.target_names) == 27
    # Globs and comma lists name the same files.
    assert expand_paths(str(paths[0].parent / "shard_*.h5")) == paths
    assert expand_paths(f"{paths[0]},{paths[1]}") == paths


def test_split_never_puts_one_lap_on_both_sides(shards) -> None:
    paths, _ = shards
    cat = FrameCatalogue.open(paths)
    keys = [tuple(k) for k in cat.lap_keys]
    for seed in range(6):
        train, val = split_by_lap(cat, 0.3, seed)
        assert len(np.intersect1d(train, val)) == 0 and len(train) + len(val) == len(cat)
        assert {keys[i] for i in train}.isdisjoint({keys[i] for i in val})
        assert 0.3 * len(cat) <= len(val) < 0.3 * len(cat) + 3  # whole laps of 3 frames, at least the fraction
    # Lap 0 of car 0 exists in both shards; it is two groups, so shard membership alone decides nothing.
    assert len(set(keys)) == 5 * 3
    a, b = split_by_lap(cat, 0.3, 1)
    a2, b2 = split_by_lap(cat, 0.3, 1)
    np.testing.assert_array_equal(a, a2)
    np.testing.assert_array_equal(b, b2)


def test_split_of_a_single_lap_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "one_lap.h5"
    write_synthetic_capture(path, n_laps=1, frames_per_lap=6)
    with pytest.raises(ValueError, match="single"):
        split_by_lap(FrameCatalogue.open(path), 0.2)


def test_standardiser_uses_training_rows_and_inverts() -> None:
    rng = np.random.default_rng(0)
    targets = rng.normal([1.0, -3.0, 5.0], [2.0, 0.1, 0.0], size=(200, 3)).astype(np.float32)
    std = TargetStandardiser.from_targets(targets[:100])
    np.testing.assert_allclose(std.mean, targets[:100].mean(axis=0), rtol=1e-5)
    np.testing.assert_allclose(std.std[:2], targets[:100].std(axis=0)[:2], rtol=1e-5)
    assert std.std[2] == 1.0  # a constant target keeps divisor 1, not 0
    z = std.transform(targets[:100])
    np.testing.assert_allclose(z[:, :2].mean(axis=0), 0.0, atol=1e-5)
    np.testing.assert_allclose(z[:, :2].std(axis=0), 1.0, rtol=1e-4)
    np.testing.assert_allclose(std.inverse(z), targets[:100], rtol=1e-5, atol=1e-5)
    again = TargetStandardiser.from_dict(std.to_dict())
    np.testing.assert_array_equal(again.mean, std.mean)


def test_dataset_items_and_worker_processes(shards) -> None:
    paths, written = shards
    cat = FrameCatalogue.open(paths)
    rows = np.array([44, 0, 20, 3, 19, 18, 31, 7])
    std = TargetStandardiser.from_targets(cat.targets)
    ds = CaptureDataset(cat, rows, std)
    images = np.concatenate([w["images"] for w in written])
    image, target = ds[0]
    assert image.dtype == torch.uint8 and image.shape == (64, 96, 3)
    np.testing.assert_array_equal(image.numpy(), images[44])
    np.testing.assert_allclose(target.numpy(), std.transform(cat.targets[44]), rtol=1e-6)
    # The parent has open handles now; forked workers must open their own and read the same frames.
    loader = DataLoader(ds, batch_size=3, num_workers=2, shuffle=False)
    got = torch.cat([b[0] for b in loader]).numpy()
    np.testing.assert_array_equal(got, images[rows])
    clone = pickle.loads(pickle.dumps(ds))  # what spawned workers receive: no handle travels
    assert clone._handles == {}
    np.testing.assert_array_equal(clone[3][0].numpy(), images[3])
    ds.close()


@pytest.mark.parametrize("num_workers", [0, 2])
def test_batches_collate_without_copy_in_order_across_shards(shards, num_workers: int) -> None:
    paths, written = shards
    cat = FrameCatalogue.open(paths)
    images = np.concatenate([w["images"] for w in written])
    rows = np.array([44, 0, 20, 3, 19, 18, 31, 7, 2])  # both shards within one batch
    ds = CaptureDataset(cat, rows)
    batch = ds.__getitems__([0, 1, 2, 8])
    assert isinstance(batch, FrameBatch) and len(batch) == 4
    np.testing.assert_array_equal(batch[2][0].numpy(), images[20])  # still a list of (image, target) pairs
    got_images, got_targets = collate_frames(batch)
    assert got_images is batch.images and got_images.shape == (4, 64, 96, 3) and got_images.dtype == torch.uint8
    np.testing.assert_array_equal(got_images.numpy(), images[rows[[0, 1, 2, 8]]])
    np.testing.assert_array_equal(got_targets.numpy(), cat.targets[rows[[0, 1, 2, 8]]])
    loader = DataLoader(ds, batch_size=4, num_workers=num_workers, collate_fn=collate_frames)
    got = [b for b in loader]
    np.testing.assert_array_equal(torch.cat([b[0] for b in got]).numpy(), images[rows])
    np.testing.assert_array_equal(torch.cat([b[1] for b in got]).numpy(), cat.targets[rows])
    ds.close()


def test_readback_bench_reports_both_figures(shards) -> None:
    from vision_rl.datasets.bench import bench_readback

    paths, _ = shards
    result = bench_readback(paths[0], n_workers=2, batch_size=4, frames_per_repeat=16, repeats=1)
    assert result["readback_fps"] > 0 and result["readback_loader_fps"] > 0
    assert result["readback_cpu_ms"] > 0 and result["readback_compression"] == "zstd"


def test_shards_of_different_frame_sizes_are_refused(tmp_path: Path) -> None:
    write_synthetic_capture(tmp_path / "a.h5", image_hw_px=(64, 96))
    write_synthetic_capture(tmp_path / "b.h5", image_hw_px=(32, 48))
    with pytest.raises(CaptureFormatError, match="do not match"):
        FrameCatalogue.open([tmp_path / "a.h5", tmp_path / "b.h5"])


def test_datamodule_lap_split_and_separate_validation(shards, tmp_path: Path) -> None:
    paths, written = shards
    dm = CaptureDataModule(paths, val_fraction=0.25, batch_size=4, num_workers=0)
    dm.prepare_data()
    dm.setup("fit")
    train_rows, val_rows = dm.train_set.rows, dm.val_set.rows
    assert len(train_rows) + len(val_rows) == 45
    np.testing.assert_allclose(dm.standardiser.mean, dm.catalogue.targets[train_rows].mean(axis=0), rtol=1e-5)
    images, targets = next(iter(dm.train_dataloader()))
    assert images.shape == (4, 64, 96, 3) and targets.shape == (4, 27) and targets.dtype == torch.float32

    val_path = tmp_path / "undisturbed.h5"
    val_written = write_synthetic_capture(val_path, n_laps=2, frames_per_lap=2, seed=99)
    dm2 = CaptureDataModule(paths[0], val_path, batch_size=8, num_workers=0)
    dm2.setup("fit")
    assert len(dm2.train_set) == 18 and len(dm2.val_set) == 4
    np.testing.assert_allclose(dm2.standardiser.mean, written[0]["targets"].mean(axis=0), rtol=1e-5)
    images, targets = next(iter(dm2.val_dataloader()))
    np.testing.assert_array_equal(images.numpy(), val_written["images"])
    np.testing.assert_allclose(dm2.standardiser.inverse(targets.numpy()), val_written["targets"], rtol=1e-5, atol=1e-5)


def test_targets_are_checked_by_their_units():
    from vision_rl.datasets import TargetValueError, check_targets

    names, units = ["d", "a", "k", "x"], ["m", "rad", "1/m", "kg"]
    good = np.array([[9_999.0, -6.0, 9.0, 1e30], [0.0, 0.0, 0.0, 0.0]], dtype=np.float32)
    check_targets(good, names, units, "f.h5")  # within every bound; an unknown unit is only checked for finiteness
    for col, value in ((0, 1e4 + 1), (1, 7.0), (2, -11.0), (3, np.nan)):
        bad = good.copy()
        bad[1, col] = value
        with pytest.raises(TargetValueError, match=rf"f\.h5: frame 1, target '{names[col]}'"):
            check_targets(bad, names, units, "f.h5")
