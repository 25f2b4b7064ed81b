"""An outside driver of known behaviour: it follows the centre line (or any lateral target) at a held speed."""

from __future__ import annotations

import numpy as np

from vision_rl.evaluation.protocol import STEP_S

#: The follower's speed unless told another, m/s.
CRUISE_MPS = 15.0


class CentreLineFollower:
    """At 10 Hz: curvature feedforward plus lateral and heading feedback towards ``target_lateral(s)``, speed held."""

    control_dt_s = STEP_S

    def __init__(self, target_lateral=lambda s: 0.0 * s, speed_mps: float = CRUISE_MPS) -> None:
        self.target_lateral = target_lateral
        self.speed_mps = speed_mps
        self.seen: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def reset(self, world, car_ids):
        self.world = world

    def act(self, state):
        track = self.world.track
        v = state.vehicle
        heading_error = np.mod(v.yaw_rad - track.heading_at(state.s_m) + np.pi, 2 * np.pi) - np.pi
        self.seen.append((state.s_m.copy(), state.lateral_m.copy(), heading_error))
        error = state.lateral_m - self.target_lateral(state.s_m)
        steer = self.world.car.wheelbase_m * track.curvature_at(state.s_m) - 0.05 * error - 0.5 * heading_error
        omega = np.clip(2.0 * (self.speed_mps - np.hypot(v.vx_mps, v.vy_mps)), -0.3, 1.0)
        return np.stack([steer, omega], axis=1)
