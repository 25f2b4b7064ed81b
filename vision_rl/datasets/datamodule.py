"""LightningDataModule over capture files: lap split or a separate validation capture, standardised targets."""

from __future__ import annotations

import os
from collections.abc import Sequence

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader

from vision_rl.capture.h5format import CaptureFormatError, open_capture, probe_captures
from vision_rl.datasets.capture_dataset import (
    CaptureDataset,
    FrameCatalogue,
    TargetStandardiser,
    collate_frames,
    expand_paths,
    split_by_lap,
)

PathSpec = str | os.PathLike[str] | Sequence[str | os.PathLike[str]]


class CaptureDataModule(L.LightningDataModule):
    """Training and validation frames from capture files.

    Args:
        train_paths: capture file(s) to train on (a path, a comma-separated list or globs).
        val_paths: a separate validation capture (the paper: undisturbed driving); when absent, whole laps of the
            training files are held out (``val_fraction`` of the frames, chosen with ``split_seed``).
        batch_size: frames per batch.
        num_workers: DataLoader worker processes (each opens its own HDF5 handles).
        standardiser: reuse these target statistics (resuming); by default they come from the training split.
    """

    def __init__(
        self,
        train_paths: PathSpec,
        val_paths: PathSpec | None = None,
        *,
        val_fraction: float = 0.1,
        split_seed: int = 0,
        batch_size: int = 64,
        num_workers: int = 2,
        standardiser: TargetStandardiser | None = None,
    ) -> None:
        super().__init__()
        self.train_paths = expand_paths(train_paths)
        self.val_paths = expand_paths(val_paths) if val_paths else None
        self.val_fraction = float(val_fraction)
        self.split_seed = int(split_seed)
        self.batch_size = int(batch_size)
        self.num_workers = int(num_workers)
        self.standardiser = standardiser
        self.train_set: CaptureDataset | None = None
        self.val_set: CaptureDataset | None = None

    def prepare_data(self) -> None:
        # Nothing to download: fail early, before any worker starts, on a file that is not a capture.
        paths = [*self.train_paths, *(self.val_paths or [])]
        probe_captures(paths)
        for path in paths:
            open_capture(path).close()

    def setup(self, stage: str | None = None) -> None:
        if self.train_set is not None:
            return
        catalogue = FrameCatalogue.open(self.train_paths)
        if self.val_paths:
            val_catalogue = FrameCatalogue.open(self.val_paths)
            same_kind = (val_catalogue.image_hw_px, val_catalogue.target_names) == (
                catalogue.image_hw_px,
                catalogue.target_names,
            )
            if not same_kind:
                raise CaptureFormatError(
                    f"{self.val_paths[0]}: validation frames {val_catalogue.image_hw_px} / targets do not match the "
                    f"training capture's {catalogue.image_hw_px}"
                )
            train_rows, val_rows = np.arange(len(catalogue)), np.arange(len(val_catalogue))
        else:
            val_catalogue = catalogue
            train_rows, val_rows = split_by_lap(catalogue, self.val_fraction, self.split_seed)
        if self.standardiser is None:
            self.standardiser = TargetStandardiser.from_targets(catalogue.targets[train_rows])
        self.train_set = CaptureDataset(catalogue, train_rows, self.standardiser)
        self.val_set = CaptureDataset(val_catalogue, val_rows, self.standardiser)

    @property
    def catalogue(self) -> FrameCatalogue:
        if self.train_set is None:
            raise RuntimeError("call setup() first")
        return self.train_set.catalogue

    def _loader(self, dataset: CaptureDataset | None, shuffle: bool) -> DataLoader:
        if dataset is None:
            raise RuntimeError("call setup() first")
        return DataLoader(
            dataset,
            batch_size=self.batch_size,
            shuffle=shuffle,
            drop_last=shuffle and len(dataset) > self.batch_size,
            num_workers=self.num_workers,
            collate_fn=collate_frames,
            persistent_workers=self.num_workers > 0,
            pin_memory=torch.cuda.is_available(),
        )

    def train_dataloader(self) -> DataLoader:
        return self._loader(self.train_set, shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader(self.val_set, shuffle=False)
