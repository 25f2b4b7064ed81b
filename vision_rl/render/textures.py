"""Procedural, tileable surface textures generated in numpy at start-up (no files, no downloads).

Every layer is a square RGB image that tiles seamlessly (all noise is periodic), so the GPU can repeat it along the
track and build mipmaps from it. The generator is seeded, so the same build gives the same bytes, hence the same
pixels.

Surface detail is smooth value noise of a few texels and up, never independent per-texel noise: per-texel grain
reaches the frame as pixel-to-pixel noise that looks like sensor noise to a compressor (it made up a third of a
compressed frame: 131 -> 89 kB with gzip on expressway) and tells an encoder nothing about the track. What makes
speed visible is kept: blotches of the asphalt, mowing stripes, wall panels and the blue-and-white band, kerbs.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

TEXTURE_SIZE_PX = 256
"""Side of every layer; 256 keeps the whole array (12 layers + mipmaps) near 3 MB and is sharp at 470x280."""

_SEED = 20240501
"""Fixed seed of the texture generator: textures are part of the renderer's definition, not of a run."""


class Layer(IntEnum):
    """Index of each surface in the texture array; meshes store it per vertex."""

    ASPHALT = 0
    LINE = 1
    KERB = 2
    WALL = 3
    WALL_TOP = 4
    GRASS = 5
    PAVEMENT = 6
    FACADE = 7
    CHECKER = 8
    METAL = 9
    ROOF = 10
    SHOULDER = 11


# ------------------------------------------------------------------------------------------------ noise helpers
def _periodic_noise(rng: np.random.Generator, cells: int, size: int = TEXTURE_SIZE_PX) -> np.ndarray:
    """Smooth value noise in [0, 1] that tiles: a random ``cells`` x ``cells`` grid, bicubic-ish upsampled."""
    grid = rng.random((cells, cells))
    pos = np.arange(size) * cells / size
    i0 = np.floor(pos).astype(np.int64)
    f = pos - i0
    f = f * f * (3.0 - 2.0 * f)  # smoothstep weights hide the grid's cell edges
    i1 = (i0 + 1) % cells
    rows = grid[i0] * (1.0 - f)[:, None] + grid[i1] * f[:, None]
    return rows[:, i0] * (1.0 - f)[None, :] + rows[:, i1] * f[None, :]


def _fractal_noise(rng: np.random.Generator, octaves: tuple[int, ...], size: int = TEXTURE_SIZE_PX) -> np.ndarray:
    """Sum of periodic noises with halving amplitude, normalised to [0, 1]."""
    total = np.zeros((size, size))
    amp = 1.0
    for cells in octaves:
        total += amp * _periodic_noise(rng, cells, size)
        amp *= 0.5
    total -= total.min()
    return total / max(total.max(), 1e-12)


def _rgb(base: tuple[float, float, float], shade: np.ndarray) -> np.ndarray:
    """Colour ``base`` (0-255) modulated by a per-texel factor (H, W) -> (H, W, 3) float."""
    return shade[..., None] * np.asarray(base, dtype=np.float64)[None, None, :]


def _uv(size: int = TEXTURE_SIZE_PX) -> tuple[np.ndarray, np.ndarray]:
    """Texel-centre coordinates in [0, 1): u across columns (first array), v across rows."""
    c = (np.arange(size) + 0.5) / size
    return np.meshgrid(c, c)


# ------------------------------------------------------------------------------------------------ layers
def _asphalt(rng: np.random.Generator) -> np.ndarray:
    """Patches of lighter and darker asphalt (1.5 m down to 0.2 m across on a 6 m tile): they stream past at speed."""
    blotch = _fractal_noise(rng, (4, 8, 16))
    patches = _fractal_noise(rng, (32, 64))
    return _rgb((78, 79, 83), 1.0 + 0.16 * (blotch - 0.5) + 0.06 * (patches - 0.5))


def _shoulder(rng: np.random.Generator) -> np.ndarray:
    return _asphalt(rng) * 0.82  # older, darker asphalt next to the wall


def _line(rng: np.random.Generator) -> np.ndarray:
    return _rgb((232, 232, 228), 1.0 + 0.04 * (_fractal_noise(rng, (8, 32)) - 0.5))


def _kerb(rng: np.random.Generator) -> np.ndarray:
    """One period along u: a red block then a white block; v runs across the kerb (bevelled edges darker)."""
    u, v = _uv()
    red = u < 0.5
    base = np.where(red[..., None], np.array([196, 28, 30.0]), np.array([236, 236, 232.0]))
    bevel = 0.78 + 0.22 * np.sin(np.pi * v) ** 0.5
    return base * bevel[..., None]


def _wall(rng: np.random.Generator) -> np.ndarray:
    """Two concrete panels along u (light, slightly darker) with dark joints; v = 0 at the foot, 1 at the top.

    A band of alternating blue and white blocks near the top moves past fast at speed: a speed cue for a
    network that sees one frame. The dark strip at the foot is dirt and tyre rubber.
    """
    u, v = _uv()
    grain = _fractal_noise(rng, (8, 32)) - 0.5
    panel_b = (u >= 0.5).astype(np.float64)
    concrete = _rgb((176, 174, 168), 1.0 - 0.07 * panel_b + 0.06 * grain)
    band = (v > 0.62) & (v < 0.84)
    block = (np.floor(u * 4.0) % 2 == 0)[..., None]
    band_rgb = np.where(block, np.array([30, 80, 170.0]), np.array([235, 235, 235.0]))
    img = np.where(band[..., None], band_rgb, concrete)
    joint = (np.abs(u - 0.0 - 0.5 / TEXTURE_SIZE_PX) < 0.012) | (np.abs(u - 0.5) < 0.012)
    img = np.where(joint[..., None], img * 0.45, img)
    foot = np.clip((0.12 - v) / 0.12, 0.0, 1.0)
    return img * (1.0 - 0.45 * foot)[..., None]


def _wall_top(rng: np.random.Generator) -> np.ndarray:
    return _rgb((196, 194, 188), 1.0 + 0.08 * (_fractal_noise(rng, (8, 32)) - 0.5))


def _grass(rng: np.random.Generator) -> np.ndarray:
    """Grass with mowing stripes along u (two stripes per tile) and clumps."""
    u, _ = _uv()
    stripes = np.where(np.floor(u * 2.0) % 2 == 0, 1.0, 0.86)
    clumps = _fractal_noise(rng, (4, 16, 64))
    return _rgb((62, 118, 46), stripes * (0.85 + 0.3 * clumps))


def _pavement(rng: np.random.Generator) -> np.ndarray:
    """Concrete slabs, 4 x 4 per tile, with joints: the city ground of the expressway."""
    u, v = _uv()
    slab = np.floor(u * 4.0) + 4.0 * np.floor(v * 4.0)
    tone = rng.random(16)[slab.astype(np.int64) % 16]
    grain = _fractal_noise(rng, (16, 64)) - 0.5
    img = _rgb((128, 128, 124), 0.92 + 0.12 * tone + 0.06 * grain)
    joint = (np.abs((u * 4.0) % 1.0 - 0.5) > 0.47) | (np.abs((v * 4.0) % 1.0 - 0.5) > 0.47)
    return np.where(joint[..., None], img * 0.6, img)


def _facade(rng: np.random.Generator) -> np.ndarray:
    """4 x 4 windows per tile (u across a facade, v up a storey): concrete frame, dark glass, a few lit panes."""
    u, v = _uv()
    cu = (u * 4.0) % 1.0
    cv = (v * 4.0) % 1.0
    glass = (cu > 0.15) & (cu < 0.85) & (cv > 0.25) & (cv < 0.85)
    cell = (np.floor(u * 4.0) + 4.0 * np.floor(v * 4.0)).astype(np.int64)
    lit = (rng.random(16) > 0.8)[cell]
    glass_rgb = np.where(lit[..., None], np.array([150, 160, 150.0]), np.array([52, 70, 92.0]))
    sky_reflection = 1.0 + 0.25 * cv[..., None]
    frame = np.array([196, 192, 182.0])
    return np.where(glass[..., None], glass_rgb * sky_reflection, frame)


def _checker(rng: np.random.Generator) -> np.ndarray:
    u, v = _uv()
    black = (np.floor(u * 8.0) + np.floor(v * 8.0)) % 2 == 0
    return np.where(black[..., None], np.array([24, 24, 24.0]), np.array([238, 238, 238.0]))


def _metal(rng: np.random.Generator) -> np.ndarray:
    return _rgb((150, 154, 160), 1.0 + 0.06 * (_fractal_noise(rng, (4, 32)) - 0.5))


def _roof(rng: np.random.Generator) -> np.ndarray:
    return _rgb((96, 96, 100), 1.0 + 0.1 * (_fractal_noise(rng, (8, 32)) - 0.5))


_GENERATORS = {
    Layer.ASPHALT: _asphalt,
    Layer.LINE: _line,
    Layer.KERB: _kerb,
    Layer.WALL: _wall,
    Layer.WALL_TOP: _wall_top,
    Layer.GRASS: _grass,
    Layer.PAVEMENT: _pavement,
    Layer.FACADE: _facade,
    Layer.CHECKER: _checker,
    Layer.METAL: _metal,
    Layer.ROOF: _roof,
    Layer.SHOULDER: _shoulder,
}


def build_texture_layers() -> np.ndarray:
    """All layers as uint8 (n_layers, TEXTURE_SIZE_PX, TEXTURE_SIZE_PX, 3), indexed by :class:`Layer`.

    Each layer has its own generator stream derived from one fixed seed, so adding a layer never changes others.
    """
    layers = np.empty((len(Layer), TEXTURE_SIZE_PX, TEXTURE_SIZE_PX, 3), dtype=np.uint8)
    for layer in Layer:
        rng = np.random.default_rng([_SEED, int(layer)])
        layers[layer] = np.clip(np.rint(_GENERATORS[layer](rng)), 0, 255).astype(np.uint8)
    return layers
