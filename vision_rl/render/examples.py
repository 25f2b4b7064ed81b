"""Example frames for the README: a few cars before each built-in track's tightest corner, hood and chase views."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vision_rl.render.renderer import CameraConfig, RenderConfig, Renderer
from vision_rl.sim.track import Track


def example_poses(track: Track) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Four cars approaching the tightest corner: the viewer 70 m before it, three others spread ahead."""
    s_corner = float(track.s_m[np.argmax(np.abs(track.curvature_1pm))])
    s = s_corner + np.array([-70.0, -52.0, -35.0, -10.0])
    lateral = np.array([0.0, 1.8, -2.2, 0.8])
    xy = track.position_at(s, lateral)
    return xy[:, 0], xy[:, 1], track.heading_at(s)


def save_example_frames(
    out_dir: str | Path,
    tracks: tuple[str, ...] = ("expressway", "flowing", "technical"),
    chase_tracks: tuple[str, ...] = ("expressway",),
) -> list[Path]:
    """Write ``<track>_hood.png`` (and ``<track>_chase.png`` for ``chase_tracks``) at 470x280; returns the paths."""
    import matplotlib.image

    from vision_rl.sim.track_library import load_track

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name in tracks:
        track = load_track(name)
        x, y, yaw = example_poses(track)
        presets = ("hood", "chase") if name in chase_tracks else ("hood",)
        for preset in presets:
            with Renderer(track, RenderConfig(camera=CameraConfig(preset=preset))) as renderer:
                frame = renderer.render(x, y, yaw, view_ids=[0])[0]
            path = out / f"{name}_{preset}.png"
            matplotlib.image.imsave(path, frame)
            written.append(path)
    return written
