"""Capture HDF5 files as one torch Dataset: frame catalogue, split by lap, target standardisation.

The small per-frame arrays (targets, lap, car id) of every file are read once into a :class:`FrameCatalogue`; the
images stay on disk and are read one frame at a time. Each process opens its own h5py handles the first time it
reads (HDF5 handles must not cross a fork), so the dataset is safe under DataLoader workers of any start method.
"""

from __future__ import annotations

import glob
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, default_collate, get_worker_info

from vision_rl.capture.h5format import CaptureFile, CaptureFormatError, open_capture, probe_captures
from vision_rl.capture.sharded import open_manifest


def expand_paths(spec: str | os.PathLike[str] | Sequence[str | os.PathLike[str]]) -> list[Path]:
    """Capture files named by a path, a comma-separated list or glob patterns (``runs/cap/shard_*.h5``).

    A ``.json`` path is the manifest of a sharded capture: it stands for its shard files, each verified against
    the manifest (present, this run's, unchanged) by :func:`vision_rl.capture.sharded.open_manifest`."""
    items = [spec] if isinstance(spec, str | os.PathLike) else list(spec)
    parts = [p.strip() for item in items for p in str(item).split(",") if p.strip()]
    out: list[Path] = []
    for part in parts:
        matches = sorted(glob.glob(part)) if any(c in part for c in "*?[") else [part]
        if not matches:
            raise CaptureFormatError(f"{part}: no capture file matches")
        for match in map(Path, matches):
            out.extend(open_manifest(match) if match.suffix == ".json" else [match])
    if not out:
        raise CaptureFormatError("no capture file given")
    return out


#: The largest plausible magnitude of a target, by its unit; a larger (or a non-finite) value means the file is
#: damaged or was made wrong, and is refused before any training:
#:
#: - ``m``: 10 km. Every distance target (edge distances along rays, distances to the edges, offset from the centre
#:   line) lies within a track's width or its ray range, metres to hundreds of metres; 10 km is no distance on a
#:   track.
#: - ``rad``: 2 pi. The heading angle to the centre line is wrapped to [-pi, pi].
#: - ``1/m``: 10 per metre, a radius of 10 cm; a racing track's tightest hairpin has a radius of metres.
#:
#: Targets of other units are only checked to be finite.
TARGET_MAGNITUDE_BOUNDS: dict[str, float] = {"m": 10_000.0, "rad": 2.0 * math.pi, "1/m": 10.0}


class TargetValueError(CaptureFormatError):
    """A target value that is non-finite or beyond :data:`TARGET_MAGNITUDE_BOUNDS`; the message names the file,
    the frame (row) and the target (column)."""


def check_targets(targets: np.ndarray, names: Sequence[str], units: Sequence[str], source: str | Path) -> None:
    """Refuse non-finite or absurd targets (see :data:`TARGET_MAGNITUDE_BOUNDS`), naming the first bad frame (the
    row in ``source``) and target (the column) with its value."""
    targets = np.asarray(targets)
    bounds = np.array([TARGET_MAGNITUDE_BOUNDS.get(u, np.inf) for u in units], dtype=np.float64)
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(targets) | (np.abs(targets.astype(np.float64)) > bounds)
    if not bad.any():
        return
    row, col = (int(v) for v in np.argwhere(bad)[0])
    value, unit = float(targets[row, col]), units[col]
    why = "not a finite number" if not math.isfinite(value) else f"beyond the plausible {bounds[col]:g} {unit}"
    raise TargetValueError(
        f"{source}: frame {row}, target {names[col]!r} is {value:g} {unit}: {why} ({int(bad.sum())} bad values in "
        "all); the file is damaged or was made wrong: capture it again"
    )


@dataclass(frozen=True, eq=False)
class TargetStandardiser:
    """Per-target affine map to zero mean and unit variance over the training frames.

    ``mean`` and ``std`` are (n_targets,) float32 in the targets' physical units (m, rad, 1/m).
    """

    mean: np.ndarray
    std: np.ndarray

    @classmethod
    def from_targets(cls, targets: np.ndarray) -> TargetStandardiser:
        targets = np.asarray(targets, dtype=np.float64)
        if targets.ndim != 2 or targets.shape[0] < 1:
            raise ValueError(f"targets must be (n_frames >= 1, n_targets), got {targets.shape}")
        std = targets.std(axis=0)
        # A target constant over the split (a straight-only capture's curvature) standardises to 0 whatever the
        # divisor; 1 keeps float noise from being blown up.
        std = np.where(std > 1e-12, std, 1.0)
        return cls(targets.mean(axis=0).astype(np.float32), std.astype(np.float32))

    def transform(self, targets: np.ndarray) -> np.ndarray:
        return ((np.asarray(targets, dtype=np.float32) - self.mean) / self.std).astype(np.float32)

    def inverse(self, standardised: np.ndarray) -> np.ndarray:
        return (np.asarray(standardised, dtype=np.float32) * self.std + self.mean).astype(np.float32)

    def to_dict(self) -> dict[str, list[float]]:
        return {"mean": self.mean.tolist(), "std": self.std.tolist()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TargetStandardiser:
        return cls(np.asarray(data["mean"], dtype=np.float32), np.asarray(data["std"], dtype=np.float32))


@dataclass(frozen=True, eq=False)
class FrameCatalogue:
    """Every frame of one or more capture files: where it is and its targets (arrays over all N frames)."""

    paths: tuple[Path, ...]
    image_hw_px: tuple[int, int]
    target_names: tuple[str, ...]
    target_units: tuple[str, ...]
    file_index: np.ndarray
    """(N,) int32 index into ``paths``."""
    frame_index: np.ndarray
    """(N,) int64 frame number inside its file."""
    targets: np.ndarray
    """(N, n_targets) float32, physical units."""
    lap: np.ndarray
    """(N,) int32 lap index of the car."""
    car_id: np.ndarray
    """(N,) int32."""
    sources: tuple[dict[str, Any], ...] = ()
    """Per file: ``file`` (its name), ``n_frames``, ``fingerprint_sha256``, ``content_sha256`` and the fingerprint's
    track geometry hash and car: what a model trained on the catalogue records of its data."""

    @classmethod
    def open(cls, paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]]) -> FrameCatalogue:
        """Read the catalogue of the given files (see :func:`expand_paths`); all must share frame size and targets.
        Non-finite or absurd targets are refused (:func:`check_targets`)."""
        files = expand_paths(paths)
        probe_captures(files)  # a file that crashes HDF5 is refused here, not in a training step
        sources: list[dict[str, Any]] = []
        cols: dict[str, list[np.ndarray]] = {k: [] for k in ("targets", "lap", "car_id", "file", "frame")}
        meta: tuple[tuple[int, int], list[str], list[str]] | None = None
        for i, path in enumerate(files):
            with open_capture(path) as cap:
                this = (cap.image_hw_px, cap.target_names, cap.target_units)
                if meta is None:
                    meta = this
                elif this[:2] != meta[:2]:
                    raise CaptureFormatError(
                        f"{path}: frames {this[0]} / {len(this[1])} targets do not match {files[0]}: "
                        f"{meta[0]} / {len(meta[1])} targets (or the target names differ)"
                    )
                fingerprint = cap.fingerprint
                sources.append(
                    {
                        "file": path.name,
                        "n_frames": cap.n_frames,
                        "fingerprint_sha256": cap.attrs["fingerprint_sha256"],
                        "content_sha256": cap.content_sha256(),
                        "track_geometry_hash": fingerprint.get("track_geometry_hash"),
                        "car_preset": fingerprint.get("car_preset"),
                    }
                )
                if cap.n_frames == 0:
                    continue
                targets = cap.targets
                check_targets(targets, cap.target_names, cap.target_units, path)
                cols["targets"].append(targets.astype(np.float32))
                cols["lap"].append(cap.lap.astype(np.int32))
                cols["car_id"].append(cap.car_id.astype(np.int32))
                cols["file"].append(np.full(cap.n_frames, i, dtype=np.int32))
                cols["frame"].append(np.arange(cap.n_frames, dtype=np.int64))
        assert meta is not None
        if not cols["targets"]:
            raise CaptureFormatError(f"{', '.join(map(str, files))}: no frames")
        return cls(
            paths=tuple(files),
            image_hw_px=meta[0],
            target_names=tuple(meta[1]),
            target_units=tuple(meta[2]),
            file_index=np.concatenate(cols["file"]),
            frame_index=np.concatenate(cols["frame"]),
            targets=np.concatenate(cols["targets"]),
            lap=np.concatenate(cols["lap"]),
            car_id=np.concatenate(cols["car_id"]),
            sources=tuple(sources),
        )

    def __len__(self) -> int:
        return len(self.frame_index)

    @property
    def lap_keys(self) -> np.ndarray:
        """(N, 3) int64 rows (file, car_id, lap): the unit a split never cuts."""
        return np.stack([self.file_index, self.car_id, self.lap], axis=1).astype(np.int64)


def split_by_lap(catalogue: FrameCatalogue, val_fraction: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Frame rows of a training and a validation split such that no (file, car, lap) has frames on both sides.

    Laps are shuffled with ``seed`` and moved to the validation side until it holds at least ``val_fraction`` of the
    frames; both sides keep at least one lap. Returns sorted row indices into the catalogue.
    """
    if not 0.0 < val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in (0, 1), got {val_fraction}")
    keys, inverse, counts = np.unique(catalogue.lap_keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    if len(keys) < 2:
        raise ValueError(
            f"{', '.join(map(str, catalogue.paths))}: a single (file, car, lap) group cannot be split by lap; "
            "capture more laps or give a separate validation file"
        )
    order = np.random.default_rng(seed).permutation(len(keys))
    cum = np.cumsum(counts[order])
    n_val_groups = int(np.searchsorted(cum, val_fraction * len(catalogue)) + 1)
    n_val_groups = min(max(n_val_groups, 1), len(keys) - 1)
    is_val_group = np.zeros(len(keys), dtype=bool)
    is_val_group[order[:n_val_groups]] = True
    is_val = is_val_group[inverse]
    return np.flatnonzero(~is_val), np.flatnonzero(is_val)


class FrameBatch(list):
    """A batch of :meth:`CaptureDataset.__getitems__`: the list of (image, target) pairs DataLoader's default collate
    expects, each a view into the whole-batch tensors ``images`` uint8 (k, H, W, 3) and ``targets`` float32 (k, n),
    which :func:`collate_frames` hands on without stacking (copying) them again."""

    def __init__(self, images: torch.Tensor, targets: torch.Tensor) -> None:
        super().__init__(zip(images, targets, strict=True))
        self.images = images
        self.targets = targets


def collate_frames(samples: list) -> tuple[torch.Tensor, torch.Tensor]:
    """DataLoader ``collate_fn`` for :class:`CaptureDataset`: a :class:`FrameBatch` as (images, targets) as it is,
    anything else through torch's default collate."""
    if isinstance(samples, FrameBatch):
        return samples.images, samples.targets
    return default_collate(samples)


def _batch_tensor(shape: tuple[int, ...]) -> torch.Tensor:
    """An uninitialised uint8 tensor; in a DataLoader worker, in shared memory.

    A worker's batch reaches the training process in shared memory; decoding into shared memory from the start
    (as default_collate allocates its output) saves copying 400 kB per frame there: measured 1.16 -> 0.99 ms of
    CPU per frame with two workers.
    """
    if get_worker_info() is not None:
        try:
            storage = torch.UntypedStorage._new_shared(math.prod(shape))
            return torch.empty(0, dtype=torch.uint8).set_(storage).view(shape)
        except (AttributeError, RuntimeError, TypeError):  # a torch without this (private) allocator
            pass
    return torch.empty(shape, dtype=torch.uint8)


#: The frames :meth:`CaptureDataset.from_path` gives: all of them, or one side of the split by lap.
SPLITS = ("all", "train", "val")


class CaptureDataset(Dataset):
    """Frames ``rows`` of a catalogue as ``(image uint8 (H, W, 3), targets float32 (n_targets,))`` pairs.

    Targets are standardised when a standardiser is given. Images are left as uint8: the model converts them
    (on the GPU when there is one), and uint8 batches cost workers a quarter of the float copies. From capture files
    in one call, batches included::

        from vision_rl.datasets import CaptureDataset

        train = CaptureDataset.from_path("runs/capture/ai.h5", split="train", standardise=True)
        for images, targets in train.loader(batch_size=64, shuffle=True):
            ...  # images uint8 (64, H, W, 3), targets float32 (64, 27), standardised over the training laps
    """

    def __init__(
        self,
        catalogue: FrameCatalogue,
        rows: np.ndarray | None = None,
        standardiser: TargetStandardiser | None = None,
    ) -> None:
        self.catalogue = catalogue
        self.rows = np.arange(len(catalogue)) if rows is None else np.asarray(rows, dtype=np.int64)
        targets = catalogue.targets[self.rows]
        self.targets = standardiser.transform(targets) if standardiser is not None else targets
        self.standardiser = standardiser
        self._handles: dict[int, CaptureFile] = {}
        self._pid = os.getpid()

    @classmethod
    def from_path(
        cls,
        paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
        split: str = "all",
        *,
        val_fraction: float = 0.1,
        split_seed: int = 0,
        standardise: bool = False,
    ) -> CaptureDataset:
        """The frames of capture file(s) (a path, a comma-separated list, globs or a sharded capture's manifest; see
        :func:`expand_paths`) as a dataset: ``split`` ``all``, or the ``train`` or ``val`` side of
        :func:`split_by_lap` (``val_fraction`` of the frames in whole laps, chosen with ``split_seed``, as
        ``train-repr`` splits them). ``standardise``: targets to zero mean and unit variance over the training side
        (all frames for ``all``); the statistics are the dataset's :attr:`standardiser`. Batches:
        :meth:`loader`."""
        if split not in SPLITS:
            raise ValueError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
        catalogue = FrameCatalogue.open(paths)
        rows = train = None
        if split != "all":
            train, val = split_by_lap(catalogue, val_fraction, split_seed)
            rows = train if split == "train" else val
        fitted = catalogue.targets if train is None else catalogue.targets[train]
        return cls(catalogue, rows, TargetStandardiser.from_targets(fitted) if standardise else None)

    def loader(self, batch_size: int = 64, shuffle: bool = False, num_workers: int = 0, **kwargs: Any) -> DataLoader:
        """A torch ``DataLoader`` of (images uint8 (k, H, W, 3), targets float32 (k, n_targets)) batches, collated by
        :func:`collate_frames` (whole batches decoded at once); ``kwargs`` go to the ``DataLoader``."""
        return DataLoader(
            self,
            batch_size=batch_size,
            shuffle=shuffle,
            num_workers=num_workers,
            collate_fn=collate_frames,
            persistent_workers=num_workers > 0,
            **kwargs,
        )

    def __len__(self) -> int:
        return len(self.rows)

    def _handle(self, file_index: int) -> CaptureFile:
        if self._pid != os.getpid():  # a forked worker inherited the parent's handles: never use them
            self._handles = {}
            self._pid = os.getpid()
        handle = self._handles.get(file_index)
        if handle is None:
            handle = open_capture(self.catalogue.paths[file_index])
            self._handles[file_index] = handle
        return handle

    def image(self, i: int) -> np.ndarray:
        row = self.rows[i]
        cap = self._handle(int(self.catalogue.file_index[row]))
        return cap.read_image(int(self.catalogue.frame_index[row]))

    def __getitem__(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        return torch.from_numpy(self.image(i)), torch.from_numpy(self.targets[i])

    def __getitems__(self, indices: list[int]) -> FrameBatch:
        """A whole batch at once (DataLoader calls this): frames of one file are decoded in parallel threads,
        straight into the memory the batch leaves a worker process in. Collate it with :func:`collate_frames`."""
        idx = np.asarray(indices, dtype=np.int64)
        rows = self.rows[idx]
        images = _batch_tensor((len(idx), *self.catalogue.image_hw_px, 3))
        out = images.numpy()
        files = self.catalogue.file_index[rows]
        file_ids = np.unique(files)
        if len(file_ids) == 1:
            self._handle(int(file_ids[0])).read_images(self.catalogue.frame_index[rows], out=out)
        else:
            for f in file_ids:
                sel = np.flatnonzero(files == f)
                out[sel] = self._handle(int(f)).read_images(self.catalogue.frame_index[rows[sel]])
        targets = torch.from_numpy(self.targets[idx])
        return FrameBatch(images, targets)

    def close(self) -> None:
        if self._pid == os.getpid():
            for handle in self._handles.values():
                handle.close()
        self._handles = {}

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_handles"] = {}  # spawned workers open their own
        return state
