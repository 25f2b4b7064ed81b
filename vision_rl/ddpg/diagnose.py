"""A trained DDPG agent's critic and actor looked at where its episodes start (whether the critic has diverged,
whether the actor's keys have saturated) and at how it drives the protocol (docs/notes/ddpg.md).

A critic's Q of a state is a discounted sum of rewards ``r = V - alpha |d| - beta crashState`` (V: the forward speed,
m/s; d: the distance to the racing line, at most ``max_line_distance_m`` before the episode ends; crashState at most
4), so no Q lies farther from 0 than ``q_bound`` = (the fastest speed on the track at the physical limit + alpha
max_line_distance_m + 4 beta) over ``1 - gamma``; a mean Q beyond it, either side, is a critic that has diverged. A
key is saturated where its pre-activation lies beyond +-5: its sigmoid or tanh then passes under 1 % of the critic's
gradient, and the actor stops learning it.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import numpy as np
import torch

from vision_rl.ddpg.agent import DDPGAgent, DDPGDriver, load_agent, to_torch
from vision_rl.envs.pixel_racing import CRASH_ROLLING, PixelRacingCore

#: Beyond this pre-activation a key's sigmoid or tanh has under 1 % of its largest slope (4 e^-5 = 0.027 of 0.25 for
#: a sigmoid; 4 e^-10 of 1 for a tanh).
SATURATED_PREACTIVATION = 5.0
KEYS = ("accelerate", "left", "right", "brake")


def diagnose_agent(run: str | os.PathLike[str], starts: int = 64, seed: int = 0) -> dict[str, Any]:
    """A saved agent's critic and keys at ``starts`` episode starts of its own task (:func:`critic_and_keys`) and how
    it drives the protocol's starts (:func:`protocol_controls`)."""
    if starts < 1:
        raise ValueError(f"starts must be >= 1, got {starts}")
    agent = load_agent(run)
    return {
        "run": str(run),
        "variant": agent.hyper.variant,
        "n_updates": agent.counters.get("n_updates"),
        "starts": starts,
        **critic_and_keys(agent, starts, seed),
        "protocol_start": protocol_controls(agent),
    }


def critic_and_keys(agent: DDPGAgent, starts: int, seed: int = 0) -> dict[str, Any]:
    """The critic's mean and largest Q of the actor's own keys against ``q_bound`` (the module's docstring), and each
    key's pre-activation (mean, spread, share saturated), over ``starts`` episode starts of the agent's task (its start
    rule)."""
    core = PixelRacingCore(dataclasses.replace(agent.env, n_cars=starts), seed=seed)
    try:
        core.reset_cars(core.ids)
        obs = core.observation()
        env = agent.env
        largest_reward = (
            core.profile.max_speed_mps
            + env.line_distance_alpha * env.max_line_distance_m
            + env.crash_penalty_beta * CRASH_ROLLING
        )
        q_bound = largest_reward / (1.0 - agent.hyper.gamma)
    finally:
        core.close()
    agent.actor.eval()
    agent.critic.eval()
    with torch.no_grad():
        z = agent.actor.preactivation(to_torch(agent.actor_inputs(obs), agent.device))
        q = agent.critic(to_torch(obs, agent.device), agent.actor.head.keys(z)).cpu().numpy()
    z = z.cpu().numpy()
    return {
        "q_mean": float(q.mean()),
        "q_max": float(q.max()),
        "q_bound": float(q_bound),
        "diverged": bool(abs(q.mean()) > q_bound),
        "keys": {
            key: {
                "preactivation_mean": float(z[:, i].mean()),
                "preactivation_std": float(z[:, i].std()),
                "saturated_share": float(np.mean(np.abs(z[:, i]) > SATURATED_PREACTIVATION)),
            }
            for i, key in enumerate(KEYS)
        },
    }


def protocol_controls(agent: DDPGAgent, seeds: int = 3) -> dict[str, Any]:
    """How the deterministic actor drives the protocol's starts (``seeds`` at once, as ``evaluate-ddpg`` drives them:
    a pixel actor's lap depends on the batch it is acted in): per start, the laps it completed, and over all their
    steps the share with the wheels straight (under 0.01 rad) and at full throttle, the mean steering angle and the
    share in wall contact. A driver at full throttle with the wheels straight is the straight driver, whose laps the
    walls steer (`vision-rl drive --driver straight`)."""
    from vision_rl.evaluation.protocol import time_laps

    driver = DDPGDriver(agent)
    try:
        timing = time_laps(driver, agent.env.track, agent.env.car, range(seeds), 2, record=True)
    finally:
        driver.close()
    # Recorded steps past a start's end repeat its last pose: count each start's own steps only.
    own = timing.time_s[:, None] <= np.array([run.time_s for run in timing.runs])[None, :] + 1e-9
    steer_rad, omega = timing.steer_rad[own], timing.omega[own]
    return {
        "seeds": seeds,
        "laps": [len(run.laps) for run in timing.runs],
        "time_s": [run.time_s for run in timing.runs],
        "steer_abs_mean_rad": float(np.abs(steer_rad).mean()),
        "wheels_straight_share": float(np.mean(np.abs(steer_rad) < 0.01)),
        "full_throttle_share": float(np.mean(omega > 0.99)),
        "wall_contact_share": float(timing.wall_contact[own].mean()),
    }
