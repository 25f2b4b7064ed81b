"""`vision-rl bench env`: environment throughput through the batched (SB3) vector environments."""

from __future__ import annotations

import time

import numpy as np

from vision_rl.envs.core import RacingConfig, RacingCore

TARGETS = {
    "timetrial_state_car_steps_per_s": ">= 15,000 (20 cars, SB3 VecEnv)",
    "overtaking_ego_steps_per_s": ">= 3,000 (20 groups of 6 cars)",
}


def _steps_per_s(step, n_egos: int, steps: int, repeats: int) -> float:
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, n_egos, 2)) * np.array([0.1, 1.0])
    step(actions[0])  # warm-up: numba kernels, normalisation statistics
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for a in actions:
            step(a)
        rates.append(n_egos * steps / (time.perf_counter() - t0))
    return float(np.median(rates))


def bench_env(track: str = "expressway", car: str = "hatchback", steps: int = 100, repeats: int = 5) -> dict:
    """Median ego-steps/s of a time-trial SB3 VecEnv (20 cars, state obs) and an overtaking core (20 x 6 cars)."""
    from vision_rl.envs.sb3 import RacingSB3VecEnv

    venv = RacingSB3VecEnv(RacingConfig(track=track, car=car, n_groups=20), seed=0)
    venv.reset()

    def sb3_step(actions):
        venv.step_async(actions)
        venv.step_wait()

    overtaking = RacingCore(
        RacingConfig(track=track, car=car, n_groups=20, scenario="setting_a", observation="overtaking"), seed=0
    )
    overtaking.reset_groups(np.arange(20))
    return {
        "timetrial_state_car_steps_per_s": _steps_per_s(sb3_step, 20, steps, repeats),
        "overtaking_ego_steps_per_s": _steps_per_s(lambda a: overtaking.step(a, autoreset=True), 20, steps, repeats),
        "targets": TARGETS,
    }
