"""`capture` end to end on a small circular track with tiny frames."""

import dataclasses

import numpy as np
import pytest

from tests.helpers.drivers import CentreLineFollower
from vision_rl.capture.h5format import CaptureFormatError, open_capture
from vision_rl.capture.sim_capture import CaptureConfig, capture_sim, physics_step_for, turned_round
from vision_rl.sim import sensors
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import get_preset
from vision_rl.sim.world import World


@pytest.fixture
def circle_csv(tmp_path):
    a = np.linspace(0.0, 2 * np.pi, 120, endpoint=False)
    r = 40.0
    rows = np.stack([r * np.cos(a), r * np.sin(a), np.full(120, 6.0), np.full(120, 6.0)], axis=1)
    path = tmp_path / "circle.csv"
    np.savetxt(path, rows, delimiter=",", header="x_m,y_m,w_tr_right_m,w_tr_left_m")
    return str(path)


def _config(track, out, **kw):
    base = CaptureConfig(out=str(out), track=track, laps=2, cars=2, fps=10, image_hw_px=(48, 64), seed=3)
    return dataclasses.replace(base, **kw)


def test_physics_step_divides_the_capture_interval_and_the_ai_steers_at_50_hz_or_faster():
    assert physics_step_for(60) == pytest.approx((1 / 120, 1 / 60, 1))
    assert physics_step_for(10) == pytest.approx((0.01, 0.02, 5))  # 5 AI steps a frame, as in `drive`
    assert physics_step_for(30) == pytest.approx((1 / 120, 1 / 60, 2))
    with pytest.raises(ValueError, match="fps"):
        physics_step_for(0)


def test_capture_writes_the_contract_and_targets_match_the_poses(gl_available, circle_csv, tmp_path):
    cfg = _config(circle_csv, tmp_path / "run.h5")
    result = capture_sim(cfg)
    assert result["complete"] and result["laps_in_file"] >= 2
    with open_capture(cfg.out) as f:
        assert f.complete
        n = f.n_frames
        assert n == result["frames_in_file"] > 0
        assert f.image_hw_px == (48, 64)
        assert f.read_image(0).dtype == np.uint8 and f.read_image(0).shape == (48, 64, 3)
        assert f.targets.shape == (n, 27) and f.targets.dtype == np.float32
        assert f.dedicated.shape == (n, 11)
        assert list(f.target_names) == list(sensors.TARGET_NAMES)
        assert list(f.target_units) == list(sensors.TARGET_UNITS)
        track = load_track(circle_csv)
        assert f.attrs["track_geometry_hash"] == track.geometry_hash
        assert f.attrs["car_preset"] == "hatchback" and f.attrs["seed"] == 3
        # The targets are those of the recorded pose: recompute a few from the geometry.
        rows = np.arange(0, n, max(1, n // 7))
        pose = f.pose[rows]
        proj = track.project(pose[:, :2])
        expected = sensors.environment_targets(
            track, sensors.WallRayCaster(track), pose[:, 0], pose[:, 1], pose[:, 2], proj.s_m, proj.lateral_m
        )
        np.testing.assert_allclose(f.targets[rows], expected, rtol=1e-4, atol=1e-3)
        # Two laps over two cars: each car drove (about) a whole lap, with non-decreasing lap indices.
        assert set(np.unique(f.car_id)) == {0, 1}
        for car in (0, 1):
            mine = f.car_id == car
            assert np.all(np.diff(f.lap[mine]) >= 0)
            s = track.project(f.pose[mine][:, :2]).s_m
            assert track.progress_delta(s[:-1], s[1:]).sum() > 0.95 * track.length_m


def test_undisturbed_capture_keeps_the_ai_on_its_line_at_a_low_frame_rate(gl_available, circle_csv, tmp_path):
    # The AI steers at 50 Hz between frames 0.1 s apart; the frames' heading errors stay those of its line.
    cfg = _config(circle_csv, tmp_path / "clean.h5", cars=1, laps=1, disrupt_ai=False)
    capture_sim(cfg)
    with open_capture(cfg.out) as f:
        np.testing.assert_allclose(np.diff(f.time_s), 0.1, atol=1e-9)
        heading = f.targets[:, list(f.target_names).index("heading_angle_to_centre_line")]
        assert np.abs(heading).max() < np.radians(15.0)
        assert f.dedicated[:, list(f.dedicated_names).index("wall_contact")].max() == 0.0


def test_existing_file_is_not_overwritten_without_force(gl_available, circle_csv, tmp_path):
    out = tmp_path / "run.h5"
    out.write_bytes(b"precious")
    with pytest.raises(FileExistsError):
        capture_sim(_config(circle_csv, out))
    assert out.read_bytes() == b"precious"


def test_interrupted_capture_keeps_its_frames_and_resume_completes_it(gl_available, circle_csv, tmp_path):
    cfg = _config(circle_csv, tmp_path / "run.h5", laps=3)

    def interrupt_after_some_frames(laps, frames):
        if frames >= 60:
            raise KeyboardInterrupt

    first = capture_sim(cfg, progress=interrupt_after_some_frames)
    assert first["interrupted"] and not first["complete"]
    with open_capture(cfg.out) as f:
        assert not f.complete
        kept = f.n_frames
        laps_before = {c: set(f.lap[f.car_id == c]) for c in (0, 1)}
    assert kept >= 60
    second = capture_sim(dataclasses.replace(cfg, resume=True))
    assert second["complete"]
    with open_capture(cfg.out) as f:
        assert f.complete and f.n_frames > kept
        for c in (0, 1):
            new_laps = set(f.lap[kept:][f.car_id[kept:] == c])
            assert not new_laps & laps_before[c]  # a lap cut by the interruption is never continued


def test_video_and_pose_log_reproduce_the_sim_targets(gl_available, circle_csv, tmp_path):
    cv2 = pytest.importorskip("cv2")
    from vision_rl.capture.video_source import capture_video

    sim = _config(circle_csv, tmp_path / "sim.h5", cars=1, laps=1, disrupt_ai=False)
    capture_sim(sim)
    with open_capture(sim.out) as f:
        images = f.read_images(np.arange(f.n_frames))
        pose, time_s, targets = f.pose, f.time_s, f.targets
    video_path = str(tmp_path / "screen.avi")
    writer = cv2.VideoWriter(video_path, cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))  # cv2 takes (width, height)
    for frame in images:
        writer.write(np.ascontiguousarray(frame[:, :, ::-1]))
    writer.release()
    poses = tmp_path / "poses.csv"
    np.savetxt(poses, np.column_stack([time_s, pose]), delimiter=",", header="time_s,x_m,y_m,yaw_rad", comments="")
    out = tmp_path / "video.h5"
    capture_video(dataclasses.replace(sim, out=str(out)), video=video_path, poses_csv=str(poses))
    with open_capture(out) as f:
        assert f.n_frames == len(targets)
        np.testing.assert_allclose(f.targets, targets, rtol=1e-4, atol=1e-3)
        np.testing.assert_allclose(f.pose, pose, atol=1e-6)
        # MJPG is lossy: the frames are close, not equal.
        assert np.abs(f.read_image(5).astype(int) - images[5]).mean() < 12


def test_pose_log_errors_name_the_problem(tmp_path):
    from vision_rl.capture.video_source import read_pose_log

    bad = tmp_path / "poses.csv"
    bad.write_text("time_s,x_m,y_m\n0,0,0\n1,1,1\n")
    with pytest.raises(ValueError, match="yaw_rad"):
        read_pose_log(bad)
    bad.write_text("time_s,x_m,y_m,yaw_rad\n0,0,0,0\n0,1,1,0\n")
    with pytest.raises(ValueError, match="increase"):
        read_pose_log(bad)


class _Follower(CentreLineFollower):
    """A protocol driver holding 2 m left of the centre line, with the identity a policy driver has."""

    identity = {"driver": "follower", "lateral_m": 2.0}

    def __init__(self) -> None:
        super().__init__(target_lateral=lambda s: 2.0 + 0.0 * s)
        self.resets = 0

    def reset(self, world, car_ids):
        super().reset(world, car_ids)
        self.resets += 1


def test_a_driver_drives_the_capture_and_the_file_names_it(gl_available, circle_csv, tmp_path):
    driver = _Follower()
    cfg = _config(circle_csv, tmp_path / "driven.h5", laps=1, disrupt_ai=False)
    result = capture_sim(cfg, driver=driver)
    assert result["complete"] and driver.resets == 1
    with open_capture(cfg.out) as f:
        np.testing.assert_allclose(np.diff(f.time_s[f.car_id == 0]), 0.1, atol=1e-9)  # its 10 Hz, a frame a step
        offset = f.targets[:, list(f.target_names).index("centre_line_offset")]
        settled = f.time_s > f.time_s.min() + 5.0  # the follower's lateral feedback has pulled it over by then
        assert np.abs(offset[settled] - 2.0).max() < 0.3  # where the follower drives, not the AI's line
        assert f.attrs["driver"] == _Follower.identity and f.attrs["fingerprint"]["driver"] == _Follower.identity
    # A file a driver began is not resumed by the AI (nor the other way round): its frames would not belong together.
    partial = _config(circle_csv, tmp_path / "partial.h5", laps=1, disrupt_ai=False, max_frames=4)
    capture_sim(partial, driver=_Follower())
    with pytest.raises(CaptureFormatError, match="driver"):
        capture_sim(dataclasses.replace(partial, resume=True))
    with pytest.raises(ValueError, match="--no-disrupt"):
        capture_sim(_config(circle_csv, tmp_path / "d.h5"), driver=_Follower())
    with pytest.raises(ValueError, match=r"--fps 7: the driver acts every 0\.1 s"):
        capture_sim(_config(circle_csv, tmp_path / "f.h5", fps=7, disrupt_ai=False), driver=_Follower())


def test_a_car_turned_more_than_a_right_angle_from_the_track_is_found(circle_csv):
    track = load_track(circle_csv)
    world = World(track, get_preset("hatchback"), n_cars=6)
    # Five cars spread round the circle, so that the track's direction differs at each; the last sits on the line
    # where the centre line's heading wraps from +pi to -pi.
    offsets = np.array([0.0, 1.5, 1.65, -1.65, np.pi, -1.5])
    world.reset(s_m=np.linspace(0.0, track.length_m, 6, endpoint=False), heading_offset_rad=offsets)
    np.testing.assert_array_equal(turned_round(track, world.state), [2, 3, 4])


def test_stronger_disruptions_are_recorded_and_cars_turned_round_are_placed_again(gl_available, circle_csv, tmp_path):
    cfg = _config(circle_csv, tmp_path / "wild.h5", laps=1, disrupt_steer_offset_rad=1.5)
    result = capture_sim(cfg)
    assert result["turned_resets"] > 0  # offsets of 1.5 rad turn cars round on this circle
    with open_capture(cfg.out) as f:
        assert f.attrs["fingerprint"]["disrupt_steer_offset_rad"] == 1.5
        heading = f.targets[:, list(f.target_names).index("heading_angle_to_centre_line")]
    # A turned car is placed again before its next frame: no frame shows a car facing backwards.
    assert np.abs(heading).max() <= np.pi / 2
