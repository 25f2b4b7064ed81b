"""``bench scaling``'s sampling row: the learner fed by sampler actors against the learner alone."""

from __future__ import annotations

import math
import os
import time
from typing import Any

import numpy as np

from vision_rl.training.distributed import (
    DistributedError,
    Pacing,
    SamplerSetup,
    SamplingLearner,
    SB3Learner,
    check_workers,
    connect,
)

#: Seconds of one slice of :func:`bench_sampling` (standalone and with samplers alternate).
BENCH_SLICE_S = 5.0
#: The learner of :func:`bench_sampling`: train-policy's ``cpu`` preset (a test checks that they agree).
BENCH_SAC: dict[str, Any] = {
    "hidden_units": (256, 256),
    "batch_size": 256,
    "learning_rate": 1e-3,
    "gamma": 0.99,
    "tau": 0.005,
    "gradient_steps": 1,
    "torch_threads": 1,
}


def bench_sampling(
    workers: int,
    seconds: float,
    seed: int = 0,
    *,
    cars: int = 20,
    track: str = "expressway",
    address: str = "",
    max_staleness: int = 1,
    version_every_updates: int = 20,
    prefill_transitions: int = 10_000,
) -> dict[str, Any]:
    """The learner with ``workers`` sampler actors against the learner alone, state observation, ``cars`` cars,
    train-policy's cpu preset (:data:`BENCH_SAC`).

    The learner's standalone rate (SAC updates on a buffer of random transitions, no sampling) and its rate when
    it trains on transitions from the samplers at the preset's ratio (one update per vector step), with the pacing
    of ``train-policy --workers``, are timed for ``seconds`` each, in alternating slices of about
    :data:`BENCH_SLICE_S`, so that a change of the machine's load falls on both alike. ``prefill_transitions``
    random transitions (the cpu preset's start steps) fill the replay buffer first, untimed."""
    import torch

    check_workers(workers, max_staleness, version_every_updates)
    if not seconds > 0:
        raise DistributedError(f"bench seconds must be > 0, got {seconds}")
    torch.set_num_threads(BENCH_SAC["torch_threads"])
    model, setup = _prefilled_learner(track, cars, seed, seconds, prefill_transitions)
    pacing = Pacing(
        workers=workers,
        n_cars=cars,
        gradient_steps=BENCH_SAC["gradient_steps"],
        learning_starts=0,
        start_timesteps=int(model.num_timesteps),
        total_timesteps=None,
        version_every_updates=version_every_updates,
        max_staleness=max_staleness,
    )
    standalone, standalone_s, stats = _alternate(model, setup, pacing, connect(address, workers), seconds)
    duration = max(stats["duration_s"], 1e-9)
    rate, standalone_rate = stats["updates"] / duration, standalone / standalone_s
    return {
        "workers": workers,
        "seconds": seconds,
        "cars": cars,
        "observation": "state",
        "batch_size": BENCH_SAC["batch_size"],
        "standalone_updates_per_s": round(standalone_rate, 2),
        "learner_updates_per_s": round(rate, 2),
        "learner_share_of_standalone": round(rate / standalone_rate, 4),
        "sampled_transitions_per_s": round(stats["transitions"] / duration, 1),
        "sampler_transitions_per_busy_s": round(stats["transitions"] / max(stats["sampler_busy_s"], 1e-9), 1),
        "learner_wait_s": stats["learner_wait_s"],
        "max_staleness": max_staleness,
        "max_staleness_seen": stats["max_staleness_seen"],
        "version_every_updates": version_every_updates,
        "load_avg_1min": round(os.getloadavg()[0], 2),
        "cpu_count": os.cpu_count(),
    }


def _prefilled_learner(track: str, cars: int, seed: int, seconds: float, prefill: int) -> tuple[Any, SamplerSetup]:
    """An SB3 SAC of :data:`BENCH_SAC` whose buffer holds ``prefill`` random transitions of a local world, and the
    samplers' set-up of the same world."""
    from stable_baselines3 import SAC
    from stable_baselines3.common.logger import Logger

    from vision_rl.envs.core import RacingConfig
    from vision_rl.envs.vector import make_sb3_vec_env
    from vision_rl.training.artifact import policy_fingerprint, racing_config_to_dict

    racing = RacingConfig(track=track, n_groups=cars)
    venv = make_sb3_vec_env(racing, seed=seed)
    model = SAC(
        "MlpPolicy",
        venv,
        learning_rate=BENCH_SAC["learning_rate"],
        buffer_size=4 * prefill + int(2 * seconds * 5_000),
        learning_starts=0,
        batch_size=BENCH_SAC["batch_size"],
        tau=BENCH_SAC["tau"],
        gamma=BENCH_SAC["gamma"],
        policy_kwargs={"net_arch": list(BENCH_SAC["hidden_units"])},
        seed=seed,
        device="cpu",
        verbose=0,
    )
    model.set_logger(Logger(folder=None, output_formats=[]))  # configure(None) leaves an empty SB3-<date> folder
    rng = np.random.default_rng(seed)
    low, high = venv.action_space.low, venv.action_space.high
    obs = venv.reset()
    for _ in range(math.ceil(prefill / cars)):
        action = rng.uniform(low, high, (cars, 2)).astype(np.float32)
        new_obs, rewards, dones, infos = venv.step(action)
        model.replay_buffer.add(obs, new_obs, model.policy.scale_action(action), rewards, dones, infos)
        obs = new_obs
        model.num_timesteps += cars
    setup = SamplerSetup(
        racing_config=racing_config_to_dict(racing),
        observation="state",
        obs_normalizer=venv.core.observer.normalizer.to_dict(),
        fingerprint=policy_fingerprint(racing, "state", venv.observation_space.shape[0], None),
        hidden_units=tuple(BENCH_SAC["hidden_units"]),
        seed=seed,
    )
    venv.close()
    return model, setup


def _alternate(model: Any, setup: SamplerSetup, pacing: Pacing, cluster: Any, seconds: float) -> tuple:
    """(standalone updates, their seconds, the sampling learner's stats) over alternating slices; during a
    standalone slice the samplers finish their chunk and then idle."""
    slices = max(1, round(seconds / BENCH_SLICE_S))
    standalone, standalone_s = 0, 0.0
    try:
        learner = SamplingLearner(SB3Learner(model), setup, pacing, cluster)
        try:
            for _ in range(slices):
                t0 = time.perf_counter()
                while time.perf_counter() - t0 < seconds / slices:
                    model.train(gradient_steps=1, batch_size=BENCH_SAC["batch_size"])
                    standalone += 1
                standalone_s += time.perf_counter() - t0
                learner.run(deadline_s=seconds / slices)
        finally:
            learner.close()
    finally:
        cluster.close()
    return standalone, standalone_s, learner.stats()
