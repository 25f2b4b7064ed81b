"""The built-in AI's transitions in SAC's replay buffer (--guide-steps)."""

import numpy as np
import pytest

from tests.helpers.policies import tiny_train_config


def test_guided_transitions_enter_the_buffer_as_the_learner_would_store_them(small_track):
    import torch
    from stable_baselines3 import SAC

    from vision_rl.envs.core import RacingConfig
    from vision_rl.envs.vector import make_sb3_vec_env
    from vision_rl.phase2_rl.guide import add_guided_transitions

    torch.set_num_threads(1)
    venv = make_sb3_vec_env(
        RacingConfig(track=small_track, n_groups=4, steer_action="rate_scaled", episode_s=5.0), seed=0
    )
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
            cfg = tiny_train_config(
                small_track,
                tmp_path / f"run{steps}",
                steps=60,
                learning_starts=50,
                guide_steps=400,
                guide_bc_weight=1e-9,
                guide_pretrain_steps=steps,
                eval_every_steps=0,
            )
            train_module.train_policy(cfg)
    finally:
        train_module._Run.build = build
    assert fits[1_000] < 0.1 * fits["variance"] < fits[0]


def test_the_ais_labels_drive_the_hairpin_clean_where_the_policies_hit_the_wall():
    """Held for each 0.1 s step, the labels (what the AI at skill 1.0 would command now) brake for the expressway
    hairpin that the trained policies enter flat out (docs/results/state-expressway-hatchback-clean) and get round
    it without touching the wall; the AI's own skill-1.0 lap there is clean too."""
    from vision_rl.envs.core import RacingConfig, RacingCore

    cfg = RacingConfig(track="expressway", n_groups=1, steer_action="rate_scaled", start_skill=1.0, normalize=False)
    core = RacingCore(cfg, seed=0)
    core.label_with_ai(1.0)
    core.reset_groups(np.array([0]))
    core.fleet.place(core.ego_ids, np.array([600.0]))
    core.steer_command_rad[:] = core.world.state.vehicle.steer_rad[core.ego_ids]
    omegas, speeds = [], []
    for _ in range(100):  # 10 s: the braking zone, the 32 m hairpin at 0.87 km and its exit
        action = core.ai_actions()
        omegas.append(action[0, 1])
        core.step(action, autoreset=False)
        v = core.world.state.vehicle
        speeds.append(3.6 * float(np.hypot(v.vx_mps[0], v.vy_mps[0])))
        assert not core.world.state.wall_contact[0]
    # It brakes hard from 157 km/h (measured: to 65 km/h; the AI driving itself at 50 Hz, to 78) and is past the
    # hairpin's apex, accelerating.
    assert min(omegas) < -0.5 and max(speeds) > 150.0 and min(speeds) < 90.0
    assert core.world.state.s_m[0] > 900.0 and omegas[-1] > 0.5


def test_label_cloning_stores_a_label_per_transition_and_pulls_the_actor_to_them(small_track):
    import torch
    from stable_baselines3.common.logger import configure

    from vision_rl.envs.core import RacingConfig
    from vision_rl.envs.vector import make_sb3_vec_env
    from vision_rl.phase2_rl.guide import guided_sac_class, start_labels

    torch.set_num_threads(1)
    venv = make_sb3_vec_env(
        RacingConfig(track=small_track, n_groups=4, steer_action="rate_scaled", episode_s=5.0), seed=0
    )
    model = guided_sac_class()(
        "MlpPolicy", venv, buffer_size=1_000, learning_starts=1_000, learning_rate=1e-3, device="cpu", seed=0
    )
    model.set_logger(configure(None, [""]))
    start_labels(model, venv, weight=1.0)
    model.learn(total_timesteps=240)  # random actions only (learning starts later): 60 vector steps, 5 s episodes
    rows = model.replay_buffer.size()
    labels = model.replay_buffer.ai_labels[:rows]
    assert rows == 60 and np.isfinite(labels).all() and np.isnan(model.replay_buffer.ai_labels[rows:]).all()
    assert np.abs(labels).max() <= 1.0 and labels[..., 1].mean() > 0.3  # scaled; the AI mostly drives on
    # Each label is the AI's answer to the state the transition starts from, not the one it ends in: a fresh
    # environment put in the first stored state answers with the first stored label.
    fresh = make_sb3_vec_env(
        RacingConfig(track=small_track, n_groups=4, steer_action="rate_scaled", episode_s=5.0), seed=0
    )
    fresh.reset()
    fresh.core.label_with_ai(1.0)
    np.testing.assert_allclose(model.policy.scale_action(fresh.core.ai_actions()), labels[0], rtol=1e-5, atol=1e-6)
    obs = torch.as_tensor(model.replay_buffer.observations[:rows].reshape(-1, model.replay_buffer.obs_shape[0]))
    target = torch.as_tensor(labels.reshape(-1, 2))

    def error() -> float:
        with torch.no_grad():
            return float(torch.mean((model.actor(obs, deterministic=True) - target) ** 2))

    before = error()
    model.clone(gradient_steps=100, batch_size=64, labels=True)
    assert error() < 0.5 * before


def test_a_steering_weight_of_zero_clones_the_pedal_alone(small_track):
    import torch
    from stable_baselines3.common.logger import configure

    from vision_rl.envs.core import RacingConfig
    from vision_rl.envs.vector import make_sb3_vec_env
    from vision_rl.phase2_rl.guide import guided_sac_class, start_labels

    torch.set_num_threads(1)

    def cloned(steer_weight: float, steer_labels: float | None) -> list[torch.Tensor]:
        """The actor's weights after cloning the labels of 20 random steps (their steering column replaced by
        ``steer_labels`` when given)."""
        venv = make_sb3_vec_env(RacingConfig(track=small_track, n_groups=2, steer_action="rate_scaled"), seed=0)
        model = guided_sac_class()("MlpPolicy", venv, buffer_size=100, learning_starts=1_000, device="cpu", seed=0)
        model.set_logger(configure(None, [""]))
        start_labels(model, venv, weight=1.0, steer_weight=steer_weight)
        model.learn(total_timesteps=40)
        if steer_labels is not None:
            model.replay_buffer.ai_labels[:20, :, 0] = steer_labels
        torch.manual_seed(1)  # the same batches for each model
        model.clone(gradient_steps=20, batch_size=16, labels=True)
        return [p.detach().clone() for p in model.actor.parameters()]

    def same(a: list[torch.Tensor], b: list[torch.Tensor]) -> bool:
        return all(torch.equal(x, y) for x, y in zip(a, b, strict=True))

    # The steering labels do not move an actor that clones the pedal alone; with their usual weight they do.
    assert same(cloned(0.0, -0.9), cloned(0.0, 0.9))
    assert not same(cloned(1.0, -0.9), cloned(1.0, 0.9))
    assert not same(cloned(0.0, None), cloned(1.0, None))


def test_the_labels_are_saved_and_restored_with_the_buffer(small_track, tmp_path):
    from stable_baselines3.common.buffers import ReplayBuffer

    from vision_rl.envs.core import RacingConfig
    from vision_rl.envs.vector import make_sb3_vec_env
    from vision_rl.training.persist import load_buffer, save_buffer

    venv = make_sb3_vec_env(RacingConfig(track=small_track, n_groups=2), seed=0)

    def fresh(labelled: bool) -> ReplayBuffer:
        buffer = ReplayBuffer(40, venv.observation_space, venv.action_space, n_envs=2)
        if labelled:
            buffer.ai_labels = np.full((buffer.buffer_size, 2, 2), np.nan, dtype=np.float32)
        return buffer

    saved = fresh(True)
    rng = np.random.default_rng(0)
    for _ in range(7):
        saved.ai_labels[saved.pos] = rng.uniform(-1, 1, (2, 2))
        obs = rng.normal(size=(2, 38)).astype(np.float32)
        saved.add(obs, obs, rng.uniform(-1, 1, (2, 2)), np.ones(2), np.zeros(2), [{}, {}])
    save_buffer(saved, tmp_path / "labelled.npz", {"run": 1})
    save_buffer(fresh(False), tmp_path / "plain.npz", {"run": 1})
    restored = fresh(True)
    assert load_buffer(restored, tmp_path / "labelled.npz", {"run": 1}) == 7
    np.testing.assert_array_equal(restored.ai_labels, saved.ai_labels)
    unlabelled = fresh(True)  # a run that starts labelling on a buffer saved without labels: none for the old rows
    load_buffer(unlabelled, tmp_path / "plain.npz", {"run": 1})
    assert np.isnan(unlabelled.ai_labels).all()


def test_label_cloning_trains_saves_its_labels_and_resumes(small_track, tmp_path):
    from vision_rl.phase2_rl.train import train_policy
    from vision_rl.training.artifact import BUFFER_NAME

    result = train_policy(tiny_train_config(small_track, tmp_path / "run", guide_label_weight=10.0, eval_every_steps=0))
    assert result["num_timesteps"] >= 200
    with np.load(tmp_path / "run" / BUFFER_NAME) as saved:  # every transition labelled, and saved with them
        assert np.isfinite(saved["ai_labels"]).all() and len(saved["ai_labels"]) == 100
    resumed = train_policy(tiny_train_config(small_track, tmp_path / "run", steps=260, resume=True, eval_every_steps=0))
    assert resumed["buffer_restored"] == 100 and resumed["num_timesteps"] >= 260


def test_the_labels_weight_fades_to_zero_before_the_last_step(small_track):
    from stable_baselines3.common.logger import configure

    from vision_rl.envs.core import RacingConfig
    from vision_rl.envs.vector import make_sb3_vec_env
    from vision_rl.phase2_rl.guide import guided_sac_class, start_labels

    venv = make_sb3_vec_env(RacingConfig(track=small_track, n_groups=2, steer_action="rate_scaled"), seed=0)
    model = guided_sac_class()("MlpPolicy", venv, buffer_size=200, learning_starts=1_000, device="cpu", seed=0)
    model.set_logger(configure(None, [""]))
    start_labels(model, venv, weight=30.0, fade_steps=100, end_steps=300)
    model.learn(total_timesteps=40)  # labelled rows to clone from
    weights = []
    model.clone = lambda steps, batch, weight=1.0, labels=False: weights.append((weight, labels))
    for step in (0, 200, 250, 290, 300, 400):
        model.num_timesteps = step
        model.train(gradient_steps=1, batch_size=8)
    # Full weight until 100 steps before the end, then linear: 15 at half way, 3 at 10 steps left, no step after.
    assert [w for w, labels in weights if labels] == pytest.approx([30.0, 30.0, 15.0, 3.0])
    start_labels(model, venv, weight=30.0)  # no fade: the weight stays
    model.num_timesteps = 10**9
    assert model.label_weight_now() == 30.0


def test_shaping_the_labels_without_labels_is_refused(small_track, tmp_path):
    from vision_rl.phase2_rl.train import train_policy

    for shaping in ({"guide_label_fade_steps": 100}, {"guide_label_steer_weight": 0.0}):
        option = "--" + next(iter(shaping)).replace("_", "-")
        with pytest.raises(ValueError, match=f"^{option} shapes the labels' cloning: give --guide-label-weight too$"):
            train_policy(tiny_train_config(small_track, tmp_path / "run", **shaping))
    with pytest.raises(ValueError, match="--guide-label-fade-steps -1 is out of range"):
        train_policy(
            tiny_train_config(small_track, tmp_path / "run", guide_label_weight=1.0, guide_label_fade_steps=-1)
        )
