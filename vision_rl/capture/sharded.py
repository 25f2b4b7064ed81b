"""Sharded capture: N Ray tasks, each an ordinary simulator capture into its own shard file, and a manifest.

A shard is :func:`vision_rl.capture.sim_capture.capture_sim` with its own seed and share of the laps; the manifest
lists and checksums the shards, and a lost shard is rerun or resumed. Ray is imported only when a sharded capture
runs. The shards, the manifest and the faults: docs/notes/capture.md.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from vision_rl.capture.h5format import (
    CaptureFormatError,
    first_difference,
    lock_exclusive,
    open_capture,
    probe_captures,
)
from vision_rl.capture.sim_capture import CaptureConfig
from vision_rl.files import atomic_write, first_line, json_text

#: The ``format`` field of a manifest, and the version this module writes and reads.
MANIFEST_FORMAT = "vision_rl capture manifest"
MANIFEST_VERSION = 1

#: The extra to install for a sharded capture.
RAY_INSTALL = "pip install 'vision_rl[ray]'"

#: Seconds between a shard's progress reports to the driver (a Ray call each).
_REPORT_INTERVAL_S = 0.5


class ManifestError(CaptureFormatError):
    """A manifest or one of its shards that cannot be used: the message names the manifest and the shard."""


class RayMissingError(ValueError):
    """Ray is not installed; the message says which extra to install."""


@dataclass(frozen=True)
class ShardedCaptureConfig(CaptureConfig):
    """A capture split into shards captured by Ray tasks at once, presented as one dataset by a manifest."""

    workers: int = 2
    """Shards, each captured by a Ray task of one CPU (at most the cluster's CPUs)."""
    address: str = ""
    """Ray cluster to run on: 'auto' (the running one), HOST:PORT, or empty for a local Ray on this machine."""
    task_retries: int = 1
    """Times Ray reruns a shard whose worker process died (the rerun continues the shard's file)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        checks = (
            (self.workers >= 1, f"--workers must be >= 1, got {self.workers}"),
            (
                self.laps >= self.workers,
                f"--laps {self.laps} < --workers {self.workers}: every shard needs at least one lap",
            ),
            (
                self.max_frames == 0 or self.max_frames >= self.workers,
                f"--max-frames {self.max_frames} < --workers {self.workers}: every shard needs at least one frame",
            ),
            (self.task_retries >= 0, f"task_retries must be >= 0, got {self.task_retries}"),
            (
                self.out.endswith(".json"),
                f"--out {self.out!r}: a sharded capture writes a manifest: give --out "
                "PATH.json (the shards go to PATH.shards/)",
            ),
        )
        for ok, message in checks:
            if not ok:
                raise ValueError(message)


def shard_seed(seed: int, index: int) -> int:
    """The capture seed of shard ``index`` of a run seeded ``seed``: a hash of both, so that no shard of one run
    repeats a shard of another (``seed + index`` would make shard 1 of seed 0 the shard 0 of seed 1)."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1, np.uint32)[0])


def _shares(total: int, n: int) -> list[int]:
    """``total`` split into ``n`` near-equal integer parts, the larger ones first."""
    return [total // n + (1 if i < total % n else 0) for i in range(n)]


def shards_dir(manifest: str | os.PathLike[str]) -> Path:
    """The folder of a manifest's shards: ``runs/cap/train.json`` -> ``runs/cap/train.shards``."""
    return Path(manifest).with_suffix(".shards")


def plan_shards(cfg: ShardedCaptureConfig) -> list[CaptureConfig]:
    """The capture of each shard: the run's settings with the shard's seed, laps, frame limit and file."""
    folder = shards_dir(cfg.out).resolve()
    laps = _shares(cfg.laps, cfg.workers)
    frames = _shares(cfg.max_frames, cfg.workers) if cfg.max_frames else [0] * cfg.workers
    base = {f.name: getattr(cfg, f.name) for f in dataclasses.fields(CaptureConfig)}
    track = cfg.track
    if Path(track).is_file():  # a track file: the same absolute path on every node (a shared filesystem)
        track = str(Path(track).resolve())
    return [
        CaptureConfig(
            **{
                **base,
                "out": str(folder / f"shard_{i:03d}.h5"),
                "track": track,
                "seed": shard_seed(cfg.seed, i),
                "laps": laps[i],
                "max_frames": frames[i],
                "resume": True,
                "force": False,
            }
        )
        for i in range(cfg.workers)
    ]


def _settings(cfg: ShardedCaptureConfig, track_geometry_hash: str) -> dict[str, Any]:
    """What every shard of the run shares (a resume must keep all of it); the track by its geometry, so that the
    same track file named by another path resumes."""
    return {
        "track_geometry_hash": track_geometry_hash,
        "car": cfg.car,
        "laps": cfg.laps,
        "cars": cfg.cars,
        "fps": float(cfg.fps),
        "disrupt_ai": bool(cfg.disrupt_ai),
        "disrupt_steer_offset_rad": float(cfg.disrupt_steer_offset_rad),
        "image_hw_px": list(cfg.image_hw_px),
        "seed": int(cfg.seed),
        "workers": int(cfg.workers),
    }


# ------------------------------------------------------------------------------------------------------ manifest
def _manifest_digest(body: dict[str, Any]) -> str:
    payload = {k: v for k, v in body.items() if k != "manifest_sha256"}
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def _shard_record(path: Path, manifest_dir: Path, index: int, cfg: CaptureConfig) -> dict[str, Any]:
    """The manifest's line of one shard, read from its file (absent or unreadable: no frames, not complete)."""
    record: dict[str, Any] = {
        "index": index,
        "path": os.path.relpath(path, manifest_dir),
        "seed": cfg.seed,
        "laps": cfg.laps,
        "complete": False,
        "n_frames": 0,
        "content_sha256": None,
        "fingerprint_sha256": None,
        "fingerprint": None,
    }
    if not path.exists():
        return record
    try:
        with open_capture(path) as cap:
            record.update(
                complete=cap.complete,
                n_frames=cap.n_frames,
                content_sha256=cap.content_sha256(),
                fingerprint_sha256=cap.attrs["fingerprint_sha256"],
                fingerprint=cap.fingerprint,
            )
    except CaptureFormatError as exc:
        record["error"] = str(exc)
    return record


def write_manifest(cfg: ShardedCaptureConfig, shards: list[CaptureConfig], settings: dict[str, Any]) -> dict:
    """Write the manifest of ``cfg.out`` from the shard files as they are now (atomically)."""
    path = Path(cfg.out)
    records = [_shard_record(Path(s.out), path.resolve().parent, i, s) for i, s in enumerate(shards)]
    body: dict[str, Any] = {
        "format": MANIFEST_FORMAT,
        "version": MANIFEST_VERSION,
        "settings": settings,
        "complete": all(r["complete"] for r in records),
        "n_frames": sum(r["n_frames"] for r in records),
        "shards": records,
    }
    body["manifest_sha256"] = _manifest_digest(body)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda tmp: tmp.write_text(json_text(body, indent=1, sort_keys=True)))
    return body


def read_manifest(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A manifest's body after checking its format, version and SHA-256 (not yet its shards)."""
    path = Path(path)
    if not path.is_file():
        raise ManifestError(f"{path}: no such file")
    try:
        body = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ManifestError(f"{path}: not a capture manifest (unreadable JSON: {exc})") from exc
    if not isinstance(body, dict) or body.get("format") != MANIFEST_FORMAT:
        raise ManifestError(
            f"{path}: not a capture manifest (no 'format': {MANIFEST_FORMAT!r}); give a capture "
            "file (.h5) or the manifest a sharded capture wrote"
        )
    if body.get("version") != MANIFEST_VERSION:
        raise ManifestError(f"{path}: manifest version {body.get('version')!r}, this reader reads {MANIFEST_VERSION}")
    if body.get("manifest_sha256") != _manifest_digest(body):
        raise ManifestError(
            f"{path}: the manifest does not match its manifest_sha256 (edited or damaged): rewrite it "
            "with capture --workers N --resume"
        )
    return body


def open_manifest(path: str | os.PathLike[str]) -> list[Path]:
    """The shard files of a manifest that hold frames, each verified against the manifest: it exists, its
    fingerprint is the one recorded (else it is another run's shard, the first differing field named) and its frames
    are those recorded (count and content SHA-256). Raises :class:`ManifestError` naming the shard."""
    path = Path(path)
    body = read_manifest(path)
    folder = path.parent
    out: list[Path] = []
    probe_captures([folder / str(r["path"]) for r in body["shards"] if not os.path.isabs(str(r["path"]))])
    for record in body["shards"]:
        rel = str(record["path"])
        shard = folder / rel
        if os.path.isabs(rel) or ".." in Path(rel).parts:
            raise ManifestError(f"{path}: shard path {rel!r} leaves the manifest's folder (edited manifest?)")
        if record["content_sha256"] is None and not shard.exists():
            continue  # a shard that had not started when the manifest was written
        if not shard.exists():
            raise ManifestError(
                f"{path}: shard {rel} is missing: restore it, or redo it with capture --workers "
                f"{len(body['shards'])} --resume"
            )
        with open_capture(shard) as cap:
            if record["fingerprint_sha256"] != cap.attrs["fingerprint_sha256"]:
                diff = first_difference(record["fingerprint"] or {}, cap.fingerprint, "fingerprint")
                what = f"{diff[0]} is {diff[2]!r} in the file, {diff[1]!r} in the manifest" if diff else "fingerprint"
                raise ManifestError(
                    f"{path}: shard {rel} is not this run's shard ({what}): restore it or capture again"
                )
            if cap.n_frames != record["n_frames"] or cap.content_sha256() != record["content_sha256"]:
                raise ManifestError(
                    f"{path}: shard {rel} changed since the manifest was written ({cap.n_frames} frames, "
                    f"{record['n_frames']} recorded, or other content): restore it, or finish the run with capture "
                    f"--workers {len(body['shards'])} --resume to rewrite the manifest"
                )
        out.append(shard)
    if not out:
        raise ManifestError(f"{path}: no shard holds frames yet")
    return out


# ------------------------------------------------------------------------------------------------------ the run
class _ProgressBoard:
    """A Ray actor (no CPU) the shards report their laps, frames and process id to."""

    def __init__(self) -> None:
        self.reports: dict[int, tuple[int, int, int]] = {}

    def report(self, index: int, laps: int, frames: int, pid: int) -> None:
        self.reports[index] = (laps, frames, pid)

    def snapshot(self) -> dict[int, tuple[int, int, int]]:
        return dict(self.reports)


def _capture_shard(cfg: CaptureConfig, index: int, board: Any) -> dict[str, Any]:
    """One shard, in a Ray worker: the capture with its CPU time and process id."""
    from vision_rl.capture.sim_capture import capture_sim

    cpu0 = time.process_time()
    pid = os.getpid()
    last = [-math.inf]
    board.report.remote(index, 0, 0, pid)

    def report(laps: int, frames: int) -> None:
        now = time.monotonic()
        if now - last[0] >= _REPORT_INTERVAL_S:
            last[0] = now
            board.report.remote(index, laps, frames, pid)

    result = capture_sim(cfg, report)
    return {**result, "cpu_s": time.process_time() - cpu0, "pid": pid}


def import_ray(what: str) -> Any:
    """The ``ray`` module, or :class:`RayMissingError` saying ``what`` needs it and how to install it."""
    try:
        import ray
    except ImportError:
        raise RayMissingError(f"{what} needs Ray: {RAY_INSTALL}") from None
    return ray


def connect_ray(address: str, what: str) -> tuple[Any, bool]:
    """(ray, whether this call started the connection): the running connection if there is one, else ``address``
    (``auto``, HOST:PORT) or, when empty, a local Ray of this machine's CPUs."""
    ray = import_ray(what)
    if ray.is_initialized():
        return ray, False
    if not address:  # a private Ray of this process: no cluster token to manage
        os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False, "configure_logging": False}
    try:
        if address:
            ray.init(address=address, **kwargs)
        else:
            ray.init(**kwargs)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        where = f"at --address {address}" if address else "on this machine"
        first = first_line(exc)
        raise ValueError(f"{what}: cannot start or reach a Ray cluster {where}: {first}") from exc
    return ray, True


def check_workers(ray: Any, workers: int, option: str = "--workers") -> int:
    """The cluster's CPU count, after refusing more ``workers`` (one CPU each) than it has."""
    cpus = int(ray.cluster_resources().get("CPU", 0))
    if workers > cpus:
        raise ValueError(
            f"{option} {workers} but the Ray cluster has {cpus} CPUs: use {option} <= {cpus} or add "
            "nodes (ray start --address HEAD:6379 on each)"
        )
    return cpus


def _check_shard(path: Path, shard: CaptureConfig, settings: dict[str, Any]) -> bool:
    """Whether the shard file at ``path`` is complete; refuses a file that is not this shard (another seed, track,
    car, cars, rate, disruption or frame size), naming the field."""
    with open_capture(path) as cap:
        attrs = cap.attrs
        expected = {
            "seed": shard.seed,
            "track_geometry_hash": settings["track_geometry_hash"],
            "car_preset": shard.car,
            "cars": shard.cars,
            "fps": float(shard.fps),
            "disrupted": bool(shard.disrupt_ai),
            "image_height": shard.image_hw_px[0],
            "image_width": shard.image_hw_px[1],
            **({"disrupt_steer_offset_rad": float(shard.disrupt_steer_offset_rad)} if shard.disrupt_ai else {}),
        }
        for key, value in expected.items():
            if attrs.get(key) != value:
                raise ManifestError(
                    f"{path}: not this run's shard: {key} is {attrs.get(key)!r} in the file but {value!r} now; resume "
                    "with the run's settings or start over with --force"
                )
        return cap.complete


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    lines = [line for line in text.splitlines() if line.strip()]
    return f"{type(exc).__name__}: {lines[-1] if lines else ''}"[:400]


ShardReports = Callable[[dict[int, tuple[int, int, int]]], None]
"""``on_shards({index: (laps, frames, pid)})``: the latest report of every running shard."""


def capture_sharded(
    cfg: ShardedCaptureConfig,
    progress: Callable[[int, int], None] | None = None,
    on_shards: ShardReports | None = None,
) -> dict[str, Any]:
    """Capture the shards of ``cfg`` as Ray tasks and write the manifest; returns a summary.

    ``progress(laps_done, frames)`` (over all shards, this run's) is called about twice a second; a
    ``KeyboardInterrupt`` raised in it stops the shards cleanly. ``on_shards`` hears every shard's latest report.
    """
    from vision_rl.sim.track_library import load_track

    manifest = Path(cfg.out)
    folder = shards_dir(manifest)
    track = load_track(cfg.track)
    settings = _settings(cfg, track.geometry_hash)
    shards = plan_shards(cfg)
    if cfg.resume and manifest.exists():
        before = read_manifest(manifest)["settings"]
        diff = first_difference(before, settings, "settings")
        if diff is not None:
            field, was, now = diff
            option = "--" + field.split(".", 1)[1].split("[")[0].replace("_", "-")
            raise ManifestError(
                f"{manifest}: cannot resume: {field} was {was!r}, now {now!r} ({option}); resume "
                "with the run's settings or start over with --force"
            )
    elif not cfg.resume and (manifest.exists() or folder.exists()) and not cfg.force:
        raise FileExistsError(f"{manifest} exists: pass --force to overwrite it or --resume to continue it")
    # Ray and its CPUs are checked before anything on disk is touched: a refused run changes nothing.
    ray, started = connect_ray(cfg.address, "capture --workers")
    lock = -1
    try:
        check_workers(ray, cfg.workers)
        folder.mkdir(parents=True, exist_ok=True)
        # The shard folder's lock, held to the end: a second run of this manifest is refused before it clears
        # or rewrites anything (each shard's writer also locks its file).
        lock = lock_exclusive(folder, "another sharded capture of this manifest")
        todo, restarted = _prepare(cfg, shards, settings)
    except BaseException:
        if lock >= 0:
            os.close(lock)
        if started:
            ray.shutdown()
        raise
    try:
        return _run(cfg, ray, started, shards, settings, todo, restarted, progress, on_shards)
    finally:
        os.close(lock)


def _prepare(
    cfg: ShardedCaptureConfig, shards: list[CaptureConfig], settings: dict[str, Any]
) -> tuple[list[int], list[int]]:
    """Clear (``force``) or create the shard folder; the shards still to capture, and those whose unreadable file
    was removed; writes the manifest as things stand."""
    manifest = Path(cfg.out)
    folder = shards_dir(manifest)
    if not cfg.resume and cfg.force:  # the folder stays: the caller holds its lock
        manifest.unlink(missing_ok=True)
        for child in folder.iterdir():
            if child.is_dir() and not child.is_symlink():
                shutil.rmtree(child)
            else:
                child.unlink()
    # Which shards are done: a resumed run keeps every complete shard and restarts only the others.
    todo: list[int] = []
    restarted: list[int] = []
    probe_captures([Path(shard.out) for shard in shards])
    for i, shard in enumerate(shards):
        path = Path(shard.out)
        if not path.exists():
            todo.append(i)
            continue
        try:
            complete = _check_shard(path, shard, settings)
        except ManifestError:
            raise
        except CaptureFormatError as exc:
            if not _holds_no_frames(path):  # never delete frames: the damage is named instead
                raise ManifestError(f"{exc}; or remove {path.name} to capture shard {i} again") from exc
            path.unlink()  # killed while the file was being created: nothing in it can be used
            restarted.append(i)
            complete = False
        if not complete:
            todo.append(i)
    write_manifest(cfg, shards, settings)
    return todo, restarted


def _holds_no_frames(path: Path) -> bool:
    """Whether an invalid shard file has nothing to lose: empty, or an HDF5 file that committed no frame (a shard
    killed while its file was being created); anything else may hold frames and is never deleted."""
    if path.stat().st_size == 0:
        return True
    try:
        with h5py.File(path, "r") as f:
            return "n_frames" in f.attrs and int(f.attrs["n_frames"]) == 0
    except (OSError, RuntimeError, ValueError, KeyError, TypeError):
        return False


def _run(
    cfg: ShardedCaptureConfig,
    ray: Any,
    started: bool,
    shards: list[CaptureConfig],
    settings: dict[str, Any],
    todo: list[int],
    restarted: list[int],
    progress: Callable[[int, int], None] | None,
    on_shards: ShardReports | None,
) -> dict[str, Any]:
    """The shards ``todo`` as Ray tasks; the manifest rewritten from the files whatever happens."""
    results: dict[int, dict[str, Any]] = {}
    failures: dict[int, str] = {}
    interrupted = False
    t0 = time.perf_counter()
    try:
        board = ray.remote(num_cpus=0)(_ProgressBoard).remote()
        task = ray.remote(_capture_shard).options(num_cpus=1, max_retries=cfg.task_retries)
        pending = {task.remote(shards[i], i, board): i for i in todo}
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=_REPORT_INTERVAL_S)
                for ref in ready:
                    index = pending.pop(ref)
                    try:
                        results[index] = ray.get(ref)
                    except ray.exceptions.RayError as exc:
                        failures[index] = _one_line(exc)
                reports = ray.get(board.snapshot.remote())
                if on_shards is not None:
                    on_shards(reports)
                if progress is not None:
                    done = [results[i] for i in results]
                    live = [r for i, r in reports.items() if i not in results]
                    progress(
                        sum(r["laps_in_file"] for r in done) + sum(r[0] for r in live),
                        sum(r["frames_written"] for r in done) + sum(r[1] for r in live),
                    )
        except KeyboardInterrupt:
            interrupted = True
            for ref in pending:  # a KeyboardInterrupt in each task: it closes its file after the current batch
                ray.cancel(ref)
            for ref, index in pending.items():
                try:
                    results[index] = ray.get(ref, timeout=120)
                except ray.exceptions.RayError:
                    pass  # cancelled: the file is read back below
    finally:
        elapsed = time.perf_counter() - t0
        body = write_manifest(cfg, shards, settings)
        if started:
            ray.shutdown()
    return _summary(cfg, body, todo, results, failures, restarted, interrupted, elapsed)


def _summary(
    cfg: ShardedCaptureConfig,
    body: dict[str, Any],
    todo: list[int],
    results: dict[int, dict[str, Any]],
    failures: dict[int, str],
    restarted: list[int],
    interrupted: bool,
    elapsed_s: float,
) -> dict[str, Any]:
    shards = []
    for record in body["shards"]:
        i = record["index"]
        status = (
            "kept"
            if i not in todo
            else "failed"
            if i in failures
            else "captured"
            if record["complete"]
            else ("interrupted")
        )
        row = {
            "index": i,
            "path": record["path"],
            "seed": record["seed"],
            "laps": record["laps"],
            "status": status,
            "frames_in_file": record["n_frames"],
            "complete": record["complete"],
        }
        if i in results:
            r = results[i]
            row.update(
                frames_written=r["frames_written"],
                capture_fps=r["capture_fps"],
                elapsed_s=r["elapsed_s"],
                cpu_s=r["cpu_s"],
                stuck_resets=r["stuck_resets"],
                turned_resets=r["turned_resets"],
            )
        if i in failures:
            row["error"] = failures[i]
        shards.append(row)
    frames_written = sum(r["frames_written"] for r in results.values())
    cpu_s = sum(r["cpu_s"] for r in results.values())
    longest_s = max((r["elapsed_s"] for r in results.values()), default=0.0)
    return {
        "out": cfg.out,
        "shards_dir": str(shards_dir(cfg.out)),
        "workers": cfg.workers,
        "complete": bool(body["complete"]),
        "interrupted": interrupted,
        "frames_written": frames_written,
        "frames_in_file": int(body["n_frames"]),
        "failed_shards": sorted(failures),
        "restarted_shards": restarted,
        # Frames per second of wall clock from submitting the tasks to the last shard's end (worker start-up
        # included), and of the shards' own capture time (the longest shard's, start-up excluded).
        "capture_fps": frames_written / elapsed_s if elapsed_s > 0 else 0.0,
        "capture_fps_in_shards": frames_written / longest_s if longest_s > 0 else 0.0,
        "cpu_s_per_frame": cpu_s / frames_written if frames_written else 0.0,
        "elapsed_s": elapsed_s,
        "shards": shards,
    }
