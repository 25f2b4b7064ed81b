"""The DDPG paper's reward-by-lap-distance figure: a scripted driver's laps, the bins' bookkeeping, bad options."""

from __future__ import annotations

import numpy as np
import pytest

from vision_rl.ddpg.reward import lap_reward_profile, plot_lap_reward
from vision_rl.envs.pixel_racing import PixelRacingConfig
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import ACTION_STEER_LIMIT_RAD


def _pursuit(track_path: str, accelerate: float):
    """Keys that steer towards the centre line 12 m ahead (pure pursuit) at a fixed throttle."""
    track = load_track(track_path)

    def act(obs):
        x, y, yaw = obs["motion"][0, 0], obs["motion"][0, 1], obs["motion"][0, 5]
        s = track.project(np.array([[x, y]])).s_m
        tx, ty = track.position_at(s + 12.0)[0]
        bearing = np.arctan2(ty - y, tx - x) - yaw
        steer = np.clip(2.0 * 2.6 * np.sin((bearing + np.pi) % (2 * np.pi) - np.pi) / 12.0, -0.5, 0.5)
        share = steer / ACTION_STEER_LIMIT_RAD  # left - right
        return np.array([[accelerate, 2 * max(share, 0) - 1, 2 * max(-share, 0) - 1, 0.0]])

    return act


def test_a_scripted_drivers_laps_fill_every_bin(small_track, tmp_path):
    track = small_track
    env = PixelRacingConfig(track=track, car="hatchback", frames=False, max_line_distance_m=50.0, start_skill=0.4)
    profile = lap_reward_profile(_pursuit(track, 0.25), env, laps=2, bin_m=40.0)
    assert profile["end"] == "2 laps", profile["end"]
    n_bins = int(np.ceil(profile["lap_length_m"] / 40.0))
    assert len(profile["bin_start_m"]) == n_bins and profile["bin_start_m"][1] == 40.0
    for lap in profile["laps"]:
        assert lap["steps"] > n_bins and all(v is not None for v in lap["mean_reward"])  # every bin driven
        assert all(v > 0 for v in lap["mean_reward"])  # forward speed outweighs the line distance here
    png = plot_lap_reward(profile, tmp_path / "reward.png", "pursuit")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_an_episode_that_ends_early_leaves_the_later_bins_empty(small_track):
    track = small_track
    env = PixelRacingConfig(track=track, car="hatchback", frames=False, max_line_distance_m=2.0)
    full_left = lambda obs: np.array([[1.0, 1.0, -1.0, 0.0]])  # noqa: E731
    profile = lap_reward_profile(full_left, env, laps=3, bin_m=40.0)
    assert profile["end"] == "terminated"
    first = profile["laps"][0]
    assert 0 < first["steps"] < 30 and first["mean_reward"][0] is not None and first["mean_reward"][-1] is None
    assert profile["laps"][1]["steps"] == profile["laps"][2]["steps"] == 0
    with pytest.raises(ValueError, match="laps must be >= 1"):
        lap_reward_profile(full_left, env, laps=0)
