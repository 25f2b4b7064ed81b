"""`bench-latency`: the encoder's batch-1 latency and throughput (:func:`vision_rl.phase1_repr.bench.bench_latency`),
beside the paper's 8 ms budget."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from vision_rl.commands.choices import BACKBONES, ENCODER_RUNTIMES
from vision_rl.commands.output import emit
from vision_rl.phase1_repr.config import BenchLatencyConfig


@dataclass(frozen=True)
class BenchLatencyOptions(BenchLatencyConfig):
    """Measure the encoder's batch-1 latency (uint8 frame in, 64-D out) and batched throughput."""

    option_choices: ClassVar[dict[str, tuple[str, ...]]] = {"backbone": BACKBONES, "runtime": ENCODER_RUNTIMES}

    json: bool = False
    """Print one JSON object."""


def format_bench_latency(result: dict[str, Any]) -> list[str]:
    budget = result["budget_ms"]
    h, w = result["input_hw_px"]
    lines = [
        f"encoder: {result['encoder']} ({result['parameters']:,} parameters), frames {w}x{h}, {result['device']} "
        f"({result['device_name']}), {result['threads']} threads, runtime {result['runtime']}",
        f"batch 1 over {result['runs']} runs: p50 {result['p50_ms']:.2f} ms  p90 {result['p90_ms']:.2f} ms  "
        f"p99 {result['p99_ms']:.2f} ms   (paper's budget: {budget:.0f} ms per frame on a GPU: "
        f"{'within' if result['within_budget'] else 'OVER'})",
        f"throughput at batch {result['batch_size']}: {result['throughput_fps']:.0f} frames/s",
    ]
    for name, v in result["variants"].items():
        if "p50_ms" in v:
            lines.append(
                f"  {name:<14s} p50 {v['p50_ms']:.2f} ms  p90 {v['p90_ms']:.2f} ms  p99 {v['p99_ms']:.2f} ms"
                f"   (budget {budget:.0f} ms)"
            )
        else:
            lines.append(f"  {name:<14s} {v.get('error') or v.get('skipped')}")
    return lines


def run_bench_latency(opts: BenchLatencyOptions) -> int:
    from vision_rl.phase1_repr.bench import bench_latency

    emit(bench_latency(opts), opts.json, format_bench_latency)
    return 0
