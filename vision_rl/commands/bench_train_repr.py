"""`vision-rl bench train-repr`: Phase 1's training step in frames/s per batch size and precision
(:func:`vision_rl.phase1_repr.bench.bench_train_step`)."""

from __future__ import annotations

from dataclasses import dataclass

from vision_rl.commands.output import emit
from vision_rl.phase1_repr.config import BenchTrainStepConfig


@dataclass(frozen=True)
class BenchTrainReprOptions(BenchTrainStepConfig):
    """Measure Phase 1's training step (train-repr's augmentation, network, loss and AdamW) on random frames already
    on the device, per batch size and precision: frames/s, the ceiling a data pipeline has to feed."""

    json: bool = False
    """Print the figures as JSON."""


def run_bench_train_repr(opts: BenchTrainReprOptions) -> int:
    from vision_rl.phase1_repr.bench import bench_train_step

    def text(result):
        h, w = result["input_hw_px"]
        head = (
            f"Phase 1 training step, frames {w}x{h}, {result['device']} ({result['device_name']}), "
            f"{result['threads']} threads"
        )
        return [head] + [
            f"  batch {r['batch_size']:>4} {r['precision']}: {r['step_ms']:8.2f} ms/step  {r['frames_per_s']:9.0f} "
            f"frames/s ({r['frames_per_s_spread'][0]:.0f}-{r['frames_per_s_spread'][1]:.0f})  "
            f"loss {r['loss_first']:.3f} -> {r['loss_last']:.3f}"
            for r in result["rows"]
        ]

    emit(bench_train_step(opts), opts.json, text)
    return 0
