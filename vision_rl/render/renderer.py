"""Offscreen OpenGL renderer of the simulator: many cars' driver views in one pass, one read-back.

Frames are a pure function of (track, config, poses, groups, colours, tile). A Renderer owns its GL context: use it
from one thread. How a batch is drawn and why a view may differ in a few edge pixels from tile to tile:
docs/notes/render.md.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from vision_rl.render.scene import GROUND_Z_M, SUN_DIR, Label, Scene, build_car_mesh, build_scene
from vision_rl.render.textures import TEXTURE_SIZE_PX, build_texture_layers
from vision_rl.sim.track import Track

MAX_WIDTH_PX = 1280
MAX_HEIGHT_PX = 720

_GL_CLIP_DISTANCE0 = 0x3000

#: Vivid, distinct body colours (sRGB 0-1) given to cars in index order when no colours are passed.
DEFAULT_CAR_COLORS = np.array(
    [
        [0.85, 0.10, 0.10],
        [0.10, 0.35, 0.85],
        [0.95, 0.75, 0.10],
        [0.10, 0.65, 0.25],
        [0.95, 0.45, 0.05],
        [0.55, 0.15, 0.70],
        [0.95, 0.95, 0.95],
        [0.10, 0.10, 0.12],
        [0.10, 0.75, 0.80],
        [0.90, 0.30, 0.60],
        [0.60, 0.60, 0.62],
        [0.45, 0.25, 0.10],
    ]
)

_SKY_ZENITH = (0.24, 0.45, 0.78)
_SKY_HORIZON = (0.78, 0.85, 0.92)
"""Sky colours (0-1); the horizon colour is also the haze colour, so distant scenery fades into the sky."""
_HAZE_CITY_M = 2500.0
_HAZE_PARK_M = 4500.0
"""Distance at which 63 % of a surface's colour is haze: a hazy city, clearer air over a park circuit."""
_VIEW_BYTES = 128
"""std140 size of the shaders' View struct: a mat4 and four vec4."""


class RendererError(RuntimeError):
    """No OpenGL context could be made (no EGL library, no driver): the message names the packages to install."""


_INSTALL_HINT = (
    "The renderer needs a headless EGL OpenGL context (Mesa llvmpipe on a CPU, the GPU vendor's driver on a GPU). "
    "On Debian/Ubuntu install the system packages libegl1 and libgl1-mesa-dri "
    "(`sudo apt-get install libegl1 libgl1-mesa-dri`); a fresh machine or a slim container image may lack them. "
    "Check with `ldconfig -p | grep -E 'libEGL|libGLX_mesa|libgallium'` and "
    "`ls /usr/lib/x86_64-linux-gnu/dri/swrast_dri.so`; GLCONTEXT_DEVICE_INDEX=N picks another EGL device."
)


@dataclass(frozen=True)
class CameraConfig:
    """Where the camera sits on the car and what it sees. ``None`` fields take the preset's value.

    Presets: ``"hood"`` (default: the driver's view from the front of the car, the frames the vision paper learned
    from) and ``"chase"`` (behind and above the car, which is then drawn).
    """

    preset: str = "hood"
    """``hood`` or ``chase``: the values of the fields left ``None``."""
    fov_deg: float | None = None
    """Horizontal field of view (deg); hood 65, chase 70 (racing games use 60-75 at 16:9)."""
    height_m: float | None = None
    """Eye height above the road (m); hood 1.1 (a hatchback's bonnet line), chase 2.4."""
    forward_m: float | None = None
    """Eye position ahead of the car centre along its heading (m); hood 1.3 (above the front axle), chase -6.5."""
    pitch_deg: float | None = None
    """Downward tilt of the view (deg, positive looks down); hood 1.5, chase 9."""
    near_m: float = 0.15
    """Near clip plane, m."""
    far_m: float = 8000.0
    """Far clip plane: past the skyline and hills around every built-in track."""
    draw_own_car: bool | None = None
    """Draw the viewing car's own body; default False for hood, True for chase."""

    _PRESETS = {
        "hood": {"fov_deg": 65.0, "height_m": 1.1, "forward_m": 1.3, "pitch_deg": 1.5, "draw_own_car": False},
        "chase": {"fov_deg": 70.0, "height_m": 2.4, "forward_m": -6.5, "pitch_deg": 9.0, "draw_own_car": True},
    }

    def __post_init__(self) -> None:
        if self.preset not in self._PRESETS:
            raise ValueError(f"camera preset must be one of {sorted(self._PRESETS)}, got {self.preset!r}")
        for key, value in self._PRESETS[self.preset].items():
            if getattr(self, key) is None:
                object.__setattr__(self, key, value)
        if not 10.0 <= self.fov_deg <= 150.0:
            raise ValueError(f"fov_deg must be within 10..150, got {self.fov_deg}")
        if not 0.0 < self.near_m < self.far_m:
            raise ValueError(f"need 0 < near_m < far_m, got {self.near_m}, {self.far_m}")


@dataclass(frozen=True)
class RenderConfig:
    """Output size, antialiasing and batching of a :class:`Renderer`."""

    width_px: int = 470
    """Frame width; 470x280 is the vision paper's network input."""
    height_px: int = 280
    """Frame height."""
    samples: int = 0
    """MSAA samples per pixel (0 = off, 2, 4, 8); 4 samples cost llvmpipe about 2.5x the CPU time per frame."""
    camera: CameraConfig = field(default_factory=CameraConfig)
    """Where the camera sits on each car."""
    max_views: int = 20
    """Views per pass (tiles in one framebuffer); more views in one call run in several passes."""
    trilinear: bool = False
    """Trilinear texture filtering (smooth mip transitions) instead of bilinear on the nearest mip level."""
    anisotropy: float = 1.0
    """Anisotropic texture filtering (1 = off): sharper far road at a cost on llvmpipe."""
    car_draw_distance_m: float = 600.0
    """Other cars farther than this are not drawn (they would be under a pixel)."""
    color_levels: int = 64
    """Levels per colour channel of the output (256 = all of uint8). The last two bits of a shaded colour are
    rounding noise of filtering, haze and lighting, not information about the scene, and a compressor pays for
    them: 64 levels (6 bits) halve a compressed 470x280 frame (zstd level 3, median of 100 views on expressway /
    technical / flowing: 86 / 69 / 47 kB at 256 levels, 43 / 34 / 23 kB at 64) with no visible banding in the sky."""

    def __post_init__(self) -> None:
        if not (16 <= self.width_px <= MAX_WIDTH_PX and 16 <= self.height_px <= MAX_HEIGHT_PX):
            raise ValueError(
                f"frame size must be within 16x16..{MAX_WIDTH_PX}x{MAX_HEIGHT_PX}, got {self.width_px}x{self.height_px}"
            )
        if self.samples not in (0, 2, 4, 8, 16):
            raise ValueError(f"samples must be 0 (off), 2, 4, 8 or 16, got {self.samples}")
        if self.max_views < 1:
            raise ValueError(f"max_views must be >= 1, got {self.max_views}")
        if not 2 <= self.color_levels <= 256:
            raise ValueError(f"color_levels must be within 2..256, got {self.color_levels}")

    @property
    def aspect(self) -> float:
        return self.width_px / self.height_px


# ------------------------------------------------------------------------------------------------ context
def _is_software(ctx) -> bool:
    name = ctx.info.get("GL_RENDERER", "").lower()
    return any(k in name for k in ("llvmpipe", "softpipe", "swrast", "lavapipe"))


def create_context(device_index: int | None = None):
    """A headless moderngl EGL context (GL 3.3+). The first hardware EGL device wins, llvmpipe otherwise.

    ``device_index`` (or the environment variable GLCONTEXT_DEVICE_INDEX) picks an EGL device explicitly.
    Raises :class:`RendererError` naming the system packages to install when no context can be made.
    """
    try:
        import moderngl
    except ImportError as exc:  # pragma: no cover - moderngl is a dependency of the render layer
        raise RendererError(f"moderngl is not installed ({exc}). {_INSTALL_HINT}") from exc
    if device_index is None and os.environ.get("GLCONTEXT_DEVICE_INDEX"):
        device_index = int(os.environ["GLCONTEXT_DEVICE_INDEX"])
    errors = []
    if device_index is not None:
        candidates = [device_index]
    else:
        candidates = list(range(8))
    software = None
    for index in candidates:
        try:
            ctx = moderngl.create_standalone_context(backend="egl", require=330, device_index=index)
        except Exception as exc:  # glcontext raises bare Exceptions
            errors.append(f"device {index}: {exc}")
            if "found" in str(exc) and "devices" in str(exc):
                break  # past the last device
            continue
        if device_index is not None or not _is_software(ctx):
            if software is not None:
                software.release()
            return ctx
        if software is None:
            software = ctx
        else:
            ctx.release()
    if software is not None:
        return software
    raise RendererError(f"Could not create a headless OpenGL (EGL) context: {'; '.join(errors)}. {_INSTALL_HINT}")


# ------------------------------------------------------------------------------------------------ shaders
_HEADER = """
#version 330
out float gl_ClipDistance[4];
struct View {
    mat4 view_proj;
    vec4 eye;      // camera position (m, scene frame)
    vec4 fwd;      // unit viewing direction
    vec4 right_t;  // right vector scaled by tan(horizontal half fov): the ray through ndc x = 1 is fwd + right_t
    vec4 up_t;     // up vector scaled by tan(vertical half fov)
};
layout(std140) uniform Views { View u_views[MAX_VIEWS]; };
uniform vec2 u_tile_scale;   // tile size / framebuffer size, in x and y
uniform int u_tile_rows;     // tiles per column (tiles are laid out column by column)

// Map a view's clip position into its tile of the shared framebuffer; clip distances keep it inside.
vec4 to_tile(vec4 clip, int tile) {
    gl_ClipDistance[0] = clip.w + clip.x;
    gl_ClipDistance[1] = clip.w - clip.x;
    gl_ClipDistance[2] = clip.w + clip.y;
    gl_ClipDistance[3] = clip.w - clip.y;
    int col = tile / u_tile_rows;
    int row = tile - col * u_tile_rows;
    // y is flipped so that the image's top row comes first in memory (no flip after read-back).
    return vec4(clip.x * u_tile_scale.x + clip.w * ((2.0 * float(col) + 1.0) * u_tile_scale.x - 1.0),
                -clip.y * u_tile_scale.y + clip.w * ((2.0 * float(row) + 1.0) * u_tile_scale.y - 1.0),
                clip.z, clip.w);
}
"""

_FOG_GLSL = """
uniform vec3 u_fog_color;
uniform float u_fog_inv_m;   // 1 / haze distance (m): 63 % of the colour is haze at that distance
float haze(float distance_m) {
    return 1.0 - exp(-distance_m * u_fog_inv_m);
}
"""

_STATIC_VS = """
in vec3 in_pos;
in vec2 in_uv;
in float in_layer;
in vec3 in_tint;
in float in_label;
in float in_view;
out vec2 v_uv;
flat out float v_layer;
out vec4 v_tint_haze;
flat out float v_label;
void main() {
    int view = int(in_view);
    vec4 clip = u_views[view].view_proj * vec4(in_pos, 1.0);
    v_uv = in_uv;
    v_layer = in_layer;
    // Haze per vertex: it varies slowly over the <= 10 m between vertices and saves an exp per pixel.
    v_tint_haze = vec4(in_tint, haze(clip.w));
    v_label = in_label;
    gl_Position = to_tile(clip, view);
}
"""

_STATIC_FS = """
uniform sampler2DArray u_tex;
in vec2 v_uv;
flat in float v_layer;
in vec4 v_tint_haze;
flat in float v_label;
out vec4 f_color;
void main() {
#ifdef LABELS
    f_color = vec4(v_label / 255.0, 0.0, 0.0, 1.0);
#else
    vec3 c = texture(u_tex, vec3(v_uv, v_layer)).rgb * v_tint_haze.rgb;
    f_color = game_color(mix(c, u_fog_color, v_tint_haze.w));
#endif
}
"""

_CAR_VS = """
uniform vec3 u_sun;
in vec3 in_pos;
in vec3 in_normal;
in float in_part;
in float in_view;
in vec3 in_pose;   // x (m), y (m), yaw (rad) in the scene frame
in vec3 in_color;
out vec4 v_color_haze;
flat out float v_label;
void main() {
    float c = cos(in_pose.z), s = sin(in_pose.z);
    vec3 p = vec3(in_pose.x + c * in_pos.x - s * in_pos.y, in_pose.y + s * in_pos.x + c * in_pos.y, in_pos.z);
    vec3 n = vec3(c * in_normal.x - s * in_normal.y, s * in_normal.x + c * in_normal.y, in_normal.z);
    float light = 0.55 + 0.45 * max(dot(n, u_sun), 0.0);
    int part = int(in_part + 0.5);
    vec3 base = in_color;
    if (part == 1) base = vec3(0.10, 0.13, 0.17) + 0.25 * max(n.z, 0.0);    // glass reflects the sky
    else if (part == 2) base = vec3(0.06, 0.06, 0.07);                         // tyres
    else if (part == 3) base = vec3(0.95, 0.08, 0.06) / 0.75;                  // tail lights glow
    vec3 color = (part == 4) ? vec3(0.14, 0.14, 0.15) : base * light;         // blob shadow
    v_label = (part == 4) ? float(ROAD_LABEL) : float(CAR_LABEL);
    int view = int(in_view);
    vec4 clip = u_views[view].view_proj * vec4(p, 1.0);
    v_color_haze = vec4(color, haze(clip.w));
    gl_Position = to_tile(clip, view);
}
"""

_CAR_FS = """
in vec4 v_color_haze;
flat in float v_label;
out vec4 f_color;
void main() {
#ifdef LABELS
    f_color = vec4(v_label / 255.0, 0.0, 0.0, 1.0);
#else
    f_color = game_color(mix(v_color_haze.rgb, u_fog_color, v_color_haze.w));
#endif
}
"""

_BACKGROUND_VS = """
in vec2 in_ndc;
in float in_view;
out vec3 v_dir;
flat out vec3 v_eye;
void main() {
    int view = int(in_view);
    // The ray direction is linear in screen position, so interpolating it across the quad is exact.
    v_dir = u_views[view].fwd.xyz + in_ndc.x * u_views[view].right_t.xyz + in_ndc.y * u_views[view].up_t.xyz;
    v_eye = u_views[view].eye.xyz;
    // z = w: the far plane, so the background only fills what nothing else covered (depth test <=).
    gl_Position = to_tile(vec4(in_ndc, 1.0, 1.0), view);
}
"""

_GROUND_FS = """
uniform sampler2DArray u_tex;
uniform float u_ground_layer;
uniform float u_ground_tile_inv_m;
uniform float u_ground_z_m;
in vec3 v_dir;
flat in vec3 v_eye;
out vec4 f_color;
void main() {
#ifdef LABELS
    f_color = vec4(float(GROUND_LABEL) / 255.0, 0.0, 0.0, 1.0);
#else
    // Infinite ground plane: where the eye ray meets it.
    float t = (u_ground_z_m - v_eye.z) / min(v_dir.z, -1e-6);
    vec2 p = v_eye.xy + t * v_dir.xy;
    vec3 ground = texture(u_tex, vec3(p * u_ground_tile_inv_m, u_ground_layer)).rgb;
    f_color = game_color(mix(ground, u_fog_color, haze(t * length(v_dir))));
#endif
}
"""

_SKY_FS = """
uniform vec3 u_zenith;
in vec3 v_dir;
out vec4 f_color;
void main() {
#ifdef LABELS
    f_color = vec4(float(SKY_LABEL) / 255.0, 0.0, 0.0, 1.0);
#else
    float sin_elevation = v_dir.z / length(v_dir);
    f_color = game_color(mix(u_fog_color, u_zenith, sqrt(clamp(sin_elevation / 0.8, 0.0, 1.0))));
#endif
}
"""


def _vs(body: str, max_views: int) -> str:
    header = _HEADER.replace("MAX_VIEWS", str(max_views))
    return header + f"#define ROAD_LABEL {int(Label.ROAD)}\n#define CAR_LABEL {int(Label.CAR)}\n" + _FOG_GLSL + body


_COLOR_GLSL = """
// Every colour is rounded to COLOR_LEVELS levels per channel (RenderConfig.color_levels) as it is written.
vec4 game_color(vec3 c) {
    return vec4(floor(clamp(c, 0.0, 1.0) * (COLOR_LEVELS - 1.0) + 0.5) / (COLOR_LEVELS - 1.0), 1.0);
}
"""


def _fs(body: str, labels: bool, color_levels: int = 256) -> str:
    defines = f"#define GROUND_LABEL {int(Label.GROUND)}\n#define SKY_LABEL {int(Label.SKY)}\n"
    defines += f"#define COLOR_LEVELS {float(color_levels):.1f}\n"
    if labels:
        defines += "#define LABELS\n"
    return "#version 330\n" + defines + _FOG_GLSL + _COLOR_GLSL + body


# ------------------------------------------------------------------------------------------------ renderer
def _as_track(track: Track | str) -> Track:
    if isinstance(track, Track):
        return track
    from vision_rl.sim import track_library  # a name, random:SEED or a CSV path

    return track_library.load_track(track)


class Renderer:
    """Renders the driver's view of cars on one track (uint8 RGB frames), batched over views.

    Example::

        with Renderer(load_track("expressway")) as r:
            frames = r.render(x_m, y_m, yaw_rad)          # (n_cars, 280, 470, 3) uint8

    Cars are drawn as coloured bodies; with ``groups`` a viewer sees only cars of its own collision group (the
    time-trial cars of one world are ghosts to each other). Frames are a pure function of the arguments.
    """

    def __init__(
        self,
        track: Track | str,
        config: RenderConfig | None = None,
        car_length_m: float = 4.1,
        car_width_m: float = 1.7,
        device_index: int | None = None,
    ) -> None:
        self.track = _as_track(track)
        self.config = config or RenderConfig()
        self.car_length_m = float(car_length_m)
        self.car_width_m = float(car_width_m)
        self._ctx = None
        self.scene: Scene = build_scene(self.track)
        ctx = create_context(device_index)
        self._ctx = ctx
        try:
            with ctx:
                self._setup(ctx)
        except Exception:
            self.close()
            raise

    # -------------------------------------------------------------- set-up
    def _setup(self, ctx) -> None:
        """Everything a render needs on the GPU, made once: framebuffers, textures, buffers and programs."""
        self._layout_tiles(ctx)
        self._make_framebuffers(ctx)
        self._make_texture(ctx)
        # Per-view data (uniform block of View structs, 128 bytes each) and a view index per instance.
        self._views_ubo = ctx.buffer(reserve=_VIEW_BYTES * self.config.max_views)
        view_index = ctx.buffer(np.arange(self.config.max_views, dtype=np.float32).tobytes())
        self._make_mesh_buffers(ctx)
        self._make_background_quads(ctx)
        self._make_programs(ctx, view_index)

    def _layout_tiles(self, ctx) -> None:
        """Rows and columns of view tiles in the shared framebuffer, checked against this device's limits."""
        cfg = self.config
        h, w = cfg.height_px, cfg.width_px
        max_size = min(int(ctx.info["GL_MAX_RENDERBUFFER_SIZE"]), *map(int, ctx.info["GL_MAX_VIEWPORT_DIMS"]))
        rows = max(1, min(cfg.max_views, max_size // h))
        cols = math.ceil(cfg.max_views / rows)
        rows = math.ceil(cfg.max_views / cols)
        if cols * w > max_size:
            raise ValueError(f"max_views={cfg.max_views} frames of {w}x{h} do not fit in a {max_size}px framebuffer")
        max_block = int(ctx.info.get("GL_MAX_UNIFORM_BLOCK_SIZE", 16384))
        if cfg.max_views * _VIEW_BYTES > max_block:
            raise ValueError(f"max_views={cfg.max_views} exceeds this GL device's {max_block // _VIEW_BYTES} views")
        self._rows, self._cols = rows, cols
        self._fb_size = (cols * w, rows * h)  # moderngl takes sizes as (width, height)
        if cfg.samples > int(ctx.info.get("GL_MAX_SAMPLES", 0)):
            raise ValueError(f"samples={cfg.samples} exceeds this GL device's maximum {ctx.info.get('GL_MAX_SAMPLES')}")

    def _make_framebuffers(self, ctx) -> None:
        """Colour (+ optional MSAA with a resolve target) and a plain one for the label pass."""
        samples = self.config.samples
        self._label_fbo = ctx.framebuffer(
            color_attachments=[ctx.renderbuffer(self._fb_size, components=4)],
            depth_attachment=ctx.depth_renderbuffer(self._fb_size),
        )
        if samples:
            self._fbo = ctx.framebuffer(
                color_attachments=[ctx.renderbuffer(self._fb_size, components=4, samples=samples)],
                depth_attachment=ctx.depth_renderbuffer(self._fb_size, samples=samples),
            )
            self._msaa = True
        else:
            self._fbo = self._label_fbo
            self._msaa = False
        # MSAA resolve targets, one per used region size: resolving only the tiles drawn, not the whole framebuffer.
        self._resolve_fbos = {}

    def _make_texture(self, ctx) -> None:
        """One mipmapped texture array, one layer per surface."""
        import moderngl

        cfg = self.config
        layers = build_texture_layers()
        # RGBA8, the format every GL driver stores and samples natively.
        rgba = np.concatenate([layers, np.full((*layers.shape[:3], 1), 255, np.uint8)], axis=3)
        tex = ctx.texture_array((TEXTURE_SIZE_PX, TEXTURE_SIZE_PX, len(layers)), 4, rgba.tobytes())
        tex.build_mipmaps()
        # Bilinear within the nearest mip level by default: trilinear costs llvmpipe about 1.5x per textured pixel.
        tex.filter = (
            moderngl.LINEAR_MIPMAP_LINEAR if cfg.trilinear else moderngl.LINEAR_MIPMAP_NEAREST,
            moderngl.LINEAR,
        )
        tex.repeat_x = tex.repeat_y = True
        if cfg.anisotropy > 1.0:
            tex.anisotropy = cfg.anisotropy
        self._tex = tex

    def _make_mesh_buffers(self, ctx) -> None:
        """The static scene's vertices, indices and draw commands, and the car body mesh with its instances."""
        scene = self.scene
        self._vbo = ctx.buffer(scene.vertices.tobytes())
        self._ibo = ctx.buffer(scene.indices.tobytes())
        self._cmd = ctx.buffer(reserve=max(1, self.config.max_views * scene.n_chunks) * 20)
        car_v, car_i = build_car_mesh(self.car_length_m, self.car_width_m)
        self._car_vbo = ctx.buffer(car_v.tobytes())
        self._car_ibo = ctx.buffer(car_i.tobytes())
        self._car_inst_capacity = 64
        self._car_inst = ctx.buffer(reserve=7 * 4 * self._car_inst_capacity)

    def _make_background_quads(self, ctx) -> None:
        """Background quads of every tile: the sky above the horizon row, the ground below it."""
        cfg = self.config
        cam = cfg.camera
        self._tan_half_fovx = math.tan(math.radians(cam.fov_deg) / 2.0)
        self._tan_half_fovy = self._tan_half_fovx / cfg.aspect
        # With no roll the horizon is the same row in every view: ndc y = tan(pitch) / tan(vertical half fov).
        horizon = float(np.clip(math.tan(math.radians(cam.pitch_deg)) / self._tan_half_fovy, -1.0, 1.0))
        quads = np.array(
            [
                [-1, horizon],
                [1, horizon],
                [1, 1],
                [-1, horizon],
                [1, 1],
                [-1, 1],
                [-1, -1],
                [1, -1],
                [1, horizon],
                [-1, -1],
                [1, horizon],
                [-1, horizon],
            ],
            "f4",
        )
        self._quad_vbo = ctx.buffer(quads.tobytes())

    def _make_programs(self, ctx, view_index) -> None:
        """The colour and label programs of the static mesh, the cars, the sky and the ground, and their vertex
        arrays."""
        cfg = self.config

        def fs(body: str, labels: bool) -> str:
            return _fs(body, labels, cfg.color_levels)

        self._vaos = {}
        for labels in (False, True):
            static = ctx.program(vertex_shader=_vs(_STATIC_VS, cfg.max_views), fragment_shader=fs(_STATIC_FS, labels))
            car = ctx.program(vertex_shader=_vs(_CAR_VS, cfg.max_views), fragment_shader=fs(_CAR_FS, labels))
            sky = ctx.program(vertex_shader=_vs(_BACKGROUND_VS, cfg.max_views), fragment_shader=fs(_SKY_FS, labels))
            ground = ctx.program(
                vertex_shader=_vs(_BACKGROUND_VS, cfg.max_views), fragment_shader=fs(_GROUND_FS, labels)
            )
            for prog in (static, car, sky, ground):
                self._set_uniforms(prog)
            self._vaos[labels] = self._vertex_arrays(ctx, view_index, static, car, sky, ground)

    def _vertex_arrays(self, ctx, view_index, static, car, sky, ground) -> tuple:
        """(static, car, sky, ground) vertex arrays of one set of programs."""
        # skip_errors: the label and colour programs each leave some attributes unused.
        static_vao = ctx.vertex_array(
            static,
            [
                (self._vbo, "3f 2f 1f 3f 1f", "in_pos", "in_uv", "in_layer", "in_tint", "in_label"),
                (view_index, "1f/i", "in_view"),
            ],
            index_buffer=self._ibo,
            index_element_size=4,
            skip_errors=True,
        )
        car_vao = ctx.vertex_array(
            car,
            [
                (self._car_vbo, "3f 3f 1f", "in_pos", "in_normal", "in_part"),
                (self._car_inst, "1f 3f 3f/i", "in_view", "in_pose", "in_color"),
            ],
            index_buffer=self._car_ibo,
            index_element_size=4,
            skip_errors=True,
        )
        sky_vao, ground_vao = (
            ctx.vertex_array(
                prog, [(self._quad_vbo, "2f", "in_ndc"), (view_index, "1f/i", "in_view")], skip_errors=True
            )
            for prog in (sky, ground)
        )
        return static_vao, car_vao, sky_vao, ground_vao

    def _set_uniforms(self, prog) -> None:
        values = {
            "u_tile_scale": (1.0 / self._cols, 1.0 / self._rows),
            "u_tile_rows": self._rows,
            "u_fog_color": _SKY_HORIZON,
            "u_fog_inv_m": 1.0 / (_HAZE_CITY_M if self.scene.city else _HAZE_PARK_M),
            "u_tex": 0,
            "u_sun": tuple(float(v) for v in SUN_DIR),
            "u_ground_layer": float(self.scene.ground_layer),
            "u_ground_tile_inv_m": 1.0 / self.scene.ground_tile_m,
            "u_ground_z_m": GROUND_Z_M,
            "u_zenith": _SKY_ZENITH,
        }
        for name, value in values.items():
            if name in prog:  # uniforms a program does not use are compiled away
                prog[name].value = value
        if "Views" in prog:
            prog["Views"].binding = 0

    # -------------------------------------------------------------- public API
    @property
    def gl_renderer(self) -> str:
        """The OpenGL renderer string (e.g. 'llvmpipe (LLVM 15.0.6, 256 bits)' or the GPU's name)."""
        return self._ctx.info["GL_RENDERER"] if self._ctx is not None else ""

    @property
    def n_static_triangles(self) -> int:
        return self.scene.n_triangles

    def render(
        self,
        x_m: np.ndarray,
        y_m: np.ndarray,
        yaw_rad: np.ndarray,
        view_ids: np.ndarray | None = None,
        groups: np.ndarray | None = None,
        car_colors: np.ndarray | None = None,
    ) -> np.ndarray:
        """The view of each car in ``view_ids`` (default: all cars): uint8 (n_views, height_px, width_px, 3).

        Args:
            x_m, y_m, yaw_rad: poses of all cars (n_cars,), world frame (yaw counter-clockwise from +x).
            view_ids: indices of the cars whose camera renders, in output order (repeats allowed).
            groups: collision group per car (n_cars,); a viewer sees only cars of its own group. None: all cars.
            car_colors: body colours (n_cars, 3), floats in [0, 1] or uint8; default a fixed palette by index.
        """
        return self._render(x_m, y_m, yaw_rad, view_ids, groups, car_colors, labels=False)

    def render_labels(
        self,
        x_m: np.ndarray,
        y_m: np.ndarray,
        yaw_rad: np.ndarray,
        view_ids: np.ndarray | None = None,
        groups: np.ndarray | None = None,
    ) -> np.ndarray:
        """Segmentation of the same views: uint8 (n_views, H, W) class ids of :class:`Label` (sky, road, wall, ...)."""
        return self._render(x_m, y_m, yaw_rad, view_ids, groups, None, labels=True)

    def close(self) -> None:
        """Release the GL context and everything in it (idempotent)."""
        if self._ctx is not None:
            self._ctx.release()  # destroys the EGL context and every GL object in it
            self._ctx = None

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - best effort at interpreter shutdown
        try:
            self.close()
        except Exception:
            pass

    # -------------------------------------------------------------- internals
    def _check_inputs(self, x_m, y_m, yaw_rad, view_ids, groups, car_colors):
        x = np.atleast_1d(np.asarray(x_m, dtype=np.float64))
        y = np.atleast_1d(np.asarray(y_m, dtype=np.float64))
        yaw = np.atleast_1d(np.asarray(yaw_rad, dtype=np.float64))
        n = len(x)
        if x.ndim != 1 or y.shape != (n,) or yaw.shape != (n,):
            raise ValueError(
                f"x_m, y_m, yaw_rad must be 1-D arrays of one length, got {x.shape}, {y.shape}, {yaw.shape}"
            )
        if not (np.isfinite(x).all() and np.isfinite(y).all() and np.isfinite(yaw).all()):
            raise ValueError("car poses must be finite")
        views = np.arange(n) if view_ids is None else np.atleast_1d(np.asarray(view_ids, dtype=np.int64))
        if views.ndim != 1 or (len(views) and (views.min() < 0 or views.max() >= n)):
            raise ValueError(f"view_ids must be car indices in 0..{n - 1}, got {views}")
        if groups is not None:
            groups = np.asarray(groups)
            if groups.shape != (n,):
                raise ValueError(f"groups must have shape ({n},), got {groups.shape}")
        if car_colors is None:
            colors = DEFAULT_CAR_COLORS[np.arange(n) % len(DEFAULT_CAR_COLORS)]
        else:
            c = np.asarray(car_colors)
            if c.shape != (n, 3):
                raise ValueError(f"car_colors must have shape ({n}, 3), got {c.shape}")
            colors = c / 255.0 if np.issubdtype(c.dtype, np.integer) else c.astype(np.float64)
        return x, y, yaw, views, groups, colors

    def _render(self, x_m, y_m, yaw_rad, view_ids, groups, car_colors, labels: bool) -> np.ndarray:
        if self._ctx is None:
            raise RendererError("this Renderer is closed")
        x, y, yaw, views, groups, colors = self._check_inputs(x_m, y_m, yaw_rad, view_ids, groups, car_colors)
        cfg = self.config
        h, w = cfg.height_px, cfg.width_px
        shape = (len(views), h, w) if labels else (len(views), h, w, 3)
        if len(views) == 0:
            return np.zeros(shape, dtype=np.uint8)
        x = x - self.scene.origin_xy_m[0]
        y = y - self.scene.origin_xy_m[1]
        parts = []
        # Make this renderer's context current for the call (several renderers may live in one thread).
        with self._ctx:
            for start in range(0, len(views), cfg.max_views):
                parts.append(self._render_pass(x, y, yaw, views[start : start + cfg.max_views], groups, colors, labels))
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def _cameras(self, x, y, yaw):
        """Eye positions (v, 3), basis vectors right/up/forward (v, 3) and view-projection matrices (v, 4, 4)."""
        cam = self.config.camera
        pitch = math.radians(cam.pitch_deg)
        cy, sy = np.cos(yaw), np.sin(yaw)
        cp, sp = math.cos(pitch), math.sin(pitch)
        eye = np.stack([x + cam.forward_m * cy, y + cam.forward_m * sy, np.full_like(x, cam.height_m)], axis=1)
        fwd = np.stack([cy * cp, sy * cp, np.full_like(x, -sp)], axis=1)
        right = np.stack([sy, -cy, np.zeros_like(x)], axis=1)
        up = np.stack([cy * sp, sy * sp, np.full_like(x, cp)], axis=1)
        view = np.zeros((len(x), 4, 4))
        view[:, 0, :3], view[:, 1, :3], view[:, 2, :3] = right, up, -fwd
        view[:, 0, 3] = -np.einsum("vk,vk->v", right, eye)
        view[:, 1, 3] = -np.einsum("vk,vk->v", up, eye)
        view[:, 2, 3] = np.einsum("vk,vk->v", fwd, eye)
        view[:, 3, 3] = 1.0
        n, f = cam.near_m, cam.far_m
        proj = np.zeros((4, 4))
        proj[0, 0] = 1.0 / self._tan_half_fovx
        proj[1, 1] = 1.0 / self._tan_half_fovy
        proj[2, 2] = (f + n) / (n - f)
        proj[2, 3] = 2.0 * f * n / (n - f)
        proj[3, 2] = -1.0
        return eye, right, up, fwd, proj[None] @ view

    def _frustum_planes(self, right, up, fwd):
        """Inward normals (v, 5, 3) of the left, right, bottom, top and near planes (all through the eye)."""
        ax = math.atan(self._tan_half_fovx)
        ay = math.atan(self._tan_half_fovy)
        ca, sa, cb, sb = math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay)
        return np.stack(
            [ca * right + sa * fwd, -ca * right + sa * fwd, cb * up + sb * fwd, -cb * up + sb * fwd, fwd], axis=1
        )

    def _static_commands(self, eye, planes) -> np.ndarray:
        """Indirect draw commands (k, 5) uint32: runs of consecutive visible chunks per view."""
        scene = self.scene
        rel = scene.chunk_centre_m[None, :, :] - eye[:, None, :]  # (v, c, 3)
        dist = np.einsum("vpk,vck->vcp", planes, rel)  # (v, c, 5)
        visible = (dist > -scene.chunk_radius_m[None, :, None]).all(axis=2)
        visible &= np.linalg.norm(rel, axis=2) - scene.chunk_radius_m[None, :] < self.config.camera.far_m
        padded = np.pad(visible, ((0, 0), (1, 1)))
        starts = np.nonzero(padded[:, 1:-1] & ~padded[:, :-2])
        ends = np.nonzero(padded[:, 1:-1] & ~padded[:, 2:])
        first = scene.chunk_first[starts[1]]
        last_end = scene.chunk_first[ends[1]] + scene.chunk_count[ends[1]]
        cmd = np.empty((len(first), 5), dtype=np.uint32)
        cmd[:, 0] = last_end - first
        cmd[:, 1] = 1
        cmd[:, 2] = first
        cmd[:, 3] = 0
        cmd[:, 4] = starts[0]  # baseInstance = the view's tile
        return cmd

    def _car_instances(self, x, y, yaw, views, groups, colors, eye, planes) -> np.ndarray:
        """Instance rows (k, 7) float32: tile, x, y, yaw, r, g, b for every car drawn in some view."""
        cam = self.config.camera
        n = len(x)
        rel = np.stack([x, y, np.full(n, 0.7)], axis=1)[None, :, :] - eye[:, None, :]  # (v, n, 3)
        radius = 0.5 * math.hypot(self.car_length_m, self.car_width_m) + 0.5
        dist = np.einsum("vpk,vnk->vnp", planes, rel)
        mask = (dist > -radius).all(axis=2) & (np.linalg.norm(rel, axis=2) < self.config.car_draw_distance_m)
        if groups is not None:
            mask &= groups[views][:, None] == groups[None, :]
        if not cam.draw_own_car:
            mask[np.arange(len(views)), views] = False
        tile, car = np.nonzero(mask)
        inst = np.empty((len(tile), 7), dtype=np.float32)
        inst[:, 0] = tile
        inst[:, 1] = x[car]
        inst[:, 2] = y[car]
        inst[:, 3] = yaw[car]
        inst[:, 4:7] = colors[car]
        return inst

    def _view_block(self, eye, right, up, fwd, vp) -> bytes:
        """The Views uniform block for these cameras (std140: mat4 column-major, then four vec4)."""
        v = len(eye)
        block = np.zeros((v, _VIEW_BYTES // 4), dtype=np.float32)
        block[:, 0:16] = vp.transpose(0, 2, 1).reshape(v, 16)
        block[:, 16:19] = eye
        block[:, 20:23] = fwd
        block[:, 24:27] = right * self._tan_half_fovx
        block[:, 28:31] = up * self._tan_half_fovy
        return block.tobytes()

    def _render_pass(self, x, y, yaw, views, groups, colors, labels: bool) -> np.ndarray:
        import moderngl

        ctx = self._ctx
        cfg = self.config
        v = len(views)
        eye, right, up, fwd, vp = self._cameras(x[views], y[views], yaw[views])
        self._views_ubo.write(self._view_block(eye, right, up, fwd, vp))
        planes = self._frustum_planes(right, up, fwd)
        cmd = self._static_commands(eye, planes)
        inst = self._car_instances(x, y, yaw, views, groups, colors, eye, planes)
        if len(inst) > self._car_inst_capacity:
            self._car_inst_capacity = 1 << math.ceil(math.log2(len(inst)))
            self._car_inst.orphan(self._car_inst_capacity * 7 * 4)
        if len(inst):
            self._car_inst.write(inst.tobytes())
        if len(cmd):
            self._cmd.write(cmd.tobytes())

        fbo = self._label_fbo if labels else self._fbo
        used_cols = math.ceil(v / self._rows)
        used_rows = min(v, self._rows)
        region = (0, 0, used_cols * cfg.width_px, used_rows * cfg.height_px)
        # Depth only: the background pass writes every pixel's colour.
        # (moderngl applies a framebuffer's colour mask when it is bound.)
        fbo.color_mask = (False, False, False, False)
        fbo.use()
        fbo.clear(depth=1.0, viewport=region)
        fbo.color_mask = (True, True, True, True)
        fbo.use()
        ctx.viewport = (0, 0, *self._fb_size)
        ctx.enable_only(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        # Faces are wound counter-clockwise seen from outside; the y flip into the tile makes that clockwise.
        ctx.front_face = "cw"
        ctx.cull_face = "back"
        for i in range(4):
            ctx.enable_direct(_GL_CLIP_DISTANCE0 + i)
        ctx.depth_func = "<"
        self._views_ubo.bind_to_uniform_block(0)
        self._tex.use(0)
        static_vao, car_vao, sky_vao, ground_vao = self._vaos[labels]
        if len(cmd):
            static_vao.render_indirect(self._cmd, moderngl.TRIANGLES, count=len(cmd))
        if len(inst):
            car_vao.render(moderngl.TRIANGLES, instances=len(inst))
        # Sky and ground last: only the pixels nothing else covered are shaded.
        ctx.depth_func = "<="
        sky_vao.render(moderngl.TRIANGLES, vertices=6, first=0, instances=v)
        ground_vao.render(moderngl.TRIANGLES, vertices=6, first=6, instances=v)
        ctx.depth_func = "<"
        read_fbo = self._label_fbo
        if self._msaa and not labels:
            size = (region[2], region[3])
            if size not in self._resolve_fbos:
                self._resolve_fbos[size] = ctx.framebuffer(color_attachments=[ctx.renderbuffer(size, components=4)])
            read_fbo = self._resolve_fbos[size]
            ctx.copy_framebuffer(read_fbo, self._fbo)  # blits the lower-left region of that size: our tiles
        components = 1 if labels else 3
        buf = bytearray(region[2] * region[3] * components)
        read_fbo.read_into(buf, viewport=region, components=components, alignment=1)
        img = np.frombuffer(buf, dtype=np.uint8)
        h, w = cfg.height_px, cfg.width_px
        if used_cols == 1:
            out = img.reshape(v, h, w, components)
        else:
            grid = img.reshape(used_rows, h, used_cols, w, components).transpose(2, 0, 1, 3, 4)
            out = np.ascontiguousarray(grid.reshape(used_rows * used_cols, h, w, components)[:v])
        return out[..., 0] if labels else out
