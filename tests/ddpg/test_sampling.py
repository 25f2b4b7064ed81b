"""train-ddpg --workers on the session's local Ray cluster: a sampler's transitions in the learner's frame replay
as its world gives them, and the update count (faults and bad options: tests/faults/test_ddpg_sampling.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.helpers.ddpg import HW, ddpg_config
from tests.helpers.tracks import STADIUM, stadium_csv
from vision_rl.ddpg.agent import FrameReplay, load_replay
from vision_rl.ddpg.train import train_ddpg
from vision_rl.envs.pixel_racing import PixelRacingConfig, PixelRacingCore
from vision_rl.training.distributed import worker_seed


@pytest.fixture(scope="module")
def track(tmp_path_factory) -> str:
    return str(stadium_csv(tmp_path_factory.mktemp("track") / "stadium.csv", *STADIUM))


def test_a_samplers_steps_reach_the_frame_replay_as_its_world_gives_them(ray_local, gl_available, track, tmp_path):
    out = tmp_path / "run"
    result = train_ddpg(ddpg_config(track, out))
    sampling = result["sampling"]
    assert result["num_steps"] == 24 and sampling["workers"] == 1 and sampling["samplers_lost"] == []
    # 12 vector steps of 2 cars; as SB3 counts, those ending past the 8 start transitions earn one update each
    assert result["n_updates"] == 12 - 4 and sampling["max_staleness_seen"] == 0
    side = json.loads((out / "ddpg.json").read_text())
    buffer = FrameReplay(200, 2, HW)
    assert load_replay(buffer, out / "replay", side["fingerprint"]) > 0
    env = PixelRacingConfig.from_dict(side["env"])
    core = PixelRacingCore(env, seed=worker_seed(0, 0))
    core.reset_cars(core.ids)
    obs = core.observation()
    cars, rows, ended = np.arange(2), np.zeros(2, dtype=np.int64), 0
    try:
        for _ in range(12):
            np.testing.assert_array_equal(buffer.image[cars, rows], obs["image"])
            np.testing.assert_array_equal(buffer.motion[cars, rows], obs["motion"])
            assert buffer.valid[cars, rows].all()
            obs, reward, terminated, truncated, _ = core.step(buffer.action[cars, rows].astype(np.float64))
            np.testing.assert_array_equal(buffer.reward[cars, rows], reward)
            np.testing.assert_array_equal(buffer.terminated[cars, rows], terminated)
            rows += 1
            done = np.flatnonzero(terminated | truncated)
            if len(done):  # the final observation's row, then the new episode's first
                np.testing.assert_array_equal(buffer.motion[done, rows[done]], obs["motion"][done])
                assert not buffer.valid[done, rows[done]].any()
                core.reset_cars(done)
                for key, value in core.observation(done).items():
                    obs[key][done] = value
                rows[done] += 1
                ended += len(done)
    finally:
        core.close()
    assert buffer.size == 24 and ended > 0  # the episodes that ended took their two rows
    episodes = (out / "episodes.jsonl").read_text().splitlines()
    assert len(episodes) == ended and all(json.loads(e)["worker"] == 0 for e in episodes)


def test_train_minutes_end_a_sampled_session(ray_local, track, tmp_path):
    """With samplers, the learner ends the session when the run's --train-minutes are up, not at its steps."""
    result = train_ddpg(ddpg_config(track, tmp_path / "run", variant="state-actor", steps=10**7, train_minutes=0.03))
    assert result["stopped_by"] == "train_minutes" and 0 < result["num_steps"] < 10**7
    assert result["train_time_s"] >= 1.8 and result["sampling"]["samplers_lost"] == []


def test_an_episode_record_names_the_rule_that_ended_it():
    """A crashState ends an episode only under terminate_on_crash: without it, the line-distance or stuck rule did;
    a truncated episode ended by time, or stuck under truncate_when_stuck."""
    from vision_rl.ddpg.sampling import episode_record

    info = {
        "crash_state": np.array([2, 3]),
        "line_distance_m": np.array([1.0, 20.0]),
        "episode_return": np.zeros(2),
        "episode_steps": np.array([7, 9]),
        "progress_m": np.zeros(2),
        "laps_completed": np.zeros(2, int),
        "stuck": np.array([True, False]),
    }
    crash_ends = PixelRacingConfig(max_line_distance_m=15.0)
    crash_goes_on = PixelRacingConfig(max_line_distance_m=15.0, terminate_on_crash=False)
    assert [episode_record(info, i, True, crash_ends)["end"] for i in (0, 1)] == ["crash 2", "crash 3"]
    assert [episode_record(info, i, True, crash_goes_on)["end"] for i in (0, 1)] == ["stuck", "line distance"]
    assert episode_record(info, 0, False, crash_goes_on)["end"] == "time"
    stuck_truncates = PixelRacingConfig(truncate_when_stuck=True)  # a truncated episode: stuck, or out of time
    assert [episode_record(info, i, False, stuck_truncates)["end"] for i in (0, 1)] == ["stuck", "time"]
