"""Files on disk, once for the whole package: the one atomic write, JSON records (strict JSON, through
:func:`json_text`; read through :func:`parse_json`; sealed with :func:`content_sha256`), SHA-256 of files, the
version.

The lowest layer: any layer that writes or checks a file imports it; it imports nothing of vision_rl.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import math
import os
import shutil
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any


class ArtifactWriteError(OSError):
    """A file that could not be written (a full disk, no permission); nothing was replaced."""


class InUseError(OSError):
    """Another process writes (or reads) this output: refused before anything was changed."""


def lock_exclusive(path: Path, holder: str, error: Callable[[str], Exception] = InUseError) -> int:
    """A descriptor holding an exclusive lock on ``path`` (a file, created empty when missing and never truncated,
    or an existing folder), taken before a writer changes anything: a second writer is refused with ``error``,
    nothing changed. ``holder`` names what else may hold it in the refusal."""
    if path.is_dir():
        fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    else:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        # flock, as HDF5's own locking: a reader (h5py's shared lock) and a writer exclude each other too.
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
            raise
        raise error(
            f"{path}: in use by another process ({holder}): nothing was changed; wait for it to end or stop it"
        ) from exc
    return fd


def lock_run_folder(folder: Path, holder: str) -> int:
    """:func:`lock_exclusive` on a trainer's run folder, made when missing. Two trainers in one folder (a --force
    or --resume of a running run) deleted or overwrote each other's files: the second is refused."""
    folder.mkdir(parents=True, exist_ok=True)
    return lock_exclusive(folder, holder)


@contextlib.contextmanager
def run_folder_locked(folder: Path, holder: str) -> Iterator[Path]:
    """Hold :func:`lock_run_folder` on ``folder`` inside; a folder made for the lock and left empty (the command
    refused its input) is removed again, so that a refusal leaves nothing behind."""
    made = not folder.exists()
    fd = lock_run_folder(folder, holder)
    try:
        yield folder
    finally:
        os.close(fd)
        if made:
            with contextlib.suppress(OSError):  # not empty (the run wrote), or already gone: kept as it is
                folder.rmdir()


def clear_folder(folder: Path) -> None:
    """Delete what ``folder`` holds but keep the folder itself: its lock (:func:`lock_run_folder`) is on it, and a
    folder deleted and made again would be one that another writer could lock."""
    for entry in folder.iterdir():
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink()


def first_line(exc: BaseException) -> str:
    """An exception's message as one line (its type's name when it has none), for the one-line errors of the CLI."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def file_sha256(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file's bytes, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def temporary_path(path: str | os.PathLike[str]) -> Path:
    """A hidden name beside ``path``, on its filesystem, unique to this process: where a write is staged."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write(path: str | os.PathLike[str], write: Callable[[Path], None]) -> str:
    """``write(tmp)``, flush it to disk, then rename ``tmp`` to ``path``: a kill or a full disk leaves the previous
    file whole. Returns the SHA-256 of what was written; a failed write raises :class:`ArtifactWriteError`."""
    path = Path(path)
    tmp = temporary_path(path)
    try:
        write(tmp)
        sha256 = file_sha256(tmp)
        _fsync(tmp)
        os.replace(tmp, path)
        _fsync(path.parent)
    except (OSError, RuntimeError) as exc:  # torch reports a failed write (a full disk) as RuntimeError
        tmp.unlink(missing_ok=True)
        reason = getattr(exc, "strerror", None) or first_line(exc)
        error = ArtifactWriteError(f"cannot write {path}: {reason}; the previous file is kept")
        error.errno = getattr(exc, "errno", None) or (errno.ENOSPC if "space" in str(exc) else errno.EIO)
        raise error from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return sha256


def finite_or_none(data: Any) -> Any:
    """``data`` with every NaN or infinite float, at any depth of dicts, lists and tuples, replaced by None."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, Mapping):
        return {key: finite_or_none(value) for key, value in data.items()}
    if isinstance(data, (list, tuple)):
        return [finite_or_none(value) for value in data]
    return data


def json_text(data: Any, indent: int | None = None, **dumps: Any) -> str:
    """``data`` as strict JSON: a missing or non-finite number (NaN, inf) is ``null``, never the bare ``NaN`` that
    :func:`json.dumps` writes by default and other readers refuse. Every record and log line of the package is
    written through it; ``dumps`` goes to :func:`json.dumps` (``sort_keys``, ``default``)."""
    return json.dumps(finite_or_none(data), indent=indent, allow_nan=False, **dumps)


#: The key under which a record carries the SHA-256 of the rest of its content (:func:`content_sha256`).
CONTENT_KEY = "content_sha256"


def content_sha256(data: Mapping[str, Any], leave_out: tuple[str, ...] = ()) -> str:
    """SHA-256 of a record's content as canonical strict JSON (keys sorted, no spaces), without its own
    :data:`CONTENT_KEY` and the keys in ``leave_out``: what reading the record back gives the same hash for."""
    body = {key: value for key, value in data.items() if key != CONTENT_KEY and key not in leave_out}
    canonical = json_text(body, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canonical.encode()).hexdigest()


def sealed_record(data: Mapping[str, Any]) -> dict[str, Any]:
    """``data`` with its :func:`content_sha256` under :data:`CONTENT_KEY`: what a record is written as."""
    return {**data, CONTENT_KEY: content_sha256(data)}


def content_damage(data: Mapping[str, Any], leave_out: tuple[str, ...] = ()) -> str | None:
    """None when ``data`` carries the :func:`content_sha256` of its content, else what is wrong, as the end of a
    sentence that names the file."""
    recorded = data.get(CONTENT_KEY)
    if not isinstance(recorded, str):
        return f"has no {CONTENT_KEY}"
    actual = content_sha256(data, leave_out)
    if recorded != actual:
        return (
            f"has content SHA-256 {actual[:12]}..., not its recorded {recorded[:12]}...: the file changed after it "
            "was written"
        )
    return None


def parse_json(text: str) -> Any:
    """``json.loads(text)``, with nesting too deep for the parser (RecursionError) reported as the ValueError of
    any other text that is not JSON, so that a reader catches one exception."""
    try:
        return json.loads(text)
    except RecursionError:
        raise ValueError("nested too deeply to read") from None


def write_json(path: str | os.PathLike[str], data: Mapping[str, Any] | list[Any], indent: int | None = 2) -> str:
    """``data`` as strict JSON (:func:`json_text`), written atomically (folders made); returns the file's SHA-256."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a file where a folder should be, or no permission: one line naming the path
        raise ArtifactWriteError(f"cannot write {path}: {exc.strerror or first_line(exc)}") from None
    return atomic_write(path, lambda tmp: tmp.write_text(json_text(data, indent=indent)))


def package_version() -> str:
    """The installed version of vision_rl's distribution, vision-rl-racing (the package index's ``vision_rl`` is
    another project), or ``unknown`` for a source tree run without installing (it has no distribution metadata)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("vision-rl-racing")
    except PackageNotFoundError:
        return "unknown"
