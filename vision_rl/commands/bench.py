"""`vision-rl bench sim | env | render | ddpg`: throughput of the simulator, the environments, the renderer and DDPG.

`vision-rl bench scaling` (1 and 2 workers side by side) is in :mod:`vision_rl.commands.bench_scaling`, `bench
train-repr` in :mod:`vision_rl.commands.bench_train_repr`.
"""

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


@dataclass(frozen=True)
class BenchDDPGOptions:
    """Measure the DDPG agent's update rate at the paper's batch 32 on random 89x120 frames, for each variant, in
    eager (NCHW) and channels-last memory layout and with its conv trunks compiled (torch.compile), side by side in
    one run."""

    variants: str = "asymmetric,symmetric,state-actor"
    """Variants to time, comma-separated."""
    layouts: str = "eager,channels_last,compiled"
    """Layouts of the convolutions to time, comma-separated: eager (NCHW), channels_last, compiled (channels-last
    through torch.compile, which needs a C++ compiler; it is compiled in the untimed updates)."""
    updates: int = 5
    """Timed updates per case (after 2 untimed)."""
    torch_threads: int = 1
    """torch intra-op threads."""
    device: str = "auto"
    """torch device of the networks and the batch: auto (cuda when torch sees a GPU), cpu, cuda or cuda:N (the GPU's
    updates are timed to their end)."""
    json: bool = False
    """Print the figures as JSON."""


def run_bench_ddpg(opts: BenchDDPGOptions) -> int:
    import torch

    from vision_rl.ddpg.agent import BENCH_LAYOUTS, bench_updates
    from vision_rl.ddpg.config import TrainDDPGConfig
    from vision_rl.phase1_repr.bench import require_device

    if opts.updates < 1 or opts.torch_threads < 1:
        raise ValueError("--updates and --torch-threads must be >= 1")
    layouts = [v.strip() for v in opts.layouts.split(",") if v.strip()]
    if not layouts or any(v not in BENCH_LAYOUTS for v in layouts):
        raise ValueError(f"--layouts {opts.layouts!r}: choose from {', '.join(BENCH_LAYOUTS)}")
    device = require_device(opts.device)
    torch.set_num_threads(opts.torch_threads)
    rows = []
    for variant in [v.strip() for v in opts.variants.split(",") if v.strip()]:
        hyper, env = TrainDDPGConfig(variant=variant).agent_configs()  # what train-ddpg trains by default
        # The state-only actor has no convolutions: one row says what it costs.
        for layout in layouts if env.frames else layouts[:1]:
            figures = bench_updates(hyper, env, opts.updates, layout=layout, device=str(device))
            rounded = {k: round(v, 3) for k, v in figures.items()}
            rows.append(
                {
                    "variant": variant,
                    "layout": layout if env.frames else "no convolutions",
                    "batch_size": hyper.batch_size,
                    "image_hw_px": list(env.image_hw_px),
                    **rounded,
                }
            )

    def text(result):
        return [
            f"{r['variant']:<12} {r['layout']:<16} "
            f"{r['updates_per_s']:8.2f} updates/s  ({r['ms_per_update']:.0f} ms each)"
            for r in result["rows"]
        ]

    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"
    emit({"torch_threads": opts.torch_threads, "device": name, "rows": rows}, opts.json, text)
    return 0
