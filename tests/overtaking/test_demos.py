"""record-demos: the AI held at the environment's 10 Hz drives like the 50 Hz AI, its recorded actions replay to the
recorded observations, and the file's episodes, checksum and fingerprint are what they say."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import vision_rl  # noqa: F401  (registers the environments)
from tests.helpers.overtaking import DEMOS_CAR as CAR
from vision_rl.evaluation.protocol import BuiltinAI, time_laps
from vision_rl.overtaking.config import RecordDemosConfig
from vision_rl.overtaking.demos import HeldAIDriver, demo_fingerprint, load_demos, record_demos
from vision_rl.sim.track_library import load_track


def test_the_held_ai_laps_like_the_ai_it_holds(small_track):
    held = time_laps(HeldAIDriver(), small_track, CAR, seeds=[0], laps=2).summary()
    ai = time_laps(BuiltinAI(), small_track, CAR, seeds=[0], laps=2).summary()
    assert held["n_finished"] == 1 and held["best_lap"]["wall_contact_s"] == 0.0
    assert held["best_lap_time_s"] == pytest.approx(ai["best_lap_time_s"], rel=0.01)


def test_replaying_the_recorded_actions_reproduces_the_recorded_observations(small_demos, small_track):
    out, _ = small_demos
    demos = load_demos(out, demo_fingerprint(small_track, CAR))
    first = demos.episode_slices()[0]
    env = gym.make("vision_rl/Overtaking-v1", track=small_track, car=CAR, scenario="stage1", episode_s=20.0)
    try:
        obs, _ = env.reset(seed=3)  # the file's first episode is group 0's first: reset(seed)'s
        np.testing.assert_array_equal(obs, demos.observations[first.start])
        for k in range(first.start, first.start + 60):
            obs, reward, *_ = env.step(demos.actions[k])
            np.testing.assert_array_equal(obs, demos.observations[k + 1])
            assert reward == demos.rewards[k]
    finally:
        env.close()
    # The actions are the AI's, in the environment's bounds, and they drive: mostly throttle, some steering.
    assert np.all(np.abs(demos.actions[:, 0]) <= np.pi / 6) and np.all(np.abs(demos.actions[:, 1]) <= 1.0)
    assert demos.actions[:, 1].mean() > 0.2 and demos.actions[:, 0].std() > 1e-3
    np.testing.assert_array_equal(demos.expert_actions, demos.actions)  # no noise injected: applied = label


def test_noise_goes_on_the_applied_action_and_the_label_stays_the_ais(small_track, tmp_path):
    out = tmp_path / "noisy.npz"
    record_demos(
        RecordDemosConfig(track=small_track, car=CAR, laps=0.3, cars=1, episode_s=20.0, seed=5, noise=0.1, out=str(out))
    )
    demos = load_demos(out, demo_fingerprint(small_track, CAR))
    jitter = (demos.actions - demos.expert_actions) / np.array([np.pi / 6, 1.0])
    assert 0.07 < jitter[:, 0].std() < 0.13 and 0.07 < jitter[:, 1].std() < 0.13  # clipping trims omega's a little
    env = gym.make("vision_rl/Overtaking-v1", track=small_track, car=CAR, scenario="stage1", episode_s=20.0)
    try:
        obs, _ = env.reset(seed=5)
        for k in range(30):  # the applied actions replay the recorded observations
            obs, *_ = env.step(demos.actions[k])
            np.testing.assert_array_equal(obs, demos.observations[k + 1])
        # The label is the held AI's action in the state the noisy drive reached.
        held = HeldAIDriver()
        held.reset(env.unwrapped.core.world, env.unwrapped.core.ego_ids)
        np.testing.assert_allclose(held.act(env.unwrapped.core.world.state)[0], demos.expert_actions[30], atol=1e-6)
    finally:
        env.close()


def test_the_file_holds_whole_episodes_and_its_figures(small_demos, small_track):
    out, result = small_demos
    demos = load_demos(out)
    slices = demos.episode_slices()
    assert result["laps_driven"] >= 2.0 and result["n_episodes"] == len(slices) >= 3
    assert all(s.stop - s.start <= 200 for s in slices)  # 20 s episodes at 10 Hz
    assert sum(s.stop - s.start for s in slices) == demos.n_transitions == result["n_transitions"]
    # Eq. 1 summed over the file is the progress driven (the AI touches no wall): the laps it says it drove.
    length_m = load_track(small_track).length_m
    assert demos.rewards.sum() == pytest.approx(result["laps_driven"] * length_m, rel=1e-3)
    assert demos.fingerprint == demo_fingerprint(small_track, CAR)
    assert demos.meta["demonstrator"]["driver"] == "built-in AI held at 10 Hz"
    assert demos.observations.dtype == np.float32 and demos.observations.shape[1] == 96


def test_a_learner_drives_while_the_ai_labels_and_include_keeps_the_earlier_rounds(small_demos, small_track, tmp_path):
    # DAgger: the applied actions are the learner's (here one that coasts straight on), the labels the AI's in the
    # states the learner reached, after the included file's transitions, which are kept as they were.
    earlier, _ = small_demos
    coast = np.array([0.0, 0.1], dtype=np.float32)
    out = tmp_path / "dagger.npz"
    cfg = RecordDemosConfig(
        track=small_track, car=CAR, laps=0.1, cars=1, episode_s=20.0, seed=4, out=str(out),
        learner="a run", include=str(earlier),
    )  # fmt: skip
    result = record_demos(cfg, learner=lambda obs: np.tile(coast, (len(obs), 1)))
    old, new = load_demos(earlier), load_demos(out)
    n_old = old.n_transitions
    assert new.n_transitions == n_old + result["n_recorded_now"] and result["n_recorded_now"] > 0
    np.testing.assert_array_equal(new.observations[:n_old], old.observations)
    np.testing.assert_array_equal(new.expert_actions[:n_old], old.expert_actions)
    np.testing.assert_array_equal(new.actions[n_old:], np.tile(coast, (result["n_recorded_now"], 1)))
    assert new.episode_starts[n_old]  # the new round starts an episode of its own
    # The AI steers back towards the line the coasting car leaves: its labels are not the learner's actions.
    assert np.abs(new.expert_actions[n_old:, 0]).max() > 1e-3
    assert new.meta["driven_by"] == {"learner": "a run"} and new.meta["included"]["sha256"] == old.sha256


def test_a_learner_named_but_not_given_is_refused(small_track, tmp_path):
    cfg = RecordDemosConfig(track=small_track, car=CAR, laps=0.1, cars=1, learner="run", out=str(tmp_path / "x.npz"))
    with pytest.raises(ValueError, match="--learner"):
        record_demos(cfg)
