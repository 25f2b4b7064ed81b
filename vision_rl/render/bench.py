"""Render throughput: frames per second for one view and for batches of views, medians over repeats."""

from __future__ import annotations

import time

import numpy as np

from vision_rl.render.renderer import CameraConfig, RenderConfig, Renderer
from vision_rl.sim.track import Track


def _grid_poses(track: Track, n_cars: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cars spread evenly over the lap on alternating sides of the centre line, heading along the track."""
    s = (np.arange(n_cars) + 0.5) * track.length_m / n_cars
    lateral = np.where(np.arange(n_cars) % 2 == 0, 2.0, -2.0)
    xy = track.position_at(s, lateral)
    return xy[:, 0], xy[:, 1], track.heading_at(s)


def bench_render(
    n_views: int = 20,
    repeats: int = 5,
    track: str | Track = "expressway",
    frames_per_repeat: int = 60,
    width_px: int = 470,
    height_px: int = 280,
    camera: str = "hood",
    samples: int = 0,
) -> dict:
    """Frames per second of the offscreen renderer, each the median of ``repeats`` timed runs.

    ``render_fps_{W}x{H}``: one view per call (a single car's camera, read-back included);
    ``render_fps_batch{n_views}``: frames per second when each call renders ``n_views`` views (one pass, one
    read-back). Both include input checks, culling and the copy into numpy, i.e. what a caller gets.
    ``render_cpu_ms_*``: process CPU time per frame for the same runs (all threads).
    Cars are spread over the lap, all in one group, so every view also draws the cars it can see.
    """
    cfg = RenderConfig(
        width_px=width_px,
        height_px=height_px,
        samples=samples,
        camera=CameraConfig(preset=camera),
        max_views=max(n_views, 1),
    )
    with Renderer(track, cfg) as renderer:
        x, y, yaw = _grid_poses(renderer.track, n_views)
        one = np.array([0])
        batch_calls = max(1, frames_per_repeat // n_views)
        renderer.render(x, y, yaw, view_ids=one)  # warm-up: shader compilation, first-use allocations
        renderer.render(x, y, yaw)
        single, batch, single_cpu, batch_cpu = [], [], [], []
        for _ in range(repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            for k in range(frames_per_repeat):
                renderer.render(x, y, yaw, view_ids=one + (k % n_views))
            single.append(frames_per_repeat / (time.perf_counter() - t0))
            single_cpu.append((time.process_time() - c0) / frames_per_repeat)
            t0, c0 = time.perf_counter(), time.process_time()
            for _ in range(batch_calls):
                renderer.render(x, y, yaw)
            batch.append(batch_calls * n_views / (time.perf_counter() - t0))
            batch_cpu.append((time.process_time() - c0) / (batch_calls * n_views))
        return {
            f"render_fps_{width_px}x{height_px}": float(np.median(single)),
            f"render_fps_batch{n_views}": float(np.median(batch)),
            # CPU time of the whole process (llvmpipe's threads included) per frame: comparable between runs
            # on a shared machine, where frames/s depend on what else is running.
            f"render_cpu_ms_{width_px}x{height_px}": 1e3 * float(np.median(single_cpu)),
            f"render_cpu_ms_batch{n_views}": 1e3 * float(np.median(batch_cpu)),
            "gl_renderer": renderer.gl_renderer,
            "static_triangles": renderer.n_static_triangles,
            "track": renderer.track.name,
            "repeats": repeats,
        }
