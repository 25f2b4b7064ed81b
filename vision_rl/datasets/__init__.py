"""Capture HDF5 files as torch datasets: lap split, target standardisation, augmentation, Lightning DataModule.

Import the DataModule from :mod:`vision_rl.datasets.datamodule` (it pulls in Lightning).
"""

from vision_rl.datasets.augment import FrameAugmentation, shift_frames
from vision_rl.datasets.capture_dataset import (
    CaptureDataset,
    FrameBatch,
    FrameCatalogue,
    TargetStandardiser,
    TargetValueError,
    check_targets,
    collate_frames,
    expand_paths,
    split_by_lap,
)

__all__ = [
    "CaptureDataset",
    "FrameAugmentation",
    "FrameBatch",
    "FrameCatalogue",
    "TargetStandardiser",
    "TargetValueError",
    "check_targets",
    "collate_frames",
    "expand_paths",
    "shift_frames",
    "split_by_lap",
]
