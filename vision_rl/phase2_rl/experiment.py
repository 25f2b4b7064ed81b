"""`experiment`: one train-policy recipe over several training seeds, each timed by the lap-time protocol, with
the seeds' mean, spread and best (:func:`vision_rl.evaluation.leaderboard.aggregate_seeds`).

An experiment folder holds ``experiment.json`` (what is trained: track, car, observation, encoder hash, steps, the
recipe; then the summary and one row per seed) and one train-policy run folder per seed, ``seed-<k>/`` with its
``evaluation.json``. A killed experiment resumes the unfinished seeds only: a seed whose policy reached the steps
and was evaluated is kept, a seed with a saved run is resumed, the others start. An existing folder made for
another track, car, observation, encoder, step count or recipe is refused, naming the field.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from vision_rl.evaluation.leaderboard import EXPERIMENT_FORMAT, aggregate_seeds
from vision_rl.phase1_repr.checkpoint import checkpoint_sha256
from vision_rl.phase2_rl.artifact import SIDECAR_NAME, PolicySpec
from vision_rl.phase2_rl.evaluate import evaluate_policy
from vision_rl.phase2_rl.persist import atomic_write
from vision_rl.phase2_rl.train import METRICS_NAME, Progress, TrainPolicyConfig, read_metrics, train_policy

EXPERIMENT_NAME = "experiment.json"
#: Options that may differ between sessions of one experiment (they change where and how, not what is trained).
#: How and where a seed runs, not what it learns: free to change when an experiment resumes.
SESSION_FIELDS = ("out", "seed", "resume", "force", "device", "encoder_runtime", "workers", "address")


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"0,1,2"`` -> (0, 1, 2); repeats, negatives and non-integers are refused."""
    try:
        seeds = tuple(int(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise ValueError(f"--seeds {text!r}: give training seeds as integers separated by commas, e.g. 0,1,2") from None
    if not seeds:
        raise ValueError("--seeds is empty: give at least one training seed, e.g. 0,1,2")
    if any(s < 0 for s in seeds):
        raise ValueError(f"--seeds {text!r}: seeds must be >= 0")
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"--seeds {text!r}: a seed is repeated; each training seed runs once")
    return seeds


def default_experiment_out(cfg: TrainPolicyConfig) -> Path:
    kind = "vision" if cfg.encoder else "state"
    return Path("runs") / "experiment" / f"{kind}-{Path(cfg.track.replace('random:', 'random-')).stem}-{cfg.car}"


def _plan(cfg: TrainPolicyConfig) -> dict[str, Any]:
    recipe = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in SESSION_FIELDS}
    return {
        "track": cfg.track,
        "car": cfg.car,
        "observation": "vision" if cfg.encoder else "state",
        "encoder_sha256": checkpoint_sha256(cfg.encoder) if cfg.encoder else None,
        "steps": cfg.steps,
        "recipe": recipe,
    }


def _seed_is_done(run: Path, steps: int) -> bool:
    try:
        spec = PolicySpec.read(run / SIDECAR_NAME)
    except (ValueError, OSError):
        return False
    return spec.num_timesteps >= steps and (run / "evaluation.json").is_file()


def run_experiment(
    cfg: TrainPolicyConfig,
    seeds: tuple[int, ...],
    out: str | os.PathLike[str] = "",
    eval_seeds: int = 3,
    name: str = "",
    progress: Callable[[int, int, int], None] | None = None,
    train_progress: Progress | None = None,
) -> dict[str, Any]:
    """Train and evaluate ``cfg`` once per training seed (resuming what a killed run left); returns the experiment
    record. ``progress(index, n_seeds, seed)`` is called as each seed starts."""
    if eval_seeds < 1:
        raise ValueError(f"--eval-seeds must be >= 1, got {eval_seeds}")
    root = Path(out) if out else default_experiment_out(cfg)
    plan = _plan(cfg)
    path = root / EXPERIMENT_NAME
    if path.is_file():
        try:
            previous = json.loads(path.read_text())
        except ValueError as exc:
            raise ValueError(f"{path}: not valid JSON ({exc}); remove it to start over") from None
        # A recipe field added after the experiment was started holds its default there.
        defaults = {f.name: f.default for f in dataclasses.fields(TrainPolicyConfig) if f.name not in SESSION_FIELDS}
        previous["recipe"] = {**defaults, **previous.get("recipe", {})}
        for key, value in plan.items():
            if previous.get(key) != value:
                if key == "recipe":
                    differs = sorted(k for k in value if previous["recipe"].get(k) != value[k])
                    key = f"recipe field {differs[0]}" if differs else key
                raise ValueError(f"{root} holds an experiment made for another {key}: use another --out")
    root.mkdir(parents=True, exist_ok=True)
    name = name or root.name
    record: dict[str, Any] = {"format": EXPERIMENT_FORMAT, "name": name, **plan, "seeds": list(seeds)}
    atomic_write(path, lambda tmp: tmp.write_text(json.dumps(record, indent=2)))
    evaluations = []
    for index, seed in enumerate(seeds):
        if progress is not None:
            progress(index, len(seeds), seed)
        run = root / f"seed-{seed}"
        if not _seed_is_done(run, cfg.steps):
            resume = (run / SIDECAR_NAME).is_file()
            result = train_policy(dataclasses.replace(cfg, seed=seed, out=str(run), resume=resume, force=False),
                                  train_progress)  # fmt: skip
            if result["interrupted"]:
                raise KeyboardInterrupt
            evaluate_policy(run, seeds=eval_seeds, name=f"{name}/seed-{seed}", encoder=cfg.encoder)
        evaluations.append(json.loads((run / "evaluation.json").read_text()))
    record["summary"] = aggregate_seeds(evaluations)
    record["per_seed"] = [
        {"seed": seed, "lap_time_s": e["best_lap_time_s"], "median_lap_time_s": e["median_lap_time_s"],
         "finished": f"{e['n_finished']}/{e['n_seeds']}", "clean": e["clean"],
         "wall_contact_s": None if e["best_lap"] is None else e["best_lap"]["wall_contact_s"]}
        for seed, e in zip(seeds, evaluations, strict=True)
    ]  # fmt: skip
    record["learning_curves"] = write_learning_curves(root, seeds, evaluations[0]["limit_lap_time_s"])
    atomic_write(path, lambda tmp: tmp.write_text(json.dumps(record, indent=2)))
    return {**record, "experiment_json": str(path)}


def learning_curves(root: str | os.PathLike[str], seeds: tuple[int, ...]) -> dict[str, Any]:
    """The periodic evaluations of every seed's run (``metrics.jsonl``: the protocol's lap against environment
    steps and training seconds) and their mean over the seeds that finished the lap at each step."""
    per_seed = {}
    for seed in seeds:
        records = read_metrics(Path(root) / f"seed-{seed}" / METRICS_NAME)
        per_seed[seed] = {
            "num_timesteps": [r["num_timesteps"] for r in records],
            "train_time_s": [r["train_time_s"] for r in records],
            "lap_time_s": [r["lap_time_s"] for r in records],
        }
    steps = sorted({n for c in per_seed.values() for n in c["num_timesteps"]})
    mean, finished = [], []
    for n in steps:
        laps = [c["lap_time_s"][c["num_timesteps"].index(n)] for c in per_seed.values() if n in c["num_timesteps"]]
        done = [t for t in laps if t is not None]
        mean.append(float(np.mean(done)) if done else None)
        finished.append(f"{len(done)}/{len(laps)}")
    return {"per_seed": per_seed, "num_timesteps": steps, "mean_lap_time_s": mean, "seeds_finished": finished}


def write_learning_curves(root: str | os.PathLike[str], seeds: tuple[int, ...], limit_lap_time_s: float) -> dict:
    """:func:`learning_curves` as ``learning_curves.json`` and ``learning_curves.png`` in the experiment folder."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    root = Path(root)
    curves = learning_curves(root, seeds)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for seed, c in curves["per_seed"].items():
        y = [np.nan if t is None else t for t in c["lap_time_s"]]
        ax.plot(c["num_timesteps"], y, "o-", lw=0.8, ms=3, alpha=0.6, label=f"seed {seed}")
    y = [np.nan if t is None else t for t in curves["mean_lap_time_s"]]
    ax.plot(curves["num_timesteps"], y, "k-", lw=2, label="mean of the seeds that finished")
    ax.axhline(limit_lap_time_s, color="grey", ls="--", lw=1, label="physical limit (QSS)")
    ax.set_xlabel("environment steps (transitions over all cars)")
    ax.set_ylabel("protocol lap 2, s (missing: no lap)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    png = root / "learning_curves.png"
    atomic_write(png, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)
    data = root / "learning_curves.json"
    atomic_write(data, lambda tmp: tmp.write_text(json.dumps(curves, indent=2)))
    return {"png": str(png), "json": str(data)}
