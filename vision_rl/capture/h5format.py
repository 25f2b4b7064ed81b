"""The capture HDF5 file (ARCHITECTURE, "Files that cross a phase boundary"): writer and validating reader.

Layout of one file (one run or one shard), N frames:

====================  =========  ===============  ==============================================================
dataset               dtype      shape            notes
====================  =========  ===============  ==============================================================
``images``            uint8      (N, H, W, 3)     RGB, one frame per chunk (random reads decode only one frame)
``targets``           float32    (N, 27)          the Phase-1 targets, attributes ``names`` and ``units``
``dedicated``         float32    (N, 11)          the dedicated features, attributes ``names`` and ``units``
``pose``              float64    (N, 3)           x_m, y_m, yaw_rad in the world frame
``time``              float64    (N,)             simulation time, s
``lap``               int32      (N,)             lap index of the car at that frame (datasets split on it)
``car_id``            int32      (N,)             which car's view the frame is
====================  =========  ===============  ==============================================================

File attributes: ``format_version``, ``target_names``, ``target_units``, ``dedicated_names``, ``dedicated_units``,
``image_height``, ``image_width``, ``compression``, ``package_version``, ``complete`` and ``n_frames`` (frames
committed by the last flush), plus the caller's attributes; :data:`REQUIRED_ATTRS` are mandatory (track name and
geometry hash, car preset, renderer settings, seed). Dict or list values are stored as JSON text and listed in the
attribute ``json_attrs`` so the reader gives them back decoded.

Crash safety: the writer flushes at most every ``flush_interval_s`` seconds, data first and then ``n_frames``, so
the count on disk never covers frames whose bytes are not there. A kill between flushes can leave datasets longer
than ``n_frames``; the reader and a resumed writer trust ``n_frames`` and ignore the tail. HDF5's default (earliest)
file format is used on purpose: the newer superblock records "open for writing" and then refuses to reopen a file
whose writer was killed without the ``h5clear`` tool.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import time
import zlib
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import h5py
import numpy as np

FORMAT_VERSION = 1

#: Caller attributes every capture file must carry (ARCHITECTURE's list: track name and a hash of its geometry, car
#: preset, renderer settings, seed; package version and the completion flag are added by the writer).
REQUIRED_ATTRS: tuple[str, ...] = ("track_name", "track_geometry_hash", "car_preset", "renderer_settings", "seed")

#: Attributes a resumed file must share with the writer reopening it, or the frames would not belong together.
_RESUME_MUST_MATCH: tuple[str, ...] = (
    *REQUIRED_ATTRS, "target_names", "dedicated_names", "image_height", "image_width",
)  # fmt: skip

#: Per-frame datasets other than the images: name -> (dtype, trailing shape or None when sized by the names).
_FRAME_DATASETS: dict[str, tuple[np.dtype, tuple[int, ...] | None]] = {
    "targets": (np.dtype(np.float32), None),
    "dedicated": (np.dtype(np.float32), None),
    "pose": (np.dtype(np.float64), (3,)),
    "time": (np.dtype(np.float64), ()),
    "lap": (np.dtype(np.int32), ()),
    "car_id": (np.dtype(np.int32), ()),
}
_UNITS = {"pose": "m, m, rad", "time": "s", "lap": "1", "car_id": "1"}
ALL_DATASETS: tuple[str, ...] = ("images", *_FRAME_DATASETS)

#: Rows per chunk of the small per-frame datasets: 4,096 rows of 27 float32 is 432 KiB, near HDF5's sweet spot,
#: and small enough that the last, partly filled chunk costs little.
_ROW_CHUNK = 4096

#: Compression of the image chunks. Measured on 470x280 renderer frames (textured asphalt, these 2-core CPUs):
#: gzip level 1 133 kB/frame and 780 random frames/s read back in one process, lzf 184 kB and 640 frames/s, none
#: 396 kB and 13,000 frames/s. gzip is the default: smallest and fastest to decode of the two codecs h5py ships;
#: its slower compression runs in a thread pool (zlib releases the GIL) and is written with write_direct_chunk.
COMPRESSIONS = ("gzip", "lzf", "none")

#: zlib level of the gzip chunks: level 1 compresses several times faster than the default 6 for a few % of size.
_GZIP_LEVEL = 1


class CaptureFormatError(ValueError):
    """A capture file that cannot be used as one: the message names the file and the problem."""


class CaptureDiskFullError(OSError):
    """The disk filled while writing; the file holds the frames of the last flush and is marked incomplete."""


def package_version() -> str:
    """The installed vision_rl version, or the source tree's when it is run without installing."""
    try:
        from importlib.metadata import PackageNotFoundError, version

        return version("vision_rl")
    except PackageNotFoundError:
        import vision_rl

        return str(getattr(vision_rl, "__version__", "unknown"))


def _encode_attr(value: Any) -> tuple[Any, bool]:
    if isinstance(value, Mapping | list | tuple) and not (
        isinstance(value, list | tuple) and all(isinstance(v, str) for v in value) and len(value) > 0
    ):
        return json.dumps(value, sort_keys=True), True
    if isinstance(value, list | tuple):
        return np.array(value, dtype=h5py.string_dtype()), False
    if value is None:
        return json.dumps(None), True
    return value, False


def _decode_attrs(raw: h5py.AttributeManager) -> dict[str, Any]:
    json_keys = set(_as_str_list(raw["json_attrs"])) if "json_attrs" in raw else set()
    out: dict[str, Any] = {}
    for key, value in raw.items():
        if key == "json_attrs":
            continue
        if key in json_keys:
            out[key] = json.loads(value)
        elif isinstance(value, np.ndarray) and value.dtype.kind in "OSU":
            out[key] = _as_str_list(value)
        elif isinstance(value, bytes):
            out[key] = value.decode()
        elif isinstance(value, np.generic):
            out[key] = value.item()
        else:
            out[key] = value
    return out


def _as_str_list(value: Any) -> list[str]:
    return [v.decode() if isinstance(v, bytes) else str(v) for v in np.atleast_1d(value)]


def _is_disk_full(exc: BaseException) -> bool:
    # h5py turns HDF5's write failure into an OSError whose errno is often unset; the text keeps the system's.
    return getattr(exc, "errno", None) == errno.ENOSPC or "No space left" in str(exc) or "errno = 28" in str(exc)


class CaptureWriter:
    """Appends batches of frames to a capture file; see the module doc for the layout and the crash guarantees.

    Args:
        path: the ``.h5`` file.
        image_hw: (height, width) of the frames in pixels.
        target_names, target_units: the 27 target names and units (``vision_rl.sim.sensors.TARGET_NAMES``...).
        dedicated_names, dedicated_units: the 11 dedicated feature names and units.
        attrs: run attributes; must hold :data:`REQUIRED_ATTRS`. Scalars and strings are stored as they are,
            dicts and lists as JSON.
        resume: reopen an incomplete file and append to it (a missing file is created); :attr:`n_frames` tells
            the caller where to continue. A complete file is refused.
        force: overwrite an existing file.
        compression: ``"gzip"`` (level 1, default), ``"lzf"`` or ``"none"``; a resumed file keeps its own.
        compress_threads: threads compressing gzip frames (0: one per CPU, at most 4).
        flush_interval_s: longest time between flushes; frames appended since the last flush are lost to a kill.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        image_hw: tuple[int, int],
        target_names: Sequence[str],
        target_units: Sequence[str],
        dedicated_names: Sequence[str],
        dedicated_units: Sequence[str],
        attrs: Mapping[str, Any],
        resume: bool = False,
        force: bool = False,
        compression: str = "gzip",
        flush_interval_s: float = 2.0,
        compress_threads: int = 0,
    ) -> None:
        self.path = Path(path)
        self.image_hw = (int(image_hw[0]), int(image_hw[1]))
        self.target_names = tuple(target_names)
        self.dedicated_names = tuple(dedicated_names)
        self.flush_interval_s = float(flush_interval_s)
        if len(target_units) != len(self.target_names) or len(dedicated_units) != len(self.dedicated_names):
            raise ValueError(f"{self.path}: every target and dedicated feature needs one unit")
        missing = [k for k in REQUIRED_ATTRS if k not in attrs]
        if missing:
            raise ValueError(f"{self.path}: attrs lack {missing} (required: {list(REQUIRED_ATTRS)})")
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression must be one of {COMPRESSIONS}, got {compression!r}")
        if resume and force:
            raise ValueError("resume and force exclude each other: resume appends, force starts over")
        if min(self.image_hw) <= 0:
            raise ValueError(f"image_hw must be positive, got {image_hw}")

        file_attrs = dict(attrs)
        file_attrs.update(
            format_version=FORMAT_VERSION,
            target_names=list(self.target_names),
            target_units=list(target_units),
            dedicated_names=list(self.dedicated_names),
            dedicated_units=list(dedicated_units),
            image_height=self.image_hw[0],
            image_width=self.image_hw[1],
            compression=compression,
            package_version=package_version(),
        )
        self._closed = True
        self._broken = False
        if self.path.exists() and resume:
            self._file = self._reopen(file_attrs)
            compression = str(self._file.attrs["compression"])
        else:
            if self.path.exists() and not force:
                raise FileExistsError(f"{self.path} exists: pass force to overwrite it or resume to continue it")
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = self._create(file_attrs, compression)
        self.compression = compression
        self._pool: ThreadPoolExecutor | None = None
        if compression == "gzip":
            n_threads = compress_threads if compress_threads > 0 else min(4, os.cpu_count() or 1)
            self._pool = ThreadPoolExecutor(n_threads, thread_name_prefix="capture-gzip")
        self._closed = False
        self._last_flush_s = time.monotonic()

    # -------------------------------------------------------------------------------------------- file set-up
    def _create(self, file_attrs: dict[str, Any], compression: str) -> h5py.File:
        f = h5py.File(self.path, "w")
        try:
            json_keys = []
            for key, value in file_attrs.items():
                encoded, is_json = _encode_attr(value)
                f.attrs[key] = encoded
                if is_json:
                    json_keys.append(key)
            f.attrs["json_attrs"] = np.array(json_keys, dtype=h5py.string_dtype())
            f.attrs["complete"] = False
            f.attrs["n_frames"] = 0
            comp: dict[str, Any] = {}
            if compression == "lzf":
                comp = {"compression": "lzf"}
            elif compression == "gzip":
                comp = {"compression": "gzip", "compression_opts": _GZIP_LEVEL}
            h, w = self.image_hw
            f.create_dataset("images", shape=(0, h, w, 3), maxshape=(None, h, w, 3), dtype=np.uint8,
                             chunks=(1, h, w, 3), **comp)  # fmt: skip
            for name, (dtype, tail) in _FRAME_DATASETS.items():
                if tail is None:
                    tail = (len(self.target_names) if name == "targets" else len(self.dedicated_names),)
                f.create_dataset(name, shape=(0, *tail), maxshape=(None, *tail), dtype=dtype,
                                 chunks=(_ROW_CHUNK, *tail))  # fmt: skip
            f["targets"].attrs["names"] = file_attrs["target_names"]
            f["targets"].attrs["units"] = file_attrs["target_units"]
            f["dedicated"].attrs["names"] = file_attrs["dedicated_names"]
            f["dedicated"].attrs["units"] = file_attrs["dedicated_units"]
            for name, unit in _UNITS.items():
                f[name].attrs["units"] = unit
            f.flush()
        except BaseException:
            f.close()
            raise
        return f

    def _reopen(self, file_attrs: dict[str, Any]) -> h5py.File:
        with open_capture(self.path) as existing:
            if existing.complete:
                raise CaptureFormatError(f"{self.path}: the file is complete; nothing to resume (use force to redo it)")
            stored = existing.attrs
            for key in _RESUME_MUST_MATCH:
                mine, theirs = _normalise(file_attrs.get(key)), _normalise(stored.get(key))
                if mine != theirs:
                    raise CaptureFormatError(
                        f"{self.path}: cannot resume: attribute {key!r} is {theirs!r} in the file, {mine!r} now"
                    )
            n_committed = existing.n_frames
        f = h5py.File(self.path, "r+")
        # Drop frames a kill left beyond the last flush: their bytes may be partial.
        for name in ALL_DATASETS:
            if f[name].shape[0] != n_committed:
                f[name].resize(n_committed, axis=0)
        f.attrs["package_version"] = file_attrs["package_version"]
        f.flush()
        return f

    # ---------------------------------------------------------------------------------------------- writing
    @property
    def n_frames(self) -> int:
        """Frames appended so far (committed or not)."""
        return int(self._file["images"].shape[0])

    def append(
        self,
        images: np.ndarray,
        targets: np.ndarray,
        dedicated: np.ndarray,
        pose: np.ndarray,
        time_s: np.ndarray,
        lap: np.ndarray,
        car_id: np.ndarray,
    ) -> None:
        """Append k frames: images uint8 (k, H, W, 3), targets (k, 27), dedicated (k, 11), pose (k, 3) as x_m, y_m,
        yaw_rad, time_s (k,), lap (k,) integers, car_id (k,) integers."""
        if self._closed or self._broken:
            raise RuntimeError(f"{self.path}: writer is {'closed' if self._closed else 'broken by a failed write'}")
        images = np.asarray(images)
        k = images.shape[0] if images.ndim == 4 else -1
        h, w = self.image_hw
        if images.shape != (k, h, w, 3) or images.dtype != np.uint8:
            raise ValueError(f"images must be uint8 (k, {h}, {w}, 3), got {images.dtype} {images.shape}")
        columns = {
            "targets": (targets, (k, len(self.target_names))),
            "dedicated": (dedicated, (k, len(self.dedicated_names))),
            "pose": (pose, (k, 3)),
            "time": (time_s, (k,)),
            "lap": (lap, (k,)),
            "car_id": (car_id, (k,)),
        }
        arrays = {}
        for name, (value, shape) in columns.items():
            arr = np.asarray(value)
            if arr.shape != shape:
                raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
            dtype = _FRAME_DATASETS[name][0]
            if dtype.kind == "i" and arr.dtype.kind not in "iu":
                if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
                    raise ValueError(f"{name} must hold integers")
            arrays[name] = arr.astype(dtype, copy=False)
        if k == 0:
            return
        start = self.n_frames
        try:
            self._write_images(start, images)
            for name, arr in arrays.items():
                self._file[name].resize(start + k, axis=0)
                self._file[name][start:] = arr
            if time.monotonic() - self._last_flush_s >= self.flush_interval_s:
                self.flush()
        except OSError as exc:
            self._broken = True
            if _is_disk_full(exc):
                committed = self._committed()
                self._abandon()
                raise CaptureDiskFullError(
                    errno.ENOSPC,
                    f"{self.path}: disk full after {committed} frames; the file keeps those frames, marked "
                    "incomplete: free space and resume",
                ) from exc
            raise

    def _write_images(self, start: int, images: np.ndarray) -> None:
        ds = self._file["images"]
        ds.resize(start + len(images), axis=0)
        if self._pool is None:
            ds[start:] = images
            return
        # The same zlib stream HDF5's deflate filter writes, so any HDF5 reader decodes these chunks.
        frames = np.ascontiguousarray(images)
        blobs = self._pool.map(lambda frame: zlib.compress(frame, _GZIP_LEVEL), frames)
        for j, blob in enumerate(blobs):
            ds.id.write_direct_chunk((start + j, 0, 0, 0), blob)

    def flush(self) -> None:
        """Write everything appended so far to disk, then record it as committed in ``n_frames``."""
        self._file.flush()
        self._file.attrs["n_frames"] = self.n_frames
        self._file.flush()
        self._last_flush_s = time.monotonic()

    def _committed(self) -> int:
        try:
            return int(self._file.attrs["n_frames"])
        except Exception:
            return -1

    def _abandon(self) -> None:
        # The disk is full: the file on disk is the state of the last flush. Closing may fail to write more, which
        # leaves that state (n_frames of the last flush) as it is; the reader ignores any tail beyond it.
        with contextlib.suppress(Exception):
            self._file.close()
        self._closed = True
        self._stop_pool()

    def _stop_pool(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def close(self, complete: bool = False) -> None:
        """Flush and close; ``complete=True`` marks the run finished (the default leaves it resumable)."""
        if self._closed:
            return
        try:
            self.flush()
            if complete:
                self._file.attrs["complete"] = True
        except OSError as exc:
            self._broken = True
            if _is_disk_full(exc):
                self._abandon()
                raise CaptureDiskFullError(errno.ENOSPC, f"{self.path}: disk full while closing") from exc
            raise
        finally:
            if not self._closed:
                self._file.close()
                self._closed = True
            self._stop_pool()

    def __enter__(self) -> CaptureWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        # Leaving the block never marks the file complete: only an explicit close(complete=True) does.
        self.close(complete=False)


def _normalise(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, tuple):
        value = list(value)
    if isinstance(value, list):
        return [_normalise(v) for v in value]
    if isinstance(value, Mapping):
        return json.loads(json.dumps(value, sort_keys=True))
    if isinstance(value, np.generic):
        return value.item()
    return value


class CaptureFile:
    """A validated capture file open for reading; use :func:`open_capture`.

    Small per-frame arrays are read whole on demand (``targets``...); images are read per frame or per index list.
    Only the first :attr:`n_frames` rows are valid (a killed writer may leave a longer tail).
    """

    def __init__(self, path: Path, handle: h5py.File, n_frames: int, attrs: dict[str, Any]) -> None:
        self.path = path
        self._f = handle
        self.n_frames = n_frames
        self.attrs = attrs
        self.images: h5py.Dataset = handle["images"]
        # Chunks that are exactly one deflate-compressed frame can be decoded outside h5py, in parallel.
        ds = self.images
        self._gzip_chunks = (
            ds.compression == "gzip" and not ds.shuffle and not ds.fletcher32 and ds.scaleoffset is None
            and ds.chunks == (1, *self.image_hw, 3)
        )  # fmt: skip

    @property
    def complete(self) -> bool:
        return bool(self.attrs["complete"])

    @property
    def image_hw(self) -> tuple[int, int]:
        return int(self.attrs["image_height"]), int(self.attrs["image_width"])

    @property
    def target_names(self) -> list[str]:
        return list(self.attrs["target_names"])

    @property
    def target_units(self) -> list[str]:
        return list(self.attrs["target_units"])

    @property
    def dedicated_names(self) -> list[str]:
        return list(self.attrs["dedicated_names"])

    @property
    def dedicated_units(self) -> list[str]:
        return list(self.attrs["dedicated_units"])

    def _column(self, name: str) -> np.ndarray:
        try:
            return self._f[name][: self.n_frames]
        except OSError as exc:
            raise CaptureFormatError(f"{self.path}: cannot read dataset {name!r}: {exc}") from exc

    @property
    def targets(self) -> np.ndarray:
        return self._column("targets")

    @property
    def dedicated(self) -> np.ndarray:
        return self._column("dedicated")

    @property
    def pose(self) -> np.ndarray:
        return self._column("pose")

    @property
    def time_s(self) -> np.ndarray:
        return self._column("time")

    @property
    def lap(self) -> np.ndarray:
        return self._column("lap")

    @property
    def car_id(self) -> np.ndarray:
        return self._column("car_id")

    def read_image(self, index: int) -> np.ndarray:
        """One frame, uint8 (H, W, 3)."""
        if not 0 <= index < self.n_frames:
            raise IndexError(f"{self.path}: frame {index} out of range [0, {self.n_frames})")
        try:
            return self.images[index]
        except OSError as exc:
            raise CaptureFormatError(f"{self.path}: frame {index} cannot be decoded: {exc}") from exc

    def read_images(self, indices: Sequence[int] | np.ndarray, threads: int = 0) -> np.ndarray:
        """Frames at ``indices`` (any order, repeats allowed), uint8 (k, H, W, 3).

        gzip frames are decoded by ``threads`` threads (0: one per CPU, at most 4; zlib releases the GIL).
        """
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        if len(idx) and (idx.min() < 0 or idx.max() >= self.n_frames):
            raise IndexError(f"{self.path}: frame indices must lie in [0, {self.n_frames})")
        out = np.empty((len(idx), *self.image_hw, 3), dtype=np.uint8)
        if self._gzip_chunks and len(idx) > 1:
            try:
                blobs = [self.images.id.read_direct_chunk((int(i), 0, 0, 0)) for i in idx]
            except OSError as exc:
                raise CaptureFormatError(f"{self.path}: frames cannot be read: {exc}") from exc
            if all(mask == 0 for mask, _ in blobs):
                n_threads = threads if threads > 0 else min(4, os.cpu_count() or 1)

                def decode(j: int) -> None:
                    out[j].reshape(-1)[:] = np.frombuffer(zlib.decompress(blobs[j][1]), dtype=np.uint8)

                try:
                    with ThreadPoolExecutor(n_threads) as pool:
                        list(pool.map(decode, range(len(idx))))
                except (zlib.error, ValueError) as exc:
                    raise CaptureFormatError(f"{self.path}: a frame cannot be decoded: {exc}") from exc
                return out
        for j, i in enumerate(idx):
            out[j] = self.read_image(int(i))
        return out

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> CaptureFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_capture(path: str | os.PathLike[str]) -> CaptureFile:
    """Open a capture file read-only and check it against the format; :class:`CaptureFormatError` names any
    problem (not HDF5, truncated, missing dataset or attribute, wrong dtype or shape, mismatched lengths)."""
    path = Path(path)
    if not path.is_file():
        raise CaptureFormatError(f"{path}: no such file")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise CaptureFormatError(
            f"{path}: not a readable HDF5 file (truncated or corrupt, or still open in a running capture?): {exc}"
        ) from exc
    try:
        attrs, n_frames = _validate(path, f)
    except CaptureFormatError:
        f.close()
        raise
    except (OSError, KeyError, ValueError, TypeError) as exc:
        f.close()
        raise CaptureFormatError(f"{path}: unreadable capture file structure (truncated or corrupt?): {exc}") from exc
    return CaptureFile(path, f, n_frames, attrs)


def _validate(path: Path, f: h5py.File) -> tuple[dict[str, Any], int]:
    def fail(problem: str) -> CaptureFormatError:
        return CaptureFormatError(f"{path}: {problem}")

    attrs = _decode_attrs(f.attrs)
    needed = (
        "format_version", "target_names", "target_units", "dedicated_names", "dedicated_units", "image_height",
        "image_width", "complete", "n_frames", "package_version", *REQUIRED_ATTRS,
    )  # fmt: skip
    missing = [k for k in needed if k not in attrs]
    if missing:
        raise fail(f"missing attributes {missing}")
    if int(attrs["format_version"]) > FORMAT_VERSION:
        raise fail(f"format version {attrs['format_version']} is newer than this reader's {FORMAT_VERSION}")
    for key in ("target_names", "dedicated_names"):
        attrs[key] = _as_str_list(attrs[key])
        units_key = key.replace("names", "units")
        attrs[units_key] = _as_str_list(attrs[units_key])
        if len(attrs[units_key]) != len(attrs[key]):
            raise fail(f"{len(attrs[key])} {key} but {len(attrs[units_key])} {units_key}")
    h, w = int(attrs["image_height"]), int(attrs["image_width"])
    expected_tail = {
        "images": (h, w, 3),
        "targets": (len(attrs["target_names"]),),
        "dedicated": (len(attrs["dedicated_names"]),),
        **{name: tail for name, (_, tail) in _FRAME_DATASETS.items() if tail is not None},
    }
    expected_dtype = {"images": np.dtype(np.uint8), **{name: d for name, (d, _) in _FRAME_DATASETS.items()}}
    lengths = {}
    for name in ALL_DATASETS:
        if name not in f:
            raise fail(f"missing dataset {name!r}")
        ds = f[name]
        if not isinstance(ds, h5py.Dataset):
            raise fail(f"{name!r} is not a dataset")
        if ds.dtype != expected_dtype[name]:
            raise fail(f"dataset {name!r} has dtype {ds.dtype}, expected {expected_dtype[name]}")
        if ds.shape[1:] != expected_tail[name]:
            tail = ", ".join(map(str, expected_tail[name]))
            raise fail(f"dataset {name!r} has shape {ds.shape}, expected (N, {tail})")
        lengths[name] = ds.shape[0]
    n_frames = int(attrs["n_frames"])
    attrs["complete"] = bool(attrs["complete"])
    if attrs["complete"] and len(set(lengths.values())) != 1:
        raise fail(f"datasets have different lengths {lengths}")
    if attrs["complete"] and n_frames != lengths["images"]:
        raise fail(f"attribute n_frames={n_frames} but the datasets hold {lengths['images']} frames")
    short = {k: v for k, v in lengths.items() if v < n_frames}
    if short:
        raise fail(f"datasets shorter than the {n_frames} committed frames: {short} (truncated?)")
    return attrs, n_frames
