"""GAIL's reference check (issue 65): the project's GAIL parts (the discriminator, its updates and the replay buffer
whose rewards are its log-odds, vision_rl.overtaking.gail) with an SB3 SAC learner of the paper's 2 x 256 network
imitate an analytic expert on Pendulum-v1, where the expected result is known: close to the expert's return
(-130 to -180 over 200 steps, by start states; a random policy about -1,000 to -1,200).

    .venv/bin/python scripts/gail_pendulum.py --steps 12000 --seed 0 \
        --out docs/results/overtaking-gail-reference/pendulum-s0.json
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback

from vision_rl.files import write_json
from vision_rl.overtaking.gail import GAILReplayBuffer, GAILUpdater

#: Pendulum-v1's dynamics: angular acceleration 15 sin(theta) + 3 u, so E = w^2 / 2 + 15 (cos theta - 1) is 0 upright
#: at rest and dE/dt = 3 u w: pump energy with u along w, then hold the top with a PD law.
GRAVITY_TERM = 15.0


def expert(obs: np.ndarray) -> np.ndarray:
    """Energy-pumping swing-up, PD near the top; torque in [-2, 2]."""
    cos_t, sin_t, w = obs
    if cos_t > 0.85:
        u = -10.0 * np.arctan2(sin_t, cos_t) - 2.0 * w
    else:
        energy = 0.5 * w**2 + GRAVITY_TERM * (cos_t - 1.0)
        u = -2.0 * energy * np.sign(w) if abs(w) > 0.05 else 2.0
    return np.array([np.clip(u, -2.0, 2.0)], dtype=np.float32)


def rollout(policy, episodes: int, first_seed: int) -> tuple[float, np.ndarray, np.ndarray]:
    """Mean return over ``episodes`` of 200 steps, and the (observation, action) pairs."""
    env = gym.make("Pendulum-v1")
    returns, observations, actions = [], [], []
    for episode in range(episodes):
        obs, _ = env.reset(seed=first_seed + episode)
        total = 0.0
        for _ in range(200):
            action = policy(obs)
            observations.append(obs)
            actions.append(action)
            obs, reward, *_ = env.step(action)
            total += float(reward)
        returns.append(total)
    return float(np.mean(returns)), np.array(observations, np.float32), np.array(actions, np.float32)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=12_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    torch.set_num_threads(1)
    expert_return, expert_obs, expert_act = rollout(expert, 10, 1000)
    env = gym.make("Pendulum-v1")
    model = SAC(
        "MlpPolicy",
        env,
        replay_buffer_class=GAILReplayBuffer,
        learning_starts=1000,
        seed=args.seed,
        policy_kwargs={"net_arch": [256, 256]},
    )
    # As train-baseline's defaults: 10 discriminator steps of 256 pairs each every 1,000 transitions.
    updater = GAILUpdater(expert_obs, expert_act / 2.0, batch=256, updates=10, learning_rate=3e-4, seed=args.seed)
    model.replay_buffer.discriminator = updater.disc

    class Discriminate(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps % 1000 == 0:
                updater.update(self.model.replay_buffer)
            return True

    t0, curve = time.perf_counter(), []
    while model.num_timesteps < args.steps:
        model.learn(2000, callback=Discriminate(), reset_num_timesteps=False)
        mean_return, _, _ = rollout(lambda o: model.predict(o, deterministic=True)[0], 5, 2000)
        curve.append({"steps": model.num_timesteps, "return": round(mean_return, 1), "discriminator": updater.last})
        print(curve[-1], f"{time.perf_counter() - t0:.0f} s", flush=True)
    random_return, _, _ = rollout(lambda o: env.action_space.sample(), 5, 2000)
    write_json(
        args.out,
        {
            "check": "GAIL (vision_rl.overtaking.gail + SB3 SAC 2 x 256) on Pendulum-v1 from an analytic expert",
            "seed": args.seed,
            "steps": args.steps,
            "expert_return": round(expert_return, 1),
            "random_return": round(random_return, 1),
            "final_return": curve[-1]["return"],
            "curve": curve,
            "wall_s": round(time.perf_counter() - t0, 1),
        },
    )


if __name__ == "__main__":
    main()
