"""`capture`: frames, the 27 targets and the 11 dedicated features to HDF5, from the simulator or a video source.

``--source sim`` (default) drives built-in AI cars and renders their views (:func:`capture_sim`);
``--source video:DEVICE_OR_FILE --poses POSES.csv`` pairs an HDMI grabber's or a video's frames with a telemetry
log (:func:`vision_rl.capture.video_source.capture_video`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from vision_rl.capture.sim_capture import CaptureConfig
from vision_rl.commands.output import emit, progress_bar, show


@dataclass(frozen=True)
class CaptureOptions(CaptureConfig):
    """Record frames, the 27 targets and the 11 dedicated features to an HDF5 file."""

    negative_switches: ClassVar[dict[str, str]] = {"disrupt_ai": "--no-disrupt"}

    source: str = "sim"
    """'sim' or 'video:DEVICE_OR_FILE' (an HDMI grabber or a video)."""
    poses: str = ""
    """Video source: telemetry CSV (time_s, x_m, y_m, yaw_rad, ...)."""
    frame_delay: int = 0
    """Video source: frames the video lags the telemetry (paper: 4)."""
    json: bool = False
    """Print the summary as JSON."""


def run_capture(opts: CaptureOptions) -> int:
    """A progress bar in laps (frames after it), then the summary."""
    from vision_rl.capture.sim_capture import capture_sim

    if not opts.out:
        raise ValueError("--out PATH.h5 is required")
    if opts.source.startswith("video:"):
        from vision_rl.capture.video_source import capture_video

        if not opts.poses:
            raise ValueError("--source video:... needs --poses POSES.csv (the telemetry to pair the frames with)")
        with progress_bar(None, "frame", "capture") as bar:
            result = capture_video(
                opts, video=opts.source.removeprefix("video:"), poses_csv=opts.poses,
                frame_delay_frames=opts.frame_delay, progress=lambda frames: show(bar, frames),
            )  # fmt: skip
        emit(result, opts.json)
        return 0
    if opts.source != "sim":
        raise ValueError(f"--source must be 'sim' or 'video:DEVICE_OR_FILE', got {opts.source!r}")
    with progress_bar(opts.laps, "lap", "capture") as bar:
        result = capture_sim(opts, lambda laps, frames: show(bar, laps, frames=frames))
    if result["interrupted"]:
        result["note"] = f"interrupted: {result['frames_in_file']} frames kept; run again with --resume to continue"
    emit(result, opts.json)
    return 130 if result["interrupted"] else 0
