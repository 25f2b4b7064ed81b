"""The DDPG paper's figure: the reward an agent earns against lap distance, for laps 1, 2 and 3 of one episode from
the start line (the paper monitors three laps of its 4,655 m Catalunya lap this way and shows no lap time).

The episode follows the agent's own environment (its reward, crashState and termination rules); only the start is
the start/finish line, so that lap k covers lap distance 0 to the lap length once. A step's reward is placed at the
lap and lap distance where the step began. Where the episode ended before a lap did, that lap's later bins are empty.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from vision_rl.envs.pixel_racing import PixelRacingConfig, PixelRacingCore
from vision_rl.sim.driving import line_and_profile


def lap_reward_profile(
    act: Callable[[dict[str, np.ndarray]], np.ndarray],
    env: PixelRacingConfig,
    laps: int = 3,
    bin_m: float = 50.0,
    time_limit_s: float = 0.0,
    seed: int = 0,
) -> dict[str, Any]:
    """Drive ``act`` (observation of one car -> keys (1, 4)) in ``env`` from the start line until ``laps`` laps, the
    episode's end or ``time_limit_s`` (0: 3 x the limit lap time per lap); returns JSON-ready per-lap mean reward per
    ``bin_m`` of lap distance (None where no step began), with each lap's steps and summed reward."""
    if laps < 1 or bin_m <= 0 or time_limit_s < 0:
        raise ValueError(f"laps must be >= 1, bin_m > 0 and time_limit_s >= 0, got {laps}, {bin_m}, {time_limit_s}")
    core = PixelRacingCore(dataclasses.replace(env, n_cars=1, start="line"), seed=seed)
    try:
        length_m = core.track.length_m
        if time_limit_s == 0:
            time_limit_s = 3.0 * laps * line_and_profile(core.track, core.car)[1].lap_time_s
        n_bins = math.ceil(length_m / bin_m)
        reward_sum, count = np.zeros((laps, n_bins)), np.zeros((laps, n_bins), dtype=np.int64)
        core.reset_cars(np.array([0]))
        obs = core.observation()
        end = "time limit"
        for _ in range(math.ceil(time_limit_s / env.control_dt_s - 1e-9)):
            lap = int(core.world.state.laps_completed[0])
            if lap >= laps:
                end = f"{laps} laps"
                break
            where = min(int(core.world.state.s_m[0] // bin_m), n_bins - 1)
            obs, reward, terminated, truncated, _ = core.step(np.asarray(act(obs), dtype=np.float64).reshape(1, 4))
            reward_sum[lap, where] += float(reward[0])
            count[lap, where] += 1
            if terminated[0] or truncated[0]:
                end = "terminated" if terminated[0] else "truncated"
                break
    finally:
        core.close()
    mean = np.where(count > 0, reward_sum / np.maximum(count, 1), np.nan)
    return {
        "track": env.track,
        "car": env.car,
        "lap_length_m": length_m,
        "bin_m": bin_m,
        "bin_start_m": (np.arange(n_bins) * bin_m).tolist(),
        "end": end,
        "laps": [
            {
                "lap": k + 1,
                "steps": int(count[k].sum()),
                "reward": float(reward_sum[k].sum()),
                "mean_reward": [None if math.isnan(x) else float(x) for x in mean[k]],
            }
            for k in range(laps)
        ],
    }


def plot_lap_reward(profile: dict[str, Any], path: str | os.PathLike[str], title: str) -> Path:
    """The profile as a PNG: mean reward per step against lap distance, one line per lap."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    fig, ax = plt.subplots(figsize=(9, 4))
    centres = np.asarray(profile["bin_start_m"]) + 0.5 * profile["bin_m"]
    for lap in profile["laps"]:
        if lap["steps"]:
            values = np.array([np.nan if v is None else v for v in lap["mean_reward"]])
            ax.plot(centres, values, label=f"lap {lap['lap']}")
    ax.set_xlabel("lap distance (m)")
    ax.set_ylabel("mean reward per 0.1 s step")
    ax.set_xlim(0, profile["lap_length_m"])
    ax.set_title(f"{title} ({profile['end']})")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
