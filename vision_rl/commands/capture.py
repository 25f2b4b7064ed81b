"""`capture`: frames, the 27 targets and the 11 dedicated features to HDF5, from the simulator or a video source.

``--source sim`` (default) drives built-in AI cars and renders their views (:func:`capture_sim`);
``--source video:DEVICE_OR_FILE --poses POSES.csv`` pairs an HDMI grabber's or a video's frames with a telemetry
log (:func:`vision_rl.capture.video_source.capture_video`).

A simulator capture stops cleanly on SIGTERM or Ctrl-C: the signal is noted and the run stops after the batch being
written, so the file keeps every frame made so far (exit 143 or 130; a second signal stops at once, losing at most
the frames since the last flush). ``--resume`` continues it.

``--workers N [--address auto|HOST:PORT]`` splits the capture into N shards captured at once by Ray tasks
(:func:`vision_rl.capture.sharded.capture_sharded`); ``--out`` is then the manifest (``PATH.json``) that
``train-repr --data`` reads like a capture file, and the shards go to ``PATH.shards/``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import signal
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from typing import ClassVar

from vision_rl.capture.sim_capture import CaptureConfig
from vision_rl.commands.choices import COMPRESSIONS
from vision_rl.commands.output import emit, progress_bar, show


@dataclass(frozen=True)
class CaptureOptions(CaptureConfig):
    """Record frames, the 27 targets and the 11 dedicated features to an HDF5 file."""

    option_choices: ClassVar[dict[str, tuple[str, ...]]] = {"compression": COMPRESSIONS}

    negative_switches: ClassVar[dict[str, str]] = {"disrupt_ai": "--no-disrupt"}
    positive_switches: ClassVar[tuple[str, ...]] = ("disrupt_ai",)  # the design card's `capture --disrupt-ai`

    out: str = ""
    """Output .h5 file (empty: capture.h5 in the current folder; with --workers, the manifest, capture.json)."""
    source: str = "sim"
    """'sim' or 'video:DEVICE_OR_FILE' (an HDMI grabber or a video)."""
    poses: str = ""
    """Video source: telemetry CSV (time_s, x_m, y_m, yaw_rad, ...)."""
    frame_delay: int = 0
    """Video source: frames the video lags the telemetry (paper: 4)."""
    policy: str = ""
    """Drive the cars with this trained policy (a train-policy run folder or its policy.pt) instead of the built-in
    AI: frames of the states Phase 2 visits. With --no-disrupt, at the policy's control rate or a whole fraction of
    it (a 0.1 s policy: 10 fps, 5 fps, ...; a 0.04 s one: 25, 12.5, ...)."""
    workers: int | None = None
    """Capture N shards at once as Ray tasks of one CPU each, --out being their manifest PATH.json (none: one
    process, no Ray)."""
    address: str = ""
    """With --workers: the Ray cluster, 'auto' (the running one) or HOST:PORT (empty: a local Ray)."""
    json: bool = False
    """Print the summary as JSON."""


class _StopRequest:
    """The first SIGTERM or SIGINT asks the capture to stop between batches; a second one acts as usual."""

    def __init__(self) -> None:
        self.signal: int | None = None
        self._previous: dict[int, object] = {}

    def _handle(self, signum: int, frame: object) -> None:
        if self.signal is not None:  # the second signal: the default action, no more waiting
            signal.signal(signum, self._previous.get(signum, signal.SIG_DFL))
            signal.raise_signal(signum)
            return
        self.signal = signum

    def check(self) -> None:
        """Called between batches: stop here (the writer closes the file with every frame written)."""
        if self.signal is not None:
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def installed(self) -> Iterator[_StopRequest]:
        if threading.current_thread() is not threading.main_thread():  # signals reach only the main thread
            yield self
            return
        for signum in (signal.SIGTERM, signal.SIGINT):
            self._previous[signum] = signal.signal(signum, self._handle)
        try:
            yield self
        finally:
            for signum, handler in self._previous.items():
                signal.signal(signum, handler)  # type: ignore[arg-type]


def run_capture(opts: CaptureOptions) -> int:
    """A progress bar in laps (frames after it), then the summary."""
    from vision_rl.capture.sim_capture import capture_sim

    if not opts.out:  # the design card's `vision-rl capture --disrupt-ai --laps 50` writes here
        opts = dataclasses.replace(opts, out="capture.json" if opts.workers is not None else "capture.h5")
    if opts.policy and (opts.workers is not None or opts.source != "sim"):
        raise ValueError("--policy drives a simulator capture in this process: leave out --workers and --source")
    if opts.workers is not None and opts.source != "sim":
        raise ValueError("--workers shards a simulator capture; a --source video:... capture runs in one process")
    if opts.source.startswith("video:"):
        from vision_rl.capture.video_source import capture_video

        if not opts.poses:
            raise ValueError("--source video:... needs --poses POSES.csv (the telemetry to pair the frames with)")
        with progress_bar(None, "frame", "capture") as bar:
            result = capture_video(
                opts,
                video=opts.source.removeprefix("video:"),
                poses_csv=opts.poses,
                frame_delay_frames=opts.frame_delay,
                progress=lambda frames: show(bar, frames),
            )
        emit(result, opts.json)
        return 0
    if opts.source != "sim":
        raise ValueError(f"--source must be 'sim' or 'video:DEVICE_OR_FILE', got {opts.source!r}")
    if opts.workers is not None:
        return _run_sharded(opts)
    if opts.address:
        raise ValueError("--address names the Ray cluster of a sharded capture: give --workers N too")
    driver = _policy_driver(opts) if opts.policy else None
    stop = _StopRequest()
    try:
        with progress_bar(opts.laps, "lap", "capture") as bar, stop.installed():

            def progress(laps: int, frames: int) -> None:
                show(bar, laps, frames=frames)
                stop.check()

            result = capture_sim(opts, progress, driver)
    finally:
        if driver is not None:
            driver.close()
    if result["interrupted"]:
        result["note"] = f"interrupted: {result['frames_in_file']} frames kept; run again with --resume to continue"
    emit(result, opts.json)
    if not result["interrupted"]:
        return 0
    return 143 if stop.signal == signal.SIGTERM else 130


def _policy_driver(opts: CaptureOptions):
    """The policy of ``--policy`` as a driver, refused on another track or car than it was trained on."""
    from vision_rl.sim.track_library import load_track
    from vision_rl.training.artifact import load_policy

    loaded = load_policy(opts.policy)
    trained = loaded.config
    if load_track(opts.track).geometry_hash != load_track(trained.track).geometry_hash or opts.car != trained.car:
        raise ValueError(
            f"--policy {opts.policy} drives {trained.track} with the {trained.car}: give --track "
            f"{trained.track} --car {trained.car}"
        )
    return loaded.driver()


def _run_sharded(opts: CaptureOptions) -> int:
    """The shards as Ray tasks; exit 1 when a shard failed (its worker died), 130/143 when interrupted."""
    from vision_rl.capture.sharded import ShardedCaptureConfig, capture_sharded

    base = {f.name: getattr(opts, f.name) for f in dataclasses.fields(CaptureConfig)}
    cfg = ShardedCaptureConfig(**base, workers=opts.workers, address=opts.address)
    stop = _StopRequest()
    with progress_bar(opts.laps, "lap", "capture") as bar, stop.installed():

        def progress(laps: int, frames: int) -> None:
            show(bar, laps, frames=frames)
            stop.check()

        result = capture_sharded(cfg, progress)
    resume = f"run again with --workers {cfg.workers} --resume to finish it"
    if result["interrupted"]:
        result["note"] = f"interrupted: {result['frames_in_file']} frames kept in the shards; {resume}"
    elif result["failed_shards"]:
        result["note"] = f"shards {result['failed_shards']} failed (their frames so far are kept); {resume}"
    emit(result, opts.json, _sharded_lines)
    if result["interrupted"]:
        return 143 if stop.signal == signal.SIGTERM else 130
    return 1 if result["failed_shards"] else 0


def _sharded_lines(result: dict) -> list[str]:
    lines = [
        f"manifest: {result['out']}   shards: {result['shards_dir']}",
        f"{result['frames_written']} frames written ({result['frames_in_file']} in the shards) by "
        f"{result['workers']} workers: {result['capture_fps']:.1f} frames/s, "
        f"{result['cpu_s_per_frame'] * 1e3:.2f} ms CPU per frame; complete: {result['complete']}",
    ]
    for shard in result["shards"]:
        error = f"  {shard['error']}" if "error" in shard else ""
        lines.append(f"  {shard['path']}: {shard['status']}, {shard['frames_in_file']} frames{error}")
    if "note" in result:
        lines.append(result["note"])
    return lines
