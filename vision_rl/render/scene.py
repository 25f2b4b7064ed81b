"""The static world of one track as a single textured mesh, cut into chunks that each view culls on its own.

Everything is built once per track in numpy: the road (five bands across: shoulder or kerb, edge line, asphalt,
edge line, shoulder or kerb), the walls (inner face, top, outer face), the start/finish gantry, landmarks (city
blocks and a skyline for the expressway, towers and a ring of hills elsewhere) and the ground. All surfaces are
quads; the mesh is sorted by chunk so that a chunk is one contiguous index range, and a view draws only the chunks
whose bounding sphere meets its frustum (one indirect draw command per run of consecutive visible chunks).

Coordinates are the track's world frame minus :attr:`Scene.origin_xy_m` (the track's bounding-box centre), so that
float32 vertices stay exact to well under a millimetre on a 5 km track.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from vision_rl.render.textures import Layer
from vision_rl.sim.track import SHOULDER_MAX_WIDTH_M, SHOULDER_SHARE, Track


class Label(IntEnum):
    """Class ids of :meth:`vision_rl.render.Renderer.render_labels` (the flat-colour segmentation pass)."""

    SKY = 0
    ROAD = 1
    LINE = 2
    KERB = 3
    WALL = 4
    GROUND = 5
    CAR = 6
    LANDMARK = 7
    GANTRY = 8


LABEL_NAMES: tuple[str, ...] = tuple(label.name.lower() for label in Label)
"""Names of the label ids, index = id."""

LABEL_COLORS = np.array(
    [
        [135, 190, 240],  # sky
        [70, 70, 70],  # road
        [255, 255, 255],  # line
        [220, 30, 30],  # kerb
        [240, 200, 40],  # wall
        [60, 150, 50],  # ground
        [230, 40, 230],  # car
        [120, 90, 200],  # landmark
        [40, 220, 220],  # gantry
    ],
    dtype=np.uint8,
)
"""A display colour for each label id (for :func:`vision_rl.render.labels_to_rgb`)."""

#: Sun direction (towards the sun): azimuth 225 deg from +x, 50 deg up; baked into static vertex tints.
SUN_DIR = np.array(
    [
        math.cos(math.radians(50)) * math.cos(math.radians(225)),
        math.cos(math.radians(50)) * math.sin(math.radians(225)),
        math.sin(math.radians(50)),
    ]
)
AMBIENT = 0.55
"""Share of light that reaches a face turned away from the sun (sky light)."""

GROUND_Z_M = 0.0
"""Height of the ground around the track (the road's level); drawn by the renderer's background pass."""
_UP = np.array([0.0, 0.0, 1.0])

FLOATS_PER_VERTEX = 10
"""Static vertex layout: position xyz (m), uv (texture repeats), texture layer, tint rgb (lighting x colour), label."""


@dataclass(frozen=True)
class SceneStyle:
    """Dimensions and look of the scenery; one per track family (city expressway or park circuit)."""

    city: bool
    """True: concrete ground, dense blocks along the track and a skyline ring; False: grass, towers and hills."""
    wall_height_m: float = 1.1
    """Concrete barrier height, m (real circuit barriers stand about 1-1.2 m)."""
    wall_thickness_m: float = 0.35
    wall_panel_m: float = 3.0
    """Length of one wall panel (the texture holds two): a pattern every few metres makes speed visible."""
    kerb_width_m: float = SHOULDER_MAX_WIDTH_M
    """Widest kerb or shoulder band, m; narrower where SHOULDER_SHARE of the half width is less (the band the sim
    counts as off track, :meth:`vision_rl.sim.track.Track.beyond_edge_line`)."""
    kerb_period_m: float = 3.0
    """One red and one white kerb block."""
    kerb_min_curvature_1pm: float = 1.0 / 130.0
    """Kerbs where the centre-line radius is below 130 m (and 15 m either side of it)."""
    kerb_extend_m: float = 15.0
    line_width_m: float = 0.2
    asphalt_tile_m: float = 6.0
    ground_tile_m: float = 16.0
    section_max_length_m: float = 10.0
    """Longest road/wall segment on a straight; corners are cut finer (see section_max_turn_deg)."""
    section_max_turn_deg: float = 3.0
    """Heading change per segment: 3 deg keeps the chord error below 2 cm on a 60 m radius."""
    section_max_width_change_m: float = 0.25
    chunk_length_m: float = 60.0
    """Track length per culling chunk."""
    gantry_height_m: float = 6.5
    """Clearance under the start/finish gantry's beam."""
    start_line_length_m: float = 2.0
    """Length of the chequered start/finish line on the road (two rows of 0.75 m squares and a bit)."""


@dataclass(frozen=True, eq=False)
class Scene:
    """The static mesh of a track and its chunk table, ready to upload."""

    vertices: np.ndarray
    """float32 (n_vertices, FLOATS_PER_VERTEX)."""
    indices: np.ndarray
    """uint32 (n_triangles * 3,), sorted by chunk."""
    chunk_first: np.ndarray
    """int64 (n_chunks,): first index of each chunk in ``indices``."""
    chunk_count: np.ndarray
    """int64 (n_chunks,): number of indices of each chunk."""
    chunk_centre_m: np.ndarray
    """float64 (n_chunks, 3): centre of each chunk's bounding sphere (scene frame)."""
    chunk_radius_m: np.ndarray
    """float64 (n_chunks,): radius of each chunk's bounding sphere."""
    origin_xy_m: np.ndarray
    """World (x, y) of the scene frame's origin: subtract it from poses before drawing."""
    ground_layer: int
    """Texture layer of the ground around the track (pavement in the city, grass in a park)."""
    ground_tile_m: float
    """Ground texture repeat (m)."""
    city: bool

    @property
    def n_triangles(self) -> int:
        return len(self.indices) // 3

    @property
    def n_chunks(self) -> int:
        return len(self.chunk_first)


# ------------------------------------------------------------------------------------------------ quad soup
class _Quads:
    """Collects quads (4 corners each) with per-quad material and chunk id."""

    def __init__(self) -> None:
        self._pos: list[np.ndarray] = []
        self._uv: list[np.ndarray] = []
        self._layer: list[np.ndarray] = []
        self._tint: list[np.ndarray] = []
        self._label: list[np.ndarray] = []
        self._chunk: list[np.ndarray] = []

    def add(self, pos, uv, layer, tint, label, chunk, facing) -> None:
        """pos (q, 4, 3), uv (q, 4, 2); layer, label, chunk scalars or (q,); tint (3,), (q, 3) or (q, 4, 3).

        ``facing`` (3,) or (q, 3) is the side a quad is seen from: corners are reordered so that they run
        counter-clockwise seen from there, and back faces can be culled.
        """
        pos = np.asarray(pos, dtype=np.float64)
        q = pos.shape[0]
        uv = np.asarray(uv, dtype=np.float64)
        normal = np.cross(pos[:, 1] - pos[:, 0], pos[:, 2] - pos[:, 0]) + np.cross(
            pos[:, 2] - pos[:, 0], pos[:, 3] - pos[:, 0]
        )
        flip = np.einsum("qk,qk->q", normal, np.broadcast_to(np.asarray(facing, dtype=np.float64), (q, 3))) < 0.0
        reverse = np.array([0, 3, 2, 1])
        pos = np.where(flip[:, None, None], pos[:, reverse], pos)
        uv = np.where(flip[:, None, None], uv[:, reverse], uv)
        # Shift each quad's uv by whole repeats so float32 texture coordinates stay small (exact tiling kept).
        uv = uv - np.floor(uv.min(axis=1, keepdims=True))
        tint = np.asarray(tint, dtype=np.float64)
        if tint.ndim == 1:
            tint = np.broadcast_to(tint, (q, 3))
        if tint.ndim == 2:
            tint = np.broadcast_to(tint[:, None, :], (q, 4, 3))
        tint = np.where(flip[:, None, None], tint[:, reverse], tint)
        self._pos.append(pos)
        self._uv.append(uv)
        self._layer.append(np.broadcast_to(np.asarray(layer, dtype=np.float64), (q,)))
        self._tint.append(tint)
        self._label.append(np.broadcast_to(np.asarray(label, dtype=np.float64), (q,)))
        self._chunk.append(np.broadcast_to(np.asarray(chunk, dtype=np.int64), (q,)))

    def build(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        pos = np.concatenate(self._pos)
        uv = np.concatenate(self._uv)
        layer = np.concatenate(self._layer)
        tint = np.concatenate(self._tint)
        label = np.concatenate(self._label)
        chunk = np.concatenate(self._chunk)
        order = np.argsort(chunk, kind="stable")
        pos, uv, layer, tint, label, chunk = (
            pos[order],
            uv[order],
            layer[order],
            tint[order],
            label[order],
            chunk[order],
        )
        q = len(pos)
        verts = np.empty((q, 4, FLOATS_PER_VERTEX), dtype=np.float32)
        verts[:, :, 0:3] = pos
        verts[:, :, 3:5] = uv
        verts[:, :, 5] = layer[:, None]
        verts[:, :, 6:9] = tint
        verts[:, :, 9] = label[:, None]
        base = (np.arange(q, dtype=np.uint32) * 4)[:, None]
        indices = (base + np.array([0, 1, 2, 0, 2, 3], dtype=np.uint32)[None, :]).reshape(-1)
        n_chunks = int(chunk.max()) + 1
        quads_per_chunk = np.bincount(chunk, minlength=n_chunks)
        first_quad = np.concatenate([[0], np.cumsum(quads_per_chunk)[:-1]])
        # Bounding spheres: box centre of each chunk's corners, radius to the farthest corner.
        corners = pos.reshape(-1, 3)
        corner_chunk = np.repeat(chunk, 4)
        lo = np.full((n_chunks, 3), np.inf)
        hi = np.full((n_chunks, 3), -np.inf)
        np.minimum.at(lo, corner_chunk, corners)
        np.maximum.at(hi, corner_chunk, corners)
        centre = 0.5 * (lo + hi)
        radius = np.zeros(n_chunks)
        np.maximum.at(radius, corner_chunk, np.linalg.norm(corners - centre[corner_chunk], axis=1))
        keep = quads_per_chunk > 0
        return (
            verts.reshape(-1, FLOATS_PER_VERTEX),
            indices,
            (first_quad * 6)[keep],
            (quads_per_chunk * 6)[keep],
            centre[keep],
            radius[keep],
        )


def _face_shade(normal_xyz: np.ndarray) -> np.ndarray:
    """Lambert shade of faces with the given normals, scaled so an upward face (the road) gets 1."""
    lit = AMBIENT + (1.0 - AMBIENT) * np.clip(normal_xyz @ SUN_DIR, 0.0, None)
    return lit / (AMBIENT + (1.0 - AMBIENT) * SUN_DIR[2])


def _box_quads(
    quads: _Quads,
    centre_xy: np.ndarray,
    half_len: np.ndarray,
    half_wid: np.ndarray,
    z0: np.ndarray,
    z1: np.ndarray,
    yaw: np.ndarray,
    side_layer: int,
    top_layer: int,
    tint: np.ndarray,
    label: int,
    chunk: np.ndarray,
    uv_scale_m: tuple[float, float],
    top_tile_m: float = 8.0,
) -> None:
    """Boxes (b,) standing on z0 up to z1, four sides and a top, lit by the sun; uv in metres / uv_scale_m."""
    centre_xy = np.atleast_2d(centre_xy)
    b = len(centre_xy)
    half_len, half_wid, z0, z1, yaw = (
        np.broadcast_to(np.asarray(a, dtype=np.float64), (b,)) for a in (half_len, half_wid, z0, z1, yaw)
    )
    chunk = np.broadcast_to(np.asarray(chunk), (b,))
    tint = np.broadcast_to(np.asarray(tint, dtype=np.float64), (b, 3))
    ax = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    ay = np.stack([-np.sin(yaw), np.cos(yaw)], axis=1)
    # Footprint corners counter-clockwise: (-,-), (+,-), (+,+), (-,+) in the box frame.
    signs = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64)
    foot = (
        centre_xy[:, None, :]
        + signs[None, :, 0:1] * (half_len[:, None, None] * ax[:, None, :])
        + signs[None, :, 1:2] * (half_wid[:, None, None] * ay[:, None, :])
    )
    for k in range(4):
        a, c = foot[:, k], foot[:, (k + 1) % 4]
        edge = c - a
        edge_len = np.hypot(edge[:, 0], edge[:, 1])
        normal = np.stack([edge[:, 1], -edge[:, 0], np.zeros(b)], axis=1) / edge_len[:, None]
        pos = np.stack(
            [
                np.column_stack([a, z0]),
                np.column_stack([c, z0]),
                np.column_stack([c, z1]),
                np.column_stack([a, z1]),
            ],
            axis=1,
        )
        u1 = edge_len / uv_scale_m[0]
        uv = np.stack(
            [
                np.column_stack([np.zeros(b), z0 / uv_scale_m[1]]),
                np.column_stack([u1, z0 / uv_scale_m[1]]),
                np.column_stack([u1, z1 / uv_scale_m[1]]),
                np.column_stack([np.zeros(b), z1 / uv_scale_m[1]]),
            ],
            axis=1,
        )
        quads.add(pos, uv, side_layer, tint * _face_shade(normal)[:, None], label, chunk, normal)
    top = np.concatenate([foot, np.broadcast_to(z1[:, None, None], (b, 4, 1))], axis=2)
    up = np.array([0.0, 0.0, 1.0])
    quads.add(top, foot / top_tile_m, top_layer, tint * _face_shade(up), label, chunk, up)


# ------------------------------------------------------------------------------------------------ track
def _dilate_circular(flag: np.ndarray, half_width: int) -> np.ndarray:
    """Boolean max filter of +-half_width samples on a closed loop."""
    if half_width <= 0:
        return flag.copy()
    n = len(flag)
    ext = np.concatenate([flag[-half_width:], flag, flag[:half_width]]).astype(np.int64)
    c = np.concatenate([[0], np.cumsum(ext)])
    window = c[2 * half_width + 1 :] - c[: -(2 * half_width + 1)]
    return window[:n] > 0


def _inside_other_branch(track: Track, xy: np.ndarray, s_m: np.ndarray, block: int = 256) -> np.ndarray:
    """Which points (m, 2) lie on the road of a part of the track far (along s) from their own arc length s_m."""
    reach = float(np.max(np.maximum(track.width_left_m, track.width_right_m)))
    far_along_m = 4.0 * reach + 20.0
    half_width = np.maximum(track.width_left_m, track.width_right_m) - 0.05
    out = np.zeros(len(xy), dtype=bool)
    for start in range(0, len(xy), block):  # blocks bound the (block, n_points) distance matrix
        p = xy[start : start + block]
        d2 = ((p[:, None, :] - track.centre_xy_m[None, :, :]) ** 2).sum(axis=2)
        ds = np.abs(s_m[start : start + block, None] - track.s_m[None, :])
        ds = np.minimum(ds, track.length_m - ds)
        out[start : start + block] = ((d2 < half_width[None, :] ** 2) & (ds > far_along_m)).any(axis=1)
    return out


def _section_indices(track: Track, style: SceneStyle, kerb: np.ndarray, forced: list[int]) -> np.ndarray:
    """Centre-line samples kept as road/wall cross-sections: every corner cut finely, straights in long pieces."""
    n = track.n_points
    max_turn = math.radians(style.section_max_turn_deg)
    heading = np.unwrap(track.heading_rad)
    forced_set = set(forced)
    keep = [0]
    last = 0
    for i in range(1, n):
        if (
            i in forced_set
            or (i - last) * track.spacing_m >= style.section_max_length_m - 1e-9
            or abs(heading[i] - heading[last]) >= max_turn
            or abs(track.width_left_m[i] - track.width_left_m[last]) >= style.section_max_width_change_m
            or abs(track.width_right_m[i] - track.width_right_m[last]) >= style.section_max_width_change_m
            or kerb[i] != kerb[i - 1]
        ):
            keep.append(i)
            last = i
    return np.asarray(keep, dtype=np.int64)


class _Sections(NamedTuple):
    """The road's cross-sections: where each segment starts and ends along the centre line and its chunk."""

    idx: np.ndarray
    """(q,) centre-line sample of each segment's start."""
    nxt: np.ndarray
    """(q,) centre-line sample of its end (the next segment's start)."""
    s0: np.ndarray
    """(q,) arc length of its start, m."""
    s1: np.ndarray
    """(q,) arc length of its end, m (past the lap length for the last segment)."""
    chunk: np.ndarray
    """(q,) culling chunk id."""


def _corners(a0: np.ndarray, a1: np.ndarray, b1: np.ndarray, b0: np.ndarray) -> np.ndarray:
    """(q, 4, k) quad corners from four (q, k) arrays, in the order given."""
    return np.stack([a0, a1, b1, b0], axis=1)


def _uv_rect(u0: np.ndarray, u1: np.ndarray, v0: float, v1: float) -> np.ndarray:
    """(q, 4, 2) uv of quads running from u0 to u1 along and from v0 to v1 across."""
    return _corners(
        np.column_stack([u0, np.full_like(u0, v0)]),
        np.column_stack([u1, np.full_like(u0, v0)]),
        np.column_stack([u1, np.full_like(u0, v1)]),
        np.column_stack([u0, np.full_like(u0, v1)]),
    )


def _band_lines(track: Track, style: SceneStyle, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((n, 6, 2) scene positions, (n, 6) lateral offsets (+ left)) of the six cross-section lines at every centre-line
    sample, from the left wall to the right wall."""
    centre = track.centre_xy_m - origin
    wl, wr = track.width_left_m, track.width_right_m
    kerb_w_l = np.minimum(style.kerb_width_m, SHOULDER_SHARE * wl)
    kerb_w_r = np.minimum(style.kerb_width_m, SHOULDER_SHARE * wr)
    line_w = np.minimum(style.line_width_m, 0.03 * np.minimum(wl, wr))
    offsets = np.stack(
        [wl, wl - kerb_w_l, wl - kerb_w_l - line_w, -(wr - kerb_w_r - line_w), -(wr - kerb_w_r), -wr], axis=1
    )  # (n, 6)
    xy = centre[:, None, :] + track.normal_left[:, None, :] * offsets[:, :, None]  # (n, 6, 2)
    return xy, offsets


def _road_quads(
    quads: _Quads, sec: _Sections, xy: np.ndarray, offsets: np.ndarray, kerb_seg: np.ndarray, style: SceneStyle
) -> None:
    """The five bands across the road: shoulder or kerb, edge line, asphalt (with the start line), edge line,
    shoulder or kerb."""
    idx, nxt, s0, s1, chunk = sec
    start_line = np.zeros(len(idx), dtype=bool)
    start_line[0] = True
    z = np.zeros((len(idx), 1))
    for band in range(5):
        a, b = band, band + 1
        p = _corners(
            np.column_stack([xy[idx, a], z]),
            np.column_stack([xy[nxt, a], z]),
            np.column_stack([xy[nxt, b], z]),
            np.column_stack([xy[idx, b], z]),
        )
        lat_a0, lat_a1, lat_b1, lat_b0 = offsets[idx, a], offsets[nxt, a], offsets[nxt, b], offsets[idx, b]
        tile = style.asphalt_tile_m
        uv = (
            _corners(
                np.column_stack([s0, lat_a0]),
                np.column_stack([s1, lat_a1]),
                np.column_stack([s1, lat_b1]),
                np.column_stack([s0, lat_b0]),
            )
            / tile
        )
        if band in (0, 4):
            # Kerb in corners, old darker asphalt elsewhere; kerb uv: u one red+white period, v 0..1 across.
            k = kerb_seg
            kuv = _uv_rect(s0, s1, 0.0, 1.0)
            kuv[:, :, 0] /= style.kerb_period_m
            quads.add(p[k], kuv[k], Layer.KERB, np.ones(3), Label.KERB, chunk[k], _UP)
            quads.add(p[~k], uv[~k], Layer.SHOULDER, np.ones(3), Label.ROAD, chunk[~k], _UP)
        elif band in (1, 3):
            quads.add(p, uv, Layer.LINE, np.ones(3), Label.LINE, chunk, _UP)
        else:
            # Chequered start/finish line across the asphalt: 8 squares per tile (0.75 m).
            sl = start_line
            quads.add(p[~sl], uv[~sl], Layer.ASPHALT, np.ones(3), Label.ROAD, chunk[~sl], _UP)
            quads.add(p[sl], uv[sl], Layer.CHECKER, np.ones(3), Label.LINE, chunk[sl], _UP)


def _strip(a0, a1, b0, b1, za: float, zb: float) -> np.ndarray:
    """(q, 4, 3) quads from the lines a (at height za) to b (at zb), each from its sample 0 to 1."""
    q = len(a0)
    return _corners(
        np.column_stack([a0, np.full(q, za)]),
        np.column_stack([a1, np.full(q, za)]),
        np.column_stack([b1, np.full(q, zb)]),
        np.column_stack([b0, np.full(q, zb)]),
    )


def _wall_quads(
    quads: _Quads, track: Track, style: SceneStyle, origin: np.ndarray, sec: _Sections, w: np.ndarray, out: np.ndarray
) -> None:
    """One wall along the line ``w`` (n, 2), ``out`` (n, 2) the outward normal: inner face, top and outer face."""
    idx, nxt, chunk = sec.idx, sec.nxt, sec.chunk
    h = style.wall_height_m
    foot_z = GROUND_Z_M
    seg = w[nxt] - w[idx]
    wall_len = np.hypot(seg[:, 0], seg[:, 1])
    u0 = np.concatenate([[0.0], np.cumsum(wall_len)[:-1]]) / (2.0 * style.wall_panel_m)
    u1 = u0 + wall_len / (2.0 * style.wall_panel_m)
    inner_n = np.column_stack([-out[idx], np.zeros(len(idx))])
    inner_n /= np.linalg.norm(inner_n, axis=1, keepdims=True)
    top_w = w + out * style.wall_thickness_m
    # Where the track crosses itself (a bridge, as at Suzuka) the flat renderer would put each branch's wall
    # across the other's road; leave those wall pieces out, making the crossing look like a junction.
    inside = _inside_other_branch(track, w[idx] + origin, track.s_m[idx])
    keep = ~(inside | np.roll(inside, -1))
    wall_uv = _uv_rect(u0, u1, foot_z / h, 1.0)
    inner = _strip(w[idx], w[nxt], w[idx], w[nxt], foot_z, h)
    shade = _face_shade(inner_n)[:, None] * np.ones(3)
    quads.add(inner[keep], wall_uv[keep], Layer.WALL, shade[keep], Label.WALL, chunk[keep], inner_n[keep])
    top = _strip(w[idx], w[nxt], top_w[idx], top_w[nxt], h, h)
    top_uv = _uv_rect(u0, u1, 0.0, 0.1)
    quads.add(top[keep], top_uv[keep], Layer.WALL_TOP, np.ones(3), Label.WALL, chunk[keep], _UP)
    outer = _strip(top_w[idx], top_w[nxt], top_w[idx], top_w[nxt], foot_z, h)
    shade = _face_shade(-inner_n)[:, None] * np.ones(3)
    quads.add(outer[keep], wall_uv[keep], Layer.WALL, shade[keep], Label.WALL, chunk[keep], -inner_n[keep])


def _track_quads(quads: _Quads, track: Track, style: SceneStyle, origin: np.ndarray) -> int:
    """Road bands and walls; returns the number of chunk ids used (track chunks are 0..k-1)."""
    kerb_raw = np.abs(track.curvature_1pm) > style.kerb_min_curvature_1pm
    kerb = _dilate_circular(kerb_raw, round(style.kerb_extend_m / track.spacing_m))
    start_end = max(1, round(style.start_line_length_m / track.spacing_m))
    idx = _section_indices(track, style, kerb, [start_end])
    nxt = np.roll(idx, -1)
    s0 = track.s_m[idx]
    seg_len = np.mod(track.s_m[nxt] - s0, track.length_m)
    seg_len[seg_len == 0] = track.length_m  # a track of a single section (never in practice)
    sec = _Sections(idx, nxt, s0, s0 + seg_len, np.floor(s0 / style.chunk_length_m).astype(np.int64))
    xy, offsets = _band_lines(track, style, origin)
    _road_quads(quads, sec, xy, offsets, kerb[idx], style)
    for col, outward_sign in ((0, 1.0), (5, -1.0)):  # left wall line (outwards = +normal), right wall line
        _wall_quads(quads, track, style, origin, sec, xy[:, col], track.normal_left * outward_sign)
    _gantry_quads(quads, track, style, origin, chunk_id=0)
    return int(sec.chunk.max()) + 1


def _gantry_quads(quads: _Quads, track: Track, style: SceneStyle, origin: np.ndarray, chunk_id: int) -> None:
    """Start/finish gantry at s = 0: two pillars beyond the walls and a chequered beam over the track."""
    c = track.centre_xy_m[0] - origin
    nl = track.normal_left[0]
    yaw = float(track.heading_rad[0])
    reach_l = track.width_left_m[0] + style.wall_thickness_m + 0.8
    reach_r = track.width_right_m[0] + style.wall_thickness_m + 0.8
    pillars = np.stack([c + nl * reach_l, c - nl * reach_r])
    tint = np.array([0.85, 0.85, 0.9])
    _box_quads(
        quads,
        pillars,
        0.4,
        0.4,
        GROUND_Z_M,
        style.gantry_height_m + 1.5,
        yaw,
        Layer.METAL,
        Layer.METAL,
        tint,
        Label.GANTRY,
        chunk_id,
        (1.0, 2.0),
    )
    mid = c + nl * 0.5 * (reach_l - reach_r)
    span_half = 0.5 * (reach_l + reach_r) + 0.4
    # The beam is a box whose long axis runs across the track (yaw + 90 deg); its faces towards the drivers
    # carry the chequered banner (uv 1 repeat per 6 m across, 1.5 m high -> 0.75 m squares).
    _box_quads(
        quads,
        mid[None],
        span_half,
        0.6,
        style.gantry_height_m,
        style.gantry_height_m + 1.5,
        yaw + 0.5 * math.pi,
        Layer.CHECKER,
        Layer.METAL,
        np.ones(3),
        Label.GANTRY,
        chunk_id,
        (6.0, 6.0),
    )


# ------------------------------------------------------------------------------------------------ scenery
def _distance_to_track(track: Track, xy_world: np.ndarray) -> np.ndarray:
    """Distance from points (n, 2) to the nearest centre-line sample (m)."""
    proj = track.project(xy_world)
    foot = track.position_at(proj.s_m)
    return np.hypot(*(xy_world - foot).T)


#: Tints of landmark boxes (lighting x colour), drawn at random per box.
_PALETTE = np.array(
    [
        [1.0, 0.97, 0.9],
        [0.85, 0.88, 0.95],
        [0.95, 0.85, 0.75],
        [0.8, 0.8, 0.82],
        [0.92, 0.92, 0.85],
        [0.75, 0.82, 0.9],
    ]
)
#: Azimuth sectors of the horizon ring: each is a chunk that a view culls on its own.
_N_SECTORS = 16


def _landmark_sites(
    track: Track, style: SceneStyle, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World (x, y), half length and half width (m) of the near landmarks: blocks along the track (city) or a few
    towers (park), rejected where they would touch the road or an earlier one."""
    max_w = float(np.max(np.maximum(track.width_left_m, track.width_right_m)))
    if style.city:
        n_try, dist_lo, dist_hi, size = 900, 12.0, 220.0, (10.0, 30.0)
    else:
        n_try, dist_lo, dist_hi, size = 90, 40.0, 500.0, (6.0, 14.0)
    s = rng.uniform(0.0, track.length_m, n_try)
    side = rng.choice([-1.0, 1.0], n_try)
    off = rng.uniform(dist_lo, dist_hi, n_try)
    base = (
        track.position_at(s)
        + np.stack([-np.sin(track.heading_at(s)), np.cos(track.heading_at(s))], axis=1)
        * (side * (off + np.where(side > 0, track.width_left_at(s), track.width_right_at(s))))[:, None]
    )
    half_len = rng.uniform(*size, n_try)
    half_wid = rng.uniform(*size, n_try)
    radius = np.hypot(half_len, half_wid)
    clear = _distance_to_track(track, base) > max_w + style.wall_thickness_m + 4.0 + radius
    base, half_len, half_wid, radius = base[clear], half_len[clear], half_wid[clear], radius[clear]
    # Drop blocks that overlap an earlier one (greedy in random order, deterministic).
    kept = []
    for i in range(len(base)):
        if all(np.hypot(*(base[i] - base[j])) > radius[i] + radius[j] for j in kept):
            kept.append(i)
    kept = np.asarray(kept, dtype=np.int64)
    return base[kept], half_len[kept], half_wid[kept]


def _near_landmarks(
    quads: _Quads,
    track: Track,
    style: SceneStyle,
    origin: np.ndarray,
    lo: np.ndarray,
    chunk_id: int,
    rng: np.random.Generator,
) -> int:
    """The landmarks along the track, chunked in 400 m cells; returns the next free chunk id."""
    cell_m = 400.0
    base, half_len, half_wid = _landmark_sites(track, style, rng)
    base = base - origin
    nb = len(base)
    if not nb:
        return chunk_id
    if style.city:
        height = np.clip(rng.lognormal(math.log(28.0), 0.6, nb), 8.0, 160.0)
    else:
        height = rng.uniform(15.0, 60.0, nb)
    yaw = track.heading_at(track.project(base + origin).s_m) + rng.normal(0.0, 0.05, nb)
    tint = _PALETTE[rng.integers(0, len(_PALETTE), nb)]
    cell = np.floor((base - lo) / cell_m).astype(np.int64)
    cell_key = cell[:, 0] * 100_000 + cell[:, 1]
    _, cell_chunk = np.unique(cell_key, return_inverse=True)
    _box_quads(
        quads,
        base,
        half_len,
        half_wid,
        GROUND_Z_M,
        height,
        yaw,
        Layer.FACADE,
        Layer.ROOF,
        tint,
        Label.LANDMARK,
        chunk_id + cell_chunk,
        (12.0, 14.0),
    )
    return chunk_id + int(cell_chunk.max()) + 1


def _sector(az: np.ndarray) -> np.ndarray:
    """Horizon sector (0.._N_SECTORS-1) of azimuths in rad."""
    return np.floor(az / (2 * math.pi) * _N_SECTORS).astype(np.int64) % _N_SECTORS


def _ring_towers(
    quads: _Quads,
    centre: np.ndarray,
    distance_m: np.ndarray,
    az: np.ndarray,
    h: np.ndarray,
    shaft: tuple[float, np.ndarray],
    top: tuple[float, float, int, int, np.ndarray, tuple[float, float]],
    chunk_id: int,
) -> None:
    """Towers on the horizon: a metal shaft (half width, tint) up to h and a top (half width, height, side and top
    layers, tint, uv scale) on it."""
    pos = centre + np.stack([np.cos(az), np.sin(az)], axis=1) * distance_m[:, None]
    sector = _sector(az)
    shaft_half, shaft_tint = shaft
    _box_quads(
        quads,
        pos,
        shaft_half,
        shaft_half,
        GROUND_Z_M,
        h,
        az,
        Layer.METAL,
        Layer.METAL,
        shaft_tint,
        Label.LANDMARK,
        chunk_id + sector,
        (4.0, 8.0),
    )
    top_half, top_height, side_layer, top_layer, top_tint, uv_scale = top
    _box_quads(
        quads,
        pos,
        top_half,
        top_half,
        h,
        h + top_height,
        az,
        side_layer,
        top_layer,
        top_tint,
        Label.LANDMARK,
        chunk_id + sector,
        uv_scale,
    )


def _city_skyline(quads: _Quads, centre: np.ndarray, ring_r: float, chunk_id: int, rng: np.random.Generator) -> None:
    """The city's horizon: a ring of blocks and a few thin towers with a masthead (the city's landmarks)."""
    n_b = 260
    az = rng.uniform(0.0, 2 * math.pi, n_b)
    r = ring_r + rng.uniform(0.0, 1400.0, n_b)
    pos = centre + np.stack([np.cos(az), np.sin(az)], axis=1) * r[:, None]
    h = np.clip(rng.lognormal(math.log(70.0), 0.55, n_b), 25.0, 320.0)
    hl = rng.uniform(12.0, 40.0, n_b)
    hw = rng.uniform(12.0, 40.0, n_b)
    tint = _PALETTE[rng.integers(0, len(_PALETTE), n_b)] * 0.95
    _box_quads(
        quads,
        pos,
        hl,
        hw,
        GROUND_Z_M,
        h,
        az,
        Layer.FACADE,
        Layer.ROOF,
        tint,
        Label.LANDMARK,
        chunk_id + _sector(az),
        (12.0, 14.0),
    )
    n_t = 6
    az_t = (np.arange(n_t) + rng.uniform(0.2, 0.8, n_t)) * 2 * math.pi / n_t
    distance_m = ring_r + rng.uniform(200, 900, n_t)
    h_t = rng.uniform(250.0, 450.0, n_t)
    mast = (2.0, 60.0, Layer.METAL, Layer.METAL, np.array([0.9, 0.25, 0.2]), (4.0, 8.0))
    _ring_towers(quads, centre, distance_m, az_t, h_t, (9.0, np.array([0.95, 0.92, 0.9])), mast, chunk_id)


def _park_hills(quads: _Quads, centre: np.ndarray, ring_r: float, chunk_id: int, rng: np.random.Generator) -> None:
    """A park's horizon: a ring of hills and a few towers with a deck."""
    k = 96
    az = np.arange(k + 1) * 2 * math.pi / k
    ridge = rng.uniform(60.0, 260.0, k)
    ridge = np.append(ridge, ridge[0])
    ridge_r = ring_r + 1500.0
    ring = centre + np.stack([np.cos(az), np.sin(az)], axis=1) * ridge_r
    outer = centre + np.stack([np.cos(az), np.sin(az)], axis=1) * (ridge_r + 900.0)
    p = _corners(
        np.column_stack([ring[:-1], np.full(k, GROUND_Z_M)]),
        np.column_stack([ring[1:], np.full(k, GROUND_Z_M)]),
        np.column_stack([outer[1:], ridge[1:]]),
        np.column_stack([outer[:-1], ridge[:-1]]),
    )
    sector = (np.arange(k) * _N_SECTORS) // k
    uv = p[:, :, :2] / 200.0
    inward = np.column_stack([centre - 0.5 * (ring[:-1] + ring[1:]), np.zeros(k)])
    inward = inward / np.linalg.norm(inward, axis=1, keepdims=True) + _UP
    quads.add(p, uv, Layer.GRASS, np.array([0.62, 0.72, 0.7]), Label.LANDMARK, chunk_id + sector, inward)
    n_t = 4
    az_t = (np.arange(n_t) + rng.uniform(0.2, 0.8, n_t)) * 2 * math.pi / n_t
    distance_m = ring_r + rng.uniform(100, 600, n_t)
    h_t = rng.uniform(120.0, 220.0, n_t)
    deck = (11.0, 14.0, Layer.FACADE, Layer.ROOF, np.array([0.9, 0.9, 0.95]), (12.0, 14.0))
    _ring_towers(quads, centre, distance_m, az_t, h_t, (5.0, np.array([0.95, 0.95, 0.95])), deck, chunk_id)


def _scenery_quads(
    quads: _Quads, track: Track, style: SceneStyle, origin: np.ndarray, first_chunk: int, rng: np.random.Generator
) -> int:
    """Landmarks (the ground is the renderer's background pass); returns the next free chunk id."""
    lo = track.centre_xy_m.min(axis=0) - origin
    hi = track.centre_xy_m.max(axis=0) - origin
    half_diag = 0.5 * float(np.hypot(*(hi - lo)))
    chunk_id = _near_landmarks(quads, track, style, origin, lo, first_chunk, rng)
    # Horizon ring: a skyline (city) or hills (park), in azimuth sectors that each view culls.
    centre = 0.5 * (lo + hi)
    ring_r = half_diag + 900.0
    if style.city:
        _city_skyline(quads, centre, ring_r, chunk_id, rng)
    else:
        _park_hills(quads, centre, ring_r, chunk_id, rng)
    return chunk_id + _N_SECTORS


def style_for(track: Track) -> SceneStyle:
    """The expressway is a city circuit; every other track is a park circuit."""
    return SceneStyle(city=track.name.lower().startswith("expressway"))


def build_scene(track: Track, style: SceneStyle | None = None) -> Scene:
    """The static mesh of ``track``; deterministic (scenery placement is seeded by the track's geometry hash)."""
    style = style or style_for(track)
    lo = track.centre_xy_m.min(axis=0)
    hi = track.centre_xy_m.max(axis=0)
    origin = 0.5 * (lo + hi)
    rng = np.random.default_rng(int(track.geometry_hash, 16) % (2**63))
    quads = _Quads()
    n_track_chunks = _track_quads(quads, track, style, origin)
    _scenery_quads(quads, track, style, origin, n_track_chunks, rng)
    verts, indices, first, count, centre, radius = quads.build()
    return Scene(
        vertices=verts,
        indices=indices,
        chunk_first=first,
        chunk_count=count,
        chunk_centre_m=centre,
        chunk_radius_m=radius,
        origin_xy_m=origin,
        ground_layer=int(Layer.PAVEMENT if style.city else Layer.GRASS),
        ground_tile_m=style.ground_tile_m,
        city=style.city,
    )


# ------------------------------------------------------------------------------------------------ car body
CAR_FLOATS_PER_VERTEX = 7
"""Car vertex layout: position xyz (m, body frame), normal xyz, part (0 paint, 1 glass, 2 tyre, 3 tail light, 4
shadow)."""


def _hexa(corners: np.ndarray, part_sides: int, part_top: int, skip_bottom: bool = True) -> list[tuple]:
    """Faces (corners, part, outward direction) of a hexahedron: 8 corners, bottom ring (--, +-, ++, -+), top ring."""
    faces = []
    b, t = corners[:4], corners[4:]
    centre = corners.mean(axis=0)
    for k in range(4):
        face = np.array([b[k], b[(k + 1) % 4], t[(k + 1) % 4], t[k]])
        faces.append((face, part_sides, face.mean(axis=0) - centre))
    faces.append((t.copy(), part_top, np.array([0.0, 0.0, 1.0])))
    if not skip_bottom:
        faces.append((b[::-1].copy(), part_sides, np.array([0.0, 0.0, -1.0])))
    return faces


def _ring(x0, x1, hw0, hw1, z):
    """Four corners of a horizontal rectangle-ish ring: (x0,-hw0), (x1,-hw1), (x1,+hw1), (x0,+hw0) at height z."""
    return np.array([[x0, -hw0, z], [x1, -hw1, z], [x1, hw1, z], [x0, hw0, z]], dtype=np.float64)


def build_car_mesh(length_m: float, width_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A low-poly car body (wedge body, glass cabin, four tyres, tail lights, blob shadow) centred on its middle.

    Returns float32 vertices (n, CAR_FLOATS_PER_VERTEX) and uint32 indices; about 60 triangles.
    """
    half_l, half_w = 0.5 * length_m, 0.5 * width_m
    faces: list[tuple] = []
    # Body: a wedge, higher at the back (0.78 m) than over the nose (0.62 m).
    body_bottom = _ring(-half_l, half_l, half_w, half_w, 0.22)
    body_top = np.array(
        [[-half_l, -half_w, 0.78], [half_l, -half_w, 0.62], [half_l, half_w, 0.62], [-half_l, half_w, 0.78]]
    )
    faces += _hexa(np.vstack([body_bottom, body_top]), 0, 0)
    # Cabin (glass sides, painted roof), set back from the middle and narrower than the body.
    cab_x0, cab_x1 = -0.36 * length_m, 0.14 * length_m
    z_base = 0.78 - 0.16 * (np.array([cab_x0, cab_x1]) + half_l) / length_m
    cab_bottom = np.array(
        [
            [cab_x0, -0.44 * width_m, z_base[0]],
            [cab_x1, -0.44 * width_m, z_base[1]],
            [cab_x1, 0.44 * width_m, z_base[1]],
            [cab_x0, 0.44 * width_m, z_base[0]],
        ]
    )
    cab_top = _ring(-0.28 * length_m, 0.0, 0.36 * width_m, 0.36 * width_m, 1.28)
    faces += _hexa(np.vstack([cab_bottom, cab_top]), 1, 0)
    # Tyres: boxes standing out of the body's flanks at both axles.
    axle_x = 0.32 * length_m
    for x in (-axle_x, axle_x):
        for y_sign in (-1.0, 1.0):
            y_in, y_out = y_sign * (half_w - 0.26), y_sign * (half_w + 0.02)
            lo_y, hi_y = min(y_in, y_out), max(y_in, y_out)
            ring_lo = np.array(
                [[x - 0.32, lo_y, 0.0], [x + 0.32, lo_y, 0.0], [x + 0.32, hi_y, 0.0], [x - 0.32, hi_y, 0.0]]
            )
            ring_hi = ring_lo + np.array([0.0, 0.0, 0.62])
            faces += _hexa(np.vstack([ring_lo, ring_hi]), 2, 2)
    # Tail lights: two thin red plates just behind the rear face.
    for y_sign in (-1.0, 1.0):
        y0, y1 = y_sign * (half_w - 0.45), y_sign * (half_w - 0.08)
        x = -half_l - 0.01
        plate = np.array([[x, y0, 0.56], [x, y1, 0.56], [x, y1, 0.70], [x, y0, 0.70]])
        faces.append((plate, 3, np.array([-1.0, 0.0, 0.0])))
    # Blob shadow on the road, a little larger than the footprint.
    sh = np.array(
        [
            [-half_l - 0.25, -half_w - 0.2, 0.02],
            [half_l + 0.25, -half_w - 0.2, 0.02],
            [half_l + 0.25, half_w + 0.2, 0.02],
            [-half_l - 0.25, half_w + 0.2, 0.02],
        ]
    )
    faces.append((sh, 4, np.array([0.0, 0.0, 1.0])))
    verts = []
    for quad, part, outward in faces:
        q = np.asarray(quad, dtype=np.float64)
        normal = np.cross(q[1] - q[0], q[2] - q[0]) + np.cross(q[2] - q[0], q[3] - q[0])
        normal /= np.linalg.norm(normal)
        # Wind every face counter-clockwise seen from outside, so that back faces can be culled.
        if np.dot(normal, outward) < 0:
            q = q[[0, 3, 2, 1]]
            normal = -normal
        for corner in q:
            verts.append([*corner, *normal, part])
    verts = np.asarray(verts, dtype=np.float32)
    n_quads = len(verts) // 4
    indices = ((np.arange(n_quads, dtype=np.uint32) * 4)[:, None] + np.array([0, 1, 2, 0, 2, 3], np.uint32)).ravel()
    return verts, indices
