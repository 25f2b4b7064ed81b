"""The capture HDF5 file, the hand-over from capture to Phase 1: writer and validating reader.

One file holds one run's (or shard's) frames, targets, dedicated features and poses, every chunk checksummed, with a
fingerprint of what the frames were made from; a killed writer leaves a valid file that a resume continues. The
layout, the fingerprint, the checksums and the crash guarantees: docs/notes/capture.md.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
import zipfile
import zlib
from collections.abc import Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import h5py
import hdf5plugin  # registers HDF5's Zstandard filter, so h5py reads zstd images
import numpy as np
import zstandard

from vision_rl import files
from vision_rl.files import atomic_write, first_line, package_version

FORMAT_VERSION = 3
#: The first format version whose files carry checksums; older files are refused.
_CHECKSUMMED_SINCE = 2
#: The first format version that records ``committed_sha256`` at every commit (format 2 only hashed a completed
#: file, so an edit of an incomplete one went unseen); format 2 files still load, and a resume upgrades them.
_COMMIT_HASHED_SINCE = 3

#: Errors h5py raises on a damaged file, whatever the damage: a flipped bit in HDF5's metadata comes out as
#: RuntimeError, KeyError or TypeError as often as OSError. Every read catches them and names the file.
_H5_ERRORS = (OSError, RuntimeError, ValueError, KeyError, TypeError, IndexError, AttributeError, ArithmeticError)

#: Caller attributes every capture file must carry, so that a frame can be traced to how it was made (track name
#: and a hash of its geometry, car preset, renderer settings, seed; package version and the completion flag are
#: added by the writer).
REQUIRED_ATTRS: tuple[str, ...] = ("track_name", "track_geometry_hash", "car_preset", "renderer_settings", "seed")

#: What the frames were made from, in the order a difference is reported: the attributes of the file's
#: ``fingerprint`` (those the file has; a video capture has no ``cars`` or ``disrupted``, one the AI drove no
#: ``driver``, an undisrupted one no ``disrupt_steer_offset_rad``).
FINGERPRINT_KEYS: tuple[str, ...] = (
    "source",
    "track_name",
    "track_geometry_hash",
    "car_preset",
    "cars",
    "fps",
    "disrupted",
    "disrupt_steer_offset_rad",
    "seed",
    "image_height",
    "image_width",
    "renderer_settings",
    "target_names",
    "dedicated_names",
    "package_version",
    "driver",
)

#: Fingerprint fields a resumed file must share with the writer reopening it, or the frames would not belong
#: together. The package version may differ (a resumed run records the version that finished it).
_RESUME_MUST_MATCH: tuple[str, ...] = tuple(k for k in FINGERPRINT_KEYS if k != "package_version")

#: Per-frame datasets other than the images: name -> (dtype, trailing shape or None when sized by the names).
_FRAME_DATASETS: dict[str, tuple[np.dtype, tuple[int, ...] | None]] = {
    "targets": (np.dtype(np.float32), None),
    "dedicated": (np.dtype(np.float32), None),
    "pose": (np.dtype(np.float64), (3,)),
    "time": (np.dtype(np.float64), ()),
    "lap": (np.dtype(np.int32), ()),
    "car_id": (np.dtype(np.int32), ()),
}
_UNITS = {"pose": "m, m, rad", "time": "s", "lap": "1", "car_id": "1", "image_crc32": "1"}
#: The per-frame table datasets with HDF5's fletcher32 checksum: the caller's columns and the images' CRC-32s.
_TABLE_DATASETS: tuple[str, ...] = (*_FRAME_DATASETS, "image_crc32")
ALL_DATASETS: tuple[str, ...] = ("images", *_TABLE_DATASETS)

#: Rows per chunk of the small per-frame datasets: 4,096 rows of 27 float32 is 432 KiB, near HDF5's sweet spot,
#: and small enough that the last, partly filled chunk costs little.
_ROW_CHUNK = 4096

#: Compression of the image chunks, one frame per chunk: zstd 3 is smaller and reads back faster than gzip and lzf,
#: and a ninth of none's size (measured side by side: docs/benchmarks.md, "Capture compression"). zstd chunks are
#: plain zstd frames under HDF5's registered Zstandard filter (id 32015, which ``hdf5plugin`` provides), so any h5py
#: that imported hdf5plugin reads them; this module compresses and decodes them itself with the ``zstandard``
#: package in threads (it releases the GIL) and moves them with write/read_direct_chunk. Files written with gzip (the
#: earlier default), lzf or none stay readable and resumable with their own codec.
COMPRESSIONS = ("zstd", "gzip", "lzf", "none")

#: zstd level of the image chunks: level 3 is zstd's default; 5 and up are 4x slower to compress for 10 % less.
_ZSTD_LEVEL = 3

#: zlib level of the gzip chunks: level 1 compresses several times faster than the default 6 for a few % of size.
_GZIP_LEVEL = 1

#: HDF5 filter id of Zstandard (registered with The HDF Group; hdf5plugin ships the filter).
_ZSTD_FILTER_ID = hdf5plugin.ZSTD_ID

_codec_state = threading.local()


def journal_path(path: str | os.PathLike[str]) -> Path:
    """The journal beside an incomplete capture file: the rows of its last, partly filled table chunk."""
    path = Path(path)
    return path.with_name(path.name + ".journal.npz")


def _chunk_start(row: int) -> int:
    return row // _ROW_CHUNK * _ROW_CHUNK


def _write_journal(path: Path, fingerprint_sha: str, start: int, rows: Mapping[str, np.ndarray]) -> None:
    # Written whole and renamed, so a kill leaves the previous journal or this one, never half of one (zip members
    # carry a CRC-32, checked when read).
    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:  # a file, not a name: np.savez would add ".npz" to the staging name
            np.savez(fh, start=np.int64(start), fingerprint_sha256=np.str_(fingerprint_sha), **rows)

    atomic_write(path, write)


def _journal_rows(path: Path, owner: str, n_committed: int, tails: Mapping[str, tuple]) -> dict[str, np.ndarray] | None:
    """The journal's rows from the start of the last, partly filled chunk of committed rows up to ``n_committed``,
    every array checked (names, dtypes, shapes, start) before any is used; None without a journal, or when the
    journal does not cover those rows (it predates their chunk)."""
    journal = journal_path(path)
    if not journal.exists():
        return None

    def damaged(problem: str) -> CaptureFormatError:
        return CaptureFormatError(
            f"{journal}: the journal of {path.name} is damaged ({problem}); nothing was changed: restore the file, "
            "or capture again with --force"
        )

    try:
        with np.load(journal, allow_pickle=False) as z:
            missing = [k for k in ("start", "fingerprint_sha256", *_TABLE_DATASETS) if k not in z.files]
            if missing:
                raise damaged(f"no {missing}")
            start, journal_owner = z["start"], z["fingerprint_sha256"]
            rows = {name: z[name] for name in _TABLE_DATASETS}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise damaged(f"unreadable: {exc}") from exc
    if (
        start.shape != ()
        or start.dtype.kind not in "iu"
        or journal_owner.shape != ()
        or journal_owner.dtype.kind != "U"
    ):
        raise damaged("its start or owner is not a single value")
    if str(journal_owner) != owner:
        raise CaptureFormatError(f"{journal}: the journal belongs to another capture than {path.name}: remove it")
    start = int(start)
    lengths = {len(rows[name]) if rows[name].ndim else -1 for name in _TABLE_DATASETS}
    for name, table in rows.items():
        dtype = np.dtype(np.uint32) if name == "image_crc32" else _FRAME_DATASETS[name][0]
        if table.dtype != dtype or table.shape[1:] != tails[name] or table.ndim != 1 + len(tails[name]):
            raise damaged(f"{name!r} is {table.dtype} {table.shape}, expected {dtype} (N, {tails[name]})")
    if start < 0 or start % _ROW_CHUNK or len(lengths) != 1:
        raise damaged(f"start {start} or the row counts {sorted(lengths)} do not fit chunks of {_ROW_CHUNK} rows")
    first = _chunk_start(n_committed)
    if first == n_committed or not start <= first or start + lengths.pop() < n_committed:
        return None  # no committed row shares a chunk with later writes, or the journal predates that chunk
    return {name: table[first - start : n_committed - start] for name, table in rows.items()}


def lock_exclusive(path: Path, holder: str = "") -> int:
    """:func:`vision_rl.files.lock_exclusive` refusing with :class:`CaptureLockedError`; ``holder`` defaults to a
    running capture or a reader."""
    return files.lock_exclusive(path, holder or "a running capture or a reader", CaptureLockedError)


def _table_hashers() -> dict[str, Any]:
    return {name: hashlib.sha256() for name in _TABLE_DATASETS}


def _commit_digest(hashers: Mapping[str, Any]) -> str:
    """``committed_sha256``: SHA-256 over each table's name and the SHA-256 of its committed rows, so that a
    writer updates it per flush from running hashes instead of reading the file again."""
    digest = hashlib.sha256()
    for name in _TABLE_DATASETS:
        digest.update(name.encode())
        digest.update(hashers[name].copy().digest())
    return digest.hexdigest()


def _digests_of(tables: Mapping[str, np.ndarray]) -> tuple[str, str]:
    """(content_sha256, committed_sha256) of the committed rows of every table."""
    content = hashlib.sha256()
    hashers = _table_hashers()
    for name in _TABLE_DATASETS:
        data = np.ascontiguousarray(tables[name]).tobytes()
        content.update(name.encode())
        content.update(data)
        hashers[name].update(data)
    return content.hexdigest(), _commit_digest(hashers)


def _zstd_compress(frame: np.ndarray) -> bytes:
    # One compressor per thread: a zstd context must not be used by two threads at once.
    comp = getattr(_codec_state, "compressor", None)
    if comp is None:
        comp = _codec_state.compressor = zstandard.ZstdCompressor(level=_ZSTD_LEVEL, write_content_size=True)
    return comp.compress(frame)


def _encode_with_crc(encode, frame: np.ndarray) -> tuple[bytes, int]:
    blob = encode(frame)
    return blob, zlib.crc32(blob)


def _zstd_decompress(blob: bytes) -> bytes:
    dec = getattr(_codec_state, "decompressor", None)
    if dec is None:
        dec = _codec_state.decompressor = zstandard.ZstdDecompressor()
    return dec.decompress(blob)


#: Chunk encoders of the codecs this module compresses itself (in a thread pool); the others go through h5py.
_ENCODERS = {"zstd": _zstd_compress, "gzip": lambda frame: zlib.compress(frame, _GZIP_LEVEL)}
#: Chunk decoders of the codecs this module decodes itself (see _direct_decoder for which datasets qualify).
_DECODERS = {"zstd": _zstd_decompress, "gzip": zlib.decompress}
_DECODE_ERRORS = (zlib.error, zstandard.ZstdError, ValueError)


def _default_threads() -> int:
    return min(4, os.cpu_count() or 1)


class CaptureFormatError(ValueError):
    """A capture file that cannot be used as one: the message names the file and the problem."""

    def __init__(self, message: str = "", *args: object) -> None:
        # A DataLoader re-raises a worker's error with the worker's traceback as its message: keep the one line.
        lines = [line for line in str(message).splitlines() if line.strip()]
        if "Traceback" in str(message) and lines:
            message = lines[-1].split("Error: ", 1)[-1]
        super().__init__(message, *args)


class CaptureLockedError(CaptureFormatError):
    """The output file is locked by another writer (or a reader): refused before anything was changed."""


class CaptureDiskFullError(OSError):
    """The disk filled while writing; the file holds the frames of the last flush and is marked incomplete."""

    def __str__(self) -> str:  # the message alone, without OSError's "[Errno 28]" prefix
        return str(self.strerror)


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


def fingerprint_of(attrs: Mapping[str, Any]) -> dict[str, Any]:
    """The :data:`FINGERPRINT_KEYS` of ``attrs`` that are present, normalised (JSON types)."""
    return {k: _normalise(attrs[k]) for k in FINGERPRINT_KEYS if k in attrs}


def fingerprint_sha256(fingerprint: Mapping[str, Any]) -> str:
    """Hex SHA-256 of a fingerprint's canonical JSON (sorted keys)."""
    return hashlib.sha256(json.dumps(_normalise(fingerprint), sort_keys=True).encode()).hexdigest()


def first_difference(old: Any, new: Any, name: str) -> tuple[str, Any, Any] | None:
    """(dotted field name, old value, new value) of the first leaf where two JSON-like values differ, else None:
    a mismatch is reported as one field, not as two whole dicts."""
    old, new = _normalise(old), _normalise(new)
    if isinstance(old, dict) and isinstance(new, dict):
        for key in [*old, *(k for k in new if k not in old)]:
            diff = first_difference(old.get(key), new.get(key), f"{name}.{key}")
            if diff is not None:
                return diff
        return None
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        for i, (a, b) in enumerate(zip(old, new, strict=True)):
            diff = first_difference(a, b, f"{name}[{i}]")
            if diff is not None:
                return diff
        return None
    return None if old == new else (name, old, new)


def _is_disk_full(exc: BaseException) -> bool:
    """No room to write: the disk is full, or the file reached the size limit (EFBIG, ``ulimit -f``)."""
    # h5py turns HDF5's write failure into an OSError or RuntimeError whose errno is often unset; the text keeps it.
    text = str(exc)
    return getattr(exc, "errno", None) in (errno.ENOSPC, errno.EFBIG) or any(
        mark in text for mark in ("No space left", "errno = 28", "File too large", "errno = 27")
    )


#: Room reserved beyond a batch's bytes for HDF5's metadata and the rows waiting for a chunk (4,096 rows of about
#: 200 bytes), bytes.
_RESERVE_MARGIN_BYTES = 2 << 20


class CaptureWriter:
    """Appends batches of frames to a capture file; the layout and the crash guarantees: docs/notes/capture.md.

    Args:
        path: the ``.h5`` file.
        image_hw_px: (height, width) of the frames in pixels.
        target_names, target_units: the 27 target names and units (``vision_rl.sim.sensors.TARGET_NAMES``...).
        dedicated_names, dedicated_units: the 11 dedicated feature names and units.
        attrs: run attributes; must hold :data:`REQUIRED_ATTRS`. Scalars and strings are stored as they are,
            dicts and lists as JSON.
        resume: reopen an incomplete file and append to it (a missing file is created); :attr:`n_frames` tells
            the caller where to continue. A complete file is refused.
        force: overwrite an existing file.
        compression: ``"zstd"`` (level 3, default), ``"gzip"`` (level 1), ``"lzf"`` or ``"none"``; a resumed file
            keeps its own.
        compress_threads: threads compressing zstd or gzip frames (0: one per CPU, at most 4).
        flush_interval_s: longest time between flushes; frames appended since the last flush are lost to a kill.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        image_hw_px: tuple[int, int],
        target_names: Sequence[str],
        target_units: Sequence[str],
        dedicated_names: Sequence[str],
        dedicated_units: Sequence[str],
        attrs: Mapping[str, Any],
        resume: bool = False,
        force: bool = False,
        compression: str = "zstd",
        flush_interval_s: float = 2.0,
        compress_threads: int = 0,
    ) -> None:
        self.path = Path(path)
        self.image_hw_px = (int(image_hw_px[0]), int(image_hw_px[1]))
        self.target_names = tuple(target_names)
        self.dedicated_names = tuple(dedicated_names)
        self.flush_interval_s = float(flush_interval_s)
        checks = (
            (len(target_units) == len(self.target_names), f"{self.path}: every target needs one unit"),
            (len(dedicated_units) == len(self.dedicated_names), f"{self.path}: every dedicated feature needs one unit"),
            (all(k in attrs for k in REQUIRED_ATTRS), f"{self.path}: attrs lack some of {list(REQUIRED_ATTRS)}"),
            (compression in COMPRESSIONS, f"compression must be one of {COMPRESSIONS}, got {compression!r}"),
            (not (resume and force), "resume and force exclude each other: resume appends, force starts over"),
            (min(self.image_hw_px) > 0, f"image_hw_px must be positive, got {image_hw_px}"),
        )
        for ok, message in checks:
            if not ok:
                raise ValueError(message)
        file_attrs = dict(attrs)
        file_attrs.update(
            format_version=FORMAT_VERSION,
            target_names=list(self.target_names),
            target_units=list(target_units),
            dedicated_names=list(self.dedicated_names),
            dedicated_units=list(dedicated_units),
            image_height=self.image_hw_px[0],
            image_width=self.image_hw_px[1],
            compression=compression,
            package_version=package_version(),
        )
        file_attrs["fingerprint"] = fingerprint_of(file_attrs)
        file_attrs["fingerprint_sha256"] = fingerprint_sha256(file_attrs["fingerprint"])
        self._closed = True
        self._broken = False
        existed = self.path.exists()
        if existed and not (resume or force):
            raise FileExistsError(f"{self.path} exists: pass --force to overwrite it or --resume to continue it")
        self._lock_fd = lock_exclusive(self.path)
        try:
            committed = self._open_file(file_attrs, compression, resume and existed)
        except BaseException:
            self._unlock()
            if not existed:
                self.path.unlink(missing_ok=True)
            raise
        if "compression" in self._file.attrs:
            compression = str(self._file.attrs["compression"])
        self._start_buffers(committed, compression, compress_threads)
        self._fingerprint_sha = str(file_attrs["fingerprint_sha256"])
        self._closed = False
        self._last_flush_s = time.monotonic()

    def _start_buffers(self, committed: dict[str, np.ndarray], compression: str, compress_threads: int) -> None:
        """The compression threads, the rows waiting for a flush, the running hashes and the journal's head."""
        self.compression = compression
        self._pool: ThreadPoolExecutor | None = None
        if compression in _ENCODERS:
            n_threads = compress_threads if compress_threads > 0 else _default_threads()
            self._pool = ThreadPoolExecutor(n_threads, thread_name_prefix=f"capture-{compression}")
        # Looked up once: h5py's name lookup costs about 0.2 ms, several times per append.
        self._ds: dict[str, h5py.Dataset] = {name: self._file[name] for name in ALL_DATASETS}
        # Frames whose chunks are being compressed (first frame, futures): written at the next append or flush,
        # so that compression runs while the caller renders the next batch.
        self._pending: list[tuple[int, list[Future[bytes]]]] = []
        # Rows of the small per-frame datasets not yet on disk, and how many are: written at a flush (or every
        # _ROW_CHUNK rows) in one call per dataset instead of a resize and a write per dataset and append.
        self._rows: dict[str, list[np.ndarray]] = {name: [] for name in _TABLE_DATASETS}
        self._n_buffered_rows = 0
        self._n_rows_on_disk = int(self._ds["targets"].shape[0])
        # Running hashes of the rows on disk: every commit records their committed_sha256.
        self._hashers = _table_hashers()
        for name, rows in committed.items():
            self._hashers[name].update(np.ascontiguousarray(rows).tobytes())
        self._resumed = committed
        self._reserved_bytes = os.fstat(self._lock_fd).st_size
        # Rows on disk from the start of the last, partly filled chunk: the head of the next journal.
        first = _chunk_start(self._n_rows_on_disk)
        self._chunk_rows = {name: committed[name][first:] for name in _TABLE_DATASETS}

    def _open_file(self, file_attrs: dict[str, Any], compression: str, reopen: bool) -> dict[str, np.ndarray]:
        """Open the locked file (reopened, or created afresh); returns its committed rows of every table."""
        if reopen and self.path.stat().st_size > 0:  # empty: a writer killed before HDF5 wrote a byte
            self._file, committed = self._reopen(file_attrs)
            return committed
        journal_path(self.path).unlink(missing_ok=True)  # a journal of the file this one replaces
        self._file = self._create(file_attrs, compression)
        return {name: self._file[name][:0] for name in _TABLE_DATASETS}

    def _unlock(self) -> None:
        if self._lock_fd >= 0:
            os.close(self._lock_fd)  # closing the descriptor releases the lock
            self._lock_fd = -1

    # -------------------------------------------------------------------------------------------- file set-up
    def _create(self, file_attrs: dict[str, Any], compression: str) -> h5py.File:
        f = h5py.File(self.path, "w", locking=False)  # this writer holds its own lock (lock_exclusive)
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
            f.attrs["committed_sha256"] = _commit_digest(_table_hashers())
            f.attrs["image_crc32_of"] = "chunk" if compression in _ENCODERS else "frame"
            comp: dict[str, Any] = {}
            if compression == "lzf":
                comp = {"compression": "lzf"}
            elif compression == "gzip":
                comp = {"compression": "gzip", "compression_opts": _GZIP_LEVEL}
            elif compression == "zstd":
                comp = dict(hdf5plugin.Zstd(clevel=_ZSTD_LEVEL))
            h, w = self.image_hw_px
            f.create_dataset(
                "images", shape=(0, h, w, 3), maxshape=(None, h, w, 3), dtype=np.uint8, chunks=(1, h, w, 3), **comp
            )
            tables = {**_FRAME_DATASETS, "image_crc32": (np.dtype(np.uint32), ())}
            for name, (dtype, tail) in tables.items():
                if tail is None:
                    tail = (len(self.target_names) if name == "targets" else len(self.dedicated_names),)
                f.create_dataset(
                    name,
                    shape=(0, *tail),
                    maxshape=(None, *tail),
                    dtype=dtype,
                    chunks=(_ROW_CHUNK, *tail),
                    fletcher32=True,
                )
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

    def _reopen(self, file_attrs: dict[str, Any]) -> tuple[h5py.File, dict[str, np.ndarray]]:
        """Reopen an incomplete file for appending, after checking everything it reads (the file, the fingerprint,
        the journal and the committed rows against their hash) before it changes anything."""
        probe_captures([self.path])
        with _open_checked(self.path, locking=False) as existing:
            if existing.complete:
                raise CaptureFormatError(
                    f"{self.path}: the file is complete; nothing to resume (use --force to capture it again)"
                )
            stored = existing.attrs.get("fingerprint", {})
            mine = file_attrs["fingerprint"]
            for key in _RESUME_MUST_MATCH:
                diff = first_difference(stored.get(key), mine.get(key), key)
                if diff is not None:
                    field, theirs, now = diff
                    raise CaptureFormatError(
                        f"{self.path}: cannot resume: {field} is {theirs!r} in the file but {now!r} now; resume with "
                        "the file's settings or start over with --force"
                    )
            committed, rewrite = existing.resumable_rows()
        try:
            return self._rewrite_for_resume(file_attrs, committed, rewrite)
        except _H5_ERRORS as exc:
            raise CaptureFormatError(
                f"{self.path}: cannot be reopened for writing (damaged file): {first_line(exc)}"
            ) from exc

    def _rewrite_for_resume(
        self, file_attrs: dict[str, Any], committed: dict[str, np.ndarray], rewrite: bool
    ) -> tuple[h5py.File, dict[str, np.ndarray]]:
        """The checked file opened for appending: the last chunk's rows rewritten from the journal when
        ``rewrite``, the uncommitted tail dropped."""
        f = h5py.File(self.path, "r+", locking=False)
        try:
            n_committed = int(f.attrs["n_frames"])
            if rewrite:
                first = _chunk_start(n_committed)
                for name in _TABLE_DATASETS:
                    # Shrinking deletes the chunk, so the write makes a new one instead of reading the damaged one.
                    f[name].resize(first, axis=0)
                    f[name].resize(n_committed, axis=0)
                    f[name][first:n_committed] = committed[name][first:]
            # Drop frames a kill left beyond the last flush: their bytes may be partial.
            for name in ALL_DATASETS:
                if f[name].shape[0] != n_committed:
                    f[name].resize(n_committed, axis=0)
            f.attrs["package_version"] = file_attrs["package_version"]
            f.attrs["committed_sha256"] = _digests_of(committed)[1]
            f.attrs["format_version"] = FORMAT_VERSION  # the file now records a hash at every commit
            f.flush()
        except BaseException:
            f.close()
            raise
        return f, committed

    # ---------------------------------------------------------------------------------------------- writing
    def resumed_rows(self, name: str) -> np.ndarray:
        """The committed rows of table ``name`` (``"lap"``, ``"time"``...) that the file held when this writer
        opened it, checked against their hash (none for a new file)."""
        return self._resumed[name].copy()

    @property
    def n_frames(self) -> int:
        """Frames appended so far (committed or not)."""
        return int(self._ds["images"].shape[0])

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
        h, w = self.image_hw_px
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
            arrays[name] = arr.astype(dtype)  # a copy: the rows wait in memory until a flush
        if k == 0:
            return
        start = self.n_frames
        try:
            # Room for this batch, the one still being compressed and the rows, before any byte is written.
            self._reserve(2 * images.nbytes + sum(a.nbytes for a in arrays.values()))
        except OSError as exc:
            if not _is_disk_full(exc):
                raise
            # Nothing of this batch is written: commit the earlier ones (their room was reserved) and stop.
            with contextlib.suppress(OSError, RuntimeError):
                self.flush()
            self._broken = True
            raise self._disk_full(exc) from exc
        try:
            self._write_images(start, images)
            for name, arr in arrays.items():
                self._rows[name].append(arr)
            self._n_buffered_rows += k
            if self._n_buffered_rows >= _ROW_CHUNK:
                self._write_rows()
            if time.monotonic() - self._last_flush_s >= self.flush_interval_s:
                self.flush()
        except (OSError, RuntimeError) as exc:
            self._broken = True
            if _is_disk_full(exc):
                raise self._disk_full(exc) from exc
            if isinstance(exc, RuntimeError):  # HDF5's word for a damaged file met while writing
                raise CaptureFormatError(f"{self.path}: writing failed (damaged file?): {first_line(exc)}") from exc
            raise

    def _reserve(self, n_bytes: int) -> None:
        """Have the disk hold room for the next ``n_bytes`` (and a margin for HDF5's metadata) beyond the file's
        allocated end before they are written: a full disk then stops the capture between batches. Inside HDF5's
        own writes it would leave a file whose recorded end lies beyond its bytes, which HDF5 refuses to open."""
        target = int(self._file.id.get_filesize()) + int(n_bytes) + _RESERVE_MARGIN_BYTES
        if target > self._reserved_bytes:
            os.posix_fallocate(self._lock_fd, 0, target)
            self._reserved_bytes = target

    def _disk_full(self, exc: BaseException) -> CaptureDiskFullError:
        committed = self._committed()
        self._abandon()
        return CaptureDiskFullError(
            errno.ENOSPC,
            f"{self.path}: disk full after {committed} frames ({first_line(exc)}); the file keeps those frames, "
            "marked incomplete: free space and resume",
        )

    def _write_images(self, start: int, images: np.ndarray) -> None:
        ds = self._ds["images"]
        ds.resize(start + len(images), axis=0)
        if self._pool is None:
            ds[start:] = images
            # h5py decodes these codecs: the checksum covers the frame bytes (one C call per frame).
            crcs = [zlib.crc32(np.ascontiguousarray(frame)) for frame in images]
            self._rows["image_crc32"].append(np.asarray(crcs, dtype=np.uint32))
            return
        # The same stream HDF5's deflate or Zstandard filter writes, so any HDF5 reader decodes these chunks. A
        # copy: the caller may reuse its buffer once append returns.
        frames = np.array(images, dtype=np.uint8, order="C", copy=True)
        encode = _ENCODERS[self.compression]
        self._pending.append((start, [self._pool.submit(_encode_with_crc, encode, frame) for frame in frames]))
        while len(self._pending) > 1:  # the batch before this one, compressed while the caller made this one
            self._write_pending()

    def _write_pending(self) -> None:
        start, futures = self._pending.pop(0)
        ds = self._ds["images"]
        crcs = np.empty(len(futures), dtype=np.uint32)
        for j, future in enumerate(futures):
            blob, crcs[j] = future.result()
            ds.id.write_direct_chunk((start + j, 0, 0, 0), blob)
        self._rows["image_crc32"].append(crcs)

    def _write_rows(self) -> None:
        if self._n_buffered_rows == 0:
            return
        # The images' checksums are known once their chunks are compressed: write those first.
        while self._pending:
            self._write_pending()
        end = self._n_rows_on_disk + self._n_buffered_rows
        new_rows = {name: np.concatenate(parts) for name, parts in self._rows.items()}
        first = _chunk_start(self._n_rows_on_disk)
        chunk_rows = {name: np.concatenate([self._chunk_rows[name], rows]) for name, rows in new_rows.items()}
        _write_journal(journal_path(self.path), self._fingerprint_sha, first, chunk_rows)
        for name, rows in new_rows.items():
            ds = self._ds[name]
            ds.resize(end, axis=0)
            ds[self._n_rows_on_disk :] = rows
            self._hashers[name].update(np.ascontiguousarray(rows).tobytes())
            self._rows[name].clear()
        # Onto the disk now, while this journal covers the chunk: HDF5's chunk cache could write it after the next
        # journal has replaced this one.
        self._file.flush()
        self._chunk_rows = {name: rows[_chunk_start(end) - first :] for name, rows in chunk_rows.items()}
        self._n_rows_on_disk = end
        self._n_buffered_rows = 0

    def flush(self) -> None:
        """Write everything appended so far to disk, then record it as committed in ``n_frames``."""
        while self._pending:
            self._write_pending()
        self._write_rows()
        self._file.flush()
        # The count and the hash of what it counts, in place (same size): one object header's two messages.
        self._file.attrs.modify("n_frames", self.n_frames)
        self._file.attrs.modify("committed_sha256", _commit_digest(self._hashers))
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
        self._unlock()

    def _release_reserve(self, end: int) -> None:
        """Give back the room reserved beyond ``end``, the closed file's allocated end (HDF5 keeps a longer file
        as it is); undone if HDF5 then refuses the file (it placed something beyond ``end`` after all)."""
        size = os.fstat(self._lock_fd).st_size
        if end <= 0 or size <= end:
            return
        os.ftruncate(self._lock_fd, end)
        try:
            h5py.File(self.path, "r", locking=False).close()
        except _H5_ERRORS:
            os.ftruncate(self._lock_fd, size)

    def _stop_pool(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def close(self, complete: bool = False) -> None:
        """Flush and close; ``complete=True`` marks the run finished (the default leaves it resumable)."""
        if self._closed:
            return
        marked_complete = False
        try:
            self._reserve(0)
            self.flush()
            if complete:
                self._file.attrs["content_sha256"] = _content_sha256(self._file, self.n_frames)
                self._file.attrs["complete"] = True
                self._file.flush()
                marked_complete = True
        except (OSError, RuntimeError) as exc:
            self._broken = True
            if _is_disk_full(exc):
                self._abandon()
                raise CaptureDiskFullError(errno.ENOSPC, f"{self.path}: disk full while closing") from exc
            raise
        finally:
            if not self._closed:
                end = -1
                with contextlib.suppress(*_H5_ERRORS):
                    end = int(self._file.id.get_filesize())  # open, it is the allocated end, not the file's size
                self._file.close()
                self._closed = True
                self._release_reserve(end)
            self._stop_pool()
            if marked_complete:  # still under the lock: no other writer's journal can be there
                journal_path(self.path).unlink(missing_ok=True)
            self._unlock()

    def __enter__(self) -> CaptureWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        # Leaving the block never marks the file complete: only an explicit close(complete=True) does.
        self.close(complete=False)


def _content_sha256(f: h5py.File, n_frames: int, path: Path | None = None) -> str:
    """Hex SHA-256 of the first ``n_frames`` rows of every table dataset; ``image_crc32`` stands for the images."""
    digest = hashlib.sha256()
    for name in _TABLE_DATASETS:
        digest.update(name.encode())
        digest.update(_read_table(f[name], n_frames, path or Path(f.filename)).tobytes())
    return digest.hexdigest()


def _read_table(ds: h5py.Dataset, n_frames: int, path: Path) -> np.ndarray:
    """The first ``n_frames`` rows; a failed fletcher32 checksum is named with the frames of the damaged chunk."""
    name = ds.name.lstrip("/")
    try:
        return ds[:n_frames]
    except _H5_ERRORS as exc:
        rows = _ROW_CHUNK
        for start in range(0, n_frames, rows):  # one read per chunk: find the damaged one
            stop = min(start + rows, n_frames)
            try:
                ds[start:stop]
            except _H5_ERRORS:
                remedy = (
                    "resume the capture (--resume), which rewrites them from its journal"
                    if journal_path(path).exists()
                    else "restore or capture it again"
                )
                raise CaptureFormatError(
                    f"{path}: dataset {name!r}, frames {start}..{stop - 1}: the data fail their checksum or cannot "
                    f"be read (damaged file): {remedy} ({first_line(exc)})"
                ) from exc
        raise CaptureFormatError(f"{path}: cannot read dataset {name!r}: {first_line(exc)}") from exc


#: Largest stored chunk read, bytes, beyond its raw size: zstd's and deflate's worst case adds a few bytes per
#: 100 kB and fletcher32 4. A damaged chunk index may declare gigabytes; the size is checked before any read.
_CHUNK_SLACK_BYTES = 65536


def _check_chunks(ds: h5py.Dataset, n_frames: int, path: Path, file_bytes: int) -> None:
    """Refuse a dataset whose chunk index lacks a chunk of a committed frame, or places one outside the file or
    declares it larger than the raw chunk, before any chunk is read (so no damaged size is ever allocated)."""
    name = ds.name.lstrip("/")
    rows = int(ds.chunks[0])
    limit = math.prod(ds.chunks) * ds.dtype.itemsize + _CHUNK_SLACK_BYTES
    found = np.zeros(-(-n_frames // rows), dtype=bool)
    bad: list[str] = []

    def visit(info: Any) -> None:
        index = int(info.chunk_offset[0]) // rows
        if index >= len(found):
            return  # a killed writer's tail, never read
        found[index] = True
        offset, size = info.byte_offset, int(info.size)
        if not bad and (offset is None or size > limit or int(offset) + size > file_bytes):
            bad.append(
                f"the chunk of frames from {index * rows} declares {size} bytes at byte {offset} of {file_bytes}"
            )

    try:
        ds.id.chunk_iter(visit)
    except _H5_ERRORS as exc:
        raise CaptureFormatError(
            f"{path}: dataset {name!r}: its chunk index cannot be read (damaged file): {first_line(exc)}"
        ) from exc
    if not bad and not found.all():
        missing = int(np.flatnonzero(~found)[0]) * rows
        bad.append(f"no stored chunk holds frame {missing} of the {n_frames} committed")
    if bad:
        raise CaptureFormatError(f"{path}: dataset {name!r}: {bad[0]} (damaged file): restore or capture it again")


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
        self._decode = _direct_decoder(self.images, self.image_hw_px)
        # The images' CRC-32s, read on the first image read; "chunk": of the stored chunk, "frame": of its bytes.
        self._crc: np.ndarray | None = None
        self._crc_of = str(attrs.get("image_crc32_of", "frame"))
        if self._crc_of == "chunk" and self._decode is None:
            raise CaptureFormatError(
                f"{path}: image checksums cover zstd/deflate chunks but the images are stored "
                "otherwise (a rewritten file?)"
            )
        self._pool: ThreadPoolExecutor | None = None
        self._pool_threads = 0
        # Every table's committed rows, read and checked against the recorded hashes on the first read of anything.
        self._tables: dict[str, np.ndarray] | None = None
        self._content_digest = ""

    @property
    def complete(self) -> bool:
        return bool(self.attrs["complete"])

    @property
    def image_hw_px(self) -> tuple[int, int]:
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
        kept = self._verified_tables().get(name)
        return kept.copy() if kept is not None else _read_table(self._f[name], self.n_frames, self.path)

    @property
    def fingerprint(self) -> dict[str, Any]:
        """What the frames were made from (docs/notes/capture.md), as a dict."""
        return dict(self.attrs.get("fingerprint", {}))

    def content_sha256(self) -> str:
        """Hex SHA-256 of the committed rows of every table (the images through their CRC-32s), after checking them
        against the hashes the writer recorded (at every commit, and when the capture completed)."""
        self._verified_tables()
        return self._content_digest

    def _verified_tables(self) -> dict[str, np.ndarray]:
        """The tables kept in memory once every table was checked (:meth:`_read_verified`)."""
        return self._tables if self._tables is not None else self._read_verified()

    def _read_verified(self) -> dict[str, np.ndarray]:
        """Every table's committed rows, after checking every dataset's chunk index; then checked against the
        recorded hashes (so an edit, or a chunk lost from the index, is refused, never read)."""
        self._check_indexes()
        tables = {name: _read_table(self._f[name], self.n_frames, self.path) for name in _TABLE_DATASETS}
        self._content_digest = self._check_digests(tables)
        # Only the images' checksums stay in memory (4 bytes a frame, in every loader worker); the other tables
        # are read again when asked for, through the same checked index and fletcher32 checksums.
        self._tables = {"image_crc32": tables["image_crc32"]}
        return tables

    def _check_indexes(self, names: Sequence[str] = ALL_DATASETS) -> None:
        file_bytes = self.path.stat().st_size
        for name in names:
            _check_chunks(self._f[name], self.n_frames, self.path, file_bytes)

    def _check_digests(self, tables: Mapping[str, np.ndarray]) -> str:
        """The content digest of ``tables``, after refusing rows that differ from the recorded hashes."""
        content, committed = _digests_of(tables)
        checks = (
            ("content_sha256", content, "was recorded when the capture completed"),
            ("committed_sha256", committed, "was recorded at the last commit"),
        )
        for key, digest, when in checks:
            recorded = self.attrs.get(key)
            if recorded is not None and str(recorded) != digest:
                raise CaptureFormatError(
                    f"{self.path}: the {self.n_frames} committed frames hash to {key} {digest[:16]}... but "
                    f"{str(recorded)[:16]}... {when} (the file was changed since): restore or capture it again"
                )
        return content

    def resumable_rows(self) -> tuple[dict[str, np.ndarray], bool]:
        """The committed rows a resumed writer continues from, and whether the last, partly filled chunk must be
        rewritten from the journal (a kill inside HDF5's rewrite of that chunk damages it); refused, with nothing
        changed, when neither the file nor its journal gives rows matching the recorded hashes."""
        self._check_indexes()  # a damaged index is no kill's work: the journal cannot mend it
        try:
            return self._read_verified(), False
        except CaptureFormatError as exc:
            damage = exc
        tails = {name: tuple(self._f[name].shape[1:]) for name in _TABLE_DATASETS}
        journal = _journal_rows(self.path, str(self.attrs["fingerprint_sha256"]), self.n_frames, tails)
        if journal is None:
            raise damage
        first = _chunk_start(self.n_frames)
        rows = {n: np.concatenate([_read_table(self._f[n], first, self.path), journal[n]]) for n in _TABLE_DATASETS}
        self._check_digests(rows)
        return rows, True

    def _crcs(self) -> np.ndarray:
        if self._crc is None:
            self._crc = self._verified_tables()["image_crc32"]
        return self._crc

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
        out = np.empty((*self.image_hw_px, 3), dtype=np.uint8)
        self._crcs()
        self._decode_into(out, self._read_chunk(index), index)
        return out

    def _read_chunk(self, index: int) -> tuple[bytes, bool] | None:
        """(the stored chunk of a frame, whether this module decodes it) when the checksum covers the chunk or this
        module decodes it, else None (h5py reads and decodes the frame)."""
        if self._decode is None:
            return None
        try:
            mask, blob = self.images.id.read_direct_chunk((int(index), 0, 0, 0))
        except _H5_ERRORS as exc:
            raise CaptureFormatError(
                f"{self.path}: dataset 'images', frame {index} cannot be read (damaged file): {first_line(exc)}"
            ) from exc
        if mask != 0 and self._crc_of == "chunk":  # this writer never skips the filter: a damaged index
            raise CaptureFormatError(f"{self.path}: dataset 'images', frame {index}: filter mask {mask} (damaged file)")
        # A set bit in the mask means HDF5 skipped an optional filter for this chunk: let h5py decode it.
        return blob, mask == 0

    def _checksum_error(self, index: int, stored: int, read: int) -> CaptureFormatError:
        return CaptureFormatError(
            f"{self.path}: dataset 'images', frame {index}: CRC-32 {read:08x} of the stored {self._crc_of} differs "
            f"from the recorded {stored:08x} (damaged file): restore or capture it again"
        )

    def _decode_into(self, out: np.ndarray, chunk: tuple[bytes, bool] | None, index: int) -> None:
        assert self._crc is not None
        stored = int(self._crc[index])
        if chunk is not None and self._crc_of == "chunk" and zlib.crc32(chunk[0]) != stored:
            raise self._checksum_error(index, stored, zlib.crc32(chunk[0]))
        try:
            if chunk is None or not chunk[1]:
                out[...] = self.images[index]
            else:
                assert self._decode is not None
                out.reshape(-1)[:] = np.frombuffer(self._decode(chunk[0]), dtype=np.uint8)
        except (*_H5_ERRORS, *_DECODE_ERRORS) as exc:
            raise CaptureFormatError(
                f"{self.path}: dataset 'images', frame {index} cannot be decoded (damaged file): {first_line(exc)}"
            ) from exc
        if self._crc_of == "frame" and zlib.crc32(out) != stored:
            raise self._checksum_error(index, stored, zlib.crc32(out))

    def read_images(
        self, indices: Sequence[int] | np.ndarray, threads: int = 0, out: np.ndarray | None = None
    ) -> np.ndarray:
        """Frames at ``indices`` (any order, repeats allowed), uint8 (k, H, W, 3), written into ``out`` when given
        (a C-contiguous uint8 array of that shape, e.g. shared memory a batch travels in).

        zstd and gzip frames are decoded by ``threads`` threads (0: one per CPU, at most 4; both codecs release
        the GIL); the pool lives as long as the file is open.
        """
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        if len(idx) and (idx.min() < 0 or idx.max() >= self.n_frames):
            raise IndexError(f"{self.path}: frame indices must lie in [0, {self.n_frames})")
        shape = (len(idx), *self.image_hw_px, 3)
        if out is None:
            out = np.empty(shape, dtype=np.uint8)
        elif out.shape != shape or out.dtype != np.uint8 or not out.flags.c_contiguous:
            raise ValueError(f"out must be a C-contiguous uint8 array of shape {shape}, got {out.dtype} {out.shape}")
        # HDF5 calls are serialised by h5py's lock anyway: read the compressed chunks here, decode in threads.
        self._crcs()
        blobs = [self._read_chunk(int(i)) for i in idx]
        n_threads = threads if threads > 0 else _default_threads()
        if len(idx) < 2 or n_threads < 2 or self._decode is None:
            for j, blob in enumerate(blobs):
                self._decode_into(out[j], blob, int(idx[j]))
            return out
        if self._pool is None or self._pool_threads != n_threads:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
            self._pool = ThreadPoolExecutor(n_threads, thread_name_prefix="capture-decode")
            self._pool_threads = n_threads
        list(self._pool.map(lambda j: self._decode_into(out[j], blobs[j], int(idx[j])), range(len(idx))))
        return out

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        self._f.close()

    def __enter__(self) -> CaptureFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _direct_decoder(ds: h5py.Dataset, image_hw_px: tuple[int, int]):
    """The chunk decoder for images stored one frame per chunk with a single zstd or deflate filter, else None
    (other layouts are read through h5py)."""
    if ds.chunks != (1, *image_hw_px, 3):
        return None
    dcpl = ds.id.get_create_plist()
    if dcpl.get_nfilters() != 1:
        return None
    filter_id = dcpl.get_filter(0)[0]
    if filter_id == h5py.h5z.FILTER_DEFLATE:
        return _DECODERS["gzip"]
    if filter_id == _ZSTD_FILTER_ID:
        return _DECODERS["zstd"]
    return None


def open_capture(path: str | os.PathLike[str]) -> CaptureFile:
    """Open a capture file read-only and check it against the format; :class:`CaptureFormatError` names any
    problem (not HDF5, truncated, missing dataset or attribute, wrong dtype or shape, mismatched lengths).

    HDF5 itself may crash on some damaged metadata: a file from a disk not yet trusted goes through
    :func:`probe_captures` first (the datasets, a resume and a manifest do)."""
    return _open_checked(Path(path), locking=True)


#: Longest a probe may read its files, s: a damaged index can send HDF5 round in circles.
_PROBE_TIMEOUT_S = 300.0

#: What a probe found of each file, by path, size and modification time (None: HDF5 reads it; else the refusal).
_probed: dict[tuple[str, int, int], str | None] = {}


def probe_captures(paths: Sequence[str | os.PathLike[str]]) -> None:
    """Parse every file as a reader does (attributes, datasets, chunk indexes, tables) in a child process first,
    and refuse, in one line naming it, a file that crashes or hangs it: HDF5's C code can segfault on a damaged
    attribute or index, which no exception in this process could catch. Refusals of the format itself are left to
    the reader, which repeats the same checks. Each file is probed once per process (until it changes)."""
    found = crashing_captures(paths)
    if found:
        raise CaptureFormatError(next(iter(found.values())))


def crashing_captures(paths: Sequence[str | os.PathLike[str]]) -> dict[Path, str]:
    """The files of ``paths`` that crash or hang HDF5, each with its one-line refusal (see :func:`probe_captures`);
    one child process reads them all, and another goes on after each crash."""
    files = [Path(p) for p in paths if Path(p).is_file()]
    keys = {p: (str(p.resolve()), p.stat().st_size, p.stat().st_mtime_ns) for p in files}
    todo = [p for p in files if keys[p] not in _probed]
    while todo:
        reached, refusal = _probe_child(todo)
        done = todo[: len(reached)] if refusal is None else todo[: max(len(reached) - 1, 0)]
        _probed.update((keys[p], None) for p in done)
        if refusal is not None:
            culprit = todo[len(done)]
            _probed[keys[culprit]] = f"{culprit}: {refusal}"
            done.append(culprit)
        todo = todo[len(done) :] if done else []
    return {p: message for p in files if (message := _probed.get(keys[p])) is not None}


def _probe_child(paths: list[Path]) -> tuple[list[str], str | None]:
    """(the files the child reached, how it failed on the last of them, or None when it read them all)."""
    code = "import sys\nfrom vision_rl.capture.h5format import _probe_main\nsys.exit(_probe_main(sys.argv[1:]))"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[2]), *sys.path])}
    try:
        proc = subprocess.run(
            [sys.executable, "-c", code, *map(str, paths)],
            capture_output=True,
            text=True,
            timeout=_PROBE_TIMEOUT_S,
            env=env,
        )
    except subprocess.TimeoutExpired as exc:
        reached = (exc.stdout or b"").decode(errors="replace").splitlines()
        return (
            reached,
            f"HDF5 did not finish reading it in {_PROBE_TIMEOUT_S:g} s (damaged file): restore or capture it again",
        )
    reached = proc.stdout.splitlines()
    if proc.returncode == 0:
        return reached, None
    how = f"signal {signal.Signals(-proc.returncode).name}" if proc.returncode < 0 else f"exit {proc.returncode}"
    return reached, f"HDF5 crashed reading it ({how}; damaged file): restore or capture it again"


def _probe_main(paths: Sequence[str]) -> int:
    """The child of :func:`probe_captures`: each path on stdout before it is read, so a crash names its file."""
    for path in paths:
        os.write(1, f"{path}\n".encode())  # to the parent, which names the file a crash stopped at
        try:
            with _open_checked(Path(path), locking=False) as cap:
                cap._read_verified()
        except CaptureFormatError:
            pass  # the reader refuses it in its own words
    return 0


def _open_checked(path: Path, locking: bool) -> CaptureFile:
    """:func:`open_capture`; ``locking=False`` for the writer, which holds its own lock on the file."""
    if not path.is_file():
        raise CaptureFormatError(f"{path}: no such file")
    try:
        f = h5py.File(path, "r", locking=locking)
    except _H5_ERRORS as exc:
        raise CaptureFormatError(
            f"{path}: not a readable HDF5 file (truncated or corrupt, or still open in a running capture?): "
            f"{first_line(exc)}"
        ) from exc
    try:
        attrs, n_frames = _validate(path, f)
        return CaptureFile(path, f, n_frames, attrs)
    except CaptureFormatError:
        f.close()
        raise
    except (*_H5_ERRORS, LookupError) as exc:
        f.close()
        raise CaptureFormatError(
            f"{path}: unreadable capture file structure (truncated or corrupt?): {first_line(exc)}"
        ) from exc


def _check_version(path: Path, attrs: Mapping[str, Any]) -> None:
    version = int(attrs["format_version"])
    if version > FORMAT_VERSION:
        raise CaptureFormatError(f"{path}: format version {version} is newer than this reader's {FORMAT_VERSION}")
    if version < _CHECKSUMMED_SINCE:
        raise CaptureFormatError(
            f"{path}: format version {version} carries no checksums, so damaged frames would go unnoticed: capture "
            f"it again (capture --force writes format {FORMAT_VERSION})"
        )


#: Largest chunk of any dataset, bytes: a frame of 4K video is 25 MB; a damaged layout may declare far more.
_MAX_CHUNK_BYTES = 64 << 20


def _check_against_fingerprint(path: Path, attrs: Mapping[str, Any]) -> None:
    """Refuse attributes that differ from the hashed fingerprint's copy of them (a flipped bit in an attribute the
    reader uses, such as the frame size, would otherwise go unseen); the package version may differ (a resume)."""
    fingerprint = attrs["fingerprint"]
    for key in _RESUME_MUST_MATCH:
        if key in fingerprint and _normalise(attrs.get(key)) != fingerprint[key]:
            raise CaptureFormatError(
                f"{path}: attribute {key} is {attrs.get(key)!r} but the fingerprint records {fingerprint[key]!r} "
                "(damaged or edited file): restore or capture it again"
            )
    if int(attrs["format_version"]) >= _COMMIT_HASHED_SINCE and "committed_sha256" not in attrs:
        raise CaptureFormatError(f"{path}: format {attrs['format_version']} but no committed_sha256 (damaged file)")


def _stored_compression(ds: h5py.Dataset) -> str:
    """The codec of the images' filter pipeline, in :data:`COMPRESSIONS`' words ("?" for any other pipeline)."""
    dcpl = ds.id.get_create_plist()
    filters = [dcpl.get_filter(i)[0] for i in range(dcpl.get_nfilters())]
    names = {h5py.h5z.FILTER_DEFLATE: "gzip", _ZSTD_FILTER_ID: "zstd", h5py.h5z.FILTER_LZF: "lzf"}
    if not filters:
        return "none"
    return names.get(filters[0], "?") if len(filters) == 1 else "?"


def _check_layout_attrs(path: Path, f: h5py.File, attrs: Mapping[str, Any]) -> None:
    """Refuse file attributes that disagree with the datasets' own: the names and units each table also carries,
    and the compression and checksum kind the images are stored with."""
    for key in ("target", "dedicated"):
        table = f["targets" if key == "target" else key].attrs
        for field in ("names", "units"):
            if field in table and _as_str_list(table[field]) != list(attrs[f"{key}_{field}"]):
                raise CaptureFormatError(
                    f"{path}: attribute {key}_{field} differs from the dataset's own {field} (damaged or edited file)"
                )
    stored = _stored_compression(f["images"])
    compression = str(attrs.get("compression", stored))
    crc_of = "chunk" if compression in _ENCODERS else "frame"
    if compression != stored or attrs["image_crc32_of"] != crc_of:
        raise CaptureFormatError(
            f"{path}: attributes compression={compression!r}, image_crc32_of={attrs['image_crc32_of']!r} but the "
            f"images are stored with {stored!r} (damaged or edited file)"
        )


def _validate(path: Path, f: h5py.File) -> tuple[dict[str, Any], int]:
    def fail(problem: str) -> CaptureFormatError:
        return CaptureFormatError(f"{path}: {problem}")

    attrs = _validate_attrs(path, f)
    lengths = _validate_datasets(path, f, attrs)
    _check_layout_attrs(path, f, attrs)
    n_frames = int(attrs["n_frames"])
    if n_frames < 0:
        raise fail(f"attribute n_frames={n_frames} is negative (damaged file)")
    attrs["complete"] = bool(attrs["complete"])
    if attrs["complete"] and "content_sha256" not in attrs:
        raise fail("marked complete but records no content_sha256 (damaged or edited file): restore or capture again")
    if attrs["complete"] and len(set(lengths.values())) != 1:
        raise fail(f"datasets have different lengths {lengths}")
    if attrs["complete"] and n_frames != lengths["images"]:
        raise fail(f"attribute n_frames={n_frames} but the datasets hold {lengths['images']} frames")
    short = {k: v for k, v in lengths.items() if v < n_frames}
    if short:
        raise fail(f"datasets shorter than the {n_frames} committed frames: {short} (truncated?)")
    return attrs, n_frames


def _validate_attrs(path: Path, f: h5py.File) -> dict[str, Any]:
    """The file's attributes, decoded, after checking that those the reader needs are there and agree with the
    hashed fingerprint."""

    def fail(problem: str) -> CaptureFormatError:
        return CaptureFormatError(f"{path}: {problem}")

    attrs = _decode_attrs(f.attrs)
    needed = (
        "format_version",
        "target_names",
        "target_units",
        "dedicated_names",
        "dedicated_units",
        "image_height",
        "image_width",
        "complete",
        "n_frames",
        "package_version",
        *REQUIRED_ATTRS,
    )
    missing = [k for k in needed if k not in attrs]
    if missing:
        raise fail(f"missing attributes {missing}")
    _check_version(path, attrs)
    missing = [k for k in ("fingerprint", "fingerprint_sha256", "image_crc32_of") if k not in attrs]
    if missing:
        raise fail(f"missing attributes {missing}")
    if not isinstance(attrs["fingerprint"], dict):
        raise fail("the fingerprint is not a record (damaged attributes)")
    if fingerprint_sha256(attrs["fingerprint"]) != attrs["fingerprint_sha256"]:
        raise fail("the fingerprint does not match its recorded fingerprint_sha256 (the attributes were edited)")
    _check_against_fingerprint(path, attrs)
    for key in ("target_names", "dedicated_names"):
        attrs[key] = _as_str_list(attrs[key])
        units_key = key.replace("names", "units")
        attrs[units_key] = _as_str_list(attrs[units_key])
        if len(attrs[units_key]) != len(attrs[key]):
            raise fail(f"{len(attrs[key])} {key} but {len(attrs[units_key])} {units_key}")
    return attrs


def _validate_datasets(path: Path, f: h5py.File, attrs: Mapping[str, Any]) -> dict[str, int]:
    """Every dataset's length, after checking its kind, dtype, shape, checksum filter and chunk size."""

    def fail(problem: str) -> CaptureFormatError:
        return CaptureFormatError(f"{path}: {problem}")

    h, w = int(attrs["image_height"]), int(attrs["image_width"])
    expected_tail = {
        "images": (h, w, 3),
        "image_crc32": (),
        "targets": (len(attrs["target_names"]),),
        "dedicated": (len(attrs["dedicated_names"]),),
        **{name: tail for name, (_, tail) in _FRAME_DATASETS.items() if tail is not None},
    }
    expected_dtype = {
        "images": np.dtype(np.uint8),
        "image_crc32": np.dtype(np.uint32),
        **{name: d for name, (d, _) in _FRAME_DATASETS.items()},
    }
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
        if name != "images" and not ds.fletcher32:
            raise fail(f"dataset {name!r} has no fletcher32 checksum (rewritten by another tool?): capture it again")
        chunks = ds.chunks or ()
        oversized = math.prod(chunks) * ds.dtype.itemsize > _MAX_CHUNK_BYTES
        if not chunks or oversized or (name == "images" and chunks != (1, h, w, 3)):
            raise fail(f"dataset {name!r} has chunks {chunks} (damaged file?)")
        lengths[name] = ds.shape[0]
    return lengths
