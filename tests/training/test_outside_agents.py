"""vision_rl.evaluate, the door for agents trained outside the project: a stock Stable-Baselines3 PPO trained on
gymnasium.make is timed by the lap-time protocol and listed by the leaderboard, as is its zip read from its tensors;
a CleanRL-style torch module is an agent as it is; what cannot be timed is refused in one line."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import vision_rl
from vision_rl.commands.evaluate import EvaluateOptions, LeaderboardOptions, run_evaluate, run_leaderboard
from vision_rl.sim.vehicle import ACTION_STEER_LIMIT_RAD
from vision_rl.training.outside import read_sb3_actor

ENV_ID = "vision_rl/TimeTrial-v1"


@pytest.mark.slow
def test_a_stock_ppo_trained_on_gym_make_is_timed_and_listed_on_the_leaderboard(small_track, tmp_path, capsys):
    from stable_baselines3 import PPO

    env = gym.make(ENV_ID, track=small_track)
    model = PPO("MlpPolicy", env, n_steps=1024, batch_size=128, n_epochs=4, seed=0, device="cpu")
    model.learn(3 * 1024)
    seen = []

    def predict(obs):
        seen.append(obs)
        return model.predict(obs, deterministic=True)[0]

    runs = tmp_path / "runs"
    protocol = dict(env_id=ENV_ID, track=small_track, runs=runs, seeds=2, time_limit_s=30.0)
    record = vision_rl.evaluate(predict, name="stock ppo", **protocol)
    assert seen[0].shape == (3, 38) and seen[0].dtype == np.float32  # what the env gives, one row per car ...
    assert np.array_equal(seen[0][2], seen[0][1])  # ... in a batch of 3, the last start's row repeated
    assert record["format"] == "vision_rl.evaluation" and record["name"] == "stock ppo"
    assert [s["seed"] for s in record["seeds"]] == [0, 1] and record["protocol"]["version"] == 1
    assert record["driver"]["agent"] == "outside" and record["driver"]["env_id"] == ENV_ID
    assert record["evaluation_json"] == str(runs / "stock-ppo" / "evaluation.json")
    written = json.loads(Path(record["evaluation_json"]).read_text())
    assert written == {k: v for k, v in record.items() if k != "evaluation_json"}
    # The model itself (SB3's predict, deterministic) drives the same laps.
    assert vision_rl.evaluate(model, name="x", write=False, **protocol)["seeds"] == record["seeds"]

    # Its zip, read from the tensors alone, drives the same laps too: the CLI's --policy agent.zip --env-id.
    model.save(tmp_path / "ppo_tt.zip")
    argv = dict(env_id=ENV_ID, track=small_track, runs=str(runs), seeds=2, time_limit_s=30.0, json=True)
    assert run_evaluate(EvaluateOptions(policy=str(tmp_path / "ppo_tt.zip"), **argv)) == 0
    from_zip = json.loads(capsys.readouterr().out)
    assert from_zip["name"] == "ppo_tt" and from_zip["seeds"] == record["seeds"]
    assert from_zip["driver"]["algorithm"] == "actor-critic (PPO, A2C)"
    assert from_zip["driver"]["num_timesteps"] == 3 * 1024

    assert run_leaderboard(LeaderboardOptions(track=small_track, runs=str(runs), json=True)) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)["rows"]}
    assert rows["stock ppo"]["kind"] == "agent (state)" and rows["ppo_tt"]["kind"] == "agent (state)"
    assert rows["stock ppo"]["evaluation_json"] == record["evaluation_json"]
    assert rows["stock ppo"]["finished"] == f"{record['n_finished']}/2"


def test_a_cleanrl_style_torch_module_is_an_agent_as_it_is(small_track, tmp_path):
    torch = pytest.importorskip("torch")
    nn = torch.nn

    class Actor(nn.Module):
        """CleanRL's TD3 actor: tanh outputs scaled onto the action box."""

        def __init__(self, env: gym.Env) -> None:
            super().__init__()
            self.fc1 = nn.Linear(int(np.prod(env.observation_space.shape)), 32)
            self.fc_mu = nn.Linear(32, int(np.prod(env.action_space.shape)))
            high, low = env.action_space.high, env.action_space.low
            self.register_buffer("action_scale", torch.tensor((high - low) / 2.0, dtype=torch.float32))
            self.register_buffer("action_bias", torch.tensor((high + low) / 2.0, dtype=torch.float32))

        def forward(self, x):
            return torch.tanh(self.fc_mu(torch.relu(self.fc1(x)))) * self.action_scale + self.action_bias

    torch.manual_seed(0)
    actor = Actor(gym.make(ENV_ID, track=small_track))
    with torch.no_grad():  # straight ahead at 60 % throttle, whatever it sees
        actor.fc_mu.weight.zero_()
        actor.fc_mu.bias.copy_(torch.tensor([0.0, 0.6931]))
    protocol = dict(env_id=ENV_ID, track=small_track, runs=tmp_path, seeds=1, time_limit_s=8.0)
    record = vision_rl.evaluate(actor, name="cleanrl-td3", **protocol)
    assert Path(record["evaluation_json"]).is_file() and record["seeds"][0]["distance_m"] > 50.0
    by_hand = vision_rl.evaluate(
        lambda obs: actor(torch.as_tensor(obs)).detach().numpy(), name="y", **protocol | {"write": False}
    )
    assert by_hand["seeds"] == record["seeds"]


@pytest.mark.parametrize("algorithm", ["PPO", "SAC", "TD3"])
def test_an_sb3_zip_read_from_its_tensors_acts_as_the_model_predicts(algorithm, small_track, tmp_path):
    import stable_baselines3
    import torch

    env = gym.make(ENV_ID, track=small_track)
    kwargs = {"policy_kwargs": {"net_arch": [32, 16], "activation_fn": torch.nn.ELU}} if algorithm == "PPO" else {}
    model = getattr(stable_baselines3, algorithm)("MlpPolicy", env, seed=1, device="cpu", **kwargs)
    model.save(tmp_path / "agent.zip")
    actor = read_sb3_actor(tmp_path / "agent.zip")
    obs = np.random.default_rng(0).normal(0.0, 2.0, (5, 38)).astype(np.float32)
    np.testing.assert_array_equal(actor(obs), model.predict(obs, deterministic=True)[0])
    actor.check_spaces(env.observation_space, env.action_space)
    with pytest.raises(ValueError, match="reads 38 inputs"):
        actor.check_spaces(gym.spaces.Box(-1, 1, (96,)), env.action_space)
    with pytest.raises(ValueError, match="acts in a box"):
        actor.check_spaces(env.observation_space, gym.spaces.Box(-1, 1, (2,)))


def test_an_sb3_zip_that_cannot_be_read_from_its_tensors_is_refused_in_one_line(tmp_path):
    from fractions import Fraction  # neither a tensor nor a plain value: a pickle that weights_only refuses

    import torch

    def zip_with(policy: object, data: dict) -> Path:
        path = tmp_path / f"agent{len(list(tmp_path.iterdir()))}.zip"
        with zipfile.ZipFile(path, "w") as archive:
            with archive.open("policy.pth", "w") as member:
                torch.save(policy, member)
            archive.writestr("data", json.dumps(data))
        return path

    layer = {"mlp_extractor.policy_net.0.weight": torch.zeros(4, 38), "mlp_extractor.policy_net.0.bias": torch.zeros(4)}
    head = {"action_net.weight": torch.zeros(2, 4), "action_net.bias": torch.zeros(2)}
    box = {"action_space": {"low": "[-0.5235988 -1.       ]", "high": "[0.5235988 1.       ]"}}
    (tmp_path / "not.zip").write_text("no zip")
    cases = {
        tmp_path / "not.zip": "not a Stable-Baselines3 zip",
        zip_with({"x": Fraction(1, 3)}, box): "whose tensors load safely",
        zip_with({**layer, **head, "features_extractor.cnn.0.weight": torch.zeros(1)}, box): "features extractor",
        zip_with({**layer, **head}, {**box, "use_sde": True}): "gSDE",
        zip_with(layer, box): "no actor found",
        zip_with({**layer, **head}, {}): "action space is not a box",
    }
    for path, why in cases.items():
        with pytest.raises(ValueError, match=why) as excinfo:
            read_sb3_actor(path)
        assert "\n" not in str(excinfo.value)
    ok = zip_with({**layer, **head}, {**box, "policy_kwargs": {":serialized:": "...", "activation_fn": "<lambda>"}})
    with pytest.raises(ValueError, match="activation"):
        read_sb3_actor(ok)


def test_what_cannot_be_timed_is_refused_in_one_line(small_track, tmp_path):
    def constant(obs):
        return np.tile([0.0, 0.5], (len(obs), 1))

    good = dict(env_id=ENV_ID, name="a", track=small_track, runs=tmp_path, seeds=1, time_limit_s=2.0, write=False)
    (tmp_path / "tiny-state").mkdir()
    (tmp_path / "tiny-state" / "policy.json").write_text("{}")  # a train-policy run's folder
    cases = [
        ({**good, "env_id": "vision_rl/TimeTrial-v9"}, constant, "not a registered environment"),
        ({**good, "env_id": "vision_rl/PixelRacing-v0"}, constant, "evaluate-ddpg"),
        ({**good, "tyres": "soft"}, constant, "unknown argument"),
        ({**good, "name": " "}, constant, "needs a name"),
        ({**good, "encoder": "ckpt.pt"}, constant, "takes no encoder"),
        ({**good, "name": "tiny-state"}, constant, "is a train-policy run"),
        (good, lambda obs: np.zeros(len(obs)), r"shape \(3,\) for 3 observations"),
        (good, lambda obs: np.full((len(obs), 2), np.nan), "non-finite"),
        (good, lambda obs: (constant(obs), None), "returned a tuple"),
        (good, "not an agent", "must be callable"),
    ]
    for kwargs, predict, why in cases:
        with pytest.raises(ValueError, match=why) as excinfo:
            vision_rl.evaluate(predict, **kwargs)
        assert "\n" not in str(excinfo.value), why
    assert vision_rl.evaluate(constant, **good)["n_seeds"] == 1


def test_actions_of_a_normalized_box_are_mapped_as_the_environment_maps_them():
    from vision_rl.training.outside import _action_map

    class Bare(gym.Env):  # no map of its own: a box's actions go linearly onto the physical range
        pass

    unit = _action_map("x", Bare(), gym.spaces.Box(-1.0, 1.0, (2,), dtype=np.float32))
    np.testing.assert_allclose(unit(np.array([[1.0, -1.0], [-0.5, 2.0]])), [[0.5236, -1.0], [-0.2618, 1.0]], atol=1e-4)
    physical = gym.spaces.Box(np.float32([-ACTION_STEER_LIMIT_RAD, -1]), np.float32([ACTION_STEER_LIMIT_RAD, 1]))
    same = np.array([[0.1, 0.2]])
    assert _action_map("x", Bare(), physical)(same) is same
    for space in (gym.spaces.Box(-1.0, 1.0, (3,)), gym.spaces.Discrete(3), gym.spaces.Box(-np.inf, np.inf, (2,))):
        with pytest.raises(ValueError, match="map"):
            _action_map("x", Bare(), space)


def test_a_newer_id_with_normalized_actions_drives_as_the_physical_one(small_track):
    newer = "vision_rl/TimeTrial-v2"
    if newer not in gym.registry:
        pytest.skip(f"{newer} is not registered in this version")
    physical = np.array([0.05, 0.7])

    def agent(scale):
        return lambda obs: np.tile(physical * scale, (len(obs), 1))

    protocol = dict(name="n", track=small_track, seeds=1, time_limit_s=6.0, write=False)
    v1 = vision_rl.evaluate(agent(np.ones(2)), env_id=ENV_ID, **protocol)
    v2 = vision_rl.evaluate(agent(np.array([1 / ACTION_STEER_LIMIT_RAD, 1.0])), env_id=newer, **protocol)
    assert v2["seeds"][0]["distance_m"] == pytest.approx(v1["seeds"][0]["distance_m"], rel=1e-6)


def test_a_vision_agent_reads_the_encoders_embedding_and_the_record_names_the_encoder(
    small_track, tiny_encoders, tmp_path
):
    from vision_rl.files import file_sha256

    encoder, other = tiny_encoders
    seen = []

    def straight_on(obs):  # straight ahead at full throttle, whatever it sees
        seen.append(obs)
        return np.tile(np.array([0.0, 1.0], np.float32), (len(obs), 1))

    protocol = dict(
        env_id="vision_rl/TimeTrial-v2",
        track=small_track,
        observation="vision",
        runs=tmp_path,
        seeds=1,
        time_limit_s=4.0,
    )
    record = vision_rl.evaluate(straight_on, name="vision-door", encoder=str(encoder), **protocol)
    assert seen[0].shape == (3, 64 + 11) and seen[0].dtype == np.float32  # [embedding, 11 car-state features]
    assert record["driver"]["observation"] == "vision"
    assert record["driver"]["encoder_sha256"] == file_sha256(encoder) != file_sha256(other)
    assert record["seeds"][0]["distance_m"] > 20.0
    with pytest.raises(ValueError, match="not found"):
        vision_rl.evaluate(straight_on, name="x", encoder=str(tmp_path / "none.pt"), write=False, **protocol)
    with pytest.raises(ValueError, match=r"image_hw_px=\(280, 470\) but the encoder reads 64 x 96 frames"):
        vision_rl.evaluate(straight_on, name="x", encoder=str(encoder), image_hw_px=(280, 470), **protocol)
