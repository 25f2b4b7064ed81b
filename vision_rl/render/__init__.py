"""Offscreen OpenGL renderer of the simulator (moderngl, headless EGL): driver's-view frames of many cars at once.

Imports only :mod:`vision_rl.sim` (and numpy, moderngl); the simulator never imports this package.
"""

from vision_rl.render.renderer import (
    DEFAULT_CAR_COLORS,
    CameraConfig,
    RenderConfig,
    Renderer,
    RendererError,
    create_context,
)
from vision_rl.render.scene import LABEL_COLORS, LABEL_NAMES, Label


def labels_to_rgb(labels):
    """Class-id images (..., H, W) from :meth:`Renderer.render_labels` as display colours (..., H, W, 3) uint8."""
    return LABEL_COLORS[labels]


__all__ = [
    "DEFAULT_CAR_COLORS",
    "LABEL_COLORS",
    "LABEL_NAMES",
    "CameraConfig",
    "Label",
    "RenderConfig",
    "Renderer",
    "RendererError",
    "bench_render",
    "create_context",
    "labels_to_rgb",
]


def bench_render(*args, **kwargs):
    """See :func:`vision_rl.render.bench.bench_render` (imported lazily: it needs a track library)."""
    from vision_rl.render.bench import bench_render as _bench

    return _bench(*args, **kwargs)
