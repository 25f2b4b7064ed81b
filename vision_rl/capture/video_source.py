"""The HDMI-grabber source: frames from ``cv2.VideoCapture`` paired with a telemetry log, targets from geometry.

The vision paper captured the PS4's screen with an HDMI grabber whose frames ran 4 frames (67 ms) behind the
game's telemetry (section 4.1). Here frame k of a video of rate ``fps`` shows the car at time
``t_k = k / fps - frame_delay_frames / fps`` of the pose log; the pose at ``t_k`` is interpolated from the log and the
27 targets are computed from the track geometry exactly as for a simulator capture.

Pose log: a CSV with a header naming at least ``time_s, x_m, y_m, yaw_rad``; optional columns ``vx_mps, vy_mps,
yaw_rate_radps, ax_mps2, ay_mps2, wall_contact, steer_rad`` fill the dedicated features (missing ones are
derived: body velocity from the pose differences, yaw rate from the heading, accelerations from the velocities).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from vision_rl.capture.sim_capture import CaptureConfig, open_writer
from vision_rl.sim import sensors
from vision_rl.sim.track_library import load_track

REQUIRED_POSE_COLUMNS = ("time_s", "x_m", "y_m", "yaw_rad")


def read_pose_log(path: str | Path) -> dict[str, np.ndarray]:
    """Columns of a telemetry CSV; a clear error for a missing file, missing columns or bad rows."""
    path = Path(path)
    try:
        with path.open() as f:
            header = f.readline().lstrip("#").strip().split(",")
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except OSError as exc:
        raise ValueError(f"pose log {path}: cannot read it ({exc})") from exc
    except ValueError as exc:
        raise ValueError(f"pose log {path}: not a numeric CSV ({exc})") from exc
    header = [h.strip() for h in header]
    missing = [c for c in REQUIRED_POSE_COLUMNS if c not in header]
    if missing:
        raise ValueError(f"pose log {path}: missing column(s) {missing}; header is {header}")
    if data.shape[1] != len(header) or len(data) < 2:
        raise ValueError(f"pose log {path}: needs >= 2 rows of {len(header)} values")
    columns = {name: data[:, i] for i, name in enumerate(header)}
    if not np.all(np.diff(columns["time_s"]) > 0):
        raise ValueError(f"pose log {path}: time_s must increase strictly")
    if not np.isfinite(data).all():
        row = int(np.argwhere(~np.isfinite(data))[0, 0]) + 2
        raise ValueError(f"pose log {path}: non-finite value on line {row}")
    return columns


def poses_at(log: dict[str, np.ndarray], t_s: np.ndarray) -> SimpleNamespace:
    """The log interpolated at times ``t_s`` (heading unwrapped first), with derived motion where not logged."""
    t = log["time_s"]
    yaw_u = np.unwrap(log["yaw_rad"])

    def at(values: np.ndarray) -> np.ndarray:
        return np.interp(t_s, t, values)

    x, y, yaw = at(log["x_m"]), at(log["y_m"]), at(yaw_u)
    # Derived motion from central differences of the log, rotated into the body frame.
    vx_w, vy_w = np.gradient(log["x_m"], t), np.gradient(log["y_m"], t)
    c, s = np.cos(yaw_u), np.sin(yaw_u)
    derived = {
        "vx_mps": c * vx_w + s * vy_w,
        "vy_mps": -s * vx_w + c * vy_w,
        "yaw_rate_radps": np.gradient(yaw_u, t),
    }
    derived["ax_mps2"] = np.gradient(derived["vx_mps"], t) - derived["yaw_rate_radps"] * derived["vy_mps"]
    derived["ay_mps2"] = np.gradient(derived["vy_mps"], t) + derived["yaw_rate_radps"] * derived["vx_mps"]
    out = {k: at(log.get(k, v)) for k, v in derived.items()}
    zeros = np.zeros_like(x)
    return SimpleNamespace(
        x_m=x,
        y_m=y,
        yaw_rad=np.angle(np.exp(1j * yaw)),
        roll_rate_radps=zeros,
        pitch_rate_radps=zeros,
        wall_contact=at(log["wall_contact"]) > 0.5 if "wall_contact" in log else zeros.astype(bool),
        steer_rad=at(log["steer_rad"]) if "steer_rad" in log else zeros,
        **out,
    )


def capture_video(
    cfg: CaptureConfig,
    *,
    video: str,
    poses_csv: str,
    frame_delay_frames: int = 0,
    batch: int = 64,
    progress: Callable[[int], None] | None = None,
) -> dict:
    """Read every frame of ``video`` (a file path or a V4L2 device number), pair it with the pose log
    ``poses_csv``, write HDF5 to ``cfg.out`` at ``cfg.image_hw_px``; ``cfg.fps`` is the rate when the video does
    not give one. ``frame_delay_frames``: frames the video lags the telemetry (the paper's grabber: 4).
    ``progress(frames)`` is called after every written batch."""
    try:
        import cv2
    except ImportError as exc:
        raise RuntimeError("the video source needs OpenCV: pip install opencv-python-headless") from exc
    if not poses_csv:
        raise ValueError("a video capture needs a pose log (the telemetry to pair the frames with)")
    log = read_pose_log(poses_csv)
    track = load_track(cfg.track)
    device = int(video) if video.isdigit() else video
    capture = cv2.VideoCapture(device)
    if not capture.isOpened():
        raise ValueError(f"cannot open video source {video!r} (a file path or a V4L2 device number)")
    fps = capture.get(cv2.CAP_PROP_FPS) or cfg.fps
    caster = sensors.WallRayCaster(track)
    settings = {"source": video, "frame_delay": frame_delay_frames, "video_fps": fps}
    writer = open_writer(Path(cfg.out), track, cfg, settings, f"video:{video}")
    h, w = cfg.image_hw_px
    frames, k, s_last, progress_m = 0, 0, None, 0.0
    try:
        done = False
        while not done:
            images = []
            while len(images) < batch:
                ok, bgr = capture.read()
                if not ok:
                    done = True
                    break
                if bgr.shape[:2] != (h, w):
                    bgr = cv2.resize(bgr, (w, h), interpolation=cv2.INTER_AREA)  # cv2 takes (width, height)
                images.append(bgr[:, :, ::-1])
            if not images:
                break
            t = (np.arange(k, k + len(images)) - frame_delay_frames) / fps
            k += len(images)
            inside = (t >= log["time_s"][0]) & (t <= log["time_s"][-1])  # frames outside the log have no pose
            if not inside.any():
                continue
            t = t[inside]
            pose = poses_at(log, t)
            xy = np.stack([pose.x_m, pose.y_m], axis=1)
            proj = track.project(xy)
            # Lap index from the progress since the first frame (the log may start anywhere on the track).
            s_prev = np.concatenate([[proj.s_m[0] if s_last is None else s_last], proj.s_m[:-1]])
            travelled_m = progress_m + np.cumsum(track.progress_delta(s_prev, proj.s_m))
            progress_m, s_last = float(travelled_m[-1]), float(proj.s_m[-1])
            targets = sensors.environment_targets(
                track, caster, pose.x_m, pose.y_m, pose.yaw_rad, proj.s_m, proj.lateral_m
            )
            dedicated = sensors.dedicated_features(pose, pose.wall_contact, pose.steer_rad)
            writer.append(
                images=np.ascontiguousarray(np.stack(images)[inside]),
                targets=targets.astype(np.float32),
                dedicated=dedicated.astype(np.float32),
                pose=np.stack([pose.x_m, pose.y_m, pose.yaw_rad], axis=1),
                time_s=t,
                lap=np.floor(travelled_m / track.length_m).astype(np.int32),
                car_id=np.zeros(len(t), dtype=np.int32),
            )
            frames += len(t)
            if progress is not None:
                progress(frames)
    finally:
        capture.release()
        writer.close(complete=True)
    return {"out": cfg.out, "frames_in_file": frames, "video_frames": k, "video_fps": fps}
