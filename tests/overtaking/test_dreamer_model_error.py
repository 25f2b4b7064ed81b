"""The world-model prediction error of a Dreamer run on held-out laps (``vision-rl dreamer-model``): the rows in the
model's convention, the start points, a model that predicts a known linear system exactly against the hold-last
baseline, and the command on a tiny run with its one-line refusals."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from torch import nn
from torch.distributions import Normal

from tests.helpers.overtaking import tiny_baseline_config
from vision_rl.commands.main import main
from vision_rl.envs.observations import ObsNormalizer
from vision_rl.files import content_damage, file_sha256
from vision_rl.overtaking.baselines import train_baseline
from vision_rl.overtaking.demos import OBS_DIM, Demos, load_demos, write_demos
from vision_rl.overtaking.dreamer import DreamerAgent, DreamerRecipe, LatentState, to_env_units
from vision_rl.overtaking.dreamer_model_error import (
    check_horizons,
    model_error,
    model_rows,
    observation_groups,
    rollout_errors,
    start_rows,
)

torch.set_num_threads(1)

IDENTITY = ObsNormalizer(offset=np.zeros(OBS_DIM), scale=np.ones(OBS_DIM))


def _demos(obs: np.ndarray, model_actions: np.ndarray, rewards: np.ndarray, lengths: list[int], normalizer=IDENTITY):
    """Laps in memory: ``model_actions`` in [-1, 1] stored in the environment's units, as record-demos does."""
    starts = np.zeros(len(obs), dtype=bool)
    starts[np.cumsum([0, *lengths[:-1]])] = True
    actions = to_env_units(model_actions).astype(np.float32)
    return Demos(
        observations=obs.astype(np.float32),
        actions=actions,
        expert_actions=actions,
        rewards=rewards.astype(np.float32),
        episode_starts=starts,
        meta={"normalizer": normalizer.to_dict(), "fingerprint": {}},
        path=Path("synthetic.npz"),
        sha256="0" * 64,
    )


def _run(world_model: nn.Module, normalizer=IDENTITY) -> SimpleNamespace:
    """What model_error reads of a loaded run."""
    spec = SimpleNamespace(normalizer=normalizer, weights_sha256="1" * 64, num_timesteps=0)
    return SimpleNamespace(
        agent=SimpleNamespace(world_model=world_model),
        spec=spec,
        config=SimpleNamespace(track="synthetic", car="tt_cup"),
        weights_path=Path("policy.pt"),
    )


class LinearModel(nn.Module):
    """A world model that is exact for o' = A o + B a, r' = c . o': its state holds the observation."""

    def __init__(self, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> None:
        super().__init__()
        self.a, self.b, self.c = (torch.as_tensor(m, dtype=torch.float32) for m in (a, b, c))
        self.unused = nn.Parameter(torch.zeros(1))
        self.encoder = nn.Identity()

    def initial(self, n: int) -> LatentState:
        return LatentState(torch.zeros(n, OBS_DIM), torch.zeros(n, 1))

    def observe_step(self, state, prev_action, embed, is_first, sample=True):
        return LatentState(embed, torch.zeros(len(embed), 1)), None, None

    def imagine_step(self, state, action):
        h = state.h @ self.a.T + action @ self.b.T
        return h, Normal(torch.zeros(len(h), 1), torch.ones(len(h), 1))

    def decoder(self, feature):
        return feature[:, :OBS_DIM]

    def reward_head(self, feature):
        return (feature[:, :OBS_DIM] @ self.c)[:, None]


def _linear_laps(lengths: list[int], seed: int = 0):
    rng = np.random.default_rng(seed)
    a = 0.95 * np.linalg.qr(rng.normal(size=(OBS_DIM, OBS_DIM)))[0]  # a damped rotation: stays bounded
    b, c = rng.normal(size=(OBS_DIM, 2)), rng.normal(size=OBS_DIM) / OBS_DIM
    obs, actions, rewards = [], [], []
    for n in lengths:
        o = rng.normal(size=OBS_DIM)
        for _ in range(n):
            u = rng.uniform(-1, 1, size=2)
            nxt = a @ o + b @ u
            obs.append(o), actions.append(u), rewards.append(c @ nxt)  # demos: r_t is the reward after a_t
            o = nxt
    return (a, b, c), _demos(np.array(obs), np.array(actions), np.array(rewards), lengths)


def test_a_model_exact_on_a_linear_system_has_no_error_and_holding_the_last_observation_has_some():
    (a, b, c), laps = _linear_laps([60, 45])
    result = model_error(_run(LinearModel(a, b, c)), laps, context_steps=5, horizons=(1, 5, 20), starts=1000)
    assert result["n_starts"] == result["n_start_points_available"] == (60 - 24) + (45 - 24)
    assert [row["horizon_steps"] for row in result["horizons"]] == [1, 5, 20]
    for row in result["horizons"]:  # off by one step in actions or rewards, or actions in env units, would show
        assert row["model"]["observation_rmse"] < 1e-4 and row["model"]["reward_rmse"] < 1e-4
        assert abs(row["model"]["reward_bias"]) < 1e-4
        assert row["hold_last"]["observation_rmse"] > 0.1 and row["hold_last"]["reward_rmse"] > 0.01
        assert row["observation_rmse_ratio_to_hold_last"] < 1e-3
    assert result["reconstruction"]["observation_rmse"] < 1e-6
    assert len(result["curve"]["model_observation_rmse"]) == 20


def test_a_model_that_expects_a_penalty_the_laps_lack_has_a_negative_reward_bias_of_its_size():
    (a, b, c), laps = _linear_laps([60, 45])

    class Pessimist(LinearModel):
        def reward_head(self, feature):
            return super().reward_head(feature) - 0.25

    result = model_error(_run(Pessimist(a, b, c)), laps, context_steps=5, horizons=(1, 20), starts=1000)
    true = np.array([row["true_reward_mean"] for row in result["horizons"]])
    assert np.abs(true).max() > 1e-3  # the laps' rewards, not zeros
    for row in result["horizons"]:
        assert row["model"]["reward_bias"] == pytest.approx(-0.25, abs=1e-5)
        assert row["model"]["reward_rmse"] == pytest.approx(0.25, abs=1e-5)


def test_holding_the_last_observation_is_exact_on_constant_laps_only():
    lengths = [30, 30]
    obs = np.repeat(np.random.default_rng(1).normal(size=(2, OBS_DIM)), lengths, axis=0)
    laps = _demos(obs, np.zeros((60, 2)), np.full(60, 0.5), lengths)
    still = LinearModel(np.eye(OBS_DIM), np.zeros((OBS_DIM, 2)), np.zeros(OBS_DIM))
    errors = rollout_errors(still, model_rows(laps, IDENTITY), start_rows(laps.episode_starts, 2, 10), 2, 10)
    assert not errors.hold_last_observation.any() and not errors.hold_last_reward.any()
    moving = _demos(obs + np.arange(60)[:, None] * 0.01, np.zeros((60, 2)), np.arange(60) * 0.1, lengths)
    errors = rollout_errors(still, model_rows(moving, IDENTITY), np.array([5, 40]), 2, 10)
    assert (errors.hold_last_observation > 0).all() and (errors.hold_last_reward > 0).all()


def test_rows_follow_the_models_convention_in_its_units():
    rng = np.random.default_rng(2)
    raw = rng.normal(3.0, 2.0, size=(8, OBS_DIM))
    recorded = ObsNormalizer(offset=np.full(OBS_DIM, 1.0), scale=np.full(OBS_DIM, 2.0))
    runs = ObsNormalizer(offset=np.full(OBS_DIM, -1.0), scale=np.full(OBS_DIM, 4.0))
    actions = rng.uniform(-1, 1, size=(8, 2))
    laps = _demos(recorded(raw), actions, np.arange(8.0), [5, 3], recorded)
    rows = model_rows(laps, runs)
    np.testing.assert_allclose(rows.observations, runs(raw), atol=1e-5)  # the run's normaliser, not the laps'
    np.testing.assert_allclose(rows.prev_actions[[1, 2, 3, 4, 6, 7]], actions[[0, 1, 2, 3, 5, 6]], atol=1e-6)
    assert not rows.prev_actions[[0, 5]].any() and rows.rewards.tolist() == [0, 0, 1, 2, 3, 0, 5, 6]
    assert rows.is_first.tolist() == [1, 0, 0, 0, 0, 1, 0, 0]


def test_start_points_lie_in_one_episode_and_a_context_longer_than_every_episode_is_refused():
    starts = np.zeros(15, dtype=bool)
    starts[[0, 5]] = True
    assert start_rows(starts, 3, 4).tolist() == [7, 8, 9, 10]
    with pytest.raises(
        ValueError, match=r"--context-steps 8 plus the longest horizon 4 = 12 steps \(the longest holds 10\)"
    ):
        start_rows(starts, 8, 4)
    for horizons, context in (((0, 5), 3), ((-1,), 3), ((5,), 0)):
        with pytest.raises(ValueError, match="whole number"):
            check_horizons(horizons, context)


def test_the_observation_groups_cover_the_96_entries_once():
    groups = observation_groups()
    assert sorted(i for cols in groups.values() for i in cols) == list(range(OBS_DIM))
    assert len(groups["lidar"]) == 72 and len(groups["curvature"]) == 14 and groups["wall_contact"] == [80]


def test_an_untrained_dreamer_gives_errors_of_every_horizon_and_step():
    recipe = DreamerRecipe(hidden_units=(16, 16), deter_units=16, stoch_units=4)
    agent = DreamerAgent(OBS_DIM, 2, recipe, seed=0)
    _, laps = _linear_laps([40])
    errors = rollout_errors(agent.world_model, model_rows(laps, IDENTITY), np.array([3, 10, 20]), 4, 15)
    assert errors.model_observation.shape == errors.hold_last_observation.shape == (15, OBS_DIM)
    assert errors.model_reward.shape == (15,) and errors.reconstruction.shape == (OBS_DIM,)
    assert np.isfinite(errors.model_observation).all() and (errors.model_observation > 0).all()


# ------------------------------------------------------------------------------------------------- the command


@pytest.fixture(scope="module")
def dreamer_and_bc(tmp_path_factory, small_track, small_demos):
    demos, _ = small_demos
    root = tmp_path_factory.mktemp("model-error")
    dreamer = tiny_baseline_config(
        small_track, demos, root / "dreamer", algo="dreamer", batch_size=4, dreamer_sequence_steps=8,
        dreamer_train_every_steps=50, eval_every_steps=0,
    )  # fmt: skip
    train_baseline(dreamer)
    train_baseline(tiny_baseline_config(small_track, demos, root / "bc", algo="bc", steps=20))
    return root / "dreamer", root / "bc", demos


def _refusal(argv: list[str], capsys) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


def test_the_command_writes_a_sealed_record_of_what_it_measured_and_refuses_bad_input(dreamer_and_bc, tmp_path, capsys):
    run, bc, laps = dreamer_and_bc
    out = tmp_path / "me.json"
    argv = ["dreamer-model", "--run", str(run), "--laps", str(laps), "--out", str(out)]
    assert main([*argv, "--context-steps", "10", "--horizons", "1,5,20", "--starts", "50"]) == 0
    assert "hold last" in capsys.readouterr().out
    record = json.loads(out.read_text())
    assert content_damage(record) is None and out.with_suffix(".png").stat().st_size > 0
    spec = json.loads((run / "policy.json").read_text())
    assert record["made_from"]["policy_sha256"] == spec["weights_sha256"]
    assert record["made_from"]["laps_sha256"] == file_sha256(laps)
    assert [row["horizon_steps"] for row in record["horizons"]] == [1, 5, 20] and record["n_starts"] == 50
    assert set(record["horizons"][0]["model"]["groups"]) == set(observation_groups())

    assert "a bc policy, not a dreamer one" in _refusal(
        ["dreamer-model", "--run", str(bc), "--laps", str(laps)], capsys
    )
    assert "--horizons must be whole numbers" in _refusal([*argv, "--horizons", "0,5"], capsys)
    assert "--horizons takes whole numbers" in _refusal([*argv, "--horizons", "five"], capsys)
    assert "the longest holds" in _refusal([*argv, "--context-steps", "400"], capsys)
    other = load_demos(laps)
    arrays = {name: getattr(other, name) for name in ("observations", "actions", "expert_actions", "rewards")}
    meta = {**other.meta, "fingerprint": {**other.meta["fingerprint"], "car": "hatchback"}}
    write_demos(tmp_path / "other.npz", {**arrays, "episode_starts": other.episode_starts}, meta)
    line = _refusal(["dreamer-model", "--run", str(run), "--laps", str(tmp_path / "other.npz")], capsys)
    assert "car = 'hatchback', not 'tt_cup'" in line
