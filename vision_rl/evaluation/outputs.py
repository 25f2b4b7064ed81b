"""What the lap-time protocol's recorded runs become: lap times as text, trajectory plots, step-by-step traces and
driver's-view videos."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from vision_rl.evaluation.protocol import STEP_S, LapTiming
from vision_rl.sim.sensors import wrap_angle


def format_lap_time(seconds: float | None) -> str:
    """``m:ss.sss`` (the papers' table format), or ``DNF``."""
    if seconds is None or not math.isfinite(seconds):
        return "DNF"
    minutes, ms = divmod(round(seconds * 1000.0), 60_000)  # round first: 59.9996 s is 1:00.000, not 0:60.000
    return f"{minutes}:{ms / 1000.0:06.3f}"


def plot_trajectory(timing: LapTiming, index: int, path: str | os.PathLike[str], title: str) -> Path:
    """The walls and seed ``index``'s scored lap (the whole run if it has none), coloured by speed; wall
    contacts marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    track = timing.track
    t0, t1 = timing.scored_window_s(index)
    keep = (timing.time_s >= t0 - 1e-9) & (timing.time_s <= t1 + 1e-9)
    x, y, v = timing.x_m[keep, index], timing.y_m[keep, index], timing.speed_mps[keep, index] * 3.6
    wall = timing.wall_contact[keep, index]
    fig, ax = plt.subplots(figsize=(8, 7))
    for wall_xy in (track.left_wall_xy_m, track.right_wall_xy_m):
        closed = np.vstack([wall_xy, wall_xy[:1]])
        ax.plot(closed[:, 0], closed[:, 1], color="0.5", lw=0.8)
    if len(x) > 1:
        points = np.stack([x, y], axis=1)
        segments = np.stack([points[:-1], points[1:]], axis=1)
        lines = LineCollection(segments, cmap="plasma", linewidths=2.0)
        lines.set_array(0.5 * (v[:-1] + v[1:]))
        ax.add_collection(lines)
        fig.colorbar(lines, ax=ax, label="speed (km/h)", shrink=0.8)
    if wall.any():
        ax.plot(x[wall], y[wall], "x", color="red", ms=5, label="wall contact")
        ax.legend(loc="upper right")
    ax.plot(*track.centre_xy_m[0], "ks", ms=6)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


#: Columns of :func:`write_trace`, with their units.
TRACE_COLUMNS = (
    "seed",
    "time_s",
    "x_m",
    "y_m",
    "s_m",
    "lateral_m",
    "speed_kmh",
    "heading_error_deg",
    "steer_rad",
    "pedal",
    "wall_contact",
)


def write_trace(timing: LapTiming, path: str | os.PathLike[str]) -> Path:
    """Every seed's run as CSV (:data:`TRACE_COLUMNS`), one row per recorded 0.1 s step up to its finish or DNF: the
    pose, where that is on the track (arc length ``s_m``, ``lateral_m`` + left of the centre line), the speed, the
    heading against the centre line's (+ turned left), the front wheels' angle, the pedal and wall contact. A start
    that did not finish reads off its last rows: where it hit what, how fast, and what it steered after."""
    if not len(timing.time_s):
        raise ValueError("a trace needs the protocol's recorded steps: time the laps with record=True")
    track = timing.track
    seeds, times, columns = [], [], []
    for i, run in enumerate(timing.runs):
        rows = timing.time_s <= run.time_s + 1e-9
        xy = np.stack([timing.x_m[rows, i], timing.y_m[rows, i]], axis=1)
        where = track.project(xy)
        heading_error = wrap_angle(timing.yaw_rad[rows, i] - where.heading_rad)
        seeds.append(np.full(rows.sum(), run.seed))
        times.append(timing.time_s[rows])
        columns.append(
            np.column_stack(
                [
                    xy,
                    where.s_m,
                    where.lateral_m,
                    3.6 * timing.speed_mps[rows, i],
                    np.degrees(heading_error),
                    timing.steer_rad[rows, i],
                    timing.omega[rows, i],
                    timing.wall_contact[rows, i],
                ]
            )
        )
    table = np.column_stack([np.concatenate(seeds), np.concatenate(times), np.concatenate(columns)])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(
        path,
        table,
        delimiter=",",
        header=",".join(TRACE_COLUMNS),
        comments="",
        fmt=["%d", "%.2f", "%.3f", "%.3f", "%.2f", "%.3f", "%.2f", "%.2f", "%.4f", "%.3f", "%d"],
    )
    return path


def _video_writer(path: Path, fps: float):
    check_video_dependencies()
    import imageio.v2 as imageio

    # Even frame sizes suffice for yuv420p; the default block of 16 would rescale 470 x 280.
    return imageio.get_writer(str(path), fps=fps, codec="libx264", quality=7, macro_block_size=2)


class VideoDependencyError(ValueError):
    """The video writer's packages are missing; the message names what to install."""


def check_video_dependencies() -> None:
    """Raise :class:`VideoDependencyError` now rather than after a long evaluation."""
    try:
        import imageio  # noqa: F401
        import imageio_ffmpeg  # noqa: F401  (the ffmpeg binary the mp4 writer needs)
    except ImportError as exc:
        raise VideoDependencyError(
            "--video needs imageio with its ffmpeg plugin: pip install 'imageio[ffmpeg]' "
            f"(it bundles a static ffmpeg binary); {exc}"
        ) from exc


def driver_views(timing: LapTiming, index: int, steps: np.ndarray, image_hw_px: tuple[int, int], batch: int = 20):
    """Seed ``index``'s driver's view at the recorded ``steps`` (indices into ``timing.time_s``), rendered
    ``batch`` poses a pass: yields (position in ``steps`` of the first view, uint8 views (k, H, W, 3))."""
    from vision_rl.render import RenderConfig, Renderer

    height, width = image_hw_px
    config = RenderConfig(width_px=width, height_px=height, max_views=batch)
    with Renderer(timing.track, config, car_length_m=timing.car.length_m, car_width_m=timing.car.width_m) as renderer:
        for first in range(0, len(steps), batch):
            rows = steps[first : first + batch]
            # Each pose is its own group, so the views of one pass do not see each other's cars.
            yield (
                first,
                renderer.render(
                    timing.x_m[rows, index],
                    timing.y_m[rows, index],
                    timing.yaw_rad[rows, index],
                    groups=np.arange(len(rows)),
                ),
            )


def write_video(
    timing: LapTiming,
    index: int,
    path: str | os.PathLike[str],
    image_hw_px: tuple[int, int] = (280, 470),
    map_size_px: int = 120,
) -> Path:
    """An mp4 of seed ``index``'s driver's view over the whole run, with a small track map (top right) and the
    speed and lap clock (bottom left). Frames come from the offscreen renderer, 20 poses per render pass."""
    from PIL import Image, ImageDraw

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    height, width = image_hw_px
    track = timing.track
    centre = track.centre_xy_m
    lo, hi = centre.min(axis=0), centre.max(axis=0)
    margin = 6
    scale = (map_size_px - 2 * margin) / float(max(hi - lo))

    def to_map(xy: np.ndarray) -> np.ndarray:
        px = (xy - lo) * scale + margin
        return np.stack([px[..., 0], map_size_px - px[..., 1]], axis=-1)

    base_map = Image.new("RGBA", (map_size_px, map_size_px), (0, 0, 0, 120))
    outline = [tuple(p) for p in to_map(np.vstack([centre, centre[:1]]))]
    ImageDraw.Draw(base_map).line(outline, fill=(255, 255, 255, 230), width=2)
    lap_starts = np.cumsum([0.0, *(lap.lap_time_s for lap in timing.runs[index].laps)])
    writer = _video_writer(path, fps=1.0 / STEP_S)
    try:
        for first, frames in driver_views(timing, index, np.arange(len(timing.time_s)), image_hw_px):
            for j, frame in enumerate(frames):
                step = first + j
                t = float(timing.time_s[step])
                image = Image.fromarray(frame).convert("RGBA")
                overlay = base_map.copy()
                cx, cy = to_map(np.array([timing.x_m[step, index], timing.y_m[step, index]]))
                ImageDraw.Draw(overlay).ellipse((cx - 3, cy - 3, cx + 3, cy + 3), fill=(255, 40, 40, 255))
                image.alpha_composite(overlay, (width - map_size_px - 4, 4))
                lap = int(np.searchsorted(lap_starts, t, side="right"))
                clock = t - lap_starts[min(lap, len(lap_starts)) - 1]
                text = f"{timing.speed_mps[step, index] * 3.6:5.0f} km/h  lap {lap}  {format_lap_time(clock)}"
                draw = ImageDraw.Draw(image)
                draw.rectangle((2, height - 16, 8 + 6 * len(text), height - 2), fill=(0, 0, 0, 140))
                draw.text((5, height - 15), text, fill=(255, 255, 255, 255))
                writer.append_data(np.asarray(image.convert("RGB")))
    finally:
        writer.close()
    return path
