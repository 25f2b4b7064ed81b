"""`vision-rl bench sim | env | render | ddpg`: throughput of the simulator, the environments, the renderer and DDPG.

`vision-rl bench scaling` (1 and 2 workers side by side) is in :mod:`vision_rl.commands.bench_scaling`, `bench
train-repr` in :mod:`vision_rl.commands.bench_train_repr`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from vision_rl.commands.options import comma_list
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
    """Measure the DDPG agent's update rate at the paper's batch 32 on random 89x120 frames, for each variant and conv
    trunk preset, in eager (NCHW) and channels-last memory layout and with its conv trunks compiled (torch.compile),
    side by side in one run; with each, the update's floating-point operations and, with --profile, its host-side
    work per update (torch.profiler: operator calls, .item() reads; on a GPU kernel launches, copies, waits)."""

    variants: str = "asymmetric,symmetric,state-actor"
    """Variants to time, comma-separated."""
    presets: str = "paper,cpu"
    """Conv trunk presets to time, comma-separated: paper, cpu (train-ddpg's --preset)."""
    layouts: str = "eager,channels_last,compiled"
    """Layouts of the convolutions to time, comma-separated: eager (NCHW), channels_last, compiled (channels-last
    through torch.compile, which needs a C++ compiler; it is compiled in the untimed updates)."""
    updates: int = 5
    """Timed updates per case (after 2 untimed)."""
    profile: bool = False
    """Also count each preset's host-side work per update with torch.profiler (one row per variant and preset)."""
    torch_threads: int = 1
    """torch intra-op threads."""
    device: str = "auto"
    """torch device of the networks and the batch: auto (cuda when torch sees a GPU), cpu, cuda or cuda:N (the GPU's
    updates are timed to their end)."""
    json: bool = False
    """Print the figures as JSON."""


def _ddpg_list(text: str, option: str, allowed: tuple[str, ...]) -> list[str]:
    items = comma_list(text)
    if not items or any(v not in allowed for v in items):
        raise ValueError(f"{option} {text!r}: choose from {', '.join(allowed)}")
    return items


def _ddpg_rows(opts: BenchDDPGOptions, variant: str, preset: str, device: str) -> list[dict[str, Any]]:
    """The timed rows of one variant and preset (one per layout; one in all for the state-only actor)."""
    from dataclasses import replace

    from vision_rl.ddpg.bench import bench_updates, profile_update, update_flops
    from vision_rl.ddpg.config import BENCH_LAYOUTS, TrainDDPGConfig

    hyper, env = TrainDDPGConfig(variant=variant).agent_configs()  # what train-ddpg trains by default
    hyper = replace(hyper, trunk=preset)
    common = {"variant": variant, "preset": preset if env.frames else "-", "batch_size": hyper.batch_size}
    common |= {"image_hw_px": list(env.image_hw_px), "gflop_per_update": round(update_flops(hyper, env) / 1e9, 3)}
    if opts.profile:
        common["profile"] = profile_update(hyper, env, device=device)
    layouts = _ddpg_list(opts.layouts, "--layouts", BENCH_LAYOUTS)
    rows = []
    # The state-only actor has no convolutions: one row says what it costs.
    for layout in layouts if env.frames else layouts[:1]:
        figures = bench_updates(hyper, env, opts.updates, layout=layout, device=device)
        rounded = {k: round(v, 3) for k, v in figures.items()}
        rows.append({**common, "layout": layout if env.frames else "no convolutions", **rounded})
    return rows


def format_bench_ddpg(result: dict[str, Any]) -> list[str]:
    lines = [
        f"device {result['device']}, {result['torch_threads']} torch thread(s), batch {result['rows'][0]['batch_size']}"
    ]
    for r in result["rows"]:
        lines.append(
            f"{r['variant']:<12} {r['preset']:<6} {r['layout']:<16} {r['updates_per_s']:8.2f} updates/s  "
            f"({r['ms_per_update']:.0f} ms each, {r['cpu_ms_per_update']:.0f} ms of CPU time, "
            f"{r['gflop_per_update']:.2f} GFLOP)"
        )
    profiled = {(r["variant"], r["preset"]): r["profile"] for r in result["rows"] if "profile" in r}
    for (variant, preset), p in profiled.items():
        lines.append(
            f"profile {variant} {preset}: per update {p['aten_ops']:.0f} aten ops ({p['leaf_ops']:.0f} "
            f"leaves, {p['optimizer_ops']:.0f} in Adam), {p['item_reads']:.0f} .item(), "
            f"{p['kernel_launches']:.0f} kernel launches, {p['memcpy']:.0f} copies, {p['device_syncs']:.0f} syncs"
        )
    return lines


def run_bench_ddpg(opts: BenchDDPGOptions) -> int:
    import torch

    from vision_rl.ddpg.config import BENCH_LAYOUTS, TRUNK_PRESETS, VARIANTS
    from vision_rl.phase1_repr.bench import require_device

    if opts.updates < 1 or opts.torch_threads < 1:
        raise ValueError("--updates and --torch-threads must be >= 1")
    variants = _ddpg_list(opts.variants, "--variants", VARIANTS)
    presets = _ddpg_list(opts.presets, "--presets", TRUNK_PRESETS)
    _ddpg_list(opts.layouts, "--layouts", BENCH_LAYOUTS)
    device = require_device(opts.device)
    torch.set_num_threads(opts.torch_threads)
    rows = []
    for variant in variants:
        # The state-only actor has no trunk: the first preset stands for all.
        for preset in presets if variant != "state-actor" else presets[:1]:
            rows += _ddpg_rows(opts, variant, preset, str(device))
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"
    emit({"torch_threads": opts.torch_threads, "device": name, "rows": rows}, opts.json, format_bench_ddpg)
    return 0
