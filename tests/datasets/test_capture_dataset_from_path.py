"""CaptureDataset.from_path: a capture file as a torch dataset and its batches in one call, split by lap and
standardised as train-repr does."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.helpers.captures import write_synthetic_capture
from vision_rl.capture.h5format import CaptureFormatError
from vision_rl.datasets import CaptureDataset, FrameCatalogue, TargetStandardiser, split_by_lap


def test_a_capture_file_is_a_dataset_and_its_batches_in_one_call(tmp_path):
    path = tmp_path / "ai.h5"
    written = write_synthetic_capture(path, n_laps=4, frames_per_lap=4, car_ids=(0, 3), seed=2)
    every = CaptureDataset.from_path(str(path))
    assert len(every) == 32 and every.standardiser is None
    images, targets = next(iter(every.loader(batch_size=10)))
    assert images.dtype == torch.uint8 and tuple(images.shape) == (10, 64, 96, 3)
    np.testing.assert_array_equal(images.numpy(), written["images"][:10])
    np.testing.assert_array_equal(targets.numpy(), written["targets"][:10])
    assert sum(len(t) for _, t in every.loader(batch_size=10, shuffle=True)) == 32

    train = CaptureDataset.from_path(path, "train", val_fraction=0.25, split_seed=3, standardise=True)
    val = CaptureDataset.from_path(path, "val", val_fraction=0.25, split_seed=3, standardise=True)
    rows = split_by_lap(FrameCatalogue.open(path), 0.25, 3)
    np.testing.assert_array_equal(train.rows, rows[0])
    np.testing.assert_array_equal(val.rows, rows[1])
    expected = TargetStandardiser.from_targets(written["targets"][rows[0]])
    for side in (train, val):  # both standardised with the training side's statistics
        np.testing.assert_allclose(side.standardiser.mean, expected.mean, rtol=1e-6)
        np.testing.assert_allclose(side.targets, expected.transform(written["targets"][side.rows]), rtol=1e-6)
    np.testing.assert_allclose(train.targets.mean(axis=0), 0.0, atol=1e-5)
    assert np.abs(val.targets.mean(axis=0)).max() > 1e-3


def test_from_path_refuses_what_it_cannot_give(tmp_path):
    path = tmp_path / "one_lap.h5"
    write_synthetic_capture(path, n_laps=1, frames_per_lap=4)
    with pytest.raises(ValueError, match="split must be one of all, train, val"):
        CaptureDataset.from_path(path, "test")
    with pytest.raises(ValueError, match="cannot be split by lap"):
        CaptureDataset.from_path(path, "train")
    with pytest.raises(CaptureFormatError, match="no capture file matches"):
        CaptureDataset.from_path(str(tmp_path / "none_*.h5"))
