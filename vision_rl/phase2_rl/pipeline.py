"""The Phase-2 half of ``vision-rl pipeline``: train a state policy and (given an encoder) a vision policy, evaluate
both with the papers' protocol, and build the leaderboard. ``vision-rl pipeline`` runs it after capture and
train-repr."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vision_rl.phase2_rl.evaluate import evaluate_policy
from vision_rl.phase2_rl.leaderboard import leaderboard
from vision_rl.phase2_rl.train import TrainPolicyConfig, train_policy


@dataclass(frozen=True)
class Phase2Sizes:
    """How much of Phase 2 a pipeline mode runs (steps are transitions over all cars; -1 / 0: the preset's)."""

    preset: str
    state_steps: int
    vision_steps: int
    cars: int
    vision_cars: int
    """Vision sampling renders and embeds every car's frame each step (about 6-10 ms per car on 2 cores), so
    fewer cars per vector step give more updates per transition in a short run."""
    learning_starts: int
    vision_learning_starts: int
    vision_gradient_steps: int
    batch_size: int
    buffer_size: int
    eval_every_steps: int
    eval_seeds: int
    vision_eval_seeds: int
    stats_steps: int
    eval_time_limit_s: float
    """0: the protocol's default (3 x the limit lap time per lap)."""
    vision_eval_time_limit_s: float


SIZES: dict[str, Phase2Sizes] = {
    # CI: a few hundred steps on whatever track the test picks, short evaluation runs.
    "tiny": Phase2Sizes("cpu", 200, 120, 2, 2, 50, 40, 0, 32, 5_000, 100, 1, 1, 5, 30.0, 30.0),
    # `pipeline --quick` on 2 cores: state 250k steps in 183 s, which drove lap 2 of the expressway in 2:18.0.
    # Vision (236 x 140 frames) learns per update much as with 20 cars, and an update costs 36 ms with 10 cars
    # against 50 ms with 20: with 10 cars it drove one lap after 150k steps (491 s) and two (lap 2 in 2:24.1)
    # after 200k (648 s; 587 s with the encoder on ONNX Runtime). The whole pipeline took 14.6 min with 150k
    # vision steps, 15.6-17.1 with 200k and 4 encoder epochs, 17.2 with 10.
    "quick": Phase2Sizes("cpu", 250_000, 200_000, 20, 10, -1, 5_000, 0, 0, 0, 50_000, 3, 3, 50, 0.0, 400.0),
    # The paper's scale: 400 epochs of 20 trials of 100 s (vision paper, section 4, Figure 3) = 8M steps.
    "full": Phase2Sizes("paper", 8_000_000, 8_000_000, 20, 20, -1, -1, 0, 0, 0, 200_000, 3, 3, 100, 0.0, 0.0),
}


def pipeline_phase2(
    encoder: str = "",
    *,
    track: str = "expressway",
    car: str = "hatchback",
    runs: str = "runs",
    quick: bool = True,
    tiny: bool = False,
    seed: int = 0,
    progress: bool = False,
    device: str = "auto",
) -> dict[str, Any]:
    """Train (state, then vision if ``encoder``), evaluate, leaderboard; returns a summary dict.

    Runs go to ``runs/policy/pipeline-<kind>`` (replaced if present); ``tiny`` is for tests, ``quick`` for
    ``pipeline --quick``, neither for the paper-scale recipe."""
    sizes = SIZES["tiny" if tiny else "quick" if quick else "full"]
    summary: dict[str, Any] = {"mode": "tiny" if tiny else "quick" if quick else "full", "track": track, "car": car}
    kinds = [("state", "", sizes.state_steps, sizes.cars, sizes.learning_starts, 0, sizes.eval_seeds,
              sizes.eval_time_limit_s)]
    if encoder:
        kinds.append(("vision", encoder, sizes.vision_steps, sizes.vision_cars, sizes.vision_learning_starts,
                      sizes.vision_gradient_steps, sizes.vision_eval_seeds, sizes.vision_eval_time_limit_s))
    else:
        summary["vision"] = {"skipped": "no encoder checkpoint given"}
    for kind, enc, steps, cars, learning_starts, gradient_steps, eval_seeds, time_limit_s in kinds:
        t0 = time.perf_counter()
        out = Path(runs) / "policy" / f"pipeline-{kind}"
        trained = train_policy(
            TrainPolicyConfig(
                encoder=enc, track=track, car=car, cars=cars, steps=steps, preset=sizes.preset, out=str(out),
                seed=seed, force=True, eval_every_steps=sizes.eval_every_steps, checkpoint_every_steps=0,
                save_buffer=False, stats_steps=sizes.stats_steps, learning_starts=learning_starts,
                gradient_steps=gradient_steps, batch_size=sizes.batch_size, buffer_size=sizes.buffer_size,
                device=device, progress=progress,
            )
        )  # fmt: skip
        t1 = time.perf_counter()
        evaluation = evaluate_policy(
            out, seeds=eval_seeds, time_limit_s=time_limit_s, name=f"pipeline-{kind}", device="cpu"
        )
        summary[kind] = {
            "policy": trained["policy"],
            "num_timesteps": trained["num_timesteps"],
            "train_time_s": trained["train_time_s"],
            "best_lap_time_s": evaluation["best_lap_time_s"],
            "median_lap_time_s": evaluation["median_lap_time_s"],
            "n_finished": evaluation["n_finished"],
            "n_seeds": evaluation["n_seeds"],
            "wall_contact_s": evaluation["wall_contact_s"],
            "distance_m": max(s["distance_m"] for s in evaluation["seeds"]),
            "evaluation_json": evaluation.get("evaluation_json"),
            "wall_time_s": {"train": round(t1 - t0, 1), "evaluate": round(time.perf_counter() - t1, 1)},
        }
    t0 = time.perf_counter()
    table = leaderboard(track, car, runs)
    summary["leaderboard"] = table["rows"]
    summary["references_from"] = table["references_from"]
    summary["leaderboard_time_s"] = round(time.perf_counter() - t0, 1)
    return summary


def format_pipeline_phase2(summary: dict[str, Any]) -> list[str]:
    """Text lines of a :func:`pipeline_phase2` summary: each policy's result, then the leaderboard."""
    from vision_rl.phase2_rl.evaluate import format_lap_time
    from vision_rl.phase2_rl.leaderboard import format_leaderboard

    lines = [f"Phase 2 ({summary['mode']}) on {summary['track']} / {summary['car']}"]
    for kind in ("state", "vision"):
        r = summary.get(kind, {})
        if "skipped" in r:
            lines.append(f"  {kind}: skipped ({r['skipped']})")
        elif r:
            lines.append(
                f"  {kind}: {r['num_timesteps']} steps in {r['wall_time_s']['train']:.0f} s; lap 2 best "
                f"{format_lap_time(r['best_lap_time_s'])} ({r['n_finished']}/{r['n_seeds']} seeds finished, "
                f"{r['distance_m']:.0f} m driven at most); {r['policy']}"
            )
    table = {"track": summary["track"], "car": summary["car"], "rows": summary["leaderboard"]}
    return lines + format_leaderboard(table)
