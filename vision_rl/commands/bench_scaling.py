"""`vision-rl bench scaling`: each job that spreads over processes (a sharded capture, train-repr on 1 and 2
devices, train-policy's sampling), run with 1 and with 2 workers side by side, alternating over ``--repeats`` so
that a change of the machine's load hits both; the table shows medians, the spread and the ratio.

The rows, what each times: docs/notes/commands.md.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vision_rl.commands.options import comma_list
from vision_rl.commands.output import emit

#: What the ratios (2 workers over 1) should reach on a 2-core machine.
SCALING_TARGETS = {"capture frames/s": ">= 1.3", "sampling learner share of standalone": ">= 0.95"}

ROWS = ("capture", "train", "sampling")

#: Figures of the sampling row: the key in ``bench_sampling``'s result and its label.
SAMPLING_FIGURES = {
    "sampled_transitions_per_s": "sampled transitions/s",
    "learner_updates_per_s": "learner updates/s",
    "learner_share_of_standalone": "learner share of standalone",
}


@dataclass(frozen=True)
class BenchScalingOptions:
    """Measure capture, train-repr and distributed sampling with 1 and 2 workers side by side: figures, spread over
    repeats and the ratio."""

    rows: str = "capture,train,sampling"
    """Rows to measure, comma-separated: capture, train, sampling."""
    track: str = "expressway"
    """Track of the capture: built-in name, random:SEED or CSV path."""
    cars: int = 4
    """Cars of each capture shard (each renders its own world)."""
    image_hw_px: tuple[int, int] = (280, 470)
    """Captured frame height and width, px."""
    capture_frames: int = 1200
    """Frames of each timed capture, over all its shards."""
    train_epochs: int = 1
    """Epochs of each train-repr run (on the frames of the last 2-worker capture)."""
    train_batch_size: int = 32
    """Frames per batch of train-repr (per process)."""
    sampling_seconds: float = 20.0
    """Seconds of each sampling measurement (standalone learner, then learner with samplers)."""
    repeats: int = 3
    """Timed repeats of every case; medians are reported with the spread."""
    address: str = ""
    """Ray cluster for the capture and sampling rows: 'auto', HOST:PORT, or empty for a local Ray."""
    seed: int = 0
    """Seed of the captures and the sampling."""
    json: bool = False
    """Print the figures as JSON."""


def _spread(values: list[float]) -> dict[str, Any]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values), "runs": values}


def _compare(one: list[dict[str, float]], two: list[dict[str, float]], keys: dict[str, str]) -> dict[str, Any]:
    """Per figure: the spread with 1 and 2 workers and the ratio of the medians (2 over 1)."""
    out: dict[str, Any] = {}
    for key, label in keys.items():
        if not all(key in r for r in [*one, *two]):
            continue
        a, b = _spread([float(r[key]) for r in one]), _spread([float(r[key]) for r in two])
        out[label] = {"workers_1": a, "workers_2": b, "ratio": b["median"] / a["median"] if a["median"] else None}
    return out


def _alternate(repeats: int, run: Callable[[int, int], dict[str, float]]) -> tuple[list[dict], list[dict]]:
    """``run(workers, repeat)`` for 1 and 2 workers in turn, ``repeats`` times each."""
    one, two = [], []
    for r in range(repeats):
        one.append(run(1, r))
        two.append(run(2, r))
    return one, two


def _capture_row(opts: BenchScalingOptions, folder: Path) -> tuple[dict[str, Any], str]:
    """The capture figures, and the manifest of the last 2-worker capture (the train row's data)."""
    from vision_rl.capture.sharded import ShardedCaptureConfig, capture_sharded

    def config(workers: int, name: str, frames: int) -> ShardedCaptureConfig:
        return ShardedCaptureConfig(
            out=str(folder / f"{name}.json"),
            track=opts.track,
            cars=opts.cars,
            image_hw_px=opts.image_hw_px,
            laps=1000,
            max_frames=frames,
            workers=workers,
            seed=opts.seed,
            force=True,
            address=opts.address,
        )

    # Untimed: starts Ray's two worker processes and loads the simulator and renderer in each.
    capture_sharded(config(2, "warmup", 2 * opts.cars))
    last: dict[str, str] = {}

    def run(workers: int, repeat: int) -> dict[str, float]:
        name = f"capture_w{workers}_r{repeat}"
        result = capture_sharded(config(workers, name, opts.capture_frames))
        if result["failed_shards"]:
            raise RuntimeError(
                f"bench scaling: capture shards {result['failed_shards']} failed: "
                f"{[s.get('error') for s in result['shards'] if 'error' in s]}"
            )
        if workers == 2:
            last["data"] = result["out"]
        return {
            "frames": result["frames_written"],
            "frames_per_s": result["capture_fps"],
            "frames_per_s_in_shards": result["capture_fps_in_shards"],
            "cpu_ms_per_frame": 1e3 * result["cpu_s_per_frame"],
        }

    one, two = _alternate(opts.repeats, run)
    figures = {
        "frames_per_s": "frames/s",
        "frames_per_s_in_shards": "frames/s inside the shards",
        "cpu_ms_per_frame": "CPU ms per frame",
    }
    return _compare(one, two, figures), last["data"]


def train_run(devices: int, data: str, out: Path, opts: BenchScalingOptions) -> dict[str, Any]:
    """One ``train-repr`` command on CPUs (``devices`` processes), as a user runs it; its JSON result."""
    argv = [
        "train-repr",
        "--data",
        data,
        "--devices",
        str(devices),
        "--strategy",
        "ddp" if devices > 1 else "auto",
        "--device",
        "cpu",
        "--epochs",
        str(opts.train_epochs),
        "--batch-size",
        str(opts.train_batch_size),
        "--num-workers",
        "0",
        "--out",
        str(out),
        "--force",
        "--json",
        "--no-progress",
    ]
    # A command of its own: Lightning starts the second DDP process by running the command line again.
    proc = subprocess.run([sys.executable, "-m", "vision_rl.commands.main", *argv], capture_output=True, text=True)
    if proc.returncode != 0:
        tail = proc.stderr.strip().splitlines()[-1:] or ["(no message)"]
        raise RuntimeError(f"bench scaling: train-repr --devices {devices} failed ({proc.returncode}): {tail[0]}")
    return json.loads(proc.stdout)


def _train_row(opts: BenchScalingOptions, data: str, folder: Path) -> dict[str, Any]:
    def run(devices: int, repeat: int) -> dict[str, float]:
        result = train_run(devices, data, folder / f"train_d{devices}_r{repeat}", opts)
        return {"frames_per_s": result["train_frames_per_s"], "frames": result["n_train_frames"]}

    one, two = _alternate(opts.repeats, run)
    return _compare(one, two, {"frames_per_s": "training frames/s"})


def _sampling_row(opts: BenchScalingOptions) -> dict[str, Any]:
    """The distributed-sampling figures, or why there are none."""
    try:
        from vision_rl.training.sampling_bench import bench_sampling
    except (ImportError, AttributeError) as exc:
        return {"missing": f"vision_rl.training.sampling_bench.bench_sampling is not available ({exc})"}

    def run(workers: int, repeat: int) -> dict[str, float]:
        return bench_sampling(workers=workers, seconds=opts.sampling_seconds, seed=opts.seed + repeat)

    one, two = _alternate(opts.repeats, run)
    return _compare(one, two, SAMPLING_FIGURES)


def _lines(result: dict[str, Any]) -> list[str]:
    lines = [
        f"{result['cpus']} CPUs, {result['repeats']} repeat(s); medians, (min..max), ratio = 2 workers / 1",
        f"{'row':<9} {'figure':<30} {'1 worker':>20} {'2 workers':>20} {'ratio':>7}",
    ]
    for row, figures in result["rows"].items():
        if "missing" in figures:
            lines.append(f"{row:<9} {figures['missing']}")
            continue
        for label, f in figures.items():
            cells = [f"{f[w]['median']:.4g} ({f[w]['min']:.3g}..{f[w]['max']:.3g})" for w in ("workers_1", "workers_2")]
            ratio = f"{f['ratio']:.2f}x" if f["ratio"] is not None else "-"
            lines.append(f"{row:<9} {label:<30} {cells[0]:>20} {cells[1]:>20} {ratio:>7}")
    lines.append("targets: " + ", ".join(f"{k} {v}" for k, v in result["targets"].items()))
    return lines


def run_bench_scaling(opts: BenchScalingOptions) -> int:
    rows = comma_list(opts.rows)
    unknown = [r for r in rows if r not in ROWS]
    if unknown or not rows:
        raise ValueError(f"--rows takes {', '.join(ROWS)} (comma-separated), got {opts.rows!r}")
    if opts.repeats < 1 or opts.train_epochs < 1 or opts.sampling_seconds <= 0:
        raise ValueError("--repeats and --train-epochs must be >= 1, --sampling-seconds > 0")
    if "train" in rows and "capture" not in rows:
        raise ValueError("--rows train trains on the capture row's frames: include capture")
    result: dict[str, Any] = {"cpus": len(os.sched_getaffinity(0)), "repeats": opts.repeats, "rows": {}}
    with tempfile.TemporaryDirectory(prefix="bench_scaling_") as tmp:
        folder = Path(tmp)
        if "capture" in rows or "sampling" in rows:
            from vision_rl.capture.sharded import connect_ray

            # One Ray for the whole bench: its worker processes stay up between the runs.
            ray, started = connect_ray(opts.address, "bench scaling")
        else:
            ray, started = None, False
        try:
            if "capture" in rows:
                result["rows"]["capture"], data = _capture_row(opts, folder)
                if "train" in rows:
                    result["rows"]["train"] = _train_row(opts, data, folder)
            if "sampling" in rows:
                result["rows"]["sampling"] = _sampling_row(opts)
        finally:
            if started:
                ray.shutdown()
    result["targets"] = SCALING_TARGETS
    emit(result, opts.json, _lines)
    return 0
