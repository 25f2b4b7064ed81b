"""vision_rl/PixelRacing-v0: the actor's frames and their mask, the critic's goal, the reward, crashState and the
episode end, the action mapping, and the vector form."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

from tests.helpers.tracks import STADIUM, stadium_csv, stadium_points
from vision_rl.envs.pixel_racing import (
    CRASH_LARGE_PROP,
    CRASH_NONE,
    CRASH_OFF_TRACK,
    CRASH_SPINNING,
    PixelObserver,
    PixelRacingConfig,
    PixelRacingCore,
    PixelRacingVectorEnv,
    crash_state,
    goal_line,
    keys_to_action,
    pixel_reward,
    process_frames,
)
from vision_rl.sim.racing_line import racing_line_from_offsets
from vision_rl.sim.track import Track
from vision_rl.sim.track_library import load_track, reference_racing_line
from vision_rl.sim.vehicle import ACTION_STEER_LIMIT_RAD, get_preset
from vision_rl.sim.world import World, WorldConfig


@pytest.fixture(scope="module")
def small_track(tmp_path_factory) -> str:
    """The Phase-2 tests' 677 m stadium as a CSV path."""
    return str(stadium_csv(tmp_path_factory.mktemp("track") / "stadium.csv", *STADIUM))


@pytest.fixture(scope="module")
def straight_track() -> Track:
    """A stadium whose bottom straight runs 400 m along +x from the origin (left of the car is +y)."""
    return Track.from_centre_line("straights", stadium_points(400.0, 60.0), 6.0, 6.0)


def _world(track: Track, s_m: float, lateral_m: float, heading_offset_rad: float = 0.0, speed_mps: float = 20.0):
    world = World(track, get_preset("gt3"), 1, np.zeros(1, dtype=np.int64), WorldConfig(control_dt_s=0.1))
    world.reset(s_m=s_m, lateral_m=lateral_m, speed_mps=speed_mps, heading_offset_rad=heading_offset_rad)
    return world


@pytest.mark.parametrize(
    ("keys", "action"),
    [
        ([1.0, 1.0, -1.0, 0.0], [ACTION_STEER_LIMIT_RAD, 1.0]),  # full throttle, full left alone
        ([0.0, -1.0, 1.0, 1.0], [-ACTION_STEER_LIMIT_RAD, -1.0]),  # full brake, full right alone
        ([0.0, 0.0, 0.0, 0.0], [0.0, 0.0]),  # a fresh actor's outputs: both keys half the step, straight
        ([1.0, 1.0, 1.0, 1.0], [0.0, 0.0]),  # everything pressed cancels
        ([5.0, 3.0, -7.0, -2.0], [ACTION_STEER_LIMIT_RAD, 1.0]),  # beyond the range: clipped
        ([np.nan, np.nan, np.nan, np.nan], [0.0, 0.0]),
        ([0.5, 0.0, -1.0, 0.25], [0.5 * ACTION_STEER_LIMIT_RAD, 0.25]),  # left held half the step, right not
    ],
)
def test_action_mapping_at_its_extremes(keys, action):
    np.testing.assert_allclose(keys_to_action(np.array([keys]))[0], action, atol=1e-12)


def test_frames_are_box_averaged_and_the_top_third_is_exactly_zero():
    rng = np.random.default_rng(0)
    raw = rng.integers(1, 256, (3, 178, 240, 3), dtype=np.uint8)
    cfg = PixelRacingConfig()
    assert cfg.mask_rows == 30  # ceil(89 / 3): the whole top third
    out = process_frames(raw, 2, cfg.mask_rows)
    assert out.shape == (3, 89, 120, 3) and out.dtype == np.uint8
    assert not out[:, :30].any()
    expected = raw[:, 60:62, 10:12].astype(float).mean(axis=(1, 2))
    np.testing.assert_allclose(out[:, 30, 5], np.floor(expected + 0.5), atol=0.51)
    assert out[:, 30:].min() > 0  # nothing below the mask is black (the raw frames have no zeros)


def test_actor_frame_shape_and_mask_from_the_renderer(gl_available, small_track):
    env = gym.make("vision_rl/PixelRacing-v0", track=small_track)
    try:
        obs, _ = env.reset(seed=0)
        assert obs["image"].shape == (89, 120, 3) and obs["image"].dtype == np.uint8
        assert obs["motion"].shape == (15,) and obs["goal"].shape == (3,)
        assert env.observation_space.contains(obs)
        assert not obs["image"][:30].any()
        assert obs["image"][30:].std() > 5.0  # the road and the scenery are drawn below the mask
        obs, reward, *_ = env.step(np.array([1.0, 0.0, 0.0, 0.0], np.float32))
        assert not obs["image"][:30].any() and isinstance(reward, float)
    finally:
        env.close()


def test_the_critics_goal_is_the_racing_line_point_on_a_straight(straight_track):
    line = racing_line_from_offsets(straight_track, np.full(straight_track.n_points, 1.5))
    world = _world(straight_track, s_m=200.0, lateral_m=-1.0)
    cfg = PixelRacingConfig(track="expressway", frames=False)
    observer = PixelObserver(cfg, straight_track, get_preset("gt3"), np.zeros(1))
    observer.line = line
    goal, dist = observer.goal(world.state, np.array([0]))
    np.testing.assert_allclose(goal[0], [200.0, 1.5, 0.0], atol=1e-2)  # 1 mm: the track is resampled
    assert dist[0] == pytest.approx(2.5, abs=1e-6)
    body = PixelObserver(
        PixelRacingConfig(track="expressway", frames=False, goal_frame="body"),
        straight_track,
        get_preset("gt3"),
        np.zeros(1),
    )
    body.line = line
    goal, _ = body.goal(world.state, np.array([0]))
    np.testing.assert_allclose(goal[0], [0.0, 2.5, 0.0], atol=1e-6)  # 2.5 m to the car's left
    motion = observer(world.state, np.array([0]))["motion"][0]
    np.testing.assert_allclose(motion[[0, 1, 5, 6]], [200.0, -1.0, 0.0, 20.0], atol=1e-2)


def test_the_reference_racing_line_follows_the_database_line():
    track = load_track("Catalunya")
    line = goal_line(track, get_preset("gt3"), "reference", "Catalunya")
    ref = reference_racing_line("Catalunya")
    _, dist = (None, np.hypot(*(line.position_at(line.line_s_at(track.project(ref).s_m)) - ref).T))
    assert np.median(dist) < 0.3


def test_reward_sign_and_size_on_known_states():
    assert pixel_reward(np.array([30.0]), np.array([2.0]), np.array([0]), 1.0, 0.0)[0] == pytest.approx(28.0)
    assert pixel_reward(np.array([30.0]), np.array([-2.0]), np.array([0]), 1.0, 0.0)[0] == pytest.approx(28.0)
    assert pixel_reward(np.array([30.0]), np.array([2.0]), np.array([3]), 1.0, 10.0)[0] == pytest.approx(-2.0)
    assert pixel_reward(np.array([-5.0]), np.array([0.0]), np.array([0]), 1.0, 0.0)[0] == pytest.approx(-5.0)


def test_reward_in_the_environment_is_speed_less_line_distance(small_track):
    core = PixelRacingCore(PixelRacingConfig(track=small_track, frames=False, start="line", n_cars=2), seed=0)
    core.reset_cars(core.ids)
    v0 = core.world.state.vehicle.vx_mps.copy()
    _, reward, terminated, truncated, info = core.step(np.tile([0.0, 0.0, 0.0, 0.0], (2, 1)))
    assert not terminated.any() and not truncated.any()
    expected = info["forward_speed_mps"] - 1.0 * info["line_distance_m"]
    np.testing.assert_allclose(reward, expected, rtol=1e-6)
    assert (info["line_distance_m"] < 1.0).all()  # the line crosses the straight here: 0.6 m after 0.1 s straight on
    assert ((reward > 0.9 * v0 - 1.0) & (reward <= v0 + 0.5)).all()  # coasting on the line: about its speed


def test_a_standing_start_is_at_rest_and_the_accelerate_key_moves_the_car_on(small_track):
    """start_skill 0: the car waits at standstill on the line (reward about 0), and 1 s of the accelerate key
    alone takes the gt3 to a speed a 9.81 m/s^2 car could not beat, forward along the line."""
    core = PixelRacingCore(PixelRacingConfig(track=small_track, frames=False, start="line", start_skill=0.0), seed=0)
    core.reset_cars(core.ids)
    assert core.world.state.vehicle.vx_mps[0] == 0.0
    _, reward, terminated, _, info = core.step(np.zeros((1, 4)))  # no pedal: it stays at rest
    assert not terminated[0] and abs(info["forward_speed_mps"][0]) < 0.05 and abs(reward[0]) < 0.1
    for _ in range(10):
        _, reward, terminated, _, info = core.step(np.array([[1.0, 0.0, 0.0, 0.0]]))
    assert not terminated[0] and 3.0 < info["forward_speed_mps"][0] < 9.81 * 1.1
    assert info["lap_distance_m"][0] > 1.0 and reward[0] > 2.0


def test_crash_states_from_known_states(straight_track):
    spin = math.radians(30.0)
    ok = _world(straight_track, 200.0, 0.0)
    assert crash_state(straight_track, ok.state, np.array([0]), spin)[0] == CRASH_NONE
    kerb = _world(straight_track, 200.0, 5.5)
    assert crash_state(straight_track, kerb.state, np.array([0]), spin)[0] == CRASH_OFF_TRACK
    wall = ok.state._replace(wall_contact=np.array([True]))
    assert crash_state(straight_track, wall, np.array([0]), spin)[0] == CRASH_LARGE_PROP
    turned = _world(straight_track, 200.0, 0.0, heading_offset_rad=math.pi)
    assert crash_state(straight_track, turned.state, np.array([0]), spin)[0] == CRASH_SPINNING
    v = ok.state.vehicle
    sliding = ok.state._replace(vehicle=v._replace(vx_mps=np.array([10.0]), vy_mps=np.array([8.0])))
    assert crash_state(straight_track, sliding, np.array([0]), spin)[0] == CRASH_SPINNING


def test_the_episode_ends_beyond_the_line_distance(small_track):
    core = PixelRacingCore(
        PixelRacingConfig(track=small_track, frames=False, start="line", max_line_distance_m=0.5), seed=0
    )
    core.reset_cars(core.ids)
    lateral = core.observer.line.lateral_at(np.zeros(1)) + 1.5
    core.world.reset(s_m=np.zeros(1), lateral_m=lateral, speed_mps=20.0)
    _, _, terminated, _, info = core.step(np.zeros((1, 4)))
    assert terminated[0] and info["crash_state"][0] == CRASH_NONE and info["line_distance_m"][0] > 0.5


@pytest.mark.parametrize("terminate_on_crash", [True, False])
def test_a_crash_ends_the_episode_only_when_asked_and_costs_beta_per_unit(small_track, terminate_on_crash):
    """A car turned round (crashState 3, spinning) on the line: the paper's next-step rule ends the episode; without
    it the episode goes on and the reward loses beta x 3."""
    config = PixelRacingConfig(
        track=small_track, frames=False, start="line", crash_penalty_beta=2.0, terminate_on_crash=terminate_on_crash
    )
    core = PixelRacingCore(config, seed=0)
    core.reset_cars(core.ids)
    lateral = core.observer.line.lateral_at(np.zeros(1))
    core.world.reset(s_m=np.zeros(1), lateral_m=lateral, speed_mps=5.0, heading_offset_rad=math.pi)
    _, reward, terminated, _, info = core.step(np.zeros((1, 4)))
    assert info["crash_state"][0] == CRASH_SPINNING and terminated[0] == terminate_on_crash
    expected = info["forward_speed_mps"] - info["line_distance_m"] - 2.0 * 3
    np.testing.assert_allclose(reward, expected, rtol=1e-5)


@pytest.mark.parametrize("truncate_when_stuck", [False, True])
def test_a_stuck_car_ends_its_episode_as_a_termination_or_when_asked_a_truncation(small_track, truncate_when_stuck):
    """A car standing on the line with no throttle is stuck by the project's rule (less than 5 m in 5 s) at the 50th
    0.1 s step: a termination by default, a truncation (bootstrapped by a learner) with ``truncate_when_stuck``."""
    config = PixelRacingConfig(
        track=small_track, frames=False, start="line", start_skill=0.0, truncate_when_stuck=truncate_when_stuck
    )
    core = PixelRacingCore(config, seed=0)
    core.reset_cars(core.ids)
    ended_at = None
    for step in range(1, 61):
        _, _, terminated, truncated, info = core.step(np.zeros((1, 4)))
        if terminated[0] or truncated[0]:
            ended_at = step
            break
    assert ended_at == 50 and info["stuck"][0] and info["crash_state"][0] == CRASH_NONE
    assert (terminated[0], truncated[0]) == (not truncate_when_stuck, truncate_when_stuck)


def test_vector_form_resets_finished_cars_in_the_same_step(small_track):
    env = PixelRacingVectorEnv(n_cars=3, seed=1, track=small_track, frames=False, episode_s=0.3)
    try:
        obs, _ = env.reset()
        assert obs["motion"].shape == (3, 15) and obs["goal"].shape == (3, 3)
        for _ in range(2):
            _, reward, _, _, info = env.step(np.zeros((3, 4), np.float32))
            assert reward.shape == (3,) and "final_obs" not in info
        obs, _, _, truncated, info = env.step(np.zeros((3, 4), np.float32))
        assert truncated.all() and info["_final_obs"].all()
        assert env.core.steps.tolist() == [0, 0, 0]  # the new episodes
        assert not np.allclose(info["final_obs"][0]["motion"], obs["motion"][0])
    finally:
        env.close()
