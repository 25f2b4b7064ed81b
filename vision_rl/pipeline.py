"""`vision-rl pipeline`: the whole two-phase job of the vision paper on one track and car.

1. capture: disrupted built-in AI laps (training frames) and clean laps (the evaluation set, as the paper's
   "undisturbed driving");
2. train-repr: the space2depth encoder on those frames, best checkpoint on the clean laps;
3. train-policy (state, then vision on the frozen encoder), evaluate both, leaderboard (Phase 2).

``--quick`` shrinks every stage to finish in about 20 minutes on 2 CPU cores; without it the paper-scale recipe
runs (50 disrupted laps at 60 fps, 50 epochs, millions of SAC steps: days on a CPU). ``--tiny`` is for tests.
Each stage's outputs stay under ``--runs`` and a stage whose output is complete is not redone, so an interrupted
pipeline continues where it stopped.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vision_rl.config import doc


@dataclass(frozen=True)
class PipelineSizes:
    train_laps: int
    eval_laps: int
    cars: int
    fps: float
    epochs: int
    max_repr_steps: int
    width_px: int
    height_px: int


SIZES = {
    "tiny": PipelineSizes(1, 1, cars=2, fps=5, epochs=1, max_repr_steps=3, width_px=96, height_px=64),
    # Half the paper's frame side: training the encoder on 470 x 280 frames ran at about 30 frames/s on one of
    # these cores, on 236 x 140 at about 230 (measured side by side), which is what fits the quick budget.
    # On the 8,048 frames of 4 disrupted laps, R^2 on the clean lap was 0.90-0.99 (by target group) after 4 epochs
    # (86 s) and 0.966-0.997 after 10 (214 s; measured in `make quick`).
    "quick": PipelineSizes(4, 1, cars=4, fps=10, epochs=10, max_repr_steps=-1, width_px=236, height_px=140),
    "full": PipelineSizes(50, 5, cars=4, fps=60, epochs=50, max_repr_steps=-1, width_px=470, height_px=280),
}


@dataclass
class PipelineConfig:
    """The whole two-phase job: capture, train-repr, train-policy (state and vision), evaluate, leaderboard."""

    quick: bool = field(default=False, metadata=doc("small sizes that finish in about 20 minutes on 2 CPU cores"))
    tiny: bool = field(default=False, metadata=doc("minimal sizes, for tests (seconds; results mean nothing)"))
    track: str = field(default="expressway", metadata=doc("track: built-in name, random:SEED or CSV path"))
    car: str = field(default="hatchback", metadata=doc("car preset"))
    runs: str = field(default="runs", metadata=doc("folder for every stage's outputs"))
    width: int = field(default=0, metadata=doc("frame width, px (0: the mode's; full: 470, the paper's; quick: 236)"))
    height: int = field(default=0, metadata=doc("frame height, px (0: the mode's; full: 280, the paper's; quick: 140)"))
    seed: int = field(default=0, metadata=doc("seed of every stage"))
    json: bool = field(default=False, metadata=doc("print the summary as JSON"))


def _capture(cfg: PipelineConfig, sizes: PipelineSizes, name: str, laps: int, disrupt: bool) -> Path:
    from vision_rl.capture.h5format import CaptureFormatError, open_capture
    from vision_rl.capture.sim_capture import CaptureConfig, capture_sim

    out = Path(cfg.runs) / "capture" / f"{name}.h5"
    resume = False
    if out.exists():
        try:
            with open_capture(out) as f:
                if f.complete:
                    return out
            resume = True
        except CaptureFormatError:
            pass
    capture_sim(
        CaptureConfig(
            out=str(out), track=cfg.track, car=cfg.car, laps=laps, disrupt_ai=disrupt, cars=sizes.cars,
            fps=sizes.fps, width=cfg.width or sizes.width_px, height=cfg.height or sizes.height_px,
            seed=cfg.seed + (0 if disrupt else 1),
            resume=resume, force=not resume,
        )
    )  # fmt: skip
    return out


def run_pipeline_stages(cfg: PipelineConfig) -> dict[str, Any]:
    """Run every stage; returns a summary with each stage's figures and durations."""
    from vision_rl.phase1_repr.train import TrainReprConfig, train_repr
    from vision_rl.phase2_rl.pipeline import pipeline_phase2

    mode = "tiny" if cfg.tiny else "quick" if cfg.quick else "full"
    sizes = SIZES[mode]
    summary: dict[str, Any] = {"mode": mode, "track": cfg.track, "car": cfg.car}
    t_start = t0 = time.perf_counter()
    train_h5 = _capture(cfg, sizes, "train", sizes.train_laps, disrupt=True)
    eval_h5 = _capture(cfg, sizes, "eval", sizes.eval_laps, disrupt=False)
    summary["capture"] = {"train": str(train_h5), "eval": str(eval_h5), "seconds": time.perf_counter() - t0}

    t0 = time.perf_counter()
    repr_out = Path(cfg.runs) / "repr" / "pipeline"
    ckpt = repr_out / "ckpt.pt"
    if not ckpt.is_file():
        result = train_repr(
            TrainReprConfig(
                data=str(train_h5), val=str(eval_h5), epochs=sizes.epochs, max_steps=sizes.max_repr_steps,
                out=str(repr_out), force=True, seed=cfg.seed, num_workers=0 if cfg.tiny else 2, progress=False,
            )
        )  # fmt: skip
        summary["train_repr"] = {k: result.get(k) for k in ("best_epoch", "val_r2", "n_train_frames", "n_val_frames")}
    summary["train_repr_seconds"] = time.perf_counter() - t0

    summary["phase2"] = pipeline_phase2(
        str(ckpt), track=cfg.track, car=cfg.car, runs=cfg.runs, quick=cfg.quick, tiny=cfg.tiny, seed=cfg.seed
    )
    summary["seconds"] = time.perf_counter() - t_start
    return summary


def format_pipeline(summary: dict[str, Any]) -> list[str]:
    """Text lines of a :func:`run_pipeline_stages` summary: stage times, the encoder's R^2, Phase 2's results."""
    from vision_rl.phase2_rl.pipeline import format_pipeline_phase2

    capture = summary["capture"]
    lines = [
        f"vision-rl pipeline ({summary['mode']}) on {summary['track']} / {summary['car']}",
        f"  capture: {capture['seconds']:.0f} s -> {capture['train']} (disrupted), {capture['eval']} (clean)",
    ]
    repr_result = summary.get("train_repr")
    if repr_result is None:
        lines.append(f"  train-repr: kept the existing encoder ({summary['train_repr_seconds']:.0f} s)")
    else:
        r2 = ", ".join(f"{group} {value:.3f}" for group, value in (repr_result["val_r2"] or {}).items())
        scored = f"best epoch {repr_result['best_epoch']}; R^2 on the clean laps: {r2}" if r2 else "no epoch scored"
        lines.append(
            f"  train-repr: {summary['train_repr_seconds']:.0f} s on {repr_result['n_train_frames']} frames, {scored}"
        )
    return [*lines, *format_pipeline_phase2(summary["phase2"]), f"done in {summary['seconds'] / 60:.1f} min"]


def run_pipeline(cfg: PipelineConfig) -> int:
    from vision_rl.cli import emit

    emit(run_pipeline_stages(cfg), cfg.json, format_pipeline)
    return 0
