"""`train-ddpg --workers N`: DDPG's transitions from N sampler actors (Ray), the learner in this process.

Each sampler steps its own PixelRacing world of the run's ``cars`` cars (rendering their frames) with a copy of the
actor and its own OU noise, and returns chunks of vector steps as numpy arrays: keys, rewards, terminations, the
next observation (the final one where an episode ended) and, where one ended, the new episode's first observation,
plus one record per finished episode. The learner's frame replay has one column of rows per car of every sampler
(``workers x cars``), each column a continuous stream, so every frame is still stored once. The pacing, the
staleness bound and the handling of a lost sampler are :mod:`vision_rl.training.distributed`'s; DDPG explores
with the actor and its noise from the first step, so the pacing's random start steps only delay the updates
(until ``max(learning_starts, batch_size)`` transitions, as the single-process loop waits for both).
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from vision_rl.training.distributed import (
    Learner,
    actor_weights,
    check_sampler_fingerprint,
    load_actor_weights,
    portable_track,
    worker_seed,
)

if TYPE_CHECKING:
    from vision_rl.envs.pixel_racing import PixelRacingConfig

OBS_KEYS = ("image", "motion", "goal")


def episode_record(info: Mapping[str, np.ndarray], i: int, terminated: bool, env: PixelRacingConfig) -> dict:
    """The line of episodes.jsonl of car ``i``, whose episode ended in a PixelRacing step with ``info`` under the
    rules of ``env``: return, steps, distance, laps and why it ended (time, crash <state>, line distance, stuck; a
    stuck end is a truncation with ``truncate_when_stuck``)."""
    if not terminated:
        end = "stuck" if env.truncate_when_stuck and info["stuck"][i] else "time"
    elif env.terminate_on_crash and info["crash_state"][i]:
        end = f"crash {int(info['crash_state'][i])}"
    elif info["line_distance_m"][i] > env.max_line_distance_m:
        end = "line distance"
    else:
        end = "stuck"
    return {
        "car": int(i),
        "return": round(float(info["episode_return"][i]), 3),
        "steps": int(info["episode_steps"][i]),
        "distance_m": round(float(info["progress_m"][i]), 2),
        "laps": int(info["laps_completed"][i]),
        "end": end,
    }


@dataclass(frozen=True)
class DDPGSamplerSetup:
    """What a DDPG sampler actor builds its world and actor from: plain values only."""

    hyper: Mapping[str, Any]
    """The run's ``DDPGHyper`` as a dict."""
    env: Mapping[str, Any]
    """The run's ``PixelRacingConfig.to_dict()`` (``n_cars`` cars per sampler; a CSV track by its absolute path)."""
    fingerprint: Mapping[str, Any]
    """The run's fingerprint; a sampler whose track, car or networks differ refuses to start."""
    seed: int
    """Base seed; sampler w uses a child of (seed, w)."""

    def body(self) -> type:
        return DDPGSampler


def sampler_setup(hyper: Any, env: Any, fingerprint: Mapping[str, Any], seed: int) -> DDPGSamplerSetup:
    """The setup of a run's samplers (``hyper`` a DDPGHyper, ``env`` a PixelRacingConfig)."""
    env_dict = {**env.to_dict(), "track": portable_track(env.track)}
    return DDPGSamplerSetup(hyper=dataclasses.asdict(hyper), env=env_dict, fingerprint=dict(fingerprint), seed=seed)


class DDPGSampler:
    """The body of a DDPG sampler actor. ``ready()`` returns its cars' first observations; ``sample(weights,
    version, steps, random_steps)`` steps the world ``steps`` times acting with the actor plus OU noise (the
    version's weights, fetched only when ``version`` changes; ``random_steps`` is ignored: see the module
    docstring) and returns the chunk."""

    def __init__(self, setup: DDPGSamplerSetup, worker: int) -> None:
        import torch

        from vision_rl.ddpg.agent import DDPGAgent, DDPGHyper, ddpg_fingerprint
        from vision_rl.envs.pixel_racing import PixelRacingConfig, PixelRacingCore

        torch.set_num_threads(1)  # the learner and the other samplers share the cores
        self.worker = worker
        seed = worker_seed(setup.seed, worker)
        env = PixelRacingConfig.from_dict(dict(setup.env))
        hyper = DDPGHyper(**dict(setup.hyper))
        mine = ddpg_fingerprint(hyper, env)
        check_sampler_fingerprint(worker, mine, setup.fingerprint)
        self.agent = DDPGAgent(hyper, env, n_cars=env.n_cars, seed=seed)
        self.core = PixelRacingCore(env, seed=seed)
        self.core.reset_cars(self.core.ids)
        self.obs = self.core.observation()
        self.env = env
        self.version = -1

    def ready(self) -> dict[str, np.ndarray]:
        return self.obs

    def pid(self) -> int:
        return os.getpid()

    def sample(self, weights: list[Any], version: int, steps: int, random_steps: int) -> dict[str, Any]:
        t0 = time.perf_counter()
        if version != self.version:
            load_actor_weights(self.agent.actor, weights)
            self.version = version
        n = self.core.config.n_cars
        out: dict[str, Any] = {
            "keys": np.empty((steps, n, 4), np.float32),
            "reward": np.empty((steps, n), np.float32),
            "terminated": np.empty((steps, n), bool),
            "done": np.empty((steps, n), bool),
            "episodes": [],
        }
        for key, value in self.obs.items():
            out[f"next_{key}"] = np.empty((steps, *value.shape), value.dtype)
            out[f"reset_{key}"] = np.zeros((steps, *value.shape), value.dtype)
        for k in range(steps):
            keys = self.agent.act(self.obs, explore=True).astype(np.float32)  # stored exactly as applied
            next_obs, reward, terminated, truncated, info = self.core.step(keys)
            done = terminated | truncated
            out["keys"][k], out["reward"][k], out["terminated"][k], out["done"][k] = keys, reward, terminated, done
            for key, value in next_obs.items():
                out[f"next_{key}"][k] = value
            ended = np.flatnonzero(done)
            if len(ended):
                for i in ended:
                    record = episode_record(info, i, bool(terminated[i]), self.env)
                    out["episodes"].append({"step": k, **record})
                self.core.reset_cars(ended)
                reset_obs = self.core.observation(ended)
                self.agent.noise.reset(ended)
                for key, value in reset_obs.items():
                    out[f"reset_{key}"][k, ended] = value
                    next_obs[key][ended] = value
            self.obs = next_obs
        out["version"] = np.int64(version)
        out["busy_s"] = np.float64(time.perf_counter() - t0)
        return out


class DDPGLearner(Learner):
    """The DDPG agent and its frame replay (``workers x cars`` columns) on the samplers' chunks.

    ``restored``: the replay holds rows of an earlier session (each sampler's first observation then starts a new
    row after them). ``on_vector_step(worker, episodes)`` is called after each vector step is stored, with the
    records of the episodes that ended in it; it counts the step and does what the single-process loop does after
    one (evaluations, checkpoints, progress), and returns False to end the session (the run's time is up)."""

    def __init__(
        self,
        agent: Any,
        buffer: Any,
        cars: int,
        rng: np.random.Generator,
        restored: bool,
        on_vector_step: Callable[[int, list[dict[str, Any]]], bool],
    ) -> None:
        self.agent, self.buffer, self.cars, self.rng = agent, buffer, cars, rng
        self.restored, self.on_vector_step = restored, on_vector_step
        self.steps = 0

    def columns(self, worker: int) -> np.ndarray:
        return np.arange(worker * self.cars, (worker + 1) * self.cars)

    def num_steps(self) -> int:
        return self.steps

    def weights(self) -> dict[str, np.ndarray]:
        return actor_weights(self.agent)

    def started(self, worker: int, ready: Any) -> None:
        cols = self.columns(worker)
        if self.restored:
            self.buffer.pos[cols] = (self.buffer.pos[cols] + 1) % self.buffer.rows
        self.buffer.start({key: ready[key] for key in OBS_KEYS if key in ready}, cars=cols)

    def take(self, chunk: Mapping[str, Any], worker: int, steps: int, elapsed_s: float) -> bool:
        cols = self.columns(worker)
        keys = [key for key in OBS_KEYS if f"next_{key}" in chunk]
        episodes = chunk["episodes"]
        for k in range(steps):
            done = chunk["done"][k]
            ended = np.flatnonzero(done)
            reset = {key: chunk[f"reset_{key}"][k, ended] for key in keys} if len(ended) else None
            self.buffer.add(
                chunk["keys"][k],
                chunk["reward"][k],
                chunk["terminated"][k],
                {key: chunk[f"next_{key}"][k] for key in keys},
                done,
                reset,
                cars=cols,
            )
            self.steps += self.cars
            ended_here = [{**e, "car": int(cols[e["car"]]), "worker": worker} for e in episodes if e["step"] == k]
            if not self.on_vector_step(worker, ended_here):
                return False
        return True

    def update(self) -> None:
        self.agent.update(self.buffer.sample(self.agent.hyper.batch_size, self.rng))
