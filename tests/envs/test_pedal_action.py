"""The pedal map: hand-computed commands, the AI's labels asking for its own pedal, the environment and a protocol
driver accelerating (and steering, with a speed-scaled steering step) alike."""

import numpy as np
import pytest

from vision_rl.envs.core import RacingConfig, RacingCore, action_for_pedal, pedal_command
from vision_rl.training.artifact import PolicyDriver


def test_pedal_command_by_hand():
    # full travel from 0.9 on, either way; half of it at 0.45; the papers' map is the entry itself, clipped
    np.testing.assert_allclose(
        pedal_command(np.array([0.95, 0.9, 0.45, -0.9, -2.0, 0.0]), 0.9), [1.0, 1.0, 0.5, -1.0, -1.0, 0.0]
    )
    np.testing.assert_allclose(pedal_command(np.array([0.97, -0.3, 1.4]), 1.0), [0.97, -0.3, 1.0])


def test_a_label_asks_for_the_ais_pedal_and_full_travel_for_the_end_of_the_range():
    omega = np.array([1.0, 0.5, -1.0, -0.3, 0.0, 1.2])
    label = action_for_pedal(omega, 0.9)
    np.testing.assert_allclose(label, [1.0, 0.45, -1.0, -0.27, 0.0, 1.0])
    np.testing.assert_allclose(pedal_command(label, 0.9), np.clip(omega, -1, 1))
    np.testing.assert_allclose(action_for_pedal(omega, 1.0), np.clip(omega, -1, 1))  # the papers' map


@pytest.mark.parametrize("pedal_full_at", [0.0, -0.5, 1.01])
def test_a_pedal_map_outside_0_1_is_refused(pedal_full_at):
    with pytest.raises(ValueError, match="pedal_full_at must be within"):
        RacingConfig(pedal_full_at=pedal_full_at)


def _speed_after(pedal_full_at: float, throttle_entry: float, steps: int = 30) -> np.ndarray:
    core = RacingCore(
        RacingConfig(track="expressway", n_groups=1, pedal_full_at=pedal_full_at, normalize=False), seed=0
    )
    core.reset_groups(np.array([0]))
    core.world.reset(s_m=np.array([2500.0]), lateral_m=np.array([0.0]), speed_mps=np.array([30.0]), car_ids=[0])
    for _ in range(steps):  # 3 s down the straight before the chicane, wheel straight
        core.step(np.array([[0.0, throttle_entry]]), autoreset=False)
    v = core.world.state.vehicle
    return np.hypot(v.vx_mps, v.vy_mps)


def test_an_entry_beyond_the_full_travel_point_accelerates_as_full_throttle_does():
    full = _speed_after(1.0, 1.0)
    np.testing.assert_array_equal(_speed_after(0.9, 0.93), full)
    # The same entry on the papers' map leaves 7 % of the throttle unused: a slower car after 3 s.
    assert _speed_after(1.0, 0.93)[0] < full[0] - 0.1


def test_a_policy_drives_the_protocol_with_the_pedal_map_and_steering_steps_it_trained_with():
    cfg = RacingConfig(
        track="technical",
        n_groups=2,
        pedal_full_at=0.8,
        steer_action="rate_scaled",
        steer_change_share_of_range=0.5,
        normalize=False,
    )
    trained = RacingCore(cfg, seed=2)
    trained.reset_groups(np.arange(2))
    replayed = RacingCore(RacingConfig(track="technical", n_groups=2, normalize=False), seed=2)
    replayed.reset_groups(np.arange(2))
    rng = np.random.default_rng(0)
    actions = np.stack([rng.uniform(-0.5, 0.5, (20, 2)), rng.uniform(-1.0, 1.0, (20, 2))], axis=-1)  # (steps, cars, 2)
    queue = list(actions)
    driver = PolicyDriver.for_config(lambda obs: queue.pop(0), "state", None, None, cfg)
    driver.reset(replayed.world, replayed.ego_ids)
    for a in actions:
        trained.step(a, autoreset=False)
        replayed.step(driver.act(replayed.world.state), autoreset=False)  # omega itself on the papers' map
    for name in ("x_m", "y_m", "vx_mps", "steer_rad", "omega"):
        np.testing.assert_array_equal(
            getattr(replayed.world.state.vehicle, name), getattr(trained.world.state.vehicle, name)
        )
    assert np.abs(trained.world.state.vehicle.omega).max() > 0.0  # the pedals did move
    driver.close()


def test_the_ais_labels_ask_the_pedal_map_for_the_ais_own_pedal():
    core = RacingCore(RacingConfig(track="expressway", n_groups=3, pedal_full_at=0.9, normalize=False), seed=1)
    core.reset_groups(np.arange(3))
    core.label_with_ai(1.0)
    asked, given = [], []
    for _ in range(60):
        labels = core.ai_actions()
        _, omega = core.labeller.act(core.world.state)
        asked.append(pedal_command(labels[:, 1], 0.9))
        given.append(np.clip(omega[core.ego_ids], -1.0, 1.0))
        core.step(labels, autoreset=False)
    np.testing.assert_allclose(np.array(asked), np.array(given), atol=1e-12)
    assert np.isclose(np.array(asked), 1.0).any() and (np.abs(np.array(asked)) < 0.99).any()  # full and partial
