"""`train-repr`: Phase 1, the frame encoder trained on capture files (:func:`vision_rl.phase1_repr.train.train_repr`).

Prints where the run went and the kept epoch's R^2 per target group, or one JSON object with ``--json``.
``--devices N --strategy ddp`` trains in N processes (Lightning's DDP): the ones Lightning starts run this same
command line again and print nothing; the process you started prints the result.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vision_rl.commands.output import emit, progress_bar, show
from vision_rl.phase1_repr.train import TrainReprConfig, launch_rank


@dataclass(frozen=True)
class TrainReprOptions(TrainReprConfig):
    """Train the Phase-1 encoder on capture files; writes ckpt.pt, metrics.json, TensorBoard logs and a figure."""

    progress: bool = True
    """Show a progress bar (optimiser steps) on stderr."""
    json: bool = False
    """Print the result as JSON."""


def format_train_repr(result: dict[str, Any]) -> list[str]:
    """The paths written (only those that exist), the frames, the kept epoch and its R^2 per target group."""
    paths = [
        (label, result.get(key))
        for label, key in (("metrics", "metrics_json"), ("figure", "figure"), ("TensorBoard", "tensorboard"))
    ]
    written = "   ".join(f"{label}: {path}" for label, path in paths if path and Path(path).exists())
    if result.get("best_epoch") is None:
        kept = "kept the last weights (no validation epoch finished)"
    else:
        kept = f"kept epoch {result['best_epoch']} (val loss {result['val_loss']:.4g})"
    lines = [
        f"ckpt.pt: {result['ckpt']}",
        *([written] if written else []),
        f"frames: {result['n_train_frames']} training, {result['n_val_frames']} validation; {kept}",
    ]
    if "train_frames_per_s" in result:
        lines.append(f"training: {result['train_frames_per_s']:.1f} frames/s on {result.get('devices', 1)} device(s)")
    for group, value in (result.get("val_r2") or {}).items():
        lines.append(f"  R^2 {group:<20s} {value:.4f}")
    return lines


def run_train_repr(opts: TrainReprOptions) -> int:
    from vision_rl.phase1_repr.train import train_repr

    first = launch_rank() == 0  # the other DDP processes train quietly
    with progress_bar(None, "step", "train-repr", enabled=opts.progress and first) as bar:

        def progress(done: int, total: int, figures: dict[str, float]) -> None:
            show(bar, done, total, **{k: round(v, 4) if isinstance(v, float) else v for k, v in figures.items()})

        result = train_repr(opts, progress if opts.progress and first else None)
    if "rank" not in result:
        emit(result, opts.json, format_train_repr)
    return 0
