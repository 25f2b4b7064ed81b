"""`play` headless: SDL's dummy video driver and scripted key events."""

import json

import numpy as np
import pytest

from vision_rl.evaluation.human import (
    ACTION_STEER_LIMIT_RAD,
    FULL_LOCK_BELOW_MPS,
    KEY_STEER_RATE_RADPS,
    KeyboardSteering,
    gamepad_command,
    speed_lock_rad,
)
from vision_rl.overtaking.config import PlayConfig
from vision_rl.overtaking.play import play

pygame = pytest.importorskip("pygame", reason="pygame is not installed: pip install 'vision_rl[play]'")


def test_keyboard_steering_ramps_at_its_rate_to_the_speed_lock_and_recentres():
    steering = KeyboardSteering()
    assert steering.update(True, False, 5.0, 0.1) == pytest.approx(KEY_STEER_RATE_RADPS * 0.1)  # + left
    for _ in range(10):
        steering.update(True, False, 5.0, 0.1)
    assert steering.steer_rad == pytest.approx(ACTION_STEER_LIMIT_RAD)
    fast = 4 * FULL_LOCK_BELOW_MPS
    assert steering.update(True, False, fast, 0.1) == pytest.approx(ACTION_STEER_LIMIT_RAD / 4)  # lock falls as 1/v
    for _ in range(10):
        steering.update(False, False, fast, 0.1)
    assert steering.steer_rad == 0.0
    assert speed_lock_rad(0.0) == pytest.approx(ACTION_STEER_LIMIT_RAD)


def test_gamepad_axes_map_to_steer_and_omega():
    np.testing.assert_allclose(gamepad_command(0.0, -1.0, -1.0, 5.0), [0.0, 0.0])  # nothing pressed
    np.testing.assert_allclose(gamepad_command(1.0, 1.0, -1.0, 5.0), [-ACTION_STEER_LIMIT_RAD, 1.0])  # right, gas
    np.testing.assert_allclose(gamepad_command(-0.5, -1.0, 1.0, 5.0), [0.5 * ACTION_STEER_LIMIT_RAD, -1.0])


def test_scripted_keys_drive_forward_time_the_run_and_record_valid_demonstrations(gl_available, monkeypatch, tmp_path):
    from vision_rl.evaluation.leaderboard import find_evaluations
    from vision_rl.overtaking.demos import demo_fingerprint, load_demos

    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    pygame.init()
    script = iter([[pygame.event.Event(pygame.KEYDOWN, key=pygame.K_UP)]])  # throttle held from the first step
    cfg = PlayConfig(
        name="tester",
        track="technical",
        laps=1,
        time_limit_s=6.0,
        realtime=False,
        window_hw_px=(64, 96),
        runs=str(tmp_path / "runs"),
    )
    result = play(cfg, events=lambda: next(script, []))

    demos = load_demos(result["demos"], demo_fingerprint("technical", "hatchback"))
    assert demos.n_transitions == 59  # 6 s at 10 Hz, the last command's step unfinished
    np.testing.assert_array_equal(demos.actions[:, 1], 1.0)
    np.testing.assert_array_equal(demos.actions[:, 0], 0.0)
    assert demos.rewards.sum() > 100.0  # forward progress, metres
    assert demos.meta["demonstrator"]["alias"] == "tester"

    records, _ = find_evaluations(cfg.runs)
    assert [r["name"] for r in records] == ["human (tester)"]
    assert records[0]["driver"]["driver"] == "human"
    assert "time limit" in result["dnf_reason"]  # 6 s is no lap: a DNF row, timed by the protocol
    assert json.loads((tmp_path / "runs/human/tester-technical-hatchback/evaluation.json").read_text())["n_seeds"] == 1


def test_recorded_actions_replayed_in_the_environment_give_the_recorded_observations(
    gl_available, monkeypatch, tmp_path
):
    from vision_rl.envs.core import RacingCore
    from vision_rl.overtaking.config import race_config
    from vision_rl.overtaking.demos import load_demos

    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    pygame.init()
    keys = [pygame.K_UP, pygame.K_LEFT]
    script = iter([[pygame.event.Event(pygame.KEYDOWN, key=k) for k in keys]])
    cfg = PlayConfig(
        name="replay",
        track="technical",
        laps=1,
        time_limit_s=2.0,
        realtime=False,
        window_hw_px=(64, 96),
        runs=str(tmp_path / "runs"),
    )
    demos = load_demos(play(cfg, events=lambda: next(script, []))["demos"])
    assert demos.actions[5, 0] > 0.0  # steering left

    # The environment starts where the protocol does (seed 0's rolling start), then takes the recorded actions.
    from vision_rl.evaluation.protocol import _start

    core = RacingCore(race_config("technical", "hatchback"), seed=0)
    lateral, speed, _ = _start(core.track, core.car, [0])
    core.world.reset(s_m=np.zeros(1), lateral_m=lateral, speed_mps=speed)
    core.observer.restart(core.world.state)
    obs = [core.observation()[0]]
    rewards = []
    for action in demos.actions[:-1]:
        o, r, *_ = core.step(action[None, :], autoreset=False)
        obs.append(o[0])
        rewards.append(r[0])
    np.testing.assert_allclose(np.stack(obs), demos.observations, atol=1e-4)
    np.testing.assert_allclose(rewards, demos.rewards[:-1], atol=1e-4)


def test_a_person_through_setting_a_is_a_reference_row_of_the_evaluation(gl_available, monkeypatch, tmp_path):
    from vision_rl.overtaking.settings import SettingError, evaluate_overtaking

    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    pygame.init()
    brake = [pygame.event.Event(pygame.KEYDOWN, key=pygame.K_DOWN)]  # held through both runs
    cfg = PlayConfig(
        name="tester",
        track="expressway",
        car="tt_cup",
        setting="A",
        time_limit_s=20.0,
        realtime=False,
        window_hw_px=(64, 96),
        runs=str(tmp_path / "runs"),
    )
    result = play(cfg, events=lambda: brake)
    assert [(r["run"], r["seed"]) for r in result["runs"]] == [(0, 0), (1, 1)] and not result["quit"]
    assert all(r["overtaken"] == 0 and r["end"].startswith("stuck") for r in result["runs"])  # stopped behind
    evaluation = evaluate_overtaking(
        [], "A", runs=2, time_limit_s=20.0, reference=False, humans=[result["setting_json"]]
    )
    (row,) = evaluation["drivers"]
    assert row["name"] == "human (tester)" and row["reference"] and row["runs"] == result["runs"]
    with pytest.raises(SettingError, match="setting A on expressway with the tt_cup, not setting B"):
        evaluate_overtaking([], "B", reference=False, humans=[result["setting_json"]])
    with pytest.raises(ValueError, match="--setting must be one of A, B"):
        play(PlayConfig(name="tester", setting="C"))
