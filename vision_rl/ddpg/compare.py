"""train-ddpg runs side by side at equal training time: how far each drives per episode, against training minutes
and episodes, and when each first completes a lap (the measure of what the asymmetric actor-critic buys).

Each run folder's ``ddpg.json`` names its variant and counters; ``episodes.jsonl`` holds one line per finished
training episode with the training time at its end. Runs are compared over the training time that all of them
reached (``common_minutes``): a run trained longer is cut there, so no variant is judged on more time than another.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vision_rl.ddpg.agent import SIDECAR_NAME, DDPGError, read_run_sidecar
from vision_rl.ddpg.train import EPISODES_NAME

#: Share of the common training time at its end over which the runs' distance per episode is summarised.
LAST_SHARE = 1 / 3


def read_episodes(run: str | os.PathLike[str]) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A train-ddpg run's sidecar and its episode records; one clear error for a folder that is not a run."""
    run = Path(run)
    try:
        sidecar = read_run_sidecar(run / SIDECAR_NAME)
        variant = sidecar["hyper"]["variant"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DDPGError(f"{run}: not a train-ddpg run folder ({SIDECAR_NAME}: {exc})") from None
    path = run / EPISODES_NAME
    if not path.is_file():
        raise DDPGError(f"{run}: no {EPISODES_NAME}: this {variant} run has not finished an episode yet")
    records = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        try:
            record = json.loads(line)
            records.append(
                {
                    **{k: float(record[k]) for k in ("train_time_s", "distance_m", "laps", "return", "steps")},
                    "end": record["end"],
                }
            )
        except (ValueError, KeyError, TypeError):
            raise DDPGError(f"{path}: line {number} is not an episode record") from None
    return sidecar, records


def compare_runs(
    runs: Sequence[str | os.PathLike[str]], names: Sequence[str] = (), bin_min: float = 5.0
) -> dict[str, Any]:
    """Distance per episode of each run in bins of ``bin_min`` training minutes up to the common time, with a
    summary per run: episodes, mean and best distance, reward per step and why episodes ended over the last third of
    the common time, first lap. Episodes and distances count to the common time; the counters (minutes, steps,
    updates and their rate) are the run's."""
    if not runs:
        raise DDPGError("--runs is empty: give train-ddpg run folders, comma-separated")
    if names and len(names) != len(runs):
        raise DDPGError(f"{len(names)} names for {len(runs)} runs: give one name per run, or none")
    if not bin_min > 0:
        raise DDPGError(f"--bin-minutes must be > 0, got {bin_min}")
    loaded = [read_episodes(run) for run in runs]
    tracks = {(s["env"]["track"], s["env"]["car"]) for s, _ in loaded}
    if len(tracks) > 1:
        raise DDPGError(f"the runs drove different tracks or cars ({sorted(tracks)}): compare one track and car")
    common_s = min(float(s["counters"]["train_time_s"]) for s, _ in loaded)
    edges_s = np.arange(0.0, common_s + 60.0 * bin_min, 60.0 * bin_min)
    rows = []
    for run, name, (sidecar, records) in zip(runs, names or [None] * len(runs), loaded, strict=True):
        t, distance, laps, returns, steps = (
            np.array([r[k] for r in records]) for k in ("train_time_s", "distance_m", "laps", "return", "steps")
        )
        inside = t <= common_s
        t, distance, laps, returns, steps = t[inside], distance[inside], laps[inside], returns[inside], steps[inside]
        ends = [r["end"] for r, kept in zip(records, inside, strict=True) if kept]
        which = np.minimum(np.digitize(t, edges_s) - 1, len(edges_s) - 2)  # an episode ending at the common time
        per_bin = [distance[which == k] for k in range(len(edges_s) - 1)]
        last = t > (1 - LAST_SHARE) * common_s
        lapped = np.flatnonzero(laps >= 1)
        counters = sidecar["counters"]
        rows.append(
            {
                "name": name or f"{sidecar['hyper']['variant']} s{sidecar.get('seed', 0)}",
                "run": str(run),
                "variant": sidecar["hyper"]["variant"],
                "seed": sidecar.get("seed"),
                "train_minutes": round(float(counters["train_time_s"]) / 60.0, 2),
                "steps": int(counters["num_steps"]),
                "updates": int(counters["n_updates"]),
                "updates_per_s": int(counters["n_updates"]) / max(float(counters["train_time_s"]), 1e-9),
                "train_cpu_minutes": (  # None: a run from before the counter
                    round(float(counters["train_cpu_s"]) / 60.0, 2) if "train_cpu_s" in counters else None
                ),
                "episodes": len(t),
                "mean_distance_last_m": round(float(distance[last].mean()), 1) if last.any() else None,
                # Below 0: the run's last episodes lost more to crashes and the line than speed earned.
                "reward_per_step_last": round(float(returns[last].sum() / steps[last].sum()), 2)
                if last.any()
                else None,
                "ends_last": dict(Counter(end for end, late in zip(ends, last, strict=True) if late).most_common()),
                "best_distance_m": round(float(distance.max()), 1) if len(t) else None,
                "first_lap_episode": int(lapped[0]) + 1 if len(lapped) else None,
                "first_lap_minutes": round(float(t[lapped[0]]) / 60.0, 2) if len(lapped) else None,
                "episode_minutes": np.round(t / 60.0, 3).tolist(),
                "episode_distance_m": np.round(distance, 1).tolist(),
                "bin_mean_distance_m": [round(float(d.mean()), 1) if len(d) else None for d in per_bin],
                "bin_episodes": [len(d) for d in per_bin],
            }
        )
    ((track_name, car),) = tracks
    return {
        "track": track_name,
        "car": car,
        "common_minutes": round(common_s / 60.0, 2),
        "bin_minutes": bin_min,
        "bin_start_minutes": (edges_s[:-1] / 60.0).tolist(),
        "last_share": LAST_SHARE,
        "runs": rows,
    }


def plot_comparison(result: dict[str, Any], path: str | os.PathLike[str], window: int = 20) -> Path:
    """Two panels: distance per episode against training minutes (each episode a dot, the bins' means a line) and
    against episodes (a running mean of ``window`` episodes)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    fig, (by_time, by_episode) = plt.subplots(1, 2, figsize=(12, 4.5))
    starts = np.asarray(result["bin_start_minutes"])
    # Each bin's point at its middle; the last bin ends at the common time.
    centres = 0.5 * (starts + np.minimum(starts + result["bin_minutes"], result["common_minutes"]))
    for k, row in enumerate(result["runs"]):
        colour = f"C{k}"
        by_time.scatter(row["episode_minutes"], row["episode_distance_m"], s=4, alpha=0.25, color=colour)
        means = np.array([np.nan if m is None else m for m in row["bin_mean_distance_m"]])
        by_time.plot(centres, means, color=colour, label=f"{row['name']} ({row['updates_per_s']:.1f} updates/s)")
        distance = np.asarray(row["episode_distance_m"])
        if len(distance):
            w = min(window, len(distance))
            running = np.convolve(distance, np.ones(w) / w, mode="valid")
            by_episode.plot(np.arange(w, len(distance) + 1), running, color=colour, label=row["name"])
    by_time.set_xlabel(f"training minutes (the runs cut at the common {result['common_minutes']:.0f})")
    by_time.set_ylabel("distance per training episode (m)")
    by_episode.set_xlabel("training episode")
    by_episode.set_ylabel(f"distance, running mean of {window} episodes (m)")
    for ax in (by_time, by_episode):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"DDPG variants on {result['track']} / {result['car']} at equal training time")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
