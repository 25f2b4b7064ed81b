"""The environments on a small track: reward signs, wrap-around, autoreset, determinism, SB3 (the checkers on every
registered id: test_registration.py)."""

import dataclasses

import gymnasium as gym
import numpy as np
import pytest

from vision_rl.envs import RacingConfig, RacingCore, make_vector_env
from vision_rl.envs.racing_env import TimeTrial

TRACK = "technical"


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("VISION_RL_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def _core(**kw) -> RacingCore:
    return RacingCore(RacingConfig(track=TRACK, normalize=False, **kw), seed=0)


def test_forward_progress_is_positive_and_reversing_negative():
    core = _core(n_groups=2)
    core.reset_groups(np.arange(2))
    core.world.reset(s_m=np.array([100.0, 300.0]), speed_mps=np.array([20.0, -8.0]))
    _, reward, *_ = core.step(np.array([[0.0, 0.0], [0.0, 0.0]]), autoreset=False)
    assert reward[0] > 1.0  # ~2 m of progress in 0.1 s at 20 m/s
    assert reward[1] < -0.5  # rolling backwards


def _circle_csv(path, radius_m=100.0, half_width_m=6.0):
    a = np.linspace(0.0, 2 * np.pi, 300, endpoint=False)
    rows = np.stack(
        [radius_m * np.cos(a), radius_m * np.sin(a), np.full(300, half_width_m), np.full(300, half_width_m)]
    )
    np.savetxt(path, rows.T, delimiter=",", header="x_m,y_m,w_tr_right_m,w_tr_left_m")
    return str(path)


def _follow_centre_line(core: RacingCore, speed_mps: float) -> np.ndarray:
    """Pure pursuit of the centre line 12 m ahead at a constant speed: actions (M, 2)."""
    st, track = core.world.state, core.track
    v = st.vehicle
    target = track.position_at(st.s_m + 12.0)
    alpha = np.arctan2(target[:, 1] - v.y_m, target[:, 0] - v.x_m) - v.yaw_rad
    steer = np.arctan(2 * core.car.wheelbase_m * np.sin(alpha) / 12.0)
    omega = np.clip(0.5 * (speed_mps - np.hypot(v.vx_mps, v.vy_mps)), -1, 1)
    return np.stack([steer, omega], axis=1)[core.ego_ids]


def test_one_lap_through_the_start_line_sums_to_the_lap_length(tmp_path):
    core = RacingCore(RacingConfig(track=_circle_csv(tmp_path / "circle.csv"), normalize=False, episode_s=1000), 0)
    core.reset_groups(np.array([0]))
    core.world.reset(s_m=core.track.length_m - 30.0, speed_mps=12.0)
    total = 0.0
    for _ in range(2000):
        _, reward, _, _, infos = core.step(_follow_centre_line(core, 12.0), autoreset=False)
        total += reward[0]
        if core.progress_m[0] >= core.track.length_m:
            break
    assert core.world.state.wall_contact_time_s[0] == 0.0
    assert core.progress_m[0] == pytest.approx(core.track.length_m, abs=2.0)  # one lap, crossing s = 0 once
    assert total == pytest.approx(core.progress_m[0], abs=0.02)  # rewards are float32
    assert infos[0]["lap_times_s"] == []  # the line was crossed once: timing started, no full lap yet


def test_wall_penalty_only_in_contact():
    core = _core(n_groups=1)
    core.reset_groups(np.array([0]))
    core.world.reset(s_m=50.0, speed_mps=25.0, heading_offset_rad=0.6)  # aimed at the left wall
    penalised = False
    for _ in range(20):
        s_prev = core.world.state.s_m[0]
        _, reward, _, _, _ = core.step(np.array([[0.0, 0.0]]), autoreset=False)
        progress = core.track.progress_delta(s_prev, core.world.state.s_m[0])
        if core.world.state.wall_contact[0]:
            v = core.world.state.vehicle
            speed2 = v.vx_mps[0] ** 2 + v.vy_mps[0] ** 2
            assert reward[0] == pytest.approx(progress - 0.005 * speed2, rel=1e-5)
            penalised = True
        else:
            assert reward[0] == pytest.approx(progress, rel=1e-5)
    assert penalised


@pytest.mark.parametrize("terminate_on_wall", [False, True])
def test_a_wall_ends_the_episode_only_when_asked(terminate_on_wall):
    core = _core(n_groups=1, terminate_on_wall=terminate_on_wall)
    core.reset_groups(np.array([0]))
    core.world.reset(s_m=50.0, speed_mps=25.0, heading_offset_rad=0.6)  # aimed at the left wall
    free_steps = 0
    while not core.world.state.wall_contact[0] and core.steps[0] < 20:
        _, _, terminated, truncated, _ = core.step(np.array([[0.0, 0.0]]), autoreset=False)
        assert terminated[0] == (terminate_on_wall and core.world.state.wall_contact[0])
        free_steps += not core.world.state.wall_contact[0]
    assert core.world.state.wall_contact[0] and free_steps > 0  # it drove a while before the wall
    assert not truncated[0]


def _place_one_standing_one_driving(core: RacingCore, stand_at_m: float) -> None:
    """Car 0 at rest at ``stand_at_m``, car 1 at 10 m/s at 300 m; the stuck rule judges both from there."""
    core.reset_groups(np.arange(2))
    core.world.reset(s_m=np.array([stand_at_m, 300.0]), speed_mps=np.array([0.0, 10.0]))
    core.stuck.reset(np.arange(2), core.world.state.unwrapped_s_m[core.ego_ids])


def _stand_and_drive(core: RacingCore) -> np.ndarray:
    """Actions: car 0 on the brake, car 1 along the centre line at 10 m/s."""
    return np.array([[0.0, -1.0], _follow_centre_line(core, 10.0)[1]])


@pytest.mark.parametrize("terminate_when_stuck", [False, True])
def test_a_stuck_car_ends_its_episode_only_when_asked(terminate_when_stuck):
    # Car 0 stands on the brake (stuck: under 5 m in 5 s), car 1 drives on; only car 0's episode may end, at the
    # first step after 5 s, and autoreset places it anew.
    core = _core(n_groups=2, terminate_when_stuck=terminate_when_stuck)
    _place_one_standing_one_driving(core, 50.0)
    ended_at = None
    for step in range(1, 81):
        _, _, terminated, truncated, infos = core.step(_stand_and_drive(core), autoreset=True)
        assert not terminated[1] and not truncated.any()
        if terminated[0]:
            ended_at = step
            assert "final_info" in infos[0] and core.steps[0] == 0  # placed anew
            break
    assert ended_at == (round(5.0 / core.config.control_dt_s) if terminate_when_stuck else None)


def _stand_until_stuck(core: RacingCore, stand_at_m: float) -> None:
    """Car 0 stands on the brake at ``stand_at_m`` until the stuck rule ends its episode; car 1 drives on."""
    _place_one_standing_one_driving(core, stand_at_m)
    for _ in range(round(5.0 / core.config.control_dt_s)):
        _, _, terminated, _, _ = core.step(_stand_and_drive(core), autoreset=True)
    assert terminated.tolist() == [True, False]


@pytest.mark.parametrize("share", [1.0, 0.5])
def test_a_share_of_starts_lies_before_where_a_car_got_stuck(share):
    # The stuck point is 40 m past the line, so a start up to 120 m before it wraps round to the end of the lap.
    core = _core(n_groups=2, terminate_when_stuck=True, restart_before_stuck_share=share, restart_before_stuck_m=120.0)
    length_m = core.track.length_m
    _stand_until_stuck(core, 40.0)
    np.testing.assert_allclose(core.stuck_points_s_m, [40.0], atol=0.1)
    back_m = []
    for _ in range(200):
        core.reset_groups(np.array([0]))
        back_m.append((40.0 - core.world.state.s_m[0]) % length_m)
    before = np.asarray(back_m) <= 120.0
    if share == 1.0:
        assert before.all() and np.ptp(back_m) > 90.0  # spread over the 120 m, not one place
        assert (np.asarray(back_m) > 40.0).any()  # some before the line
    else:
        assert 0.35 < before.mean() < 0.65  # the rest uniformly over the lap (120 m of it: under 10 %)


def test_starts_before_stuck_points_need_stuck_ends_and_keep_nothing_when_off():
    with pytest.raises(ValueError, match="use terminate_when_stuck"):
        RacingConfig(restart_before_stuck_share=0.5)
    with pytest.raises(ValueError, match="within \\[0, 1\\]"):
        RacingConfig(terminate_when_stuck=True, restart_before_stuck_share=1.5)
    off = _core(n_groups=2, terminate_when_stuck=True)
    _stand_until_stuck(off, 40.0)
    assert len(off.stuck_points_s_m) == 0


def test_overtaking_reward_and_info_on_setting_a():
    core = _core(n_groups=1, scenario="setting_a", observation="overtaking")
    obs, info = None, None
    core.reset_groups(np.array([0]))
    assert core.world.n_cars == 6
    gaps = core._gaps()[0]
    np.testing.assert_allclose(gaps, [50, 100, 150, 200, 250], atol=1.0)
    for _ in range(5):
        obs, _reward, _, _, infos = core.step(np.array([[0.0, 1.0]]), autoreset=False)
    info = infos[0]
    assert obs.shape == (1, 96)
    assert {"travel_time_s", "travel_distance_m", "car_contact_s", "wall_contact_s", "overtaken"} <= set(info)
    assert info["overtaken"] == 0
    assert np.all(obs[0, 7:79] <= 20.0 + 1e-9)


def test_opponents_act_at_the_ai_rate_and_stay_off_the_walls():
    core = _core(scenario="setting_b", n_groups=2)
    # 10 Hz agents, 50 Hz built-in AI: the world steps at the AI's rate, the egos' commands held over 5 steps.
    assert core.world_steps == 5 and core.world.model.config.control_dt_s == pytest.approx(0.02)
    core.reset_groups(np.arange(2))
    for _ in range(300):  # 30 s; the egos hold their lane at a crawl, the opponents race ahead
        core.step(np.array([[0.0, 0.1], [0.0, 0.1]]), autoreset=False)
    opponents = np.flatnonzero(np.arange(core.world.n_cars) % core.group_size != 0)
    assert core.world.state.time_s[0] == pytest.approx(30.0)
    # Acting at 10 Hz, one opponent here scraped a wall for 20 s; at 50 Hz the ten touch for 0.3 s in all.
    assert core.world.state.wall_contact_time_s[opponents].sum() < 1.0


def test_autoreset_gives_a_fresh_observation_and_final_observation():
    env = make_vector_env(RacingConfig(track=TRACK, n_groups=3, episode_s=0.3), seed=1)
    env.reset()
    for _ in range(2):
        _obs, _, terminated, truncated, info = env.step(np.zeros((3, 2), dtype=np.float32))
        assert not (terminated | truncated).any()
    new_obs, _, terminated, truncated, info = env.step(np.zeros((3, 2), dtype=np.float32))
    assert truncated.all() and not terminated.any()
    assert info["_final_obs"].all()
    # The returned observation starts a new episode somewhere else; the final one continues the old episode.
    assert not np.allclose(new_obs, info["final_obs"][0])
    assert env.core.steps.tolist() == [0, 0, 0]


def test_same_seed_same_rollout():
    def rollout(seed):
        env = make_vector_env(RacingConfig(track=TRACK, n_groups=4), seed=seed)
        obs, _ = env.reset()
        rng = np.random.default_rng(0)
        out = [obs]
        for _ in range(20):
            obs, reward, *_ = env.step(rng.uniform(-0.3, 0.3, (4, 2)).astype(np.float32))
            out += [obs, reward]
        return out

    a, b, c = rollout(7), rollout(7), rollout(8)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(a[0], c[0])


def test_observation_normalisation_is_cached_and_reused(tmp_path, monkeypatch):
    monkeypatch.setenv("VISION_RL_CACHE", str(tmp_path))
    first = RacingCore(RacingConfig(track=TRACK), seed=0).observer.normalizer
    files = list((tmp_path / "obs_stats").glob("*.json"))
    assert len(files) == 1
    second = RacingCore(RacingConfig(track=TRACK), seed=5).observer.normalizer
    np.testing.assert_array_equal(first.offset, second.offset)
    files[0].write_text("{not json")
    third = RacingCore(RacingConfig(track=TRACK), seed=0).observer.normalizer
    np.testing.assert_allclose(third.offset, first.offset)
    # Computed first by an environment of 0.04 s steps, the statistics are those of the 0.1 s one.
    files[0].unlink()
    finer = RacingCore(RacingConfig(track=TRACK, control_dt_s=0.04), seed=0).observer.normalizer
    np.testing.assert_array_equal(finer.offset, first.offset)
    np.testing.assert_array_equal(finer.scale, first.scale)


@pytest.mark.parametrize("env_id", ["vision_rl/TimeTrial-v1", "vision_rl/Overtaking-v1"])
def test_same_seed_same_episode_in_every_env_builder(env_id):
    from vision_rl.envs import make_sb3_vec_env

    single = gym.make(env_id, track=TRACK).unwrapped
    config = dataclasses.replace(single.config, n_groups=3)
    actions = np.random.default_rng(0).uniform(-1.0, 1.0, (200, 3, 2)) * np.array([0.1, 1.0])

    def first_group(reset, step) -> np.ndarray:
        out = [np.asarray(reset())]
        for a in actions:
            out.append(np.asarray(step(a)))
        return np.stack(out)

    runs = {
        "gym.make": first_group(lambda: single.reset(seed=3)[0], lambda a: single.step(a[0])[0]),
    }
    vec = make_vector_env(config, seed=3)
    runs["make_vector_env(seed)"] = first_group(lambda: vec.reset()[0][0], lambda a: vec.step(a)[0][0])
    vec = make_vector_env(config)
    runs["reset(seed)"] = first_group(lambda: vec.reset(seed=3)[0][0], lambda a: vec.step(a)[0][0])
    sb3 = make_sb3_vec_env(config)
    sb3.seed(3)

    def sb3_step(a):
        sb3.step_async(a)
        return sb3.step_wait()[0][0]

    runs["make_sb3_vec_env"] = first_group(lambda: sb3.reset()[0], sb3_step)
    reference = runs.pop("gym.make")
    assert reference.shape[0] == 201
    for name, obs in runs.items():
        np.testing.assert_array_equal(obs, reference, err_msg=name)
    other = make_vector_env(config, seed=4).reset()[0][0]
    assert not np.array_equal(other, reference[0])


def test_vision_observation_without_renderer_is_a_clear_error(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "vision_rl.render", None)
    env = TimeTrial(track=TRACK, observation="vision")
    with pytest.raises(RuntimeError, match="renderer"):
        env.reset(seed=0)


def test_unknown_argument_is_rejected():
    with pytest.raises(TypeError, match="unknown argument"):
        TimeTrial(track=TRACK, wheels=3)
    with pytest.raises(ValueError, match="scenario"):
        RacingConfig(scenario="drag_race")


def test_sb3_sac_runs_2000_steps_on_the_vector_env():
    torch = pytest.importorskip("torch")
    from stable_baselines3 import SAC

    from vision_rl.envs import make_sb3_vec_env

    torch.set_num_threads(1)
    venv = make_sb3_vec_env(RacingConfig(track=TRACK, n_groups=20, episode_s=5.0), seed=0)
    model = SAC(
        "MlpPolicy",
        venv,
        batch_size=64,
        learning_starts=200,
        train_freq=1,
        gradient_steps=1,
        policy_kwargs={"net_arch": [32, 32]},
        seed=0,
        device="cpu",
    )
    model.learn(total_timesteps=2000)
    assert model.num_timesteps >= 2000
    assert model.replay_buffer.size() * 20 >= 2000  # one row per step holds all 20 envs
    obs = venv.reset()
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (20, 2)
    assert dataclasses.asdict(venv.config)["n_groups"] == 20


def test_the_off_track_penalty_charges_the_steps_that_end_beyond_the_edge_line():
    core = _core(n_groups=1, wall_penalty_c_w=0.0, off_track_penalty_c_o=0.01)
    core.reset_groups(np.array([0]))
    core.world.reset(s_m=50.0, speed_mps=25.0, heading_offset_rad=0.3)  # drifting left across the edge line
    charged = 0
    for _ in range(20):
        s_prev = core.world.state.s_m[0]
        _, reward, _, _, _ = core.step(np.array([[0.0, 0.0]]), autoreset=False)
        st = core.world.state
        progress = core.track.progress_delta(s_prev, st.s_m[0])
        side_m = st.lateral_m[0] + 0.5 * core.car.width_m  # drifting left: the body's left side
        beyond = core.track.beyond_edge_line(st.s_m[:1], np.array([side_m]))[0]
        # by hand: 5 m to the wall here, the edge line 15 % of that (0.75 m) inside it
        assert core.track.width_left_at(st.s_m[:1])[0] == 5.0 and beyond == (side_m > 5.0 - 0.75)
        speed2 = st.vehicle.vx_mps[0] ** 2 + st.vehicle.vy_mps[0] ** 2
        assert reward[0] == pytest.approx(progress - 0.01 * beyond * speed2, rel=1e-5, abs=1e-5)
        charged += bool(beyond)
    assert 0 < charged < 20  # on the track at first, then beyond the line
    with pytest.raises(ValueError, match="penalty weights"):
        _core(n_groups=1, off_track_penalty_c_o=-0.1)
