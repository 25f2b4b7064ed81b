"""The vision observation for SAC: frames embedded by the frozen encoder inside the vector env, so the replay buffer
holds 75-D vectors (64-D phi_rep + 11 dedicated features), not images (vision paper, section 4, "Reinforcement
Learning using Representation")."""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvWrapper

from vision_rl.envs.core import RacingCore
from vision_rl.envs.observations import ObsNormalizer
from vision_rl.phase2_rl.artifact import Observer
from vision_rl.sim.ai_driver import Disruptor

#: Seed of the statistics rollout: fixed so that one encoder on one track gives one normaliser.
STATS_SEED = 12345


class EmbeddingVecEnv(VecEnvWrapper):
    """Wraps a ``vision`` racing VecEnv (Dict obs of frames and features): every step embeds all egos' frames in one
    encoder batch, together with the terminal frames of finished episodes, and returns (n, obs_dim) float32."""

    def __init__(self, venv: VecEnv, observer: Observer) -> None:
        if observer.kind != "vision":
            raise ValueError("EmbeddingVecEnv needs a vision observer")
        space = spaces.Box(-np.inf, np.inf, (observer.dim,), dtype=np.float32)
        super().__init__(venv, observation_space=space)
        self.observer = observer

    def reset(self) -> np.ndarray:
        obs = self.venv.reset()
        return self.observer.vision_vector(obs["image"], obs["features"])

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        ended = [i for i, info in enumerate(infos) if "terminal_observation" in info]
        images, features = obs["image"], obs["features"]
        if ended:
            last = [infos[i]["terminal_observation"] for i in ended]
            images = np.concatenate([images, np.stack([o["image"] for o in last])])
            features = np.concatenate([features, np.stack([o["features"] for o in last])])
        vectors = self.observer.vision_vector(images, features)
        n = self.num_envs
        for k, i in enumerate(ended):
            infos[i] = {**infos[i], "terminal_observation": vectors[n + k]}
        return vectors[:n], rewards, dones, infos


def sample_vision_statistics(core: RacingCore, encoder, steps: int, seed: int = STATS_SEED) -> ObsNormalizer:
    """z-score statistics of the raw vision vector (embedding + dedicated features) over ``steps`` control steps of
    the core's egos driven by the disrupted built-in AI from random starts (the states a capture run sees).

    The encoder's training data is not at hand, so the statistics come from this one short rollout; they are stored
    with the policy and never recomputed for it. The core's generator is restored afterwards."""
    if core.config.observation != "vision":
        raise ValueError("the core must render vision observations")
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    raw = Observer("vision", None, encoder)
    saved_rng = core.rng
    core.rng = np.random.default_rng(seed)
    disruptor = Disruptor(core.world.n_cars, seed=seed)
    core.reset_groups(np.arange(core.config.n_groups))
    samples = []
    for _ in range(steps):
        core.advance(disruptor=disruptor)
        samples.append(raw(core))
    core.rng = saved_rng
    return ObsNormalizer.from_samples("vision", np.concatenate(samples).astype(np.float64))
