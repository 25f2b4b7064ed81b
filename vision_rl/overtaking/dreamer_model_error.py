"""How well a Dreamer run's world model (:mod:`.dreamer`) predicts laps it did not train on (``vision-rl
dreamer-model``): the measure that tells a DNF of a model that cannot predict the race from one of an actor that
does not use a good model.

From each start point of the laps the model filters its posterior over ``context_steps`` rows with the true
observations and actions (as the driver does, posterior means), then imagines open-loop with the true actions, prior
means, up to the longest horizon; at each horizon the predicted observation (in the normalised units the model sees,
over all 96 entries and per group of entries) and reward are compared with the truth, as root mean squared errors
over the start points, beside a baseline that holds the last observed observation and reward. A model whose error is
not below the hold-last baseline's predicts nothing. How to read it: docs/notes/overtaking.md, "dreamer.py".
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch

from vision_rl.envs.observations import OBS_NAMES, ObsNormalizer
from vision_rl.files import atomic_write, sealed_record, write_json
from vision_rl.overtaking.baselines import load_baseline
from vision_rl.overtaking.config import OBSERVATION
from vision_rl.overtaking.demos import Demos, demo_fingerprint, load_demos, normalizer_sha256
from vision_rl.overtaking.dreamer import LatentState, LoadedDreamer, WorldModel, to_model_units

RECORD_FORMAT = "vision_rl.dreamer_model_error"
RECORD_FORMAT_VERSION = 2  # 2: the model's reward bias and the true reward per horizon
DEFAULT_HORIZONS = (1, 5, 10, 25, 50)
CONTROL_DT_S = 0.1


def observation_groups(names: tuple[str, ...] = OBS_NAMES[OBSERVATION]) -> dict[str, list[int]]:
    """Entries of the observation by group, in order: the words before the first ``_`` where several names share
    them (``velocity``, ``lidar``, ``curvature``...), else the whole name (``wall_contact``)."""
    heads = [name.split("_")[0] for name in names]
    groups: dict[str, list[int]] = {}
    for i, (name, head) in enumerate(zip(names, heads, strict=True)):
        groups.setdefault(head if heads.count(head) > 1 else name, []).append(i)
    return groups


def load_dreamer_run(path: str | os.PathLike[str]) -> LoadedDreamer:
    """A train-baseline dreamer run, refusing any other run in one line (:class:`~.baseline_run.BaselineError`)."""
    loaded = load_baseline(path, algo="dreamer")
    assert isinstance(loaded, LoadedDreamer)
    return loaded


def load_laps_for(path: str | os.PathLike[str], run: LoadedDreamer) -> Demos:
    """Demonstrations (``record-demos``) of the run's track, car and observation, refused in one line otherwise
    (:class:`~.demos.DemoError`); their normaliser may differ from the run's (:func:`model_rows` converts)."""
    config = run.config
    expected = demo_fingerprint(config.track, config.car, run.spec.normalizer)
    return load_demos(path, {k: v for k, v in expected.items() if k != "normalizer_sha256"})


class ModelRows(NamedTuple):
    """Laps in :class:`~.dreamer.SequenceReplay`'s row convention, in the model's units (float32 arrays)."""

    observations: np.ndarray  # (N, obs_dim), normalised by the run's normaliser
    prev_actions: np.ndarray  # (N, 2) in [-1, 1]: the action that led to the row (0 at an episode's start)
    rewards: np.ndarray  # (N,) received on arriving at the row (0 at an episode's start)
    is_first: np.ndarray  # (N,)


def model_rows(demos: Demos, normalizer: ObsNormalizer) -> ModelRows:
    """The laps as the run's model sees them: observations re-normalised from the laps' normaliser to the run's
    where they differ (through the raw values, float64), actions scaled as the driver's inverse."""
    obs = demos.observations
    recorded = ObsNormalizer.from_dict(demos.meta["normalizer"])
    if normalizer_sha256(recorded) != normalizer_sha256(normalizer):
        obs = normalizer(obs.astype(np.float64) * recorded.scale + recorded.offset)
    first = demos.episode_starts
    # A demos row holds (o_t, a_t, r_{t+1}); the model's row t holds (o_t, a_{t-1}, r_t).
    prev_actions = np.zeros_like(demos.actions)
    prev_actions[1:] = to_model_units(demos.actions[:-1])
    rewards = np.zeros_like(demos.rewards)
    rewards[1:] = demos.rewards[:-1]
    prev_actions[first], rewards[first] = 0.0, 0.0
    return ModelRows(obs.astype(np.float32), prev_actions, rewards, first.astype(np.float32))


def start_rows(episode_starts: np.ndarray, context_steps: int, max_horizon: int) -> np.ndarray:
    """Rows that can end a context of ``context_steps`` rows and be followed by ``max_horizon`` rows, all in one
    episode; refuses laps without one in a line."""
    n = len(episode_starts)
    rows = np.arange(n)
    episode = np.cumsum(episode_starts) - 1
    first_row = np.flatnonzero(episode_starts)
    last_row = np.append(first_row[1:], n) - 1
    ok = (rows - first_row[episode] >= context_steps - 1) & (last_row[episode] - rows >= max_horizon)
    if not ok.any():
        longest = int((last_row - first_row).max()) + 1
        raise ValueError(
            f"no episode of the laps holds --context-steps {context_steps} plus the longest horizon {max_horizon} "
            f"= {context_steps + max_horizon} steps (the longest holds {longest}): shorten them or record longer laps"
        )
    return rows[ok]


class RolloutErrors(NamedTuple):
    """Means over the start points. Squared errors: per step 1..H and observation entry (H, obs_dim), per step (H,)
    for the reward; the posterior's reconstruction of the context's last observation (obs_dim,). Then, per step, the
    mean of the model's reward less the true one (its bias: negative where it expects penalties the laps do not
    have) and the mean true reward."""

    model_observation: np.ndarray
    model_reward: np.ndarray
    hold_last_observation: np.ndarray
    hold_last_reward: np.ndarray
    reconstruction: np.ndarray
    model_reward_bias: np.ndarray
    true_reward: np.ndarray


@torch.no_grad()
def rollout_errors(model: WorldModel, rows: ModelRows, starts: np.ndarray, context_steps: int, horizon: int):
    """:class:`RolloutErrors` of the model filtering ``context_steps`` rows ending at each of ``starts`` and
    imagining ``horizon`` steps on from there, all start points at once."""
    device = next(model.parameters()).device
    index = starts[:, None] + np.arange(1 - context_steps, horizon + 1)[None, :]  # (N, C + H)

    def take(array: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(array[index], device=device)

    obs, prev_actions = take(rows.observations), take(rows.prev_actions)
    rewards, first = take(rows.rewards), take(rows.is_first)
    embed = model.encoder(obs[:, :context_steps])
    state = model.initial(len(starts))
    for t in range(context_steps):  # as the driver filters: posterior means
        state, _, _ = model.observe_step(state, prev_actions[:, t], embed[:, t], first[:, t], sample=False)
    last = context_steps - 1
    reconstruction = (model.decoder(state.feature()) - obs[:, last]) ** 2
    predicted_obs, predicted_reward = [], []
    for k in range(1, horizon + 1):  # open loop: the true actions, the prior's means
        h, prior = model.imagine_step(state, prev_actions[:, last + k])
        state = LatentState(h, prior.mean)
        feature = state.feature()
        predicted_obs.append(model.decoder(feature))
        predicted_reward.append(model.reward_head(feature).squeeze(-1))
    true_obs, true_reward = obs[:, last + 1 :], rewards[:, last + 1 :]  # (N, H, ...)
    model_obs = (torch.stack(predicted_obs, 1) - true_obs) ** 2
    reward_error = torch.stack(predicted_reward, 1) - true_reward
    hold_obs = (true_obs - obs[:, last : last + 1]) ** 2
    hold_reward = (true_reward - rewards[:, last : last + 1]) ** 2
    means = (model_obs, reward_error**2, hold_obs, hold_reward, reconstruction, reward_error, true_reward)
    return RolloutErrors(*(e.double().mean(0).cpu().numpy() for e in means))


def check_horizons(horizons: tuple[int, ...], context_steps: int) -> None:
    """One line for horizons or a context that cannot be measured."""
    if not horizons or any(int(h) != h or h <= 0 for h in horizons):
        raise ValueError(f"--horizons must be whole numbers of steps above 0, got {','.join(map(str, horizons))}")
    if int(context_steps) != context_steps or context_steps < 1:
        raise ValueError(f"--context-steps must be a whole number of steps of at least 1, got {context_steps}")


def _rmse(squared: np.ndarray, groups: dict[str, list[int]]) -> dict[str, Any]:
    """RMSE over all entries of a (obs_dim,) mean squared error, and per group."""
    return {
        "observation_rmse": float(np.sqrt(squared.mean())),
        "groups": {name: float(np.sqrt(squared[cols].mean())) for name, cols in groups.items()},
    }


def _horizon_rows(errors: RolloutErrors, horizons: tuple[int, ...]) -> list[dict[str, Any]]:
    groups = observation_groups()
    out = []
    for h in sorted(set(horizons)):
        model = {
            **_rmse(errors.model_observation[h - 1], groups),
            "reward_rmse": float(np.sqrt(errors.model_reward[h - 1])),
            "reward_bias": float(errors.model_reward_bias[h - 1]),
        }
        hold = {
            **_rmse(errors.hold_last_observation[h - 1], groups),
            "reward_rmse": float(np.sqrt(errors.hold_last_reward[h - 1])),
        }
        ratio = model["observation_rmse"] / hold["observation_rmse"] if hold["observation_rmse"] > 0 else None
        out.append(
            {
                "horizon_steps": h,
                "horizon_s": round(h * CONTROL_DT_S, 3),
                "model": model,
                "hold_last": hold,
                "observation_rmse_ratio_to_hold_last": ratio,
                "true_reward_mean": float(errors.true_reward[h - 1]),
            }
        )
    return out


def model_error(
    run: LoadedDreamer,
    laps: Demos,
    context_steps: int = 20,
    horizons: tuple[int, ...] = DEFAULT_HORIZONS,
    starts: int = 1000,
    seed: int = 0,
) -> dict[str, Any]:
    """The world model's prediction error on ``laps`` (see the module's docstring) from ``starts`` start points
    drawn at random (``seed``) among those the laps hold (all of them when fewer): per horizon, the model's and the
    hold-last baseline's RMSE, the curve over every step to the longest, and the record's fingerprint."""
    check_horizons(tuple(horizons), context_steps)
    if starts < 1:
        raise ValueError(f"--starts must be at least 1, got {starts}")
    max_horizon = max(horizons)
    rows = model_rows(laps, run.spec.normalizer)
    available = start_rows(laps.episode_starts, context_steps, max_horizon)
    rng = np.random.default_rng(seed)
    chosen = np.sort(rng.choice(available, size=min(starts, len(available)), replace=False))
    errors = rollout_errors(run.agent.world_model, rows, chosen, context_steps, max_horizon)
    steps = np.arange(1, max_horizon + 1)
    return {
        "format": RECORD_FORMAT,
        "format_version": RECORD_FORMAT_VERSION,
        "made_from": {
            "policy": str(run.weights_path),
            "policy_sha256": run.spec.weights_sha256,
            "laps": str(laps.path),
            "laps_sha256": laps.sha256,
        },
        "num_timesteps": run.spec.num_timesteps,
        "track": run.config.track,
        "car": run.config.car,
        "settings": {"context_steps": context_steps, "horizons": sorted(set(horizons)), "starts": starts, "seed": seed},
        "units": {
            "observation": "the normalised units the model sees (z-score; lidar a share of its range)",
            "reward": "Eq. 1, per step",
        },
        "n_starts": len(chosen),
        "n_start_points_available": len(available),
        "reconstruction": _rmse(errors.reconstruction, observation_groups()),
        "horizons": _horizon_rows(errors, tuple(horizons)),
        "curve": {
            "horizon_steps": steps.tolist(),
            "model_observation_rmse": np.sqrt(errors.model_observation.mean(1)).tolist(),
            "hold_last_observation_rmse": np.sqrt(errors.hold_last_observation.mean(1)).tolist(),
            "model_reward_rmse": np.sqrt(errors.model_reward).tolist(),
            "hold_last_reward_rmse": np.sqrt(errors.hold_last_reward).tolist(),
        },
    }


def default_out(run: LoadedDreamer) -> Path:
    """Where the record goes unless told: beside the run's policy."""
    return run.spec_path.parent / "model_error.json"


def write_model_error(result: dict[str, Any], out: str | os.PathLike[str]) -> dict[str, str]:
    """The record sealed at ``out`` (JSON) and its figure beside it (``.png``); returns both paths."""
    out = Path(out)
    write_json(out, sealed_record(result))
    png = out.with_suffix(".png")
    atomic_write(png, lambda tmp: _figure(result, tmp))
    return {"json": str(out), "png": str(png)}


def _figure(result: dict[str, Any], path: Path) -> None:
    """Observation and reward RMSE against horizon, the model beside the hold-last baseline, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curve = result["curve"]
    seconds = np.asarray(curve["horizon_steps"]) * CONTROL_DT_S
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, what, unit in ((axes[0], "observation", "normalised units"), (axes[1], "reward", "per step")):
        ax.plot(seconds, curve[f"model_{what}_rmse"], label="world model (open loop)")
        ax.plot(seconds, curve[f"hold_last_{what}_rmse"], "--", label="hold last")
        ax.set_xlabel("horizon, s")
        ax.set_ylabel(f"{what} RMSE, {unit}")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(
        f"Dreamer world model on held-out laps: {result['n_starts']} starts, context "
        f"{result['settings']['context_steps']} steps, {result['num_timesteps']} training steps"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=100, format="png")
    plt.close(fig)


__all__ = [
    "DEFAULT_HORIZONS",
    "ModelRows",
    "RolloutErrors",
    "check_horizons",
    "default_out",
    "load_dreamer_run",
    "load_laps_for",
    "model_error",
    "model_rows",
    "observation_groups",
    "rollout_errors",
    "start_rows",
    "write_model_error",
]
