"""The offscreen renderer: determinism, geometry seen from the camera, batching, groups, sizes and errors."""

import numpy as np
import pytest

from vision_rl.render import LABEL_NAMES, CameraConfig, Label, RenderConfig, Renderer, RendererError, labels_to_rgb
from vision_rl.render.scene import _inside_other_branch, build_car_mesh, build_scene
from vision_rl.render.textures import Layer, build_texture_layers
from vision_rl.sim.track import Track

W, H = 470, 280


@pytest.fixture(scope="module")
def wide(gl_available, wide_circle):
    with Renderer(wide_circle) as r:
        yield r


@pytest.fixture(scope="module")
def chase(gl_available, wide_circle):
    with Renderer(wide_circle, RenderConfig(camera=CameraConfig(preset="chase"))) as r:
        yield r


def poses(track, s_m, lateral_m):
    s = np.asarray(s_m, dtype=float)
    xy = track.position_at(s, np.asarray(lateral_m, dtype=float))
    return xy[:, 0], xy[:, 1], track.heading_at(s)


# ------------------------------------------------------------------------------------------------ determinism
def test_same_state_same_pixels_across_calls_and_instances(wide, wide_circle):
    x, y, yaw = poses(wide_circle, [50.0, 400.0, 1200.0], [0.0, 3.0, -8.0])
    first = wide.render(x, y, yaw)
    assert np.array_equal(first, wide.render(x, y, yaw))
    with Renderer(wide_circle) as other:
        assert np.array_equal(first, other.render(x, y, yaw))
    # ...and the frames depend on the state: moving one ghost car 1 m changes its own view, not the others'.
    ghosts = np.arange(3)
    before = wide.render(x, y, yaw, groups=ghosts)
    moved = wide.render(x + np.array([0.0, 1.0, 0.0]), y, yaw, groups=ghosts)
    assert np.array_equal(moved[0], before[0]) and not np.array_equal(moved[1], before[1])


# ------------------------------------------------------------------------------------------------ geometry
@pytest.mark.parametrize("side", [1.0, -1.0])
def test_car_hugging_a_wall_sees_it_on_that_side_only(wide, wide_circle, side):
    # The car body's edge is 0.15 m from the wall (half width 0.85 m); the other wall is 58 m away.
    x, y, yaw = poses(wide_circle, [100.0], [side * (30.0 - 1.0)])
    wall = wide.render_labels(x, y, yaw)[0] == Label.WALL
    near, far = (wall[:, : W // 3], wall[:, -W // 3 :]) if side > 0 else (wall[:, -W // 3 :], wall[:, : W // 3])
    assert near.mean() > 0.3
    assert far.mean() < 0.03


def test_image_is_upright_sky_on_top_road_at_the_bottom(wide, wide_circle):
    x, y, yaw = poses(wide_circle, [10.0], [0.0])
    labels = wide.render_labels(x, y, yaw)[0]
    assert np.isin(labels[0], [Label.SKY, Label.LANDMARK]).all()
    assert (labels[0] == Label.SKY).mean() > 0.5
    assert (labels[-1] == Label.ROAD).mean() > 0.9
    rgb = wide.render(x, y, yaw)[0].astype(int)
    assert (rgb[0, :, 2] > rgb[0, :, 0] + 30).mean() > 0.5  # blue sky above
    road = rgb[-1, W // 4 : 3 * W // 4]
    assert (np.abs(road[:, 0] - road[:, 2]) < 20).all() and road.mean() < 140  # grey asphalt below


def test_kerbs_in_tight_corners_not_on_gentle_curves(gl_available, tight_circle, wide, wide_circle):
    with Renderer(tight_circle) as tight:
        x, y, yaw = poses(tight_circle, [10.0], [0.0])
        assert (tight.render_labels(x, y, yaw)[0] == Label.KERB).mean() > 0.01
    x, y, yaw = poses(wide_circle, [10.0], [0.0])
    assert not (wide.render_labels(x, y, yaw)[0] == Label.KERB).any()


def test_start_gantry_ahead_is_visible_and_not_from_the_far_side(wide, wide_circle):
    length = wide_circle.length_m
    x, y, yaw = poses(wide_circle, [length - 40.0, 0.5 * length], [0.0, 0.0])
    labels = wide.render_labels(x, y, yaw)
    assert (labels[0] == Label.GANTRY).sum() > 500
    assert not (labels[1] == Label.GANTRY).any()


def test_wall_pattern_changes_along_the_track(wide, wide_circle):
    """The wall's panels/stripes repeat every few metres: 1.5 m of travel changes the wall's pixels."""
    x, y, yaw = poses(wide_circle, [100.0, 101.5], [29.0, 29.0])
    frames = wide.render(x, y, yaw)
    wall = wide.render_labels(x, y, yaw)[0] == Label.WALL
    diff = np.abs(frames[0].astype(int) - frames[1].astype(int)).sum(axis=2)
    assert (diff[wall] > 60).mean() > 0.1


# ------------------------------------------------------------------------------------------------ cars and groups
def test_other_car_of_same_group_visible_of_other_group_not(wide, wide_circle):
    x, y, yaw = poses(wide_circle, [100.0, 120.0], [0.0, 0.0])
    car = [(wide.render_labels(x, y, yaw, view_ids=[0], groups=g)[0] == Label.CAR).sum() for g in ([0, 0], [0, 1])]
    assert car[0] > 300
    assert car[1] == 0
    assert (wide.render_labels(x, y, yaw, view_ids=[0])[0] == Label.CAR).sum() == car[0]  # no groups: all seen
    # The car ahead is drawn in its colour (uint8 or float colours give the same frame).
    red = wide.render(x, y, yaw, view_ids=[0], car_colors=np.array([[0, 0, 255], [255, 0, 0]], np.uint8))[0]
    red_f = wide.render(x, y, yaw, view_ids=[0], car_colors=np.array([[0, 0, 1.0], [1.0, 0, 0]]))[0]
    assert np.array_equal(red, red_f)
    mask = wide.render_labels(x, y, yaw, view_ids=[0])[0] == Label.CAR
    body = red[mask].astype(int)
    assert (body[:, 0] > body[:, 2] + 40).mean() > 0.3


def test_hood_camera_hides_own_car_chase_camera_shows_it(wide, chase, wide_circle):
    x, y, yaw = poses(wide_circle, [100.0], [0.0])
    assert not (wide.render_labels(x, y, yaw)[0] == Label.CAR).any()
    car = chase.render_labels(x, y, yaw)[0] == Label.CAR
    rows, cols = np.nonzero(car)
    assert car.sum() > 2000
    assert rows.mean() > 0.6 * H and abs(cols.mean() - W / 2) < 0.05 * W  # bottom centre, straight ahead


# ------------------------------------------------------------------------------------------------ batching and sizes
def test_tiled_batch_equals_individual_renders(wide, wide_circle):
    x, y, yaw = poses(wide_circle, [30.0, 300.0, 900.0, 1500.0, 2500.0], [0.0, 5.0, -5.0, 20.0, -25.0])
    batch = wide.render(x, y, yaw)
    single = np.concatenate([wide.render(x, y, yaw, view_ids=[i]) for i in range(5)])
    # Tiles sit at different framebuffer offsets, so float rounding may move a polygon edge by a sub-pixel:
    # at most a few isolated edge pixels differ.
    same = (batch == single).all(axis=3)
    assert same.mean() > 0.995
    assert np.abs(batch.astype(int) - single).mean() < 0.3
    labels_batch = wide.render_labels(x, y, yaw)
    assert (labels_batch == np.stack([wide.render_labels(x, y, yaw, view_ids=[i])[0] for i in range(5)])).mean() > 0.995


def test_more_views_than_tiles_and_repeated_views(gl_available, wide_circle):
    x, y, yaw = poses(wide_circle, [30.0, 300.0, 900.0, 1500.0, 2500.0], [0.0, 5.0, -5.0, 20.0, -25.0])
    with Renderer(wide_circle, RenderConfig(max_views=2)) as small, Renderer(wide_circle) as big:
        views = [4, 0, 1, 2, 3, 0]
        a = small.render(x, y, yaw, view_ids=views)
        b = big.render(x, y, yaw, view_ids=views)
        assert a.shape == (6, H, W, 3)
        assert (a == b).all(axis=3).mean() > 0.995
        assert (b[1] == b[5]).all(axis=2).mean() > 0.995


def test_non_default_size_shape_dtype_and_grid_layout(gl_available, wide_circle):
    x, y, yaw = poses(wide_circle, [30.0, 300.0, 900.0], [0.0, 5.0, -5.0])
    with Renderer(wide_circle, RenderConfig(width_px=320, height_px=200)) as r:
        frames = r.render(x, y, yaw, view_ids=[2, 0])
        labels = r.render_labels(x, y, yaw, view_ids=[2, 0])
    assert frames.shape == (2, 200, 320, 3) and frames.dtype == np.uint8
    assert labels.shape == (2, 200, 320) and labels.dtype == np.uint8
    assert labels.max() < len(LABEL_NAMES)
    assert labels_to_rgb(labels).shape == (2, 200, 320, 3)
    # 720p tiles need two columns of tiles at 30 views: the column-major tile order must still be view order.
    with Renderer(wide_circle, RenderConfig(width_px=1280, height_px=720, max_views=30)) as r:
        assert r._cols == 2
        many = np.array([0, 1, 2] * 8)
        lab = r.render_labels(x, y, yaw, view_ids=many)
        assert lab.shape == (24, 720, 1280)
        assert all((lab[i] == lab[i % 3]).mean() > 0.995 for i in range(24))
        assert not (lab[0] == lab[1]).all()
    assert wide_circle  # keep the fixture used


def test_antialiasing_renders(gl_available, wide_circle):
    x, y, yaw = poses(wide_circle, [30.0, 900.0], [0.0, 5.0])
    with Renderer(wide_circle, RenderConfig(samples=4)) as aa, Renderer(wide_circle) as plain:
        for views in ([0], [0, 1]):
            a, p = aa.render(x, y, yaw, view_ids=views), plain.render(x, y, yaw, view_ids=views)
            assert a.shape == p.shape == (len(views), H, W, 3)
            diff = np.abs(a.astype(int) - p).sum(axis=3)
            assert all(0 < (d > 0).mean() < 0.3 for d in diff)  # edges smoothed, the picture otherwise the same


def test_colour_levels_round_every_channel(wide, wide_circle):
    x, y, yaw = poses(wide_circle, [30.0, 900.0], [0.0, 5.0])
    frames = wide.render(x, y, yaw)  # default: 64 levels per channel
    levels = np.round(np.arange(64) * 255 / 63)
    assert np.isin(frames, levels).all()
    with Renderer(wide_circle, RenderConfig(color_levels=256)) as full:
        fine = full.render(x, y, yaw)
    assert not np.isin(fine, levels).all()  # all of uint8 keeps the values in between
    assert np.abs(fine.astype(int) - frames).max() <= 3  # the same picture, rounded to the nearest level


# ------------------------------------------------------------------------------------------------ bad input
def test_bad_configs_and_inputs(wide, wide_circle):
    with pytest.raises(ValueError, match="frame size"):
        RenderConfig(width_px=1920, height_px=1080)
    with pytest.raises(ValueError, match="samples"):
        RenderConfig(samples=3)
    with pytest.raises(ValueError, match="color_levels"):
        RenderConfig(color_levels=1)
    with pytest.raises(ValueError, match="preset"):
        CameraConfig(preset="cockpit")
    x, y, yaw = poses(wide_circle, [30.0, 60.0], [0.0, 0.0])
    with pytest.raises(ValueError, match="one length"):
        wide.render(x, y[:1], yaw)
    with pytest.raises(ValueError, match="view_ids"):
        wide.render(x, y, yaw, view_ids=[2])
    with pytest.raises(ValueError, match="groups"):
        wide.render(x, y, yaw, groups=[0])
    with pytest.raises(ValueError, match="finite"):
        wide.render(np.array([np.nan, 0.0]), y, yaw)
    assert wide.render(x, y, yaw, view_ids=[]).shape == (0, H, W, 3)


def test_closed_renderer_raises(gl_available, wide_circle):
    r = Renderer(wide_circle)
    r.close()
    r.close()  # idempotent
    with pytest.raises(RendererError, match="closed"):
        r.render(np.zeros(1), np.zeros(1), np.zeros(1))


def test_no_gl_context_gives_a_clear_error(monkeypatch, wide_circle):
    import moderngl

    def fail(*args, **kwargs):
        raise Exception("eglGetDisplay failed")

    monkeypatch.delenv("GLCONTEXT_DEVICE_INDEX", raising=False)
    monkeypatch.setattr(moderngl, "create_standalone_context", fail)
    with pytest.raises(RendererError) as info:
        Renderer(wide_circle)
    message = str(info.value)
    assert "libegl1" in message and "libgl1-mesa-dri" in message and "eglGetDisplay failed" in message


# ------------------------------------------------------------------------------------------------ assets
def test_textures_are_deterministic_and_distinct():
    a, b = build_texture_layers(), build_texture_layers()
    assert a.dtype == np.uint8 and a.shape[0] == len(Layer) and a.shape[3] == 3
    assert np.array_equal(a, b)
    means = a.reshape(len(Layer), -1, 3).mean(axis=1)
    assert means[Layer.GRASS, 1] > means[Layer.GRASS, 0] + 30  # grass is green
    assert means[Layer.LINE].min() > 200  # lines are white
    assert means[Layer.ASPHALT].max() < 110  # asphalt is dark
    kerb = a[Layer.KERB].reshape(-1, 3).astype(int)
    assert ((kerb[:, 0] > 150) & (kerb[:, 1] < 60)).mean() > 0.3  # red blocks
    assert (kerb.min(axis=1) > 180).mean() > 0.3  # white blocks


def test_surface_detail_is_smooth_not_per_texel_noise():
    # Per-texel grain reaches frames as pixel noise that doubles their compressed size and shows nothing of the
    # track. Neighbouring texels of the noisy surfaces differ by < 1 level on average (the grainy textures: 5-13).
    a = build_texture_layers().astype(int)
    for layer in (Layer.ASPHALT, Layer.SHOULDER, Layer.LINE, Layer.GRASS, Layer.WALL_TOP, Layer.METAL, Layer.ROOF):
        step = np.abs(np.diff(a[layer], axis=1)).mean()
        assert step < 1.0, f"{layer.name}: mean step {step:.2f} between neighbouring texels"
    assert np.ptp(a[Layer.ASPHALT].mean(axis=2)) > 10  # still patchy, so the road streams past at speed


def test_scene_mesh_sizes_and_determinism(wide_circle, tight_circle):
    s1, s2 = build_scene(wide_circle), build_scene(wide_circle)
    assert np.array_equal(s1.vertices, s2.vertices) and np.array_equal(s1.indices, s2.indices)
    assert 1_000 < s1.n_triangles < 60_000
    assert s1.chunk_count.sum() == len(s1.indices)
    assert np.all(np.diff(s1.chunk_first) == s1.chunk_count[:-1])  # chunks are contiguous index ranges
    # Kerb geometry only on the tight circle.
    assert not (build_scene(wide_circle).vertices[:, 5] == Layer.KERB).any()
    assert (build_scene(tight_circle).vertices[:, 5] == Layer.KERB).any()
    verts, idx = build_car_mesh(4.1, 1.7)
    assert verts[:, 0].min() == pytest.approx(-2.05 - 0.25) and verts[:, 1].max() == pytest.approx(0.85 + 0.2)
    assert len(idx) % 3 == 0 and idx.max() < len(verts)


def test_bench_render_reports_both_figures(gl_available, wide_circle):
    from vision_rl.render import bench_render

    result = bench_render(n_views=3, repeats=1, track=wide_circle, frames_per_repeat=3)
    assert result["render_fps_470x280"] > 0 and result["render_fps_batch3"] > 0
    assert result["static_triangles"] > 0


def test_walls_are_left_out_where_the_track_crosses_itself(wide_circle):
    """A figure-eight (a bridge in reality, flat here): no wall may stand across the other branch's road."""
    t = np.linspace(0.0, 2 * np.pi, 600, endpoint=False)
    lemniscate = 300.0 * np.stack([np.cos(t), np.sin(t) * np.cos(t)], axis=1) / (1.0 + np.sin(t) ** 2)[:, None]
    fig8 = Track.from_centre_line("fig8", lemniscate, 6.0, 6.0)
    scene = build_scene(fig8)
    quads = scene.vertices.reshape(-1, 4, scene.vertices.shape[1])
    walls = quads[np.isin(quads[:, 0, 5], [Layer.WALL, Layer.WALL_TOP]), :, :2] + scene.origin_xy_m
    # Points spread over each wall quad (bilinear in its corners).
    u = np.linspace(0.0, 1.0, 11)
    uu, vv = (g.ravel() for g in np.meshgrid(u, u))
    w = np.stack([(1 - uu) * (1 - vv), uu * (1 - vv), uu * vv, (1 - uu) * vv], axis=1)
    points = np.einsum("pc,qck->qpk", w, walls).reshape(-1, 2)
    near = np.hypot(points[:, 0], points[:, 1]) < 40.0  # the branches cross at the origin along y = +-x
    for d in (np.array([1.0, 1.0]), np.array([1.0, -1.0])):
        off_line = np.abs(points[:, 0] * d[1] - points[:, 1] * d[0]) / np.sqrt(2.0)
        assert not (near & (off_line < 5.5)).any()  # no wall inside either branch's road
    assert near.sum() > 100  # walls resume right after the crossing
    assert not _inside_other_branch(wide_circle, wide_circle.left_wall_xy_m, wide_circle.s_m).any()
