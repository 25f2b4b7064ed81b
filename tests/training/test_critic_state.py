"""The asymmetric critic (``--critic-state``): the vector it reads, an actor blind to it, runs that drive as vision."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.helpers.policies import tiny_train_config
from tests.helpers.rendering import renderer_available
from vision_rl.envs import RacingConfig, make_sb3_vec_env
from vision_rl.envs import observations as obs_lib
from vision_rl.envs.observer import Observer
from vision_rl.phase1_repr import load_encoder
from vision_rl.phase2_rl.train import train_policy
from vision_rl.training.artifact import PolicySpec, load_policy, sac_policy
from vision_rl.training.critic_state import CRITIC_COLUMNS
from vision_rl.training.evaluate import evaluate_policy

_REASON = renderer_available()


def test_the_actor_never_reads_the_critics_columns_and_the_critic_does():
    torch.manual_seed(0)
    policy = sac_policy(75 + CRITIC_COLUMNS, [32, 32], critic_state=True)
    assert policy.actor.latent_pi[0].in_features == 75
    assert policy.critic.qf0[0].in_features == 75 + CRITIC_COLUMNS + 2  # the observation and the action
    obs = torch.randn(4, 75 + CRITIC_COLUMNS)
    other = obs.clone()
    other[:, 75:] = torch.randn(4, CRITIC_COLUMNS) * 10
    with torch.no_grad():
        assert torch.equal(policy.actor(obs, deterministic=True), policy.actor(other, deterministic=True))
        action = policy.actor(obs, deterministic=True)
        assert not torch.allclose(policy.critic(obs, action)[0], policy.critic(other, action)[0])


def test_a_state_observation_cannot_add_the_state_again():
    with pytest.raises(ValueError, match="critic_state appends the state observation to the vision vector"):
        make_sb3_vec_env(RacingConfig(observation="state", critic_state=True), seed=0)


@pytest.mark.skipif(bool(_REASON), reason=_REASON or "renderer available")
def test_the_vector_is_the_vision_vector_then_the_state_observation(small_track, tiny_encoders):
    cfg = RacingConfig(track=small_track, observation="vision", n_groups=2, image_hw_px=(64, 96), critic_state=True)
    core = make_sb3_vec_env(cfg, seed=0).core
    encoder = load_encoder(tiny_encoders[0])
    both = Observer("vision", core.track, core.car, core.groups, None, encoder, cfg.image_hw_px, critic_state=True)
    vision = Observer("vision", core.track, core.car, core.groups, None, encoder, cfg.image_hw_px)
    state, ids = core.world.state, core.ego_ids
    raw = both.raw(state, ids)
    assert both.space.shape == (75 + CRITIC_COLUMNS,) and raw.shape == (2, 75 + CRITIC_COLUMNS)
    np.testing.assert_array_equal(raw[:, :75], vision.raw(state, ids))
    np.testing.assert_array_equal(raw[:, 75:], obs_lib.state_observation(core.track, both.caster, state, ids))
    with pytest.raises(ValueError, match="it needs an encoder"):
        Observer("vision", core.track, core.car, core.groups, critic_state=True)


@pytest.mark.skipif(bool(_REASON), reason=_REASON or "renderer available")
def test_a_run_with_the_state_critic_drives_from_the_vision_vector_alone(
    small_track, tiny_encoders, tmp_path, monkeypatch
):
    out = tmp_path / "asym"
    result = train_policy(
        tiny_train_config(
            small_track,
            out,
            encoder=str(tiny_encoders[0]),
            steps=120,
            learning_starts=40,
            stats_steps=3,
            eval_every_steps=60,
            critic_state=True,
        )
    )
    assert result["num_timesteps"] == 120
    spec = PolicySpec.read(out / "policy.json")
    assert spec.config.critic_state and spec.fingerprint["obs_dim"] == 75 + CRITIC_COLUMNS
    loaded = load_policy(out)
    assert loaded.obs_dim == 75 + CRITIC_COLUMNS
    driven = evaluate_policy(out, seeds=1, laps=1, time_limit_s=3.0, write=False)

    def no_state(*args, **kwargs):
        raise AssertionError("a driver computed the state observation")

    monkeypatch.setattr(obs_lib, "state_observation", no_state)
    again = evaluate_policy(out, seeds=1, laps=1, time_limit_s=3.0, write=False)
    assert again["seeds"][0]["distance_m"] == driven["seeds"][0]["distance_m"] > 0
