"""World input faults: World.reset and World.step refuse poses, speeds, commands and car ids they cannot use, with
one line that names the argument, the car and the value; the world is left as it was."""

from __future__ import annotations

import numpy as np
import pytest

from vision_rl.sim.track import Track
from vision_rl.sim.world import World, WorldInputError


@pytest.fixture(scope="module")
def world() -> World:
    a = np.linspace(0.0, 2 * np.pi, 300, endpoint=False)
    track = Track.from_centre_line("ring", 150.0 * np.stack([np.cos(a), np.sin(a)], axis=1), 6.0, 6.0)
    return World(track, "hatchback", n_cars=3)


#: what was tried: (keyword arguments of World.reset, text the message must hold)
BAD_RESETS = {
    "NaN arc length": ({"s_m": np.array([0.0, np.nan, 20.0])}, "s_m[1] = nan is not a finite number"),
    "infinite lateral offset": ({"s_m": 0.0, "lateral_m": np.inf}, "lateral_m = inf is not a finite number"),
    "NaN speed": ({"s_m": 0.0, "speed_mps": np.array([1.0, 2.0, np.nan])}, "speed_mps[2] = nan"),
    "-inf heading offset": ({"s_m": 0.0, "heading_offset_rad": -np.inf}, "heading_offset_rad = -inf"),
    "poses of the wrong length": ({"s_m": np.zeros(2)}, "s_m must be a number or an array of shape (3,)"),
    "a 2-D array of poses": ({"s_m": np.zeros((3, 1))}, "got shape (3, 1)"),
    "text for a pose": ({"s_m": "ten"}, "s_m must be a number or an array of numbers"),
    "a lateral offset beyond the wall": (
        {"s_m": 10.0, "lateral_m": np.array([0.0, -7.5, 1.0])},
        "lateral_m[1] = -7.50 m puts car 1 outside the right wall, 6.00 m",
    ),
    "a speed in km/h (300)": ({"s_m": 0.0, "speed_mps": 300.0}, "speed_mps[0] = 300 is beyond +-150 m/s"),
    "a car id out of range": ({"s_m": 0.0, "car_ids": [0, 3]}, "car_ids[1] = 3 is not a car of this world (0..2)"),
    "a negative car id": ({"s_m": 0.0, "car_ids": [-1]}, "car_ids[0] = -1 is not a car"),
    "a car listed twice": ({"s_m": 0.0, "car_ids": [1, 1]}, "car_ids lists a car twice"),
    "a fractional car id": ({"s_m": 0.0, "car_ids": [0.5]}, "car_ids must be a 1-D array of integer car indices"),
}


@pytest.mark.parametrize("case", list(BAD_RESETS))
def test_bad_reset_is_refused(fault, world, case):
    kwargs, expected = BAD_RESETS[case]
    before = world.state
    with pytest.raises(WorldInputError) as err:
        world.reset(**kwargs)
    assert expected in str(err.value), str(err.value)
    assert isinstance(err.value, ValueError) and world.state is before
    fault.refused(f"World.reset with {case}", str(err.value))


#: what was tried: (steer, omega, control_steps, text the message must hold)
BAD_STEPS = {
    "a NaN steering command": (np.array([0.0, np.nan, 0.0]), 0.5, 1, "steer_cmd_rad[1] = nan is not a finite"),
    "an infinite throttle command": (0.0, np.array([0.2, 0.2, np.inf]), 1, "omega_cmd[2] = inf is not a finite"),
    "commands for 2 of 3 cars": (np.zeros(2), 0.0, 1, "steer_cmd_rad must be a number or an array of shape (3,)"),
    "zero control steps": (0.0, 0.0, 0, "control_steps must be an integer >= 1, got 0"),
    "a fractional control step count": (0.0, 0.0, 1.5, "control_steps must be an integer >= 1, got 1.5"),
}


@pytest.mark.parametrize("case", list(BAD_STEPS))
def test_bad_step_is_refused(fault, world, case):
    steer, omega, steps, expected = BAD_STEPS[case]
    world.reset(s_m=np.array([0.0, 50.0, 100.0]), speed_mps=10.0)
    before = world.state
    with pytest.raises(WorldInputError) as err:
        world.step(steer, omega, steps)
    assert expected in str(err.value), str(err.value)
    assert world.state is before
    fault.refused(f"World.step with {case}", str(err.value))


def test_out_of_range_commands_are_clipped_not_refused(fault, world):
    world.reset(s_m=np.array([0.0, 50.0, 100.0]), speed_mps=10.0)
    world.step(np.array([5.0, -5.0, 0.0]), np.array([3.0, -3.0, 0.0]))
    assert np.all(np.abs(world.state.prev_steer_cmd_rad) <= np.pi / 6 + 1e-12)
    assert np.isfinite(np.asarray(world.state.vehicle)).all()
    fault.recovered("steering of 5 rad and throttle of 3 (beyond the action box)", "clipped to +-pi/6 and +-1")
