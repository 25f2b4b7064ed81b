import numpy as np
import pytest

from vision_rl.sim.ai_driver import DisruptionParams
from vision_rl.sim.driving import line_and_profile
from vision_rl.sim.fleet import AI_CONTROL_DT_S, AIFleet, StuckDetector, StuckRule, ai_ticks
from vision_rl.sim.vehicle import get_preset
from vision_rl.sim.world import World, WorldConfig


def test_stuck_detector_flags_once_per_window_and_never_a_moving_car():
    s_m = np.zeros(2)
    detector = StuckDetector(s_m, dt_s=1.0, rule=StuckRule(window_s=5.0, min_progress_m=5.0))
    flagged = []
    for _ in range(12):
        s_m = s_m + np.array([0.0, 2.0])  # car 0 parked, car 1 at 2 m per step
        stuck = detector.update(s_m)
        flagged.append(list(stuck))
        if len(stuck):
            detector.reset(stuck, s_m)
    # Car 0 after a full window, then again only after a full window since its reset; car 1 never.
    assert [step + 1 for step, ids in enumerate(flagged) if ids] == [5, 10]
    assert all(ids in ([], [0]) for ids in flagged)


def test_driving_backwards_is_stuck():
    detector = StuckDetector(np.zeros(1), dt_s=0.5, rule=StuckRule(window_s=1.0, min_progress_m=5.0))
    detector.update(np.array([-10.0]))
    assert list(detector.update(np.array([-20.0]))) == [0]


def test_held_cars_keep_their_commands_and_contact_flags_cover_the_whole_advance(stadium):
    car = "hatchback"
    line, profile = line_and_profile(stadium, get_preset(car))
    world = World(stadium, car, n_cars=2, config=WorldConfig(control_dt_s=AI_CONTROL_DT_S))
    fleet = AIFleet(world, line, profile, skill=0.9)
    fleet.place(np.arange(2), np.array([10.0, 10.0]))
    # Car 1 held at full left lock on the straight: it reaches the left wall within the 2 s advance.
    fleet.advance(100, held_ids=np.array([1]), held_steer_rad=np.array([0.5]), held_omega=np.array([0.5]))
    st = world.state
    assert st.prev_steer_cmd_rad[1] == pytest.approx(min(0.5, world.car.steer_limit_rad))
    assert st.wall_contact_time_s[1] > 0.0 and st.wall_contact_time_s[0] == 0.0
    # The flag covers the advance even if the car left the wall before its last world step.
    assert st.wall_contact[1]
    assert st.unwrapped_s_m[0] > 10.0 + 30.0  # the AI car drove on


def test_a_fleet_refuses_a_world_slower_than_the_ai(stadium):
    line, profile = line_and_profile(stadium, get_preset("hatchback"))
    with pytest.raises(ValueError, match="acts every"):
        AIFleet(World(stadium, "hatchback", config=WorldConfig(control_dt_s=0.1)), line, profile)


def test_disrupted_fleets_are_reproducible(stadium):
    line, profile = line_and_profile(stadium, get_preset("hatchback"))
    ends = []
    for _ in range(2):
        world = World(stadium, "hatchback", n_cars=3, config=WorldConfig(control_dt_s=AI_CONTROL_DT_S))
        fleet = AIFleet(world, line, profile, skill=0.65, disruption=DisruptionParams(), seed=7)
        fleet.place(np.arange(3), np.array([0.0, 300.0, 600.0]))
        fleet.advance(200)
        ends.append(world.state.vehicle.x_m.copy())
    np.testing.assert_array_equal(ends[0], ends[1])


def test_ai_ticks_of_a_control_step():
    assert [ai_ticks(dt) for dt in (0.02, 0.04, 0.1, 0.3)] == [1, 2, 5, 15]
    assert [ai_ticks(dt) for dt in (0.05, 0.03, 0.01, 0.0)] == [None, None, None, None]
