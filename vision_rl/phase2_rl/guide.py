"""Demonstrations of the built-in AI in an off-policy learner's replay buffer (not in the papers).

SAC on the papers' reward learned, on expressway, never to brake: every state and vision policy of 400k steps kept
the throttle on into the 32 m hairpin at 150-159 km/h and let the outer wall take the speed, whatever the wall
penalty's weight or form (docs/results/state-expressway-hatchback-speed-scaled, "The wall is a brake"). Braking
early enough is a long run of actions that exploration around a full-throttle policy does not find; the AI's laps
show it. Its transitions go into the buffer before the first update, rewarded by the environment's own reward, and
the learner trains on them beside its own as long as the buffer keeps them.
"""

from __future__ import annotations

import numpy as np


def _copy(obs):
    return {k: v.copy() for k, v in obs.items()} if isinstance(obs, dict) else obs.copy()


def _put(obs, g: int, value) -> None:
    if isinstance(obs, dict):
        for k in obs:
            obs[k][g] = value[k]
    else:
        obs[g] = value


def add_guided_transitions(model, venv, n_transitions: int) -> int:
    """Drive every ego of ``venv`` (a :class:`vision_rl.envs.sb3.RacingSB3VecEnv`) by the built-in AI and add at
    least ``n_transitions`` of its transitions to ``model``'s replay buffer, as Stable-Baselines3's own collection
    would add them (the true last observation of an ended episode, time limits marked as truncations). Returns how
    many were added; ``venv`` is left mid-episode, so a learner resets it before collecting its own."""
    core = venv.core
    obs = venv.reset()
    added = 0
    while added < n_transitions:
        next_obs, reward, terminated, truncated, infos, actions = core.guided_step(autoreset=True)
        last_obs = _copy(next_obs)
        buffer_infos = []
        for g, info in enumerate(infos):
            if "final_info" in info:
                _put(last_obs, g, info["final_observation"])
            buffer_infos.append({"TimeLimit.truncated": bool(truncated[g] and not terminated[g])})
        scaled = model.policy.scale_action(actions.astype(np.float32))
        model.replay_buffer.add(obs, last_obs, scaled, reward, terminated | truncated, buffer_infos)
        obs = next_obs
        added += len(reward)
    return added
