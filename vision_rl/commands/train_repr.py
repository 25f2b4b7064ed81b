"""`train-repr`: Phase 1, the frame encoder trained on capture files (:func:`vision_rl.phase1_repr.train.train_repr`).

Prints where the run went and the kept epoch's R^2 per target group, or one JSON object with ``--json``.
``--devices N --strategy ddp`` trains in N processes (Lightning's DDP): the ones Lightning starts run this same
command line again and print nothing; the process you started prints the result.

SIGTERM or Ctrl-C stops the run at once (exit 143 or 130): ``lightning/last.ckpt`` keeps the last epoch's end, no
``ckpt.pt`` is written, and ``--resume`` goes on to the weights the uninterrupted run would have ended in.
"""

from __future__ import annotations

import dataclasses
import signal
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vision_rl.commands.output import emit, note, progress_bar, show
from vision_rl.phase1_repr.config import TrainReprConfig, launch_rank


@dataclass(frozen=True)
class TrainReprOptions(TrainReprConfig):
    """Train the Phase-1 encoder on capture files; writes ckpt.pt, metrics.json, TensorBoard logs and a figure."""

    progress: bool = True
    """Show a progress bar (optimiser steps) on stderr."""
    json: bool = False
    """Print the result as JSON."""


def format_train_repr(result: dict[str, Any]) -> list[str]:
    """The paths written (only those that exist), the frames, the kept epoch and its R^2 per target group; of an
    interrupted run, what ``last.ckpt`` keeps."""
    if result.get("interrupted"):
        return [result["note"]]
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


def _captures_here(opts: TrainReprOptions) -> TrainReprOptions:
    """The design card's bare ``train-repr``: with no --data, the capture files (``*.h5``) of the current folder;
    with no --out either, the run goes into the current folder, so ``ckpt.pt`` lies beside the captures where
    ``train-policy --encoder ckpt.pt`` finds it. Says so on stderr (stdout keeps the result)."""
    if opts.data or opts.resume:
        return opts
    found = sorted(p.name for p in Path.cwd().glob("*.h5") if p.is_file())
    if not found:
        return opts  # train_repr says that training needs data
    out = "." if opts.out == TrainReprConfig.out else opts.out
    if launch_rank() == 0:
        note(f"train-repr: no --data, training on the capture files here: {', '.join(found)}")
        note(f"train-repr: writing the run into {Path(out).resolve()} (ckpt.pt, metrics.json, ...)")
    return dataclasses.replace(opts, data=",".join(found), out=out)


class _Stop:
    """SIGTERM raises KeyboardInterrupt, as Ctrl-C does, so that training stops at once; ``signal`` says which came."""

    def __init__(self) -> None:
        self.signal = signal.SIGINT

    def _on_sigterm(self, signum: int, frame: Any) -> None:
        self.signal = signal.SIGTERM
        raise KeyboardInterrupt

    @contextmanager
    def installed(self) -> Iterator[None]:
        previous = signal.signal(signal.SIGTERM, self._on_sigterm)
        try:
            yield
        finally:
            signal.signal(signal.SIGTERM, previous)

    @property
    def exit_code(self) -> int:
        return 143 if self.signal == signal.SIGTERM else 130


def interrupted_result(out: Path, stop: KeyboardInterrupt) -> dict[str, Any]:
    """What an interrupted run keeps: from :class:`TrainingInterrupted`, or from the run folder when the signal came
    outside training (loading the data, writing ``ckpt.pt`` after the last epoch)."""
    from vision_rl.phase1_repr.train import TrainingInterrupted

    if isinstance(stop, TrainingInterrupted):
        last, epochs, steps = stop.last_ckpt, stop.finished_epochs, stop.optimiser_steps
    else:
        last, epochs, steps = Path(out) / "lightning" / "last.ckpt", None, None
        last = last if last.is_file() else None
    if last is None:
        note = "interrupted before an epoch ended: nothing to resume; run again to start over"
    elif epochs is None:
        note = f"interrupted: {last} keeps the run's last epoch's end; run again with --resume to continue"
    else:
        held = f"{epochs} finished epoch{'s' * (epochs != 1)} (optimiser step {steps})"
        note = f"interrupted: {last} keeps {held}; run again with --resume to continue"
    return {"interrupted": True, "last_ckpt": str(last) if last else None, "finished_epochs": epochs, "note": note}


def run_train_repr(opts: TrainReprOptions) -> int:
    """Train; exit 0, or 143 (SIGTERM) / 130 (Ctrl-C) for a run stopped with its last epoch's end kept."""
    from vision_rl.phase1_repr.train import train_repr

    first = launch_rank() == 0  # the other DDP processes train quietly
    opts = _captures_here(opts)
    stop = _Stop()
    stopped: KeyboardInterrupt | None = None
    with stop.installed(), progress_bar(None, "step", "train-repr", enabled=opts.progress and first) as bar:

        def progress(done: int, total: int, figures: dict[str, float]) -> None:
            show(bar, done, total, **{k: round(v, 4) if isinstance(v, float) else v for k, v in figures.items()})

        try:
            result = train_repr(opts, progress if opts.progress and first else None)
        except KeyboardInterrupt as exc:  # TrainingInterrupted, or a signal outside training
            stopped = exc
    if stopped is not None:
        if first:
            emit(interrupted_result(Path(opts.out), stopped), opts.json, format_train_repr)
        return stop.exit_code
    if "rank" not in result:
        emit(result, opts.json, format_train_repr)
    return 0
