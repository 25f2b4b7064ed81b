"""An asymmetric SAC actor-critic for the vision observation: the critic also reads the 38-D state observation.

With ``RacingConfig.critic_state`` the training environment's vector is ``[embedding, 11 dedicated features,
38-D state]``. The critic reads all of it, so its value of a state does not carry the encoder's error (it errs two
to three times as much on a policy's own laps as on the AI's, and most at the walls:
docs/results/vision-expressway-hatchback); the actor, the only part that drives, reads its first ``actor_inputs``
columns alone. The DDPG paper's critic reads state its pixel actor cannot see (pcars2-ddpg-asymmetric-actor-critic,
section III; Pinto et al., "Asymmetric Actor Critic for Image-Based Robot Learning", RSS 2018).

A policy trained so drives from what a vision policy sees: the protocol's drivers observe the vision vector alone
and pad the critic's columns with zeros, which the actor's first layer never reads (:func:`actor_only`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.sac.policies import Actor, SACPolicy

from vision_rl.envs.observations import STATE_OBS_NAMES, ObsNormalizer

#: Columns the critic reads beyond the actor's: the ``state`` observation.
CRITIC_COLUMNS = len(STATE_OBS_NAMES)


class FirstColumns(BaseFeaturesExtractor):
    """The first ``columns`` entries of a flat observation."""

    def __init__(self, observation_space: spaces.Box, columns: int) -> None:
        if not 0 < columns <= observation_space.shape[0]:
            raise ValueError(f"columns must be in [1, {observation_space.shape[0]}], got {columns}")
        super().__init__(observation_space, columns)

    def forward(self, observations):
        return observations[:, : self.features_dim]


class CriticStateSACPolicy(SACPolicy):
    """SB3's SAC MLP policy whose actor reads the first ``actor_inputs`` columns and whose critics read them all."""

    def __init__(self, *args, actor_inputs: int, **kwargs) -> None:
        self.actor_inputs = int(actor_inputs)
        super().__init__(*args, **kwargs)

    def make_actor(self, features_extractor: BaseFeaturesExtractor | None = None) -> Actor:
        return super().make_actor(FirstColumns(self.observation_space, self.actor_inputs))

    def _get_constructor_parameters(self) -> dict:
        return {**super()._get_constructor_parameters(), "actor_inputs": self.actor_inputs}


def sac_policy_class(obs_dim: int, critic_state: bool) -> tuple[type[SACPolicy], dict]:
    """SB3's SAC policy class and its extra keywords for an ``obs_dim``-input network."""
    if not critic_state:
        return SACPolicy, {}
    return CriticStateSACPolicy, {"actor_inputs": obs_dim - CRITIC_COLUMNS}


def actor_only(
    normalizer: ObsNormalizer, predict: Callable[[np.ndarray], np.ndarray]
) -> tuple[ObsNormalizer, Callable[[np.ndarray], np.ndarray]]:
    """The normaliser of the actor's columns, and ``predict`` fed the actor's columns with zeros for the critic's."""
    columns = len(normalizer.offset) - CRITIC_COLUMNS

    def padded(obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32)
        return predict(np.hstack([obs, np.zeros((len(obs), CRITIC_COLUMNS), np.float32)]))

    return ObsNormalizer(normalizer.offset[:columns], normalizer.scale[:columns]), padded
