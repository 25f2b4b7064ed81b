"""The reference check of the DDPG agent: the project's agent (the ``state-actor`` variant's layers, update, noise and
replay, driven through a :class:`~vision_rl.ddpg.agent.VectorTask`) beside Stable-Baselines3's ``DDPG`` and ``TD3``
on a standard Gymnasium task (``Pendulum-v1``, ``MountainCarContinuous-v0``), with the same hyper-parameters,
exploration noise, network widths, warm-up and observation scaling, so that a bug can be told from a hard task.

Each run records its learning curve: the return of every training episode and a deterministic evaluation every
``eval_every_steps`` against environment steps (:func:`run_reference`, one JSON record per run); :func:`summarise`
and :func:`plot_reference` put the runs of several seeds together (mean and spread per algorithm).

What the two sides share, step for step (SB3's off-policy loop as of 2.x): the first ``learning_starts`` actions are
uniform in the action box plus the noise; then the actor's action plus the noise, clipped to [-1, 1] and mapped
linearly onto the task's bounds; the stored action is the clipped one in [-1, 1]; one update per step once
``learning_starts`` steps are stored; a time limit is not a termination (the target bootstraps through it);
observations enter scaled by the observation box's centre and half width. What differs and cannot be made equal:
SB3's critic is one MLP on the state and action concatenated (widths :data:`SB3_CRITIC_ARCH`), ours two pathways
(state, action) merged; ours may carry batch-norm (``ours-bn``); SB3 takes one learning rate for both networks.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vision_rl.ddpg.agent import DDPGAgent, FrameReplay, VectorTask
from vision_rl.ddpg.config import ALGOS, DDPGError, DDPGHyper, ReferenceRun

RECORD_FORMAT = "vision_rl.ddpg_reference"
#: Evaluation episodes start from these seeds on (the same starts for every algorithm and run).
EVAL_SEED = 10_000
#: SB3's actor: the widths of our state actor's layers.
SB3_ACTOR_ARCH = (150, 300, 300)
#: SB3's critic, one MLP on (state, action): the widths along one path of ours (a pathway's 150, 300, 300, then the
#: merge's 600).
SB3_CRITIC_ARCH = (150, 300, 300, 600)


# ------------------------------------------------------------------------------------------------ the task


@dataclass(frozen=True)
class TaskScaling:
    """A Box task's observation scaling (centre and half width of its finite bounds; 0 and 1 where unbounded) and
    action bounds: actions in [-1, 1] map linearly onto [low, high]."""

    obs_offset: tuple[float, ...]
    obs_scale: tuple[float, ...]
    action_low: tuple[float, ...]
    action_high: tuple[float, ...]

    @classmethod
    def of(cls, env: Any) -> TaskScaling:
        from gymnasium import spaces

        obs_space, act_space = env.observation_space, env.action_space
        if not isinstance(obs_space, spaces.Box) or not isinstance(act_space, spaces.Box):
            raise DDPGError(f"the reference check needs Box observations and actions, got {obs_space}, {act_space}")
        if len(obs_space.shape) != 1 or not np.all(np.isfinite(act_space.low) & np.isfinite(act_space.high)):
            raise DDPGError("the reference check needs a flat observation and a bounded action box")
        low, high = obs_space.low.astype(np.float64), obs_space.high.astype(np.float64)
        finite = np.isfinite(low) & np.isfinite(high)
        offset = np.where(finite, 0.5 * (low + high), 0.0)
        scale = np.where(finite, np.maximum(0.5 * (high - low), 1e-8), 1.0)
        return cls(
            tuple(offset.tolist()),
            tuple(scale.tolist()),
            tuple(act_space.low.astype(float).tolist()),
            tuple(act_space.high.astype(float).tolist()),
        )

    def vector_task(self) -> VectorTask:
        return VectorTask(self.obs_offset, self.obs_scale, len(self.action_low))

    def scale_obs(self, obs: np.ndarray) -> np.ndarray:
        return ((np.asarray(obs, np.float64) - self.obs_offset) / self.obs_scale).astype(np.float32)

    def to_env(self, action: np.ndarray) -> np.ndarray:
        """An action in [-1, 1] on the task's bounds."""
        low, high = np.asarray(self.action_low), np.asarray(self.action_high)
        return (low + 0.5 * (np.asarray(action, np.float64) + 1.0) * (high - low)).astype(np.float32)


def evaluate_policy(task: str, policy: Callable[[np.ndarray], np.ndarray], episodes: int) -> list[float]:
    """Returns of ``episodes`` episodes of ``policy`` (raw observation -> action on the task's bounds) from the
    starts of seeds :data:`EVAL_SEED` on."""
    import gymnasium as gym

    env = gym.make(task)
    returns = []
    try:
        for k in range(episodes):
            obs, _ = env.reset(seed=EVAL_SEED + k)
            total, done = 0.0, False
            while not done:
                obs, reward, terminated, truncated, _ = env.step(policy(obs))
                total += float(reward)
                done = terminated or truncated
            returns.append(total)
    finally:
        env.close()
    return returns


class _Curve:
    """A run's learning curve: training episodes and periodic deterministic evaluations against steps."""

    def __init__(self, run: ReferenceRun) -> None:
        self.run = run
        self.episodes: list[dict[str, Any]] = []
        self.evaluations: list[dict[str, Any]] = []

    def episode(self, num_steps: int, episode_return: float, length_steps: int) -> None:
        self.episodes.append(
            {"num_steps": int(num_steps), "return": float(episode_return), "length": int(length_steps)}
        )

    def after_step(self, num_steps: int, policy: Callable[[np.ndarray], np.ndarray]) -> None:
        every = self.run.eval_every_steps
        if every and num_steps % every == 0 and num_steps < self.run.steps:
            self.evaluate(num_steps, policy, self.run.eval_episodes)

    def evaluate(self, num_steps: int, policy: Callable[[np.ndarray], np.ndarray], episodes: int) -> None:
        returns = evaluate_policy(self.run.task, policy, episodes)
        self.evaluations.append(
            {"num_steps": int(num_steps), "mean_return": float(np.mean(returns)), "returns": returns}
        )


# ------------------------------------------------------------------------------------------------ ours


def _train_ours(run: ReferenceRun, curve: _Curve) -> dict[str, Any]:
    """The project's agent through its act / replay / update API, SB3's loop step for step (module docstring)."""
    import gymnasium as gym

    hyper = run.agent_hyper
    env = gym.make(run.task)
    scaling = TaskScaling.of(env)
    task = scaling.vector_task()
    agent = DDPGAgent(hyper, task, n_cars=1, seed=run.seed)
    buffer = FrameReplay(hyper.buffer_size, 1, None, {"state": task.obs_dim}, task.action_dim)
    rng = np.random.default_rng(run.seed + 1)  # warm-up actions and batches

    def policy(obs: np.ndarray) -> np.ndarray:
        return scaling.to_env(agent.act({"state": np.asarray(obs, np.float32)[None]})[0])

    obs, _ = env.reset(seed=run.seed)
    buffer.start({"state": np.asarray(obs, np.float32)[None]})
    episode_return, episode_steps = 0.0, 0
    try:
        for step in range(1, run.steps + 1):
            if step <= run.learning_starts:
                action = np.clip(rng.uniform(-1.0, 1.0, (1, task.action_dim)) + agent.noise(), -1.0, 1.0)
            else:
                action = agent.act({"state": np.asarray(obs, np.float32)[None]}, explore=True)
            next_obs, reward, terminated, truncated, _ = env.step(scaling.to_env(action[0]))
            episode_return, episode_steps = episode_return + float(reward), episode_steps + 1
            done = terminated or truncated
            reset_obs = None
            if done:
                curve.episode(step, episode_return, episode_steps)
                episode_return, episode_steps = 0.0, 0
                first_obs, _ = env.reset()
                reset_obs = {"state": np.asarray(first_obs, np.float32)[None]}
                agent.noise.reset()
            buffer.add(
                action,
                np.array([reward], np.float32),
                np.array([terminated]),
                {"state": np.asarray(next_obs, np.float32)[None]},
                np.array([done]),
                reset_obs,
            )
            obs = first_obs if done else next_obs
            curve.after_step(step, policy)
            if step > run.learning_starts and buffer.size >= hyper.batch_size:
                agent.update(buffer.sample(hyper.batch_size, rng))
        curve.evaluate(run.steps, policy, run.final_eval_episodes)
    finally:
        env.close()
    return {"updates": agent.n_updates}


# ------------------------------------------------------------------------------------------------ SB3


def sb3_kwargs(run: ReferenceRun) -> dict[str, Any]:
    """Stable-Baselines3's constructor arguments of ``run`` (plain values: they go into the record)."""
    h = run.hyper
    return {
        "learning_rate": h.actor_lr,
        "buffer_size": h.buffer_size,
        "learning_starts": run.learning_starts,
        "batch_size": h.batch_size,
        "tau": h.tau,
        "gamma": h.gamma,
        "train_freq": 1,
        "gradient_steps": 1,
        "policy_kwargs": {"net_arch": {"pi": list(SB3_ACTOR_ARCH), "qf": list(SB3_CRITIC_ARCH)}},
        "noise": {"kind": "ornstein-uhlenbeck", "theta": h.ou_theta, "sigma": h.ou_sigma, "dt": h.ou_dt, "mu": h.ou_mu},
    }


def _train_sb3(run: ReferenceRun, curve: _Curve) -> dict[str, Any]:
    import gymnasium as gym
    from gymnasium.wrappers import TransformObservation
    from stable_baselines3 import DDPG, TD3
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.noise import OrnsteinUhlenbeckActionNoise

    raw = gym.make(run.task)
    scaling = TaskScaling.of(raw)
    n = len(scaling.obs_scale)
    box = gym.spaces.Box(-np.inf, np.inf, (n,), np.float32)
    env = Monitor(TransformObservation(raw, scaling.scale_obs, box))
    kwargs = sb3_kwargs(run)
    noise = kwargs.pop("noise")
    k = len(scaling.action_low)
    kwargs["action_noise"] = OrnsteinUhlenbeckActionNoise(
        np.full(k, noise["mu"]), np.full(k, noise["sigma"]), theta=noise["theta"], dt=noise["dt"]
    )
    algo = DDPG if run.algo == "sb3-ddpg" else TD3
    model = algo("MlpPolicy", env, seed=run.seed, device="cpu", verbose=0, **kwargs)

    def policy(obs: np.ndarray) -> np.ndarray:
        return model.predict(scaling.scale_obs(obs), deterministic=True)[0]

    class _Record(BaseCallback):
        def _on_step(self) -> bool:
            for info in self.locals["infos"]:
                if "episode" in info:
                    curve.episode(self.num_timesteps, info["episode"]["r"], info["episode"]["l"])
            curve.after_step(self.num_timesteps, policy)
            return True

    try:
        model.learn(run.steps, callback=_Record())
        curve.evaluate(run.steps, policy, run.final_eval_episodes)
    finally:
        env.close()
    return {"updates": int(model._n_updates)}


# ------------------------------------------------------------------------------------------------ runs and records


def run_reference(run: ReferenceRun) -> dict[str, Any]:
    """Train ``run`` and return its record: settings, training episodes, evaluations, final return (the mean of
    the last evaluation's ``final_eval_episodes``), updates and wall-clock time. Call
    ``torch.set_num_threads`` first to pin the threads."""
    curve = _Curve(run)
    t0 = time.perf_counter()
    extra = _train_ours(run, curve) if run.algo.startswith("ours") else _train_sb3(run, curve)
    return {
        "format": RECORD_FORMAT,
        "format_version": 1,
        **{f.name: getattr(run, f.name) for f in dataclasses.fields(run) if f.name != "hyper"},
        "hyper": asdict(run.agent_hyper),
        "sb3": sb3_kwargs(run) if run.algo.startswith("sb3") else None,
        "train_time_s": round(time.perf_counter() - t0, 2),
        **extra,
        "final_return": curve.evaluations[-1]["mean_return"],
        "episodes": curve.episodes,
        "evaluations": curve.evaluations,
    }


def same_settings(record: Mapping[str, Any], run: ReferenceRun) -> bool:
    """Whether a stored record is of ``run`` (task, algorithm, seed, schedule and hyper-parameters)."""
    wanted = {f.name: getattr(run, f.name) for f in dataclasses.fields(run) if f.name != "hyper"}
    try:  # a hyper-parameter added since the record was written holds its default there
        hyper = DDPGHyper(**record.get("hyper", {}))
    except (TypeError, DDPGError):
        return False
    return (
        record.get("format") == RECORD_FORMAT
        and all(record.get(k) == v for k, v in wanted.items())
        and hyper == run.agent_hyper
    )


def _band(values: Sequence[float]) -> dict[str, float]:
    a = np.asarray(values, np.float64)
    return {"mean": float(a.mean()), "std": float(a.std(ddof=1)) if len(a) > 1 else 0.0, "n": len(a)}


def binned_returns(record: Mapping[str, Any], bin_steps: int) -> dict[int, float]:
    """Mean training-episode return per bin of ``bin_steps`` steps (keyed by the bin's end step), from the
    episodes that ended in it."""
    bins: dict[int, list[float]] = {}
    for e in record["episodes"]:
        end = int(math.ceil(e["num_steps"] / bin_steps) * bin_steps)
        bins.setdefault(end, []).append(e["return"])
    return {end: float(np.mean(v)) for end, v in sorted(bins.items())}


def summarise(records: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One row per (task, algorithm): seeds, steps, final return's mean and std over seeds (sample std), and likewise
    the mean of the last 5 evaluations (one policy's 10 episodes are a noisy reading of a run whose policy still
    oscillates) and of the last 10 training episodes' returns (with exploration noise)."""
    groups: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    for r in records:
        groups.setdefault((r["task"], r["algo"]), []).append(r)
    rows = []
    for (task, algo), rs in groups.items():
        rows.append(
            {
                "task": task,
                "algo": algo,
                "seeds": sorted(r["seed"] for r in rs),
                "steps": sorted({r["steps"] for r in rs}),
                "final_return": _band([r["final_return"] for r in rs]),
                "last5_eval_return": _band([np.mean([e["mean_return"] for e in r["evaluations"][-5:]]) for r in rs]),
                "last10_train_return": _band([np.mean([e["return"] for e in r["episodes"][-10:]]) for r in rs]),
                "train_time_s": _band([r["train_time_s"] for r in rs]),
            }
        )
    order = {a: i for i, a in enumerate(ALGOS)}
    return sorted(rows, key=lambda row: (row["task"], order.get(row["algo"], len(ALGOS))))


def plot_reference(records: Sequence[Mapping[str, Any]], path: str | Path, bin_steps: int = 1_000) -> Path:
    """A figure per task (side by side): left the training episodes' return (binned by ``bin_steps``), right the
    deterministic evaluations, each the mean over seeds with a band of one standard deviation, a line per
    algorithm."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = sorted({r["task"] for r in records})
    fig, axes = plt.subplots(len(tasks), 2, figsize=(11, 3.6 * len(tasks)), squeeze=False)
    for row, task in zip(axes, tasks, strict=True):
        for algo in [a for a in ALGOS if any(r["algo"] == a and r["task"] == task for r in records)]:
            runs = [r for r in records if r["algo"] == algo and r["task"] == task]
            train = [binned_returns(r, bin_steps) for r in runs]
            evals = [{e["num_steps"]: e["mean_return"] for e in r["evaluations"]} for r in runs]
            for ax, curves in zip(row, (train, evals), strict=True):
                steps = sorted(set.intersection(*(set(c) for c in curves)))
                values = np.array([[c[s] for s in steps] for c in curves])
                mean, std = values.mean(0), values.std(0, ddof=1) if len(values) > 1 else np.zeros(len(steps))
                (line,) = ax.plot(steps, mean, label=f"{algo} ({len(runs)} seeds)")
                ax.fill_between(steps, mean - std, mean + std, color=line.get_color(), alpha=0.2)
        row[0].set_title(f"{task}: training episodes (mean of each {bin_steps} steps)")
        row[1].set_title(f"{task}: deterministic evaluation")
        for ax in row:
            ax.set_xlabel("environment steps")
            ax.set_ylabel("return")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def record_path(out: str | Path, run: ReferenceRun) -> Path:
    """Where ``run``'s record goes: ``out/<task>/<algo>-s<seed>.json``."""
    return Path(out) / run.task / f"{run.algo}-s{run.seed}.json"


def load_or_run(run: ReferenceRun, out: str | Path, force: bool = False) -> tuple[dict[str, Any], bool]:
    """``run``'s record from ``out`` when one of the same settings is there (unless ``force``), else trained and
    written there; returns (record, whether it was trained now)."""
    import json

    from vision_rl.files import sealed_record, write_json

    path = record_path(out, run)
    if path.is_file() and not force:
        try:
            record = json.loads(path.read_text())
        except (OSError, ValueError):
            record = {}
        if same_settings(record, run):
            return record, False
    record = run_reference(run)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, sealed_record(record), indent=None)  # `vision-rl report` reads it: sealed, as every record is
    return record, True
