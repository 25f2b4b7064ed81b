"""The built-in AI's transitions in SAC's replay buffer (--guide-steps)."""

import numpy as np
import pytest

from tests.phase2_rl.conftest import tiny_train_config


def test_guided_transitions_enter_the_buffer_as_the_learner_would_store_them(small_track):
    import torch
    from stable_baselines3 import SAC

    from vision_rl.envs.core import RacingConfig
    from vision_rl.envs.vector import make_sb3_vec_env
    from vision_rl.phase2_rl.guide import add_guided_transitions

    torch.set_num_threads(1)
    venv = make_sb3_vec_env(RacingConfig(track=small_track, n_groups=4, steer_action="rate_scaled", episode_s=5.0),
                            seed=0)  # fmt: skip
    model = SAC("MlpPolicy", venv, buffer_size=1_000, device="cpu")
    added = add_guided_transitions(model, venv, 250)
    buffer = model.replay_buffer
    rows = added // 4
    assert added == 252 and buffer.pos == rows  # whole vector steps, 4 cars each
    actions = buffer.actions[:rows]
    assert np.all(np.abs(actions) <= 1.0) and actions[..., 1].max() > 0.3  # scaled to the policy's [-1, 1]; throttle
    assert buffer.rewards[:rows].mean() > 0.5  # progress along the line
    # 5 s episodes: each car ended one every 50 steps as a truncation (a time limit), not a terminal state, and the
    # last guided step ends every car's episode (the learner starts its own).
    ended = buffer.dones[:rows].astype(bool)
    assert ended.sum() == 4 * (rows // 50) + 4 and ended[-1].all() and buffer.timeouts[:rows][ended].all()
    # An ended episode's next observation is its last one, not the next episode's first.
    row = int(np.flatnonzero(ended[:, 0])[0])
    assert not np.allclose(buffer.next_observations[row, 0], buffer.observations[row + 1, 0])


def test_train_policy_fills_the_buffer_first_and_refuses_a_negative_count(small_track, tmp_path):
    from vision_rl.phase2_rl.train import train_policy

    result = train_policy(tiny_train_config(small_track, tmp_path / "run", guide_steps=100, eval_every_steps=0))
    assert result["guided_transitions"] == 100 and result["num_timesteps"] >= 200
    with pytest.raises(ValueError, match="--guide-steps -1"):
        train_policy(tiny_train_config(small_track, tmp_path / "bad", guide_steps=-1))


def test_the_cloning_step_pulls_the_actor_towards_the_ais_actions(small_track):
    import torch

    from vision_rl.envs.core import RacingConfig
    from vision_rl.envs.vector import make_sb3_vec_env
    from vision_rl.phase2_rl.guide import add_guided_transitions, guided_sac_class

    torch.set_num_threads(1)
    venv = make_sb3_vec_env(RacingConfig(track=small_track, n_groups=4, steer_action="rate_scaled"), seed=0)
    model = guided_sac_class()("MlpPolicy", venv, buffer_size=1_000, learning_rate=1e-3, device="cpu", seed=0)
    from stable_baselines3.common.logger import configure

    model.set_logger(configure(None, [""]))
    added = add_guided_transitions(model, venv, 400)
    model.demo_rows = added // 4
    buffer = model.replay_buffer
    obs = torch.as_tensor(buffer.observations[: model.demo_rows].reshape(-1, buffer.obs_shape[0]))
    target = torch.as_tensor(buffer.actions[: model.demo_rows].reshape(-1, 2))

    def error() -> float:
        with torch.no_grad():
            return float(torch.mean((model.actor(obs, deterministic=True) - target) ** 2))

    before = error()
    model.train(gradient_steps=50, batch_size=64)  # SAC alone: the cloning weight is 0
    without = error()
    model.bc_weight = 1.0
    model.train(gradient_steps=50, batch_size=64)
    assert error() < 0.5 * min(before, without)


def test_pretraining_fits_the_actor_to_the_ais_actions_before_sac_updates(small_track, tmp_path):
    import torch

    from vision_rl.phase2_rl import train as train_module

    torch.set_num_threads(1)
    fits = {}
    build = train_module._Run.build

    def measured_build(run):
        model = build(run)
        buffer, rows = model.replay_buffer, model.demo_rows
        obs = torch.as_tensor(buffer.observations[:rows].reshape(-1, buffer.obs_shape[0]))
        target = torch.as_tensor(buffer.actions[:rows].reshape(-1, 2))
        with torch.no_grad():
            fits[run.cfg.guide_pretrain_steps] = float(torch.mean((model.actor(obs, deterministic=True) - target) ** 2))
        fits["variance"] = float(target.var(0).mean())
        return model

    train_module._Run.build = measured_build
    try:
        for steps in (0, 1_000):
            cfg = tiny_train_config(small_track, tmp_path / f"run{steps}", steps=60, learning_starts=50,
                                    guide_steps=400, guide_bc_weight=1e-9, guide_pretrain_steps=steps,
                                    eval_every_steps=0)  # fmt: skip
            train_module.train_policy(cfg)
    finally:
        train_module._Run.build = build
    assert fits[1_000] < 0.1 * fits["variance"] < fits[0]
