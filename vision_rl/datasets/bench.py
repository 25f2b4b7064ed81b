"""Read-back throughput of capture files: random frames per second, decoded on a given number of cores."""

from __future__ import annotations

import gc
import multiprocessing
import os
import resource
import time
from collections.abc import Sequence

import numpy as np
import torch
from torch.utils.data import DataLoader, RandomSampler

from vision_rl.capture.h5format import open_capture
from vision_rl.datasets.capture_dataset import CaptureDataset, FrameCatalogue, collate_frames


def bench_readback(
    paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    n_workers: int = 2,
    batch_size: int = 64,
    frames_per_repeat: int = 2048,
    repeats: int = 3,
) -> dict:
    """Random frames per second read back from capture files by ``n_workers`` processes, medians over ``repeats``.

    ``readback_fps``: ``n_workers`` processes, each with its own HDF5 handle and one thread, read and decode
    random frames in batches of ``batch_size`` (random access with decoding, as training reads).
    ``readback_loader_fps``: what a training loop receives from a DataLoader with ``n_workers`` worker processes
    over :class:`CaptureDataset` (adds moving each batch to the training process through shared memory).
    ``*_cpu_ms``: CPU time per frame of all processes involved; on a shared machine these are the figures to
    compare between runs (wall-clock rates depend on what else runs).
    """
    files = FrameCatalogue.open(paths).paths
    raw_fps, raw_cpu = [], []
    for k in range(repeats):
        fps, cpu_s = _raw_readback(files[0], n_workers, batch_size, frames_per_repeat, seed=k)
        raw_fps.append(fps)
        raw_cpu.append(cpu_s / frames_per_repeat)
    loader_fps, loader_cpu_ms = _loader_readback(paths, n_workers, batch_size, frames_per_repeat, repeats)
    with open_capture(files[0]) as cap:
        compression = str(cap.attrs.get("compression", "unknown"))
    return {
        "readback_fps": float(np.median(raw_fps)),
        "readback_cpu_ms": 1e3 * float(np.median(raw_cpu)),
        "readback_loader_fps": loader_fps,
        "readback_loader_cpu_ms": loader_cpu_ms,
        "readback_workers": n_workers,
        "readback_compression": compression,
    }


def _read_random_frames(path, n_frames, batch_size, seed, barrier, results) -> None:
    with open_capture(path) as cap:
        idx = np.random.default_rng(seed).integers(0, cap.n_frames, (max(1, n_frames // batch_size), batch_size))
        out = np.empty((batch_size, *cap.image_hw_px, 3), dtype=np.uint8)
        cap.read_images(idx[0], threads=1, out=out)  # first reads: file metadata, decoder set-up
        barrier.wait()
        t0, c0 = time.perf_counter(), time.process_time()
        for batch in idx:
            cap.read_images(batch, threads=1, out=out)
        results.put((time.perf_counter() - t0, time.process_time() - c0))


def _raw_readback(path, n_procs: int, batch_size: int, n_frames: int, seed: int) -> tuple[float, float]:
    """(frames/s of all processes together, CPU seconds of all of them) for n_frames random frames in all."""
    # fork: the readers need only h5py and numpy, and a forked process starts in milliseconds.
    ctx = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn")
    barrier, results = ctx.Barrier(n_procs), ctx.Queue()
    per_proc = n_frames // n_procs
    procs = [
        ctx.Process(
            target=_read_random_frames, args=(str(path), per_proc, batch_size, 1000 * seed + i, barrier, results)
        )
        for i in range(n_procs)
    ]
    for p in procs:
        p.start()
    try:
        got = [results.get(timeout=600) for _ in procs]
    finally:
        for p in procs:
            p.join()
    frames = n_procs * max(1, per_proc // batch_size) * batch_size
    return frames / max(wall for wall, _ in got), sum(cpu for _, cpu in got)


def _loader_readback(paths, n_workers: int, batch_size: int, n_frames: int, repeats: int) -> tuple[float, float]:
    """(median frames/s delivered by a DataLoader, CPU ms per frame of its workers and this process)."""
    dataset = CaptureDataset(FrameCatalogue.open(paths))
    threads_before = torch.get_num_threads()
    torch.set_num_threads(1)  # the workers do the work; this process only collects batches
    try:
        sampler = RandomSampler(dataset, replacement=True, num_samples=n_frames, generator=torch.Generator())
        loader = DataLoader(
            dataset,
            batch_size=batch_size,
            sampler=sampler,
            num_workers=n_workers,
            collate_fn=collate_frames,
            persistent_workers=n_workers > 0,
        )
        self_before = resource.getrusage(resource.RUSAGE_SELF)
        children_before = resource.getrusage(resource.RUSAGE_CHILDREN)
        fps = []
        for k in range(repeats + 1):
            t0 = time.perf_counter()
            n = sum(len(images) for images, _ in loader)
            if k > 0:  # the first pass starts the workers
                fps.append(n / (time.perf_counter() - t0))
        del loader  # joins the workers, so that their CPU time is counted as the children's
        gc.collect()
        cpu_s = _cpu_s(resource.getrusage(resource.RUSAGE_SELF)) - _cpu_s(self_before)
        cpu_s += _cpu_s(resource.getrusage(resource.RUSAGE_CHILDREN)) - _cpu_s(children_before)
    finally:
        torch.set_num_threads(threads_before)
        dataset.close()
    return float(np.median(fps)), 1e3 * cpu_s / ((repeats + 1) * n_frames)


def _cpu_s(usage: resource.struct_rusage) -> float:
    return usage.ru_utime + usage.ru_stime
