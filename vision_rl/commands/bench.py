"""`vision-rl bench sim | env | render`: throughput of the simulator, the environments and the renderer."""

from __future__ import annotations

from dataclasses import dataclass

from vision_rl.commands.output import emit


@dataclass(frozen=True)
class BenchSimOptions:
    """Measure simulator throughput: physics, a full control step with sensors, and the lidar."""

    track: str = "expressway"
    """Track: built-in name, random:SEED or CSV path."""
    car: str = "hatchback"
    """Car preset."""
    repeats: int = 7
    """Timed repeats; medians are reported."""
    json: bool = False
    """Print the figures as JSON."""


def run_bench_sim(opts: BenchSimOptions) -> int:
    from vision_rl.sim.bench import bench_sim

    emit(bench_sim(opts.track, opts.car, opts.repeats), opts.json)
    return 0


@dataclass(frozen=True)
class BenchEnvOptions:
    """Measure environment throughput: 20 time-trial cars through the SB3 VecEnv, 20 overtaking groups of 6."""

    track: str = "expressway"
    """Track: built-in name, random:SEED or CSV path."""
    car: str = "hatchback"
    """Car preset."""
    repeats: int = 5
    """Timed repeats of 100 steps; medians are reported."""
    json: bool = False
    """Print the figures as JSON."""


def run_bench_env(opts: BenchEnvOptions) -> int:
    from vision_rl.envs.bench import bench_env

    emit(bench_env(opts.track, opts.car, repeats=opts.repeats), opts.json)
    return 0


@dataclass(frozen=True)
class BenchRenderOptions:
    """Measure the renderer (one view, 20 tiled views), capture end to end (physics, targets, render, write) and
    random read-back of the captured frames (2 DataLoader workers)."""

    track: str = "expressway"
    """Track: built-in name, random:SEED or CSV path."""
    repeats: int = 5
    """Timed repeats; medians are reported."""
    capture_frames: int = 2000
    """Frames of the end-to-end capture measurement (4 cars)."""
    json: bool = False
    """Print the figures as JSON."""


#: What each figure should reach on a 2-core CPU, printed beside the figures.
RENDER_TARGETS = {
    "render_fps_470x280": ">= 300",
    "render_fps_batch20": ">= 400",
    "capture_fps": ">= 150",
    "bytes_per_frame": "<= 50,000 (15 GB for 300,000 frames)",
    "readback_fps": ">= 2,000 (2 worker processes)",
}


def run_bench_render(opts: BenchRenderOptions) -> int:
    import tempfile

    from vision_rl.capture.sim_capture import CaptureConfig, capture_sim
    from vision_rl.datasets.bench import bench_readback
    from vision_rl.render.bench import bench_render

    result = bench_render(n_views=20, repeats=opts.repeats, track=opts.track)
    with tempfile.TemporaryDirectory() as tmp:
        config = CaptureConfig(out=f"{tmp}/bench.h5", track=opts.track, cars=4, max_frames=opts.capture_frames)
        cap = capture_sim(config)
        result.update(capture_fps=cap["capture_fps"], bytes_per_frame=cap["bytes_per_frame"])
        # Random frames of that capture, read back the way training reads them (2 DataLoader worker processes).
        result.update(bench_readback(cap["out"], n_workers=2, repeats=opts.repeats))
    result["targets"] = RENDER_TARGETS
    emit(result, opts.json)
    return 0
