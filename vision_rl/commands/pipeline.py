"""`vision-rl pipeline`: the whole two-phase job of the vision paper on one track and car: capture, train-repr,
train-policy on the frozen embedding and on the state, their evaluation and the leaderboard. ``--quick`` is the
small job (``make quick``), ``--tiny`` the seconds-long one for tests; a stage whose output is complete is not
redone, so an interrupted pipeline continues where it stopped.

The stages, in detail: docs/notes/commands.md.
"""

from __future__ import annotations

import contextlib
import functools
import json
import math
import multiprocessing
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vision_rl.commands.output import emit, interrupt_on_sigterm, note, progress_bar, restore_sigterm, show


@dataclass(frozen=True)
class PipelineSizes:
    """How much of every stage a pipeline mode runs. Steps count transitions over all cars."""

    train_laps: int
    """Disrupted laps captured for training, summed over the capture cars."""
    eval_laps: int
    """Clean laps captured for validation."""
    capture_cars: int
    """Built-in AI cars driving (and rendered) together in the captures."""
    capture_fps: float
    """Capture rate, frames per second per car."""
    image_hw_px: tuple[int, int]
    """Frame height and width, px, of the captures and so of the encoder."""
    repr_epochs: int
    """Epochs of train-repr."""
    repr_max_steps: int
    """Optimiser steps of train-repr at most (-1: no limit)."""
    sac_preset: str
    """train-policy's SAC preset (paper or cpu)."""
    steer_action: str
    """How the policies' first action entry steers (``angle``: the papers'; see ``RacingConfig.steer_action``)."""
    state_steps: int
    """SAC steps of the state policy."""
    vision_steps: int
    """SAC steps of the vision policy."""
    state_cars: int
    """Cars sampled at once by the state policy's training."""
    vision_cars: int
    """Cars sampled at once by the vision policy's training. Vision sampling renders and embeds every car's frame
    each step (about 6-10 ms per car on 2 cores), so fewer cars per vector step give more updates per transition
    in a short run."""
    state_learning_starts: int
    """Random-action steps before the state policy's first update (-1: the preset's)."""
    vision_learning_starts: int
    """Random-action steps before the vision policy's first update (-1: the preset's)."""
    vision_gradient_steps: int
    """Updates per vector step of the vision policy (0: the preset's)."""
    vision_workers: int
    """Sampler processes of the vision policy's training (``train-policy --workers``; 0: it samples in the
    learner's process). A sampler renders and embeds the frames while the learner updates."""
    batch_size: int
    """SAC batch size (0: the preset's)."""
    buffer_size: int
    """Replay buffer capacity, transitions (0: the preset's)."""
    eval_every_steps: int
    """Evaluate each policy in training every this many steps."""
    vision_target_entropy: float
    """Vision: SAC's entropy target, nats (0: the preset's, Stable-Baselines3's -2 for the 2 action dimensions)."""
    vision_learning_rate_final: float
    """Vision: the learning rate falls linearly to this by the run's last step (0: the preset's constant rate)."""
    vision_stuck_ends_episode: bool
    """Vision: a stuck car ends its training episode (``train-policy --stuck-ends-episode``; False: it stands out
    its 100 s, as in the papers)."""
    vision_steer_change_penalty_c_s: float
    """Vision: c_s of the steering-change penalty against the angle usable at the car's speed
    (``train-policy --steer-change-penalty-c-s C --steer-change-penalty-scale usable``; 0: the papers' reward)."""
    vision_critic_state: bool
    """Vision: SAC's critic also reads the 38-D state observation, the actor the vision vector alone
    (``train-policy --critic-state``; False: the paper's critic, which reads what the actor reads)."""
    state_eval_seeds: int
    """Start seeds of the state policy's final evaluation."""
    vision_eval_seeds: int
    """Start seeds of the vision policy's final evaluation."""
    stats_steps: int
    """Vision: control steps of the feature-statistics rollout."""
    state_eval_time_limit_s: float
    """Time limit of one state evaluation run, s (0: the protocol's default, 3 x the limit lap time per lap)."""
    vision_eval_time_limit_s: float
    """Time limit of one vision evaluation run, s (0: the protocol's default)."""


SIZES: dict[str, PipelineSizes] = {
    # CI: a few hundred steps on whatever track the test picks, short evaluation runs.
    "tiny": PipelineSizes(
        train_laps=1,
        eval_laps=1,
        capture_cars=2,
        capture_fps=5,
        image_hw_px=(64, 96),
        repr_epochs=1,
        repr_max_steps=3,
        sac_preset="cpu",
        steer_action="rate_scaled",
        state_steps=200,
        vision_steps=120,
        state_cars=2,
        vision_cars=2,
        state_learning_starts=50,
        vision_learning_starts=40,
        vision_gradient_steps=0,
        vision_workers=0,
        batch_size=32,
        buffer_size=5_000,
        eval_every_steps=100,
        vision_target_entropy=-4.0,
        vision_learning_rate_final=1e-4,
        vision_stuck_ends_episode=True,
        vision_steer_change_penalty_c_s=0.5,
        vision_critic_state=True,
        state_eval_seeds=1,
        vision_eval_seeds=1,
        stats_steps=5,
        state_eval_time_limit_s=30.0,
        vision_eval_time_limit_s=30.0,
    ),
    # Frames at half the paper's side: the encoder trains on 236 x 140 frames at about 230 frames/s on one of these
    # cores, on 470 x 280 at about 30 (side by side); only the first fits the quick budget. Vision drives 10 cars: an
    # update costs 36 ms against 50 ms with 20 and learns about as much. Every other value was measured over the same
    # training seeds: docs/studies/quick-vision-recipe.md, docs/results/make-quick/README.md and, for the steering,
    # docs/results/state-expressway-hatchback-speed-scaled/README.md.
    "quick": PipelineSizes(
        train_laps=4,
        eval_laps=1,
        capture_cars=4,
        capture_fps=10,
        image_hw_px=(140, 236),
        repr_epochs=10,
        repr_max_steps=-1,
        sac_preset="cpu",
        steer_action="rate_scaled",
        state_steps=250_000,
        vision_steps=200_000,
        state_cars=20,
        vision_cars=10,
        state_learning_starts=-1,
        vision_learning_starts=5_000,
        vision_gradient_steps=0,
        vision_workers=1,
        batch_size=0,
        buffer_size=0,
        eval_every_steps=50_000,
        vision_target_entropy=-4.0,
        vision_learning_rate_final=1e-4,
        vision_stuck_ends_episode=True,
        vision_steer_change_penalty_c_s=0.5,
        vision_critic_state=True,
        state_eval_seeds=3,
        vision_eval_seeds=3,
        stats_steps=50,
        state_eval_time_limit_s=0.0,
        vision_eval_time_limit_s=400.0,
    ),
    # The paper's scale: 50 disrupted laps at 60 fps and 470 x 280, 50 encoder epochs; SAC for 400 epochs of 20
    # trials of 100 s (vision paper, section 4, Figure 3) = 8M steps. The vision frames render in a sampler process
    # as in quick (not timed at this scale).
    "full": PipelineSizes(
        train_laps=50,
        eval_laps=5,
        capture_cars=4,
        capture_fps=60,
        image_hw_px=(280, 470),
        repr_epochs=50,
        repr_max_steps=-1,
        sac_preset="paper",
        steer_action="angle",
        state_steps=8_000_000,
        vision_steps=8_000_000,
        state_cars=20,
        vision_cars=20,
        state_learning_starts=-1,
        vision_learning_starts=-1,
        vision_gradient_steps=0,
        vision_workers=1,
        batch_size=0,
        buffer_size=0,
        eval_every_steps=200_000,
        vision_target_entropy=0.0,
        vision_learning_rate_final=0.0,
        vision_stuck_ends_episode=False,
        vision_steer_change_penalty_c_s=0.0,
        vision_critic_state=False,
        state_eval_seeds=3,
        vision_eval_seeds=3,
        stats_steps=100,
        state_eval_time_limit_s=0.0,
        vision_eval_time_limit_s=0.0,
    ),
}


@dataclass(frozen=True)
class PipelineOptions:
    """The whole two-phase job: capture, train-repr, train-policy (state and vision), evaluate, leaderboard."""

    quick: bool = False
    """Small sizes: within 20 minutes on 2 CPU cores (12.5 measured, 16.4 held to 1.5 cores)."""
    tiny: bool = False
    """Minimal sizes, for tests (seconds; results mean nothing)."""
    track: str = "expressway"
    """Track: built-in name, random:SEED or CSV path."""
    car: str = "hatchback"
    """Car preset."""
    runs: str = "runs"
    """Folder for every stage's outputs."""
    image_hw_px: tuple[int, int] = (0, 0)
    """Frame height and width, px (0 0: the mode's; full: 280 470, the paper's; quick: 140 236)."""
    seed: int = 0
    """Seed of every stage."""
    state_policy_laps: int = 0
    """Laps the trained state policy drives for Phase 1 beside the AI's, over 2 cars, undisrupted (capture --policy;
    0: none). Phase 1 then waits for the state policy: with 2, make quick took 22.2 min (13.1 without); its encoder
    erred a third as much at the walls, and its vision policies finished 100 of 104 starts over 8 training seeds
    (without: 99; docs/results/vision-expressway-hatchback)."""
    json: bool = False
    """Print the summary as JSON."""

    def __post_init__(self) -> None:
        # Refused before the state policy's process starts, not minutes in (a 0 beside a size was ignored before).
        h, w = self.image_hw_px
        if (h, w) != (0, 0) and not (h > 0 and w > 0):
            raise ValueError(f"--image-hw-px must be two positive sizes (height, width) or 0 0, got {h} {w}")
        if self.quick and self.tiny:
            raise ValueError("--quick and --tiny: choose one")
        if self.state_policy_laps < 0:
            raise ValueError(f"--state-policy-laps must be >= 0 (0: none), got {self.state_policy_laps}")

    @property
    def mode(self) -> str:
        return "tiny" if self.tiny else "quick" if self.quick else "full"


def _clock(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


class StageReport:
    """What the pipeline says on stderr while it runs (stdout keeps the summary, or the one JSON document): a line
    as each stage starts and as it ends, with the time since the pipeline started and the stage's own, and a bar
    with ETA during the long ones (hidden where stderr is not a terminal)."""

    def __init__(self, enabled: bool = True) -> None:
        self.enabled = enabled
        self.t0 = time.perf_counter()

    def line(self, text: str) -> None:
        if self.enabled:
            note(f"[pipeline {_clock(time.perf_counter() - self.t0)}] {text}")

    def started(self, name: str, detail: str = "") -> float:
        self.line(f"{name}: started" + (f" ({detail})" if detail else ""))
        return time.perf_counter()

    def ended(self, name: str, since: float, detail: str = "") -> None:
        self.line(f"{name}: done in {_clock(time.perf_counter() - since)}" + (f"; {detail}" if detail else ""))

    @contextlib.contextmanager
    def stage(self, name: str, detail: str = "") -> Iterator[None]:
        since = self.started(name, detail)
        try:
            yield
        except BaseException:
            self.line(f"{name}: stopped after {_clock(time.perf_counter() - since)}")
            raise
        self.ended(name, since)

    def background(self, name: str, result: Callable[[], Any], detail: str = "") -> Callable[[], Any]:
        """``result`` (a second process's, see :func:`_in_second_process`) reported as a stage: started now, ended
        when its result first arrives."""
        since = self.started(name, ", ".join(filter(None, [detail, "in a second process"])))

        @functools.cache
        def waited() -> Any:
            value = result()
            self.ended(name, since)
            return value

        return waited

    @contextlib.contextmanager
    def bar(self, total: int | None, unit: str, desc: str) -> Iterator[Any]:
        with progress_bar(total, unit, desc, enabled=self.enabled) as bar:
            yield bar


def _capture_path(opts: PipelineOptions, name: str) -> Path:
    return Path(opts.runs) / "capture" / f"{name}.h5"


def _captured(path: Path) -> str:
    """``complete``, ``partial`` (an interrupted capture, resumable) or ``none`` (absent or unreadable)."""
    from vision_rl.capture.h5format import CaptureFormatError, open_capture

    if not path.exists():
        return "none"
    try:
        with open_capture(path) as f:
            return "complete" if f.complete else "partial"
    except CaptureFormatError:
        return "none"


def _image_hw_px(opts: PipelineOptions, sizes: PipelineSizes) -> tuple[int, int]:
    return opts.image_hw_px if all(opts.image_hw_px) else sizes.image_hw_px


def _capture(
    opts: PipelineOptions,
    sizes: PipelineSizes,
    name: str,
    laps: int,
    disrupt: bool,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    from vision_rl.capture.sim_capture import CaptureConfig, capture_sim

    out = _capture_path(opts, name)
    state = _captured(out)
    if state == "complete":
        return out
    resume = state == "partial"
    captured = capture_sim(
        CaptureConfig(
            out=str(out),
            track=opts.track,
            car=opts.car,
            laps=laps,
            disrupt_ai=disrupt,
            cars=sizes.capture_cars,
            fps=sizes.capture_fps,
            image_hw_px=_image_hw_px(opts, sizes),
            seed=opts.seed + (0 if disrupt else 1),
            resume=resume,
            force=not resume,
        ),
        progress,
    )
    if captured["interrupted"]:  # what it captured is kept, and the next pipeline resumes it
        raise KeyboardInterrupt
    return out


#: Cars the state policy drives together for ``--state-policy-laps``, as in make experiment's policy captures.
STATE_POLICY_CARS = 2


def _capture_state_policy(opts: PipelineOptions, sizes: PipelineSizes) -> Path:
    """``opts.state_policy_laps`` of the trained state policy, undisrupted: always captured again, as the policy is
    trained again, and cut at the lap-time protocol's time limit, where a policy that does not lap would run on."""
    from vision_rl.capture.sim_capture import CaptureConfig, capture_sim
    from vision_rl.evaluation.protocol import TIME_LIMIT_LIMIT_LAPS
    from vision_rl.sim.driving import line_and_profile
    from vision_rl.sim.track_library import load_track
    from vision_rl.sim.vehicle import get_preset
    from vision_rl.training.artifact import load_policy

    out = _capture_path(opts, "state_policy")
    laps = opts.state_policy_laps
    limit_lap_s = line_and_profile(load_track(opts.track), get_preset(opts.car))[1].lap_time_s
    driver = load_policy(Path(opts.runs) / "policy" / "pipeline-state").driver()
    try:
        captured = capture_sim(
            CaptureConfig(
                out=str(out),
                track=opts.track,
                car=opts.car,
                laps=laps,
                disrupt_ai=False,
                cars=STATE_POLICY_CARS,
                fps=sizes.capture_fps,
                image_hw_px=_image_hw_px(opts, sizes),
                seed=opts.seed,
                force=True,
                max_frames=math.ceil(laps * TIME_LIMIT_LIMIT_LAPS * limit_lap_s * sizes.capture_fps),
            ),
            driver=driver,
        )
    finally:
        driver.close()
    if captured["interrupted"]:
        raise KeyboardInterrupt
    return out


def _send_result(send: Any, niceness: int, fn: Callable[..., Any], args: tuple) -> None:
    os.nice(niceness)
    try:
        send.send((True, fn(*args)))
    except BaseException as exc:  # an interrupt too: the parent raises what its stage raised
        send.send((False, exc))


@contextlib.contextmanager
def _in_second_process(fn: Callable[..., Any], *args: Any, niceness: int = 0) -> Iterator[Callable[[], Any]]:
    """``fn(*args)`` in a spawned process at ``niceness``; yields a function that waits for its result and returns
    it, raises what it raised, or raises RuntimeError when the process ended without one (killed, out of memory):
    a pool would wait for that result for ever. Leaving the block stops the process (SIGTERM), so an interrupted
    pipeline leaves nothing running."""
    context = multiprocessing.get_context("spawn")  # no fork of a process that holds torch's threads
    receive, send = context.Pipe(duplex=False)
    process = context.Process(target=_send_result, args=(send, niceness, fn, args), daemon=True)
    process.start()
    send.close()

    def result() -> Any:
        try:
            ok, value = receive.recv()
        except EOFError:
            process.join()
            raise RuntimeError(
                f"the pipeline's second process ({fn.__name__}) ended with exit code {process.exitcode} and no result"
            ) from None
        if not ok:
            raise value
        return value

    try:
        yield result
    finally:
        process.terminate()
        process.join()
        receive.close()


def sampler_processes(sizes: PipelineSizes) -> int:
    """The vision policy's sampler processes: the mode's, or 0 (sampling in the learner's process) without Ray, the
    `ray` extra that the README's set-up installs."""
    from vision_rl.training.distributed import DistributedError, import_ray

    try:
        import_ray()
    except DistributedError:
        return 0
    return sizes.vision_workers


def _policy_stage(
    kind: str,
    encoder: str,
    sizes: PipelineSizes,
    track: str,
    car: str,
    runs: str,
    seed: int,
    device: str,
    progress: Callable[[int, int, Any], None] | None = None,
) -> dict[str, Any]:
    """Train one Phase 2 policy (``state``, or ``vision`` on ``encoder``) from scratch and time its last weights by
    the protocol; ``progress`` is train-policy's (steps done, steps in all, the last evaluation)."""
    from vision_rl.config import from_flat
    from vision_rl.phase2_rl.config import TrainPolicyConfig
    from vision_rl.phase2_rl.train import train_policy
    from vision_rl.training.artifact import MODEL_NAME
    from vision_rl.training.evaluate import evaluate_policy

    vision = kind == "vision"
    workers = sampler_processes(sizes) if vision else 0
    t0 = time.perf_counter()
    out = Path(runs) / "policy" / f"pipeline-{kind}"
    trained = train_policy(
        from_flat(
            TrainPolicyConfig,
            encoder=encoder,
            track=track,
            car=car,
            cars=sizes.vision_cars if vision else sizes.state_cars,
            steps=sizes.vision_steps if vision else sizes.state_steps,
            preset=sizes.sac_preset,
            out=str(out),
            seed=seed,
            force=True,
            checkpoint_every_steps=0,
            eval_every_steps=sizes.eval_every_steps,
            save_buffer=False,
            stats_steps=sizes.stats_steps,
            learning_starts=sizes.vision_learning_starts if vision else sizes.state_learning_starts,
            gradient_steps=sizes.vision_gradient_steps if vision else 0,
            batch_size=sizes.batch_size,
            buffer_size=sizes.buffer_size,
            device=device,
            steer_action=sizes.steer_action,
            workers=workers or None,
            target_entropy=sizes.vision_target_entropy if vision else 0.0,
            learning_rate_final=sizes.vision_learning_rate_final if vision else 0.0,
            stuck_ends_episode=vision and sizes.vision_stuck_ends_episode,
            steer_change_penalty_c_s=sizes.vision_steer_change_penalty_c_s if vision else 0.0,
            steer_change_penalty_scale="usable",  # moot where c_s is 0
            critic_state=vision and sizes.vision_critic_state,
        ),
        progress,
    )
    if trained["interrupted"]:
        raise KeyboardInterrupt
    t1 = time.perf_counter()
    evaluation = evaluate_policy(
        out,
        seeds=sizes.vision_eval_seeds if vision else sizes.state_eval_seeds,
        time_limit_s=sizes.vision_eval_time_limit_s if vision else sizes.state_eval_time_limit_s,
        name=f"pipeline-{kind}",
        device="cpu",
    )
    return {
        "policy": str(out / MODEL_NAME),
        "num_timesteps": trained["num_timesteps"],
        "train_time_s": trained["train_time_s"],
        "sampling": trained["sampling"],
        "best_lap_time_s": evaluation["best_lap_time_s"],
        "median_lap_time_s": evaluation["median_lap_time_s"],
        "n_finished": evaluation["n_finished"],
        "n_seeds": evaluation["n_seeds"],
        "clean": evaluation["clean"],
        "distance_m": max(s["distance_m"] for s in evaluation["seeds"]),
        "evaluation_json": evaluation.get("evaluation_json"),
        "wall_time_s": {"train": round(t1 - t0, 1), "evaluate": round(time.perf_counter() - t1, 1)},
    }


def state_in_second_process(*stage: Any) -> contextlib.AbstractContextManager[Callable[[], dict[str, Any]]]:
    """The state policy's stage (``_policy_stage("state", "", *stage)``) in a second process at the lowest priority:
    it takes what the other stages leave of the cores (the vision learner and its sampler wait for each other at
    times), so the vision policy, the long pole, is not slowed by it."""
    return _in_second_process(_policy_stage, "state", "", *stage, niceness=19)


def _reported_policy_stage(
    report: StageReport, kind: str, encoder: str, steps: int, stage: tuple[Any, ...]
) -> dict[str, Any]:
    """:func:`_policy_stage` in this process, with its start and end lines and a bar over its training steps."""
    with report.stage(f"{kind} policy", f"{steps} steps, then the lap-time protocol"):
        with report.bar(steps, "step", f"{kind} policy") as bar:
            return _policy_stage(kind, encoder, *stage, progress=lambda done, total, last: show(bar, done, total))


def pipeline_phase2(
    encoder: str,
    sizes: PipelineSizes,
    *,
    mode: str,
    track: str = "expressway",
    car: str = "hatchback",
    runs: str = "runs",
    seed: int = 0,
    device: str = "auto",
    state: Callable[[], dict[str, Any]] | None = None,
    report: StageReport | None = None,
) -> dict[str, Any]:
    """Train and evaluate the state policy and, with an ``encoder``, the vision policy; the leaderboard; returns a
    summary dict. Runs go to ``runs/policy/pipeline-<kind>`` (replaced if present).

    With an encoder the state policy trains in a second process beside the vision one, whose frames render and
    embed in ``sizes.vision_workers`` sampler processes while its learner updates: together they keep the cores busy
    (the state run needs about one core, the vision learner and its sampler about one each). ``state`` waits for
    the state policy's result where the caller already trains it in such a process (:func:`state_in_second_process`).
    ``report`` says on stderr as each stage starts and ends."""
    from vision_rl.evaluation.leaderboard import leaderboard

    report = report or StageReport()
    summary: dict[str, Any] = {"mode": mode, "track": track, "car": car}
    stage = (sizes, track, car, runs, seed, device)
    if encoder:
        with contextlib.ExitStack() as stack:
            if state is None:
                state = report.background("state policy", stack.enter_context(state_in_second_process(*stage)))
            vision = _reported_policy_stage(report, "vision", encoder, sizes.vision_steps, stage)
            summary["state"], summary["vision"] = state(), vision
    else:
        summary["state"] = _reported_policy_stage(report, "state", "", sizes.state_steps, stage)
        summary["vision"] = {"skipped": "no encoder checkpoint given"}
    t0 = time.perf_counter()
    with report.stage("leaderboard"):
        table = leaderboard(track, car, runs)
    summary["leaderboard"] = table
    summary["leaderboard_time_s"] = round(time.perf_counter() - t0, 1)
    return summary


def _check_kept_encoder(opts: PipelineOptions) -> None:
    """An encoder kept from an earlier run must have seen the state policy's laps exactly when this run asks for
    them: else the option would be dropped, or taken, without a word."""
    data_json = Path(opts.runs) / "repr" / "pipeline" / "data.json"
    if not (data_json.parent / "ckpt.pt").is_file() or not data_json.is_file():
        return
    files = {Path(entry["file"]).name for entry in json.loads(data_json.read_text())["train"]}
    seen_laps = _capture_path(opts, "state_policy").name in files
    if seen_laps != bool(opts.state_policy_laps):
        seen = "with" if seen_laps else "without"
        raise ValueError(
            f"{data_json.parent} holds an encoder trained {seen} the state policy's laps and "
            f"--state-policy-laps is {opts.state_policy_laps}: remove that folder to train it again, or "
            "run as before"
        )


def run_pipeline_stages(opts: PipelineOptions, report: StageReport | None = None) -> dict[str, Any]:
    """Run every stage; returns a summary with each stage's figures and durations. ``report`` (by default one on
    stderr) says as each stage starts and ends."""
    sizes = SIZES[opts.mode]
    report = report or StageReport()
    _check_kept_encoder(opts)  # before the state policy's minutes
    # The state policy needs neither the frames nor the encoder: it trains from the start, at the lowest priority,
    # on what the captures and Phase 1 leave of the cores, and then beside the vision policy.
    with state_in_second_process(sizes, opts.track, opts.car, opts.runs, opts.seed, "auto") as state:
        return _stages_beside_the_state_policy(opts, sizes, report.background("state policy", state), report)


def _reported_capture(report: StageReport, opts: PipelineOptions, sizes: PipelineSizes) -> Path:
    """The disrupted laps' capture, with its start and end lines and a bar over its laps."""
    with report.stage("capture", f"{sizes.train_laps} disrupted laps"):
        with report.bar(sizes.train_laps, "lap", "capture") as bar:
            return _capture(
                opts, sizes, "train", sizes.train_laps, True, lambda laps, frames: show(bar, laps, frames=frames)
            )


def _stages_beside_the_state_policy(
    opts: PipelineOptions, sizes: PipelineSizes, state: Callable[[], dict[str, Any]], report: StageReport
) -> dict[str, Any]:
    from vision_rl.phase1_repr.config import TrainReprConfig
    from vision_rl.phase1_repr.train import train_repr

    summary: dict[str, Any] = {"mode": opts.mode, "track": opts.track, "car": opts.car}
    t_start = t0 = time.perf_counter()
    # A capture keeps about 1.2 cores busy: the clean laps are captured in a second process beside the disrupted
    # ones; what a stopped one captured is resumed by the next pipeline.
    if _captured(_capture_path(opts, "eval")) == "complete":
        eval_h5 = _capture_path(opts, "eval")
        report.line(f"capture of the clean laps: kept {eval_h5}")
        train_h5 = _reported_capture(report, opts, sizes)
    else:
        with _in_second_process(_capture, opts, sizes, "eval", sizes.eval_laps, False) as clean:
            clean = report.background("capture of the clean laps", clean, f"{sizes.eval_laps} laps")
            train_h5 = _reported_capture(report, opts, sizes)
            eval_h5 = clean()
    summary["capture"] = {"train": str(train_h5), "eval": str(eval_h5), "seconds": time.perf_counter() - t0}

    repr_out = Path(opts.runs) / "repr" / "pipeline"
    ckpt = repr_out / "ckpt.pt"
    data = [str(train_h5)]
    if opts.state_policy_laps and not ckpt.is_file():
        t0 = time.perf_counter()
        state = functools.cache(state)  # Phase 2 takes this same result
        report.line("the state policy's laps: waiting for the state policy")
        state()
        t1 = time.perf_counter()
        with report.stage("the state policy's laps", f"{opts.state_policy_laps} laps"):
            data.append(str(_capture_state_policy(opts, sizes)))
        summary["state_policy_capture"] = {"path": data[-1], "waited_s": t1 - t0, "seconds": time.perf_counter() - t1}

    t0 = time.perf_counter()
    if ckpt.is_file():
        report.line(f"train-repr: kept {ckpt}")
    else:
        with report.stage("train-repr", f"{sizes.repr_epochs} epochs"), report.bar(None, "step", "train-repr") as bar:
            result = train_repr(
                TrainReprConfig(
                    data=",".join(data),
                    val=str(eval_h5),
                    epochs=sizes.repr_epochs,
                    max_steps=sizes.repr_max_steps,
                    out=str(repr_out),
                    force=True,
                    seed=opts.seed,
                    num_workers=0 if opts.tiny else 2,
                ),
                progress=lambda done, total, figures: show(bar, done, total),
            )
        summary["train_repr"] = {k: result.get(k) for k in ("best_epoch", "val_r2", "n_train_frames", "n_val_frames")}
    summary["train_repr_seconds"] = time.perf_counter() - t0

    summary["phase2"] = pipeline_phase2(
        str(ckpt),
        sizes,
        mode=opts.mode,
        track=opts.track,
        car=opts.car,
        runs=opts.runs,
        seed=opts.seed,
        state=state,
        report=report,
    )
    summary["seconds"] = time.perf_counter() - t_start
    return summary


def format_phase2(summary: dict[str, Any]) -> list[str]:
    """Text lines of a :func:`pipeline_phase2` summary: each policy's result, then the leaderboard."""
    from vision_rl.commands.evaluate import format_leaderboard
    from vision_rl.evaluation.outputs import format_lap_time

    lines = [f"Phase 2 ({summary['mode']}) on {summary['track']} / {summary['car']}"]
    for kind in ("state", "vision"):
        r = summary.get(kind, {})
        if "skipped" in r:
            lines.append(f"  {kind}: skipped ({r['skipped']})")
        elif r:
            workers = (r.get("sampling") or {}).get("workers", 0)
            sampled = f", {workers} sampler process{'es' * (workers > 1)}" if workers else ""
            lines.append(
                f"  {kind}: {r['num_timesteps']} steps in {r['wall_time_s']['train']:.0f} s{sampled}; "
                f"lap 2 best {format_lap_time(r['best_lap_time_s'])} ({r['n_finished']}/{r['n_seeds']} seeds finished, "
                f"{r['distance_m']:.0f} m driven at most); {r['policy']}"
            )
    return lines + format_leaderboard(summary["leaderboard"])


def format_pipeline(summary: dict[str, Any]) -> list[str]:
    """Text lines of a :func:`run_pipeline_stages` summary: stage times, the encoder's R^2, Phase 2's results."""
    capture = summary["capture"]
    lines = [
        f"vision-rl pipeline ({summary['mode']}) on {summary['track']} / {summary['car']}",
        f"  capture: {capture['seconds']:.0f} s -> {capture['train']} (disrupted), {capture['eval']} (clean)",
    ]
    by_policy = summary.get("state_policy_capture")
    if by_policy:
        lines.append(
            f"  the state policy's laps: {by_policy['seconds']:.0f} s -> {by_policy['path']} (after "
            f"{by_policy['waited_s']:.0f} s waiting for the state policy)"
        )
    repr_result = summary.get("train_repr")
    if repr_result is None:
        lines.append(f"  train-repr: kept the existing encoder ({summary['train_repr_seconds']:.0f} s)")
    else:
        r2 = ", ".join(f"{group} {value:.3f}" for group, value in (repr_result["val_r2"] or {}).items())
        scored = f"best epoch {repr_result['best_epoch']}; R^2 on the clean laps: {r2}" if r2 else "no epoch scored"
        lines.append(
            f"  train-repr: {summary['train_repr_seconds']:.0f} s on {repr_result['n_train_frames']} frames, {scored}"
        )
    return [*lines, *format_phase2(summary["phase2"]), f"done in {summary['seconds'] / 60:.1f} min"]


def run_pipeline(opts: PipelineOptions) -> int:
    previous = interrupt_on_sigterm()
    try:
        summary = run_pipeline_stages(opts, StageReport())
    except KeyboardInterrupt:
        emit(
            {"interrupted": True, "resume": "run the same command again"},
            opts.json,
            lambda r: ["interrupted: the finished stages are kept (a policy trains again); run the same command again"],
        )
        return 130
    finally:
        restore_sigterm(previous)
    emit(summary, opts.json, format_pipeline)
    return 0
