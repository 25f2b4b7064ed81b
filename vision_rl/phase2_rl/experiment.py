"""`experiment`: one train-policy recipe over several training seeds, each timed by the lap-time protocol, with
the seeds' mean, spread and best (:func:`vision_rl.evaluation.leaderboard.aggregate_seeds`). A killed experiment
resumes its unfinished seeds; a folder made for another recipe is refused, naming the field.

The folder's layout, the selected weights and seeds side by side: docs/notes/phase2_rl.md.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import multiprocessing
import os
import queue
import signal
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vision_rl.config import flat_values
from vision_rl.evaluation.leaderboard import AI_SEEDS, EXPERIMENT_FORMAT, aggregate_seeds, read_evaluation
from vision_rl.evaluation.protocol import BuiltinAI, time_laps
from vision_rl.files import atomic_write, file_sha256, json_text, sealed_record
from vision_rl.phase2_rl.config import TrainPolicyConfig, check_bounds
from vision_rl.phase2_rl.train import train_policy
from vision_rl.training.artifact import SIDECAR_NAME, PolicySpec, chosen_weights
from vision_rl.training.evaluate import EVALUATION_NAME, evaluate_policy
from vision_rl.training.sac import METRICS_NAME, Progress, read_metrics

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
    kind = cfg.kind.value
    return (
        Path("runs")
        / "experiment"
        / f"{kind}-{Path(cfg.racing.track.replace('random:', 'random-')).stem}-{cfg.racing.car}"
    )


def _plan(cfg: TrainPolicyConfig) -> dict[str, Any]:
    recipe = {k: v for k, v in flat_values(cfg).items() if k not in SESSION_FIELDS}
    return {
        "track": cfg.racing.track,
        "car": cfg.racing.car,
        "observation": cfg.kind.value,
        "encoder_sha256": file_sha256(cfg.encoder) if cfg.encoder else None,
        "steps": cfg.steps,
        "recipe": recipe,
    }


def _seed_run(root: str | os.PathLike[str], seed: int) -> Path:
    """A training seed's train-policy run folder (the leaderboard knows an experiment's seeds by this name)."""
    return Path(root) / f"seed-{seed}"


def _seed_is_done(run: Path, steps: int) -> bool:
    try:
        spec = PolicySpec.read(run / SIDECAR_NAME)
    except (ValueError, OSError):
        return False
    best = chosen_weights(run)
    evaluated = (run / EVALUATION_NAME).is_file() and (best is None or (best / EVALUATION_NAME).is_file())
    return spec.num_timesteps >= steps and evaluated


def _seed_rows(seeds: Sequence[int], evaluations: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    return [
        {
            "seed": seed,
            "lap_time_s": e["best_lap_time_s"],
            "median_lap_time_s": e["median_lap_time_s"],
            "finished": f"{e['n_finished']}/{e['n_seeds']}",
            "clean": e["clean"],
            **{
                key: None if e["best_lap"] is None else e["best_lap"].get(key)
                for key in ("wall_contact_s", "wall_hits", "fastest_wall_hit_kmh")
            },
        }
        for seed, e in zip(seeds, evaluations, strict=True)
    ]


def _selected(root: Path, seeds: Sequence[int], last: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The summary of the weights the held-out starts chose, the last weights standing in for a seed without."""
    evaluations, kept_at = [], []
    for seed, final in zip(seeds, last, strict=True):
        best = chosen_weights(_seed_run(root, seed))
        evaluations.append(read_evaluation(best / EVALUATION_NAME) if best else final)
        kept_at.append(PolicySpec.read(best / SIDECAR_NAME).num_timesteps if best else None)
    rows = _seed_rows(seeds, evaluations)
    for row, steps in zip(rows, kept_at, strict=True):
        row["kept_at_steps"] = steps  # None: no evaluation finished the held-out starts (clean); the last weights
    return {"summary": aggregate_seeds(evaluations), "per_seed": rows}


#: ``progress(steps_done, steps_total)``: environment steps over all of an experiment's seeds.
ExperimentProgress = Callable[[int, int], None]


def run_experiment(
    cfg: TrainPolicyConfig,
    seeds: tuple[int, ...],
    out: str | os.PathLike[str] = "",
    eval_seeds: int = 3,
    name: str = "",
    progress: ExperimentProgress | None = None,
    seeds_at_once: int = 1,
) -> dict[str, Any]:
    """Train and evaluate ``cfg`` once per training seed (resuming what a killed run left), ``seeds_at_once`` of
    them side by side in their own processes; returns the experiment record. A KeyboardInterrupt (or a seed's
    process stopped from outside) saves every running seed and is raised."""
    if eval_seeds < 1:
        raise ValueError(f"--eval-seeds must be >= 1, got {eval_seeds}")
    if seeds_at_once < 1:
        raise ValueError(f"--seeds-at-once must be >= 1, got {seeds_at_once}")
    check_bounds(flat_values(cfg))  # a bad option is refused before the experiment folder is written
    root = Path(out) if out else default_experiment_out(cfg)
    plan = _plan(cfg)
    path = root / EXPERIMENT_NAME
    if path.is_file():
        try:
            previous = json.loads(path.read_text())
        except ValueError as exc:
            raise ValueError(f"{path}: not valid JSON ({exc}); remove it to start over") from None
        # A recipe field added after the experiment was started holds its default there.
        defaults = {k: v for k, v in flat_values(TrainPolicyConfig()).items() if k not in SESSION_FIELDS}
        previous["recipe"] = {**defaults, **previous.get("recipe", {})}
        for key, value in plan.items():
            if previous.get(key) != value:
                if key == "recipe":
                    differs = sorted(k for k in value if previous["recipe"].get(k) != value[k])
                    key = f"recipe field {differs[0]}" if differs else key
                raise ValueError(f"{root} holds an experiment made for another {key}: use another --out")
    root.mkdir(parents=True, exist_ok=True)
    name = name or root.name
    record: dict[str, Any] = {
        "format": EXPERIMENT_FORMAT,
        "name": name,
        **plan,
        "seeds": list(seeds),
        "seeds_at_once": seeds_at_once,
    }
    atomic_write(path, lambda tmp: tmp.write_text(json_text(sealed_record(record), indent=2)))
    steps_done = {seed: cfg.steps if _seed_is_done(_seed_run(root, seed), cfg.steps) else 0 for seed in seeds}
    todo = [seed for seed in seeds if steps_done[seed] < cfg.steps]

    def seed_steps(seed: int, steps: int) -> None:
        steps_done[seed] = steps
        if progress is not None:
            progress(sum(steps_done.values()), cfg.steps * len(seeds))

    job = _SeedJob(cfg, root, eval_seeds, name)
    if seeds_at_once == 1 or len(todo) <= 1:
        for seed in todo:
            if job.run(seed, lambda steps, total, last_eval, seed=seed: seed_steps(seed, steps)):
                raise KeyboardInterrupt
    else:
        _run_side_by_side(job, todo, seeds_at_once, seed_steps)
    # Checked records only: a summary sealed over an edited seed's lap would pass it off as the experiment's.
    evaluations = [read_evaluation(_seed_run(root, seed) / EVALUATION_NAME) for seed in seeds]
    record["summary"] = aggregate_seeds(evaluations)
    record["per_seed"] = _seed_rows(seeds, evaluations)
    if cfg.select_starts:
        record["selected"] = _selected(root, seeds, evaluations)
    if cfg.evaluation.every_steps > 0:  # without periodic evaluations the runs have no curve to draw
        ai = time_laps(BuiltinAI(), cfg.racing.track, cfg.racing.car, seeds=AI_SEEDS).summary()["best_lap_time_s"]
        record["learning_curves"] = write_learning_curves(
            root, seeds, evaluations[0]["limit_lap_time_s"], ai, cfg.racing.control_dt_s
        )
    atomic_write(path, lambda tmp: tmp.write_text(json_text(sealed_record(record), indent=2)))
    return {**record, "experiment_json": str(path)}


@dataclasses.dataclass(frozen=True)
class _SeedJob:
    """One seed's work: train (or resume) its run, then time its policy with the protocol."""

    cfg: TrainPolicyConfig
    root: Path
    eval_seeds: int
    name: str

    def run(self, seed: int, progress: Progress | None = None) -> bool:
        """Train and evaluate ``seed``; True when training was interrupted (the run saved, not evaluated)."""
        run = _seed_run(self.root, seed)
        resume = (run / SIDECAR_NAME).is_file()
        result = train_policy(
            dataclasses.replace(self.cfg, seed=seed, out=str(run), resume=resume, force=False), progress
        )
        if result["interrupted"]:
            return True
        evaluate_policy(run, seeds=self.eval_seeds, name=f"{self.name}/seed-{seed}", encoder=self.cfg.encoder)
        best = chosen_weights(run)
        if best:
            evaluate_policy(
                best, seeds=self.eval_seeds, name=f"{self.name}/seed-{seed}/selected", encoder=self.cfg.encoder
            )
        return False


#: Seconds between a seed process's progress messages.
_PROGRESS_EVERY_S = 1.0


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def _seed_process(job: _SeedJob, seed: int, messages: Any) -> None:
    """A seed's own process: its steps as it trains, then ``done`` (interrupted or not) or ``error``."""
    # Ctrl-C reaches the whole process group; the parent decides and stops each seed with SIGTERM, which saves the
    # run at its next rollout (a second signal at once would stop it in the middle of saving).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _raise_interrupt)
    last_s = 0.0

    def report(steps: int, total: int, last_eval: Any) -> None:
        nonlocal last_s
        if time.monotonic() - last_s >= _PROGRESS_EVERY_S:
            last_s = time.monotonic()
            messages.put(("steps", seed, steps))

    try:
        messages.put(("done", seed, job.run(seed, report)))
    except KeyboardInterrupt:  # stopped during the evaluation: the trained run is kept, evaluated on resume
        messages.put(("done", seed, True))
    except Exception as exc:  # the parent raises it, naming the seed
        messages.put(("error", seed, (isinstance(exc, ValueError), str(exc))))


def _run_side_by_side(
    job: _SeedJob, todo: list[int], seeds_at_once: int, seed_steps: Callable[[int, int], None]
) -> None:
    """Run ``todo``'s seeds, ``seeds_at_once`` processes at a time; an interrupt or a seed's failure stops (and so
    saves) the others before it is raised."""
    context = multiprocessing.get_context("spawn")  # no fork of a process that holds torch's threads
    messages = context.Queue()
    waiting, running = list(todo), {}
    try:
        while waiting or running:
            while waiting and len(running) < seeds_at_once:
                seed = waiting.pop(0)
                running[seed] = context.Process(
                    target=_seed_process, args=(job, seed, messages), name=f"experiment-seed-{seed}"
                )
                running[seed].start()
            try:
                kind, seed, value = messages.get(timeout=1.0)
            except queue.Empty:
                for seed, process in running.items():
                    if process.exitcode not in (None, 0):
                        raise RuntimeError(
                            f"training seed {seed}'s process ended with exit code {process.exitcode} "
                            "before it reported; run the experiment again to resume it"
                        ) from None
                continue
            if kind == "steps":
                seed_steps(seed, value)
                continue
            running.pop(seed).join()
            if kind == "error":
                bad_input, text = value
                raise (ValueError if bad_input else RuntimeError)(f"training seed {seed}: {text}")
            if value:
                raise KeyboardInterrupt
            seed_steps(seed, job.cfg.steps)
    finally:
        for process in running.values():
            if process.is_alive():
                process.terminate()  # SIGTERM: the seed saves at its next rollout and stops
        for process in running.values():
            while process.is_alive():  # read what it still sends, or a full pipe would keep it from exiting
                process.join(timeout=0.5)
                with contextlib.suppress(queue.Empty):
                    while True:
                        messages.get_nowait()


#: The vision paper's epoch (Fig. 3 right): 20 trials of 100 s, car-seconds (20,000 environment steps at 10 Hz).
EPOCH_CAR_S = 2000.0


def epochs_per_step(control_dt_s: float) -> float:
    """The paper's epochs in one environment step of ``control_dt_s`` seconds."""
    return control_dt_s / EPOCH_CAR_S


def learning_curves(root: str | os.PathLike[str], seeds: tuple[int, ...], control_dt_s: float = 0.1) -> dict[str, Any]:
    """The periodic evaluations of every seed's run (``metrics.jsonl``: the protocol's lap against environment
    steps and training seconds) and their summary over the seeds (:func:`summarise_curves`)."""
    per_seed = {}
    for seed in seeds:
        records = read_metrics(_seed_run(root, seed) / METRICS_NAME)
        per_seed[str(seed)] = {
            "num_timesteps": [r["num_timesteps"] for r in records],
            "train_time_s": [r["train_time_s"] for r in records],
            "lap_time_s": [r["lap_time_s"] for r in records],
        }
    return {"per_seed": per_seed, **summarise_curves(per_seed, control_dt_s)}


def summarise_curves(per_seed: dict[str, dict[str, list]], control_dt_s: float = 0.1) -> dict[str, Any]:
    """At each evaluated step: epochs (:data:`EPOCH_CAR_S`; steps of ``control_dt_s``), mean and standard deviation
    of the lap over the seeds that finished it, how many did, and the seeds' mean training time (s)."""
    steps = sorted({n for c in per_seed.values() for n in c["num_timesteps"]})
    out: dict[str, Any] = {
        "control_dt_s": control_dt_s,
        "num_timesteps": steps,
        "epochs": [n * epochs_per_step(control_dt_s) for n in steps],
        "mean_lap_time_s": [],
        "std_lap_time_s": [],
        "seeds_finished": [],
        "mean_train_time_s": [],
    }
    for n in steps:
        at = [
            (c["lap_time_s"][i], c["train_time_s"][i])
            for c in per_seed.values()
            for i in [c["num_timesteps"].index(n)]
            if n in c["num_timesteps"]
        ]
        done = [lap for lap, _ in at if lap is not None]
        out["mean_lap_time_s"].append(float(np.mean(done)) if done else None)
        out["std_lap_time_s"].append(float(np.std(done, ddof=1)) if len(done) > 1 else None)
        out["seeds_finished"].append(f"{len(done)}/{len(at)}")
        out["mean_train_time_s"].append(float(np.mean([t for _, t in at])))
    return out


def time_to_beat(curves: dict[str, Any], reference_lap_time_s: float) -> dict[str, Any] | None:
    """The first evaluation at which every seed evaluated there finished and their mean lap beats the reference
    (the built-in AI's): steps, epochs and the seeds' mean training time; None if it never does."""
    for i, n in enumerate(curves["num_timesteps"]):
        done, evaluated = (int(x) for x in curves["seeds_finished"][i].split("/"))
        mean = curves["mean_lap_time_s"][i]
        if done == evaluated and mean is not None and mean < reference_lap_time_s:
            return {"num_timesteps": n, "epochs": curves["epochs"][i], "train_time_s": curves["mean_train_time_s"][i]}
    return None


def plot_learning_curves(
    series: Sequence[tuple[str, dict[str, Any]]],
    limit_lap_time_s: float,
    ai_lap_time_s: float | None,
    path: str | os.PathLike[str],
    seeds_drawn: bool = False,
) -> None:
    """Lap against environment steps (the paper's epochs on the top axis) and against training minutes: each
    series' mean over its seeds with a +-1 std band (``seeds_drawn``: each seed's own line too), the limit and the
    built-in AI's lap; the legend says when each mean beats the AI. Series of different control steps are drawn
    against the paper's epochs instead (equal simulated time; their steps are not comparable)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    control_dts_s = {curves["control_dt_s"] for _, curves in series}
    by_steps = len(control_dts_s) <= 1
    fig, axes = plt.subplots(1, 2, figsize=(12, 5), sharey=True)
    for k, (label, curves) in enumerate(series):
        color = f"C{k}"
        mean = np.array([np.nan if v is None else v for v in curves["mean_lap_time_s"]])
        std = np.array([0.0 if v is None else v for v in curves["std_lap_time_s"]])
        beat = None if ai_lap_time_s is None else time_to_beat(curves, ai_lap_time_s)
        if ai_lap_time_s is None:
            when = ""
        elif beat is None:
            when = " (never beats the AI)"
        else:
            when = f" (beats the AI at {beat['num_timesteps'] / 1000:.0f}k steps, {beat['train_time_s'] / 60:.0f} min)"
        n_seeds = len(curves["per_seed"])
        scale = 1.0 if by_steps else epochs_per_step(curves["control_dt_s"])  # steps or epochs on the first axes
        first = np.array(curves["num_timesteps"]) * scale
        for ax, x in zip(axes, (first, np.array(curves["mean_train_time_s"]) / 60), strict=True):
            ax.plot(x, mean, "-", color=color, lw=2, label=f"{label}: mean of {n_seeds} seeds{when}")
            ax.fill_between(x, mean - std, mean + std, color=color, alpha=0.2)
        if seeds_drawn:
            for j, (seed, c) in enumerate(curves["per_seed"].items()):
                y = [np.nan if t is None else t for t in c["lap_time_s"]]
                style = dict(marker="osv^D"[j % 5], lw=0.7, ms=3, alpha=0.6, color=color)
                axes[0].plot(np.array(c["num_timesteps"]) * scale, y, label=f"seed {seed}", **style)
                axes[1].plot(np.array(c["train_time_s"]) / 60, y, **style)
    for ax in axes:
        ax.axhline(limit_lap_time_s, color="grey", ls="--", lw=1, label="physical limit (QSS)")
        if ai_lap_time_s is not None:
            ax.axhline(ai_lap_time_s, color="k", ls=":", lw=1, label="built-in AI, default skill")
    epochs_label = "the paper's epochs (20 trials of 100 s)"
    if by_steps:
        axes[0].set_xlabel("environment steps (transitions over all cars)")
        per_step = epochs_per_step(min(control_dts_s, default=0.1))
        top = axes[0].secondary_xaxis("top", functions=(lambda n: n * per_step, lambda e: e / per_step))
        top.set_xlabel(epochs_label)
    else:
        axes[0].set_xlabel(epochs_label)
    axes[1].set_xlabel("training time (min; evaluations excluded)")
    axes[0].set_ylabel("protocol lap 2, s (missing: no seed finished)")
    # Below the axes, so that the legend never hides a curve or a tick label.
    handles, labels = axes[0].get_legend_handles_labels()
    n_rows = -(-len(labels) // 2)
    fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=7)
    fig.tight_layout(rect=(0, 0.035 * n_rows, 1, 1))
    path = Path(path)
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)


def write_learning_curves(
    root: str | os.PathLike[str],
    seeds: tuple[int, ...],
    limit_lap_time_s: float,
    ai_lap_time_s: float | None = None,
    control_dt_s: float = 0.1,
) -> dict:
    """:func:`learning_curves` as ``learning_curves.json`` (with the limit, the AI's lap and when the mean beat it)
    and ``learning_curves.png`` in the experiment folder."""
    root = Path(root)
    curves = learning_curves(root, seeds, control_dt_s)
    curves.update(
        limit_lap_time_s=limit_lap_time_s,
        ai_lap_time_s=ai_lap_time_s,
        time_to_beat_ai=None if ai_lap_time_s is None else time_to_beat(curves, ai_lap_time_s),
    )
    png = root / "learning_curves.png"
    plot_learning_curves([("SAC", curves)], limit_lap_time_s, ai_lap_time_s, png, seeds_drawn=True)
    data = root / "learning_curves.json"
    atomic_write(data, lambda tmp: tmp.write_text(json_text(curves, indent=2)))
    return {"png": str(png), "json": str(data)}


def compare_learning_curves(
    files: Sequence[str | os.PathLike[str]],
    names: Sequence[str],
    limit_lap_time_s: float,
    ai_lap_time_s: float,
    out: str | os.PathLike[str],
) -> dict[str, Any]:
    """Several experiments' ``learning_curves.json`` on one figure (the paper's Fig. 3 right: state and vision
    agents, or encoders of different Phase 1 seeds): ``compare.png`` and ``compare.json`` in ``out``."""
    if len(names) != len(files):
        raise ValueError(f"--names gives {len(names)} names for {len(files)} curve files")
    series = []
    for name, file in zip(names, files, strict=True):
        try:
            data = json.loads(Path(file).read_text())
            per_seed = data["per_seed"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{file}: not a learning_curves.json of an experiment ({exc})") from None
        curves = {"per_seed": per_seed, **summarise_curves(per_seed, data.get("control_dt_s", 0.1))}
        curves["time_to_beat_ai"] = time_to_beat(curves, ai_lap_time_s)
        series.append((name, curves))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plot_learning_curves(series, limit_lap_time_s, ai_lap_time_s, out / "compare.png")
    record = {
        "limit_lap_time_s": limit_lap_time_s,
        "ai_lap_time_s": ai_lap_time_s,
        "series": [{"name": n, "file": str(f), **c} for (n, c), f in zip(series, files, strict=True)],
    }
    atomic_write(out / "compare.json", lambda tmp: tmp.write_text(json_text(record, indent=2)))
    return {**record, "files": {"png": str(out / "compare.png"), "json": str(out / "compare.json")}}
