"""The Dreamer agent (the Table III PlaNet row): lambda-returns against hand-computed values, the sequence replay's
order across wrap-around and episode starts, a world model that learns known dynamics, an actor that learns the
rewarded direction through imagination alone, and a train-baseline run that drives, continues and refuses."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from tests.helpers.overtaking import tiny_baseline_config
from vision_rl.config import replace_flat
from vision_rl.evaluation.protocol import time_laps
from vision_rl.overtaking.baseline_run import BaselineError
from vision_rl.overtaking.baselines import load_baseline, train_baseline
from vision_rl.overtaking.dreamer import DreamerAgent, DreamerRecipe, SequenceReplay, lambda_returns
from vision_rl.training.artifact import PolicyError

TINY = DreamerRecipe(
    hidden_units=(32, 32),
    deter_units=32,
    stoch_units=4,
    batch_sequences=16,
    sequence_steps=8,
    imagine_steps=5,
    imagine_starts=64,
    free_nats=0.0,
    actor_lr=1e-3,
    value_lr=1e-3,
    explore_std=0.3,
)


def test_lambda_returns_match_hand_computed_values():
    rewards = torch.tensor([[1.0], [2.0]])
    values = torch.tensor([[0.0], [10.0], [20.0]])
    discounts = torch.tensor([[0.5], [0.5]])
    # R_1 = 2 + 0.5 (0.5 * 20 + 0.5 * 20) = 12;  R_0 = 1 + 0.5 (0.5 * 10 + 0.5 * 12) = 6.5
    assert lambda_returns(rewards, values, discounts, 0.5)[:, 0].tolist() == [6.5, 12.0]
    assert lambda_returns(rewards, values, discounts, 0.0)[:, 0].tolist() == [6.0, 12.0]  # one-step TD targets
    assert lambda_returns(rewards, values, discounts, 1.0)[:, 0].tolist() == [7.0, 12.0]  # discounted sum + v_H


def test_the_replay_keeps_each_cars_rows_in_order_across_wrap_around():
    replay = SequenceReplay(5, 2, obs_dim=1, action_dim=1)
    for t in range(7):  # car 0 wraps round (keeps 2..6), car 1 gets 3 rows
        cars = np.array([0, 1]) if t < 3 else np.array([0])
        ones = np.ones(len(cars))
        replay.add(cars, np.full((len(cars), 1), t), np.zeros((len(cars), 1)), t * ones, ones, (t == 0) * ones)
    assert replay.filled.tolist() == [5, 3]
    rng = np.random.default_rng(0)
    batch = replay.sample(rng, 200, 3)
    first_obs = batch.observations[:, :, 0].numpy()
    assert (np.diff(first_obs, axis=1) == 1).all()  # consecutive rows of one car
    assert set(first_obs[:, 0].tolist()) == {0.0, 2.0, 3.0, 4.0}  # car 1 from 0; car 0 from 2, 3, 4
    assert (batch.rewards.numpy() == first_obs).all()
    assert ((batch.is_first.numpy() == 1) == (first_obs == 0)).all()
    with pytest.raises(ValueError, match="no car has 6 rows"):
        replay.sample(rng, 1, 6)
    copy = SequenceReplay(5, 2, 1, 1)
    assert copy.restore(replay.arrays()) == 8
    again = copy.sample(np.random.default_rng(0), 200, 3)
    assert set(again.observations[:, 0, 0].tolist()) == {0.0, 2.0, 3.0, 4.0}
    copy.add(np.array([0]), np.full((1, 1), 7), np.zeros((1, 1)), np.ones(1), np.ones(1), np.zeros(1))
    assert copy.arrays()["observations"][:, 0, 0].tolist() == [3, 4, 5, 6, 7]  # the oldest row went first
    with pytest.raises(ValueError, match="rows of 2 cars, this replay has 3"):
        SequenceReplay(5, 3, 1, 1).restore(replay.arrays())


def _line_world(replay: SequenceReplay, rng: np.random.Generator, steps: int) -> None:
    """A 1-D world: x' = clip(x + 0.3 a, -1, 1), reward x' (further right is better), random actions; episodes of
    20 steps from random x."""
    n = replay.n_cars
    cars = np.arange(n)
    x = rng.uniform(-1, 1, n)
    replay.add(cars, x[:, None], np.zeros((n, 1)), np.zeros(n), np.ones(n), np.ones(n))
    for t in range(1, steps):
        if t % 20 == 0:
            x = rng.uniform(-1, 1, n)
            replay.add(cars, x[:, None], np.zeros((n, 1)), np.zeros(n), np.ones(n), np.ones(n))
            continue
        a = rng.uniform(-1, 1, n)
        x = np.clip(x + 0.3 * a, -1, 1)
        replay.add(cars, x[:, None], a[:, None], x, np.ones(n), np.zeros(n))


def test_the_world_model_learns_known_dynamics_and_the_actor_learns_through_imagination():
    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    replay = SequenceReplay(400, 8, obs_dim=1, action_dim=1)
    _line_world(replay, rng, 400)
    agent = DreamerAgent(1, 1, TINY, seed=0)
    probe = torch.linspace(-0.8, 0.8, 9)[:, None]

    def mean_action() -> float:  # the actor's mode after filtering one observation at each probe position
        action, _ = agent.act(agent.initial(len(probe)), probe.numpy(), np.ones(len(probe)), explore=False)
        return float(action.mean())

    before = mean_action()
    terms = [agent.update(replay.sample(rng, 16, 8)) for _ in range(200)]

    def mean(name: str, rows: list[dict[str, float]]) -> float:
        return float(np.mean([row[name] for row in rows]))

    # Predicting the mean position would cost 0.5 Var(x) = 0.17 nats for the observation and the reward alike.
    for name in ("observation_nll", "reward_nll"):
        assert mean(name, terms[-20:]) < 0.6 * mean(name, terms[:5]), name
    assert mean("continue_nll", terms[-20:]) < 0.01  # no episode in the data ends by a crash
    # The data's actions are uniform: only imagined rollouts through the learned model show that +1 pays.
    assert abs(before) < 0.3 and mean_action() > 0.6
    assert agent.n_updates == 200 and 0 < terms[-1]["imagined_return"] < 100  # bounded by 1 / (1 - 0.99)


@pytest.fixture(scope="module")
def dreamer_run(tmp_path_factory, small_track, small_demos):
    demos, _ = small_demos
    out = tmp_path_factory.mktemp("dreamer") / "run"
    cfg = tiny_baseline_config(
        small_track, demos, out, algo="dreamer", batch_size=4, dreamer_sequence_steps=8, dreamer_train_every_steps=50
    )
    return out, cfg, train_baseline(cfg)


def test_a_dreamer_run_drives_the_protocol_the_same_way_twice(dreamer_run, small_track):
    out, _, result = dreamer_run
    assert result["status"] == "done" and result["num_timesteps"] == 300
    assert result["session"]["updates"] == (300 - 100) // 50
    loaded = load_baseline(out, "dreamer")
    assert loaded.spec.fingerprint["algo"] == "dreamer" and loaded.spec.sac["hidden_units"] == [256, 256]
    laps = []
    for _ in range(2):  # the recurrent state restarts with each protocol run
        driver = loaded.driver()
        laps.append(time_laps(driver, small_track, "tt_cup", seeds=[0], laps=1, time_limit_s=10.0).summary())
        driver.close()
    assert laps[0]["seeds"] == laps[1]["seeds"]

    def drive(seeds):  # each batch of 3 starts keeps its own recurrent state
        driver = loaded.driver()
        timing = time_laps(driver, small_track, "tt_cup", seeds=seeds, laps=1, time_limit_s=3.0, record=True)
        driver.close()
        return np.stack([timing.x_m, timing.yaw_rad, timing.steer_rad])

    together = drive(range(4))
    apart = np.concatenate([drive([0, 1, 2]), drive([3])], axis=2)
    assert together.shape == apart.shape == (3, 30, 4) and np.array_equal(together, apart)
    assert np.array_equal(drive([0]), together[..., :1])
    assert json.loads((out / "metrics.jsonl").read_text().splitlines()[0])["n_updates"] >= 2
    with pytest.raises(BaselineError, match="a dreamer policy, not a sac one"):
        load_baseline(out, "sac")


def test_a_dreamer_run_continues_with_its_sequences_and_refuses_a_damaged_buffer(dreamer_run, tmp_path):
    out, cfg, _ = dreamer_run
    import shutil

    more = train_baseline(replace_flat(cfg, steps=400))
    assert more["num_timesteps"] == 400 and more["session"]["steps"] == 100
    assert more["buffer_restored"] == 2 * 151  # 2 cars x (150 steps + the first observation)
    state = torch.load(out / "policy.pt", weights_only=True)
    assert state["counters"] == {"num_timesteps": 400, "n_updates": (400 - 100) // 50, "episode_num": 0}
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    with np.load(copy / "replay_buffer.npz") as data:  # re-saved with its rewards x -1000: its hashes no longer hold
        arrays = {name: data[name] for name in data.files}
    np.savez(copy / "replay_buffer.npz", **{**arrays, "rewards": arrays["rewards"] * -1000.0})
    with pytest.raises(BaselineError, match="the array rewards is not the one written"):
        train_baseline(replace_flat(cfg, out=str(copy), steps=500))
    (copy / "replay_buffer.npz").write_bytes(b"not a zip")
    with pytest.raises(BaselineError, match="damaged or mismatched sequence-replay file"):
        train_baseline(replace_flat(cfg, out=str(copy), steps=500))
    (copy / "replay_buffer.npz").unlink()  # without its sequences it collects again, then updates at the same rate
    refilled = train_baseline(replace_flat(cfg, out=str(copy), steps=600))
    assert refilled["buffer_restored"] == 0 and refilled["session"]["updates"] == (600 - 400 - 100) // 50
    weights = copy / "policy.pt"
    weights.write_bytes(weights.read_bytes()[:-10])
    with pytest.raises(PolicyError, match="SHA-256"):
        load_baseline(copy)
