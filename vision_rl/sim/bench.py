"""`vision-rl bench sim`: throughput of the physics, of a full control step with sensors, and of the lidar."""

from __future__ import annotations

import time

import numpy as np

from vision_rl.sim import sensors, vehicle
from vision_rl.sim.track_library import load_track
from vision_rl.sim.world import World, WorldConfig

#: What each figure should reach on a 2-core CPU, printed beside the figures.
TARGETS = {
    "physics_car_substeps_per_s": ">= 2,000,000 (1,000 cars)",
    "control_car_steps_per_s": ">= 20,000 (20 cars, 10 Hz step with 27 targets and 11 features)",
    "lidar_ms_20_cars": "<= 1 ms (72 beams each)",
}


def bench_control_step(track_spec: str, car: str, n_cars: int = 20, steps: int = 50, repeats: int = 7) -> float:
    """Median car-steps/s of one 10 Hz control step (physics substeps, contacts, 27 targets, 11 features)."""
    track = load_track(track_spec)
    world = World(track, car=car, n_cars=n_cars, config=WorldConfig(physics_dt_s=0.01, control_dt_s=0.1))
    caster = sensors.WallRayCaster(track)
    rng = np.random.default_rng(0)
    world.reset(s_m=np.linspace(0.0, track.length_m, n_cars, endpoint=False), speed_mps=20.0)
    steer = rng.uniform(-0.05, 0.05, (steps, n_cars))
    omega = rng.uniform(0.0, 0.5, (steps, n_cars))

    def one_step(k: int) -> None:
        world.step(steer[k], omega[k])
        st = world.state
        v = st.vehicle
        sensors.environment_targets(track, caster, v.x_m, v.y_m, v.yaw_rad, st.s_m, st.lateral_m)
        sensors.dedicated_features(v, st.wall_contact, st.prev_steer_cmd_rad)

    one_step(0)  # compile numba kernels outside the timing
    rates = []
    for _ in range(repeats):
        world.reset(s_m=np.linspace(0.0, track.length_m, n_cars, endpoint=False), speed_mps=20.0)
        t0 = time.perf_counter()
        for k in range(steps):
            one_step(k)
        rates.append(n_cars * steps / (time.perf_counter() - t0))
    return float(np.median(rates))


def bench_sim(track_spec: str = "expressway", car: str = "hatchback", repeats: int = 7) -> dict:
    """All `bench sim` figures (medians over ``repeats``) with their targets."""
    result: dict = {}
    result.update(vehicle.bench_physics(n_cars=1000))
    result["control_car_steps_per_s"] = bench_control_step(track_spec, car, repeats=repeats)
    result.update(sensors.bench_sensors(n_cars=20))
    result["targets"] = TARGETS
    return result
