"""`evaluate`: a trained policy through the one lap-time protocol (:mod:`vision_rl.evaluation.protocol`): two
consecutive laps from a rolling start, the second scored, best and median over start seeds. The record goes to
``evaluation.json`` beside the policy, where the leaderboard finds it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vision_rl.budget import DURATION_MAX_S
from vision_rl.envs.core import RacingConfig
from vision_rl.evaluation.controls import lap_controls
from vision_rl.evaluation.encoder_error import encoder_error_on_lap
from vision_rl.evaluation.leaderboard import evaluation_record, seal_evaluation
from vision_rl.evaluation.outputs import (
    check_video_dependencies,
    format_lap_time,
    plot_trajectory,
    write_trace,
    write_video,
)
from vision_rl.evaluation.protocol import BuiltinAI, LapTiming, time_laps
from vision_rl.evaluation.sections import compare_sections, lap_sections
from vision_rl.files import write_json
from vision_rl.sim.ai_driver import DEFAULT_SKILL
from vision_rl.training.artifact import BEST_DIR, MODEL_NAME, LoadedPolicy, PolicyDriver, load_policy

#: A run's evaluation record, beside its ``policy.pt``.
EVALUATION_NAME = "evaluation.json"


def evaluation_path(weights: Path) -> Path:
    """``evaluation.json`` beside a run's ``policy.pt``; ``<stem>.evaluation.json`` beside a snapshot."""
    name = EVALUATION_NAME if weights.name == MODEL_NAME else f"{weights.stem}.evaluation.json"
    return weights.parent / name


def default_policy_name(weights: Path) -> str:
    if weights.name == MODEL_NAME and weights.parent.name == BEST_DIR:  # the weights a run's held-out starts chose
        return f"{weights.parent.parent.name}/{BEST_DIR}"
    if weights.name == MODEL_NAME:
        return weights.parent.name
    if weights.parent.name == "checkpoints":
        return f"{weights.parent.parent.name}/{weights.stem}"
    return weights.stem


@dataclass(frozen=True)
class ProtocolRun:
    """How :func:`timed_record` times a driver and what it adds to the record (``evaluate``'s options)."""

    laps: int = 2
    seeds: int = 3
    seed: int = 0
    time_limit_s: float = 0.0
    video: str = ""
    plot: str = ""
    trace: str = ""
    sections_m: float = 0.0
    reference_skill: float = 1.0
    encoder_error: bool = False

    def check(self) -> None:
        """Refuse, before any driving, what cannot be run or written."""
        for name in ("laps", "seeds", "seed"):  # a str or float here failed deep in numpy, or drove on
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer):
                raise ValueError(f"{name} must be a whole number, got {value!r}")
        if self.seeds < 1:
            raise ValueError(f"seeds must be >= 1, got {self.seeds}")
        if not (isinstance(self.time_limit_s, int | float) and 0 <= self.time_limit_s <= DURATION_MAX_S):
            raise ValueError(
                f"time_limit_s must be a number of seconds from 0 (the protocol's limit) to {DURATION_MAX_S:g}, "
                f"got {self.time_limit_s!r}"
            )
        if self.sections_m < 0 or not 0.0 < self.reference_skill <= 1.0:
            raise ValueError(
                f"--sections-m must be >= 0 and --reference-skill in (0, 1], got {self.sections_m}, "
                f"{self.reference_skill}"
            )
        for flag, out in (("--plot", self.plot), ("--video", self.video), ("--trace", self.trace)):
            if out and Path(out).is_dir():  # found now, not after the whole evaluation
                raise ValueError(f"{flag} {out} is a folder: give the file to write")
        if self.video:
            check_video_dependencies()

    @property
    def records_steps(self) -> bool:
        return bool(self.plot or self.video or self.sections_m or self.encoder_error or self.trace)


def timed_record(
    driver: PolicyDriver,
    config: RacingConfig,
    name: str,
    run: ProtocolRun,
    encoder: Any = None,
) -> dict[str, Any]:
    """The protocol's record of ``driver`` on ``config``'s track and car: what ``evaluation.json`` holds, with the
    outputs ``run`` asks for (plot, video, trace, sections, the encoder's error). Closes the driver."""
    if run.encoder_error and encoder is None:
        raise ValueError("--encoder-error measures a vision policy's encoder: this policy observes the state")
    try:
        timing = time_laps(
            driver,
            config.track,
            config.car,
            range(run.seed, run.seed + run.seeds),
            run.laps,
            run.time_limit_s,
            record=run.records_steps,
        )
    finally:
        driver.close()
    result = evaluation_record(timing, driver.identity, name)
    best = timing.best_index()
    title = (
        f"{result['name']}: lap {run.laps} {format_lap_time(result['best_lap_time_s'])} "
        f"(seed {result['best_seed']}, {timing.track.name}, {timing.car.name})"
    )
    result["plot"] = str(plot_trajectory(timing, best, run.plot, title)) if run.plot else None
    result["video"] = str(write_video(timing, best, run.video, config.image_hw_px)) if run.video else None
    result["trace"] = str(write_trace(timing, run.trace)) if run.trace else None
    if run.sections_m > 0:
        result["sections"] = _sections(timing, best, run.sections_m, run.reference_skill)
    if run.encoder_error:
        result["encoder_error"] = _encoder_error(timing, best, encoder, config.image_hw_px)
    return result


def write_record(result: dict[str, Any], out: Path) -> dict[str, Any]:
    """Store ``result`` as ``out`` (where the leaderboard finds it), sealed again over the figures added since it
    was timed (sections, the encoder's error); the record then names its file."""
    write_json(out, seal_evaluation(result))
    result["evaluation_json"] = str(out)
    return result


def evaluate_policy(
    policy: str | os.PathLike[str] | LoadedPolicy,
    laps: int = 2,
    seeds: int = 3,
    seed: int = 0,
    encoder: str = "",
    time_limit_s: float = 0.0,
    video: str = "",
    plot: str = "",
    name: str = "",
    device: str = "cpu",
    write: bool = True,
    encoder_runtime: str = "auto",
    sections_m: float = 0.0,
    reference_skill: float = 1.0,
    encoder_error: bool = False,
    trace: str = "",
) -> dict[str, Any]:
    """Run the protocol for a policy (path or loaded) on the track and car it was trained on; returns the record
    and, with ``write``, stores it as ``evaluation.json`` beside the policy for the leaderboard. ``sections_m`` > 0
    adds ``sections``: the best scored lap against the built-in AI's at ``reference_skill``, section by section
    (:mod:`vision_rl.evaluation.sections`). ``encoder_error`` (vision) adds ``encoder_error``: the encoder's error on
    the 27 targets along the best scored lap and along the built-in AI's lap from the same start
    (:mod:`vision_rl.evaluation.encoder_error`). ``trace``: a CSV of every seed's run, step by step
    (:func:`~vision_rl.evaluation.outputs.write_trace`). An agent trained elsewhere: :func:`vision_rl.evaluate`."""
    run = ProtocolRun(laps, seeds, seed, time_limit_s, video, plot, trace, sections_m, reference_skill, encoder_error)
    run.check()
    loaded = policy if isinstance(policy, LoadedPolicy) else load_policy(policy, encoder, device, encoder_runtime)
    name = name or default_policy_name(loaded.weights_path)
    result = timed_record(loaded.driver(), loaded.config, name, run, loaded.encoder)
    return write_record(result, evaluation_path(loaded.weights_path)) if write else result


def _encoder_error(timing: LapTiming, best: int, encoder: Any, hw: tuple[int, int]) -> dict[str, Any]:
    ai = time_laps(BuiltinAI(), timing.track, timing.car, [timing.runs[best].seed], timing.laps, record=True)
    return {
        "policy": encoder_error_on_lap(timing, best, encoder, hw),
        "built_in_ai": {"skill": DEFAULT_SKILL, **encoder_error_on_lap(ai, 0, encoder, hw)},
    }


def _sections(timing: LapTiming, best: int, section_m: float, reference_skill: float) -> dict[str, Any]:
    reference: dict[str, Any] = {"driver": "built-in AI", "skill": reference_skill, "lap_time_s": None}
    rows = controls = None
    if timing.scored(best) is not None:
        ai = time_laps(
            BuiltinAI(skill=reference_skill),
            timing.track,
            timing.car,
            [run.seed for run in timing.runs],
            timing.laps,
            record=True,
        )
        ai_best = ai.best_index()
        if ai.scored(ai_best) is None:
            raise ValueError(f"the built-in AI at skill {reference_skill:g} finished no lap: no reference")
        reference["lap_time_s"] = ai.scored(ai_best).lap_time_s
        rows = compare_sections(lap_sections(timing, best, section_m), lap_sections(ai, ai_best, section_m))
        controls = {"lap": lap_controls(timing, best), "reference": lap_controls(ai, ai_best)}
    return {"section_m": section_m, "reference": reference, "rows": rows, "controls": controls}
