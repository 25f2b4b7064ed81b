"""train-baseline: BC recovers a known policy, the GAIL discriminator separates expert from random pairs and its
log-odds reward pulls a learner towards the expert, and the four algorithms write run folders that load (online
ones continue where they stopped)."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces
from stable_baselines3 import SAC, TD3

from tests.helpers.overtaking import tiny_baseline_config
from vision_rl.overtaking.baselines import load_baseline, train_baseline
from vision_rl.overtaking.bc import fit_bc, smoothed_labels
from vision_rl.overtaking.demos import Demos
from vision_rl.overtaking.gail import GAILReplayBuffer, GAILUpdater
from vision_rl.training.artifact import load_policy, sac_policy


def test_bc_recovers_a_known_linear_policy():
    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(3000, 96)).astype(np.float32)
    weights = rng.normal(scale=0.05, size=(96, 2))  # actions in [-1, 1] units, mostly inside (-0.6, 0.6)
    actions = np.clip(obs @ weights, -0.95, 0.95).astype(np.float32)
    policy = sac_policy(96, [256, 256])
    idx = rng.permutation(3000)
    fit = fit_bc(
        policy,
        obs,
        actions,
        idx[:2500],
        idx[2500:],
        learning_rate=1e-3,
        batch_size=128,
        max_updates=100_000,
        max_epochs=200,
        patience=10,
        min_improvement=0.01,
        seed=0,
    )
    assert fit["stopped"].startswith("converged")
    fresh = rng.normal(size=(500, 96)).astype(np.float32)
    target = np.clip(fresh @ weights, -0.95, 0.95)
    with torch.no_grad():
        predicted = torch.tanh(policy.actor.get_action_dist_params(torch.as_tensor(fresh))[0]).numpy()
    # Against the actions' own variance (about 0.06): the fit explains well over 90 % of it on unseen observations.
    assert np.mean((predicted - target) ** 2) < 0.05 * np.var(target)


def test_the_steering_label_is_smoothed_within_each_episode_only():
    # The held AI's alternation (+a, -a, ...) averages out over 2 steps; the throttle and an episode's first step
    # stay as recorded, and no episode borrows its neighbour's labels.
    steer = np.array([0.3, -0.1, 0.3, -0.1, 0.3, 0.2, 0.2, 0.2], dtype=np.float32)
    labels = np.stack([steer, np.linspace(0, 1, 8, dtype=np.float32)], axis=1)
    starts = np.zeros(8, dtype=bool)
    starts[[0, 5]] = True
    demos = Demos(np.zeros((8, 96), np.float32), labels, labels, np.zeros(8, np.float32), starts, {}, Path("x"), "")
    smoothed = smoothed_labels(demos, 2)
    np.testing.assert_allclose(smoothed[:, 0], [0.3, 0.1, 0.1, 0.1, 0.1, 0.2, 0.2, 0.2], atol=1e-6)
    np.testing.assert_array_equal(smoothed[:, 1], labels[:, 1])
    np.testing.assert_array_equal(smoothed_labels(demos, 1), labels)
    np.testing.assert_allclose(smoothed_labels(demos, 3)[:5, 0], [0.3, 0.1, 0.5 / 3, 0.1 / 3, 0.5 / 3], atol=1e-6)


def _expert(obs: np.ndarray) -> np.ndarray:
    """The tiny problem's expert: a = 0.8 x the first observation."""
    return 0.8 * obs[:, :1]


def test_the_discriminator_separates_expert_from_random_pairs():
    rng = np.random.default_rng(1)
    obs = rng.uniform(-1, 1, size=(2000, 3)).astype(np.float32)
    updater = GAILUpdater(obs, _expert(obs), batch=128, updates=1, learning_rate=1e-3, seed=0, hidden_units=(64, 64))
    random_buffer = type("Buffer", (), {})()  # a replay buffer's arrays: (rows, n_envs, ...)
    random_buffer.observations = rng.uniform(-1, 1, size=(2000, 1, 3)).astype(np.float32)
    random_buffer.actions = rng.uniform(-1, 1, size=(2000, 1, 1)).astype(np.float32)
    random_buffer.buffer_size, random_buffer.full, random_buffer.pos, random_buffer.n_envs = 2000, True, 0, 1
    for _ in range(600):
        updater.update(random_buffer)
    test_obs = rng.uniform(-1, 1, size=(1000, 3)).astype(np.float32)
    expert_r = updater.disc.reward(torch.as_tensor(test_obs), torch.as_tensor(_expert(test_obs)))
    random_act = rng.uniform(-1, 1, size=(1000, 1)).astype(np.float32)
    random_r = updater.disc.reward(torch.as_tensor(test_obs), torch.as_tensor(random_act))
    far = np.abs(random_act - _expert(test_obs))[:, 0] > 0.3  # random actions clearly unlike the expert's
    accuracy = 0.5 * ((expert_r > 0).float().mean() + (random_r[far] < 0).float().mean())
    assert accuracy > 0.9
    assert float(expert_r.mean()) > float(random_r[far].mean()) + 2.0  # log-odds: the expert's pairs pay more


class _TinyTask(gym.Env):
    """Observations uniform in [-1, 1]^3, one action in [-1, 1]; 10-step episodes; the reward is left to GAIL."""

    observation_space = spaces.Box(-1.0, 1.0, (3,), dtype=np.float32)
    action_space = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        self.obs = self.np_random.uniform(-1, 1, 3).astype(np.float32)
        return self.obs, {}

    def step(self, action):
        self.t += 1
        self.obs = self.np_random.uniform(-1, 1, 3).astype(np.float32)
        return self.obs, 0.0, False, self.t >= 10, {}


def test_the_gail_reward_pulls_the_learner_towards_the_expert():
    rng = np.random.default_rng(2)
    expert_obs = rng.uniform(-1, 1, size=(4000, 3)).astype(np.float32)
    updater = GAILUpdater(
        expert_obs, _expert(expert_obs), batch=128, updates=5, learning_rate=1e-3, seed=0, hidden_units=(64, 64)
    )
    torch.manual_seed(0)
    torch.set_num_threads(1)
    model = SAC(
        "MlpPolicy",
        _TinyTask(),
        learning_starts=200,
        batch_size=64,
        gamma=0.0,
        learning_rate=3e-3,
        replay_buffer_class=GAILReplayBuffer,
        policy_kwargs={"net_arch": [64, 64]},
        seed=0,
        device="cpu",
    )
    model.replay_buffer.discriminator = updater.disc
    probe = rng.uniform(-1, 1, size=(500, 3)).astype(np.float32)

    def error() -> float:
        return float(np.mean(np.abs(model.predict(probe, deterministic=True)[0] - _expert(probe))))

    from stable_baselines3.common.callbacks import BaseCallback

    class Loop(BaseCallback):  # the discriminator learns every 100 transitions, as in train-baseline's loop
        def _on_step(self) -> bool:
            if self.num_timesteps % 100 == 0:
                updater.update(self.model.replay_buffer)
            return True

    before = error()
    model.learn(1200, callback=Loop())
    after = error()
    assert before > 0.3 and after < 0.15 and after < 0.4 * before


@pytest.fixture(scope="module")
def tiny_runs(tmp_path_factory, small_track, small_demos):
    demos, _ = small_demos
    root = tmp_path_factory.mktemp("baselines")
    results = {
        algo: train_baseline(tiny_baseline_config(small_track, demos, root / algo, algo=algo))
        for algo in ("bc", "td3", "gail")
    }
    return root, results


def test_each_algorithm_writes_a_run_folder_that_loads(tiny_runs, small_track):
    root, results = tiny_runs
    for algo, result in results.items():
        assert result["status"] == "done", algo
        record = json.loads((root / algo / "baseline.json").read_text())
        assert record["algo"] == algo and record["settings"]["demos_sha256" if algo != "td3" else "algo"]
        loaded = load_baseline(root / algo, algo)
        assert loaded.spec.fingerprint["algo"] == algo and loaded.spec.sac["hidden_units"] == [256, 256]
        assert loaded.act(np.zeros((4, 96), dtype=np.float32)).shape == (4, 2)
        assert (root / algo / "metrics.jsonl").read_text().strip()
    assert type(load_baseline(root / "td3").policy).__name__ == "TD3Policy"
    assert load_policy(root / "bc").spec.fingerprint["algo"] == "bc"  # bc and gail are SAC policies for every loader
    fit = results["bc"]["fit"]
    assert fit["best_held_out_mse"] < 0.05 and fit["epochs"] <= 30
    gail = torch.load(root / "gail" / "policy.pt", weights_only=True)
    assert "discriminator" in gail and "discriminator_optimizer" in gail


def test_an_online_run_continues_where_it_stopped(tiny_runs, small_track, small_demos, tmp_path, monkeypatch):
    root, results = tiny_runs
    demos, _ = small_demos
    assert results["td3"]["num_timesteps"] == 300
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    more = train_baseline(tiny_baseline_config(small_track, demos, root / "td3", algo="td3", steps=400))
    assert not list(tmp_path.glob("SB3-*"))  # SB3's default logger leaves one empty folder per learn()
    assert more["num_timesteps"] == 400 and more["session"]["steps"] == 100
    assert more["buffer_restored"] == 300  # the saved replay buffer came back (per car x 2 cars)
    model_state = torch.load(root / "td3" / "policy.pt", weights_only=True)
    assert model_state["counters"]["num_timesteps"] == 400
    # The evaluation at the last step timed the saved weights, after SB3's last update.
    last = [json.loads(line) for line in (root / "td3" / "metrics.jsonl").read_text().splitlines()][-1]
    assert last["num_timesteps"] == 400 and last["n_updates"] == model_state["counters"]["n_updates"]
    again = train_baseline(tiny_baseline_config(small_track, demos, root / "td3", algo="td3", steps=400))
    assert again["trained_now"] is False


def test_td3_is_sb3_td3_with_the_paper_network(tiny_runs):
    root, _ = tiny_runs
    sidecar = json.loads((root / "td3" / "policy.json").read_text())
    assert sidecar["sac"]["hidden_units"] == [256, 256] and sidecar["sac"]["action_noise_std_share"] == 0.1
    assert TD3.__module__.startswith("stable_baselines3")


def test_the_commands_record_train_quick_and_refuse_in_one_line(small_track, tmp_path, capsys):
    from vision_rl.commands.main import main

    demos = tmp_path / "ai.npz"
    assert (
        main(
            [
                "record-demos",
                "--track",
                small_track,
                "--laps",
                "0.2",
                "--cars",
                "1",
                "--out",
                str(demos),
                "--no-progress",
                "--json",
            ]
        )
        == 0
    )
    assert json.loads(capsys.readouterr().out)["n_transitions"] > 0
    out = tmp_path / "td3"
    assert (
        main(
            [
                "train-baseline",
                "--algo",
                "td3",
                "--tiny",
                "--track",
                small_track,
                "--demos",
                str(demos),
                "--out",
                str(out),
                "--device",
                "cpu",
                "--no-progress",
                "--json",
            ]
        )
        == 0
    )
    result = json.loads(capsys.readouterr().out)
    assert result["status"] == "done" and result["num_timesteps"] == 300 and result["settings"]["cars"] == 2
    with pytest.raises(SystemExit) as info:  # --algo has choices: argparse refuses it
        main(["train-baseline", "--algo", "planet"])
    assert info.value.code == 2
    assert "--algo: invalid choice: 'planet'" in capsys.readouterr().err


def test_every_algorithm_has_a_learner_and_a_bad_one_is_refused_by_name():
    from vision_rl.overtaking.baseline_run import check_config
    from vision_rl.overtaking.baselines import ALGOS
    from vision_rl.overtaking.config import ALGO_NAMES, TrainBaselineConfig

    assert tuple(ALGOS) == ALGO_NAMES
    with pytest.raises(ValueError, match="PlaNet's row is trained as its successor, --algo dreamer"):
        check_config(TrainBaselineConfig(algo="planet"))


def test_bc_gives_one_policy_per_seed(small_track, small_demos, tmp_path):
    demos, _ = small_demos
    from vision_rl.overtaking.baselines import load_baseline, train_baseline

    weights = []
    for k in range(2):
        cfg = tiny_baseline_config(small_track, demos, tmp_path / f"bc{k}", algo="bc", steps=20)
        train_baseline(cfg)
        policy = load_baseline(tmp_path / f"bc{k}", algo="bc").policy
        weights.append(torch.cat([p.flatten() for p in policy.parameters()]))
        torch.manual_seed(1000 + k)  # whatever the global generator holds when the next run starts
    assert torch.equal(weights[0], weights[1])
