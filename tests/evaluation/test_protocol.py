"""The lap-time protocol: a hand-computed lap, the built-in AI as an outside driver, DNFs, contact accounting."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers.drivers import CRUISE_MPS, CentreLineFollower
from tests.helpers.tracks import STADIUM
from vision_rl.evaluation.leaderboard import leaderboard
from vision_rl.evaluation.protocol import STEP_S, BuiltinAI, time_laps, world_tick_s
from vision_rl.sim.ai_driver import DEFAULT_SKILL, AIDriver
from vision_rl.sim.driving import line_and_profile
from vision_rl.sim.fleet import STUCK_RULE


def test_second_lap_is_scored_and_matches_the_hand_computed_lap(small_track):
    timing = time_laps(CentreLineFollower(), small_track, "hatchback", seeds=[0, 1], laps=2, record=True)
    s = timing.summary()
    expected_s = timing.track.length_m / CRUISE_MPS  # on the centre line at constant speed
    for seed in s["seeds"]:
        assert seed["finished"] and seed["dnf_reason"] is None and len(seed["laps"]) == 2
        scored = seed["laps"][1]
        assert seed["lap_time_s"] == scored["lap_time_s"] == pytest.approx(expected_s, rel=0.01)
        assert scored["wall_contact_s"] == 0.0 and scored["off_track_s"] == 0.0 and seed["clean"]
        assert scored["wall_hits"] == 0 and scored["fastest_wall_hit_kmh"] == 0.0
        assert scored["avg_speed_kmh"] == pytest.approx(3.6 * CRUISE_MPS, rel=0.01)
        assert scored["distance_m"] == pytest.approx(timing.track.length_m, rel=0.01)
    assert s["best_lap_time_s"] == min(x["lap_time_s"] for x in s["seeds"])
    # The run stops once every car has its laps; the trajectory covers it at 10 Hz.
    assert timing.time_s[-1] == pytest.approx(sum(lap["lap_time_s"] for lap in s["seeds"][0]["laps"]), abs=0.15)
    assert timing.x_m.shape == (len(timing.time_s), 2)
    # Rolling start at the built-in AI's speed on the line, jittered per seed by at most 2 %.
    line, profile = line_and_profile(timing.track, timing.car)
    ai_speed = DEFAULT_SKILL * profile.speed_at(line.line_s_at(np.zeros(1)))[0]
    assert np.all(np.abs(timing.start_speed_mps / ai_speed - 1.0) <= 0.02)
    assert timing.start_speed_mps[0] != timing.start_speed_mps[1]


class OutsideAI:
    """The built-in AI's controller called from an outside driver, as a user would wrap their own."""

    control_dt_s = 0.02

    def reset(self, world, car_ids):
        line, profile = line_and_profile(world.track, world.car)
        self.ai = AIDriver(world.car, line, profile, world.n_cars, skill=DEFAULT_SKILL, groups=world.model.groups)

    def act(self, state):
        return np.stack(self.ai.act(state), axis=1)


def test_the_ai_wrapped_as_an_outside_driver_gets_the_ai_rows_lap_time(small_track, tmp_path):
    outside = time_laps(OutsideAI(), small_track, "hatchback", seeds=(0, 1, 2)).summary()
    builtin = time_laps(BuiltinAI(), small_track, "hatchback", seeds=(0, 1, 2)).summary()
    assert outside["seeds"] == builtin["seeds"]
    assert outside["n_finished"] == 3
    table = leaderboard(small_track, "hatchback", str(tmp_path / "no-runs"))
    (ai_row,) = [r for r in table["rows"] if r["kind"] == "ai"]
    assert ai_row["lap_time_s"] == outside["best_lap_time_s"]
    assert ai_row["protocol_version"] == builtin["protocol"]["version"]
    assert ai_row["gap_to_limit_pct"] > 0.0 and ai_row["gap_to_ai_pct"] == 0.0


class Parker:
    """Brakes to a stop and stays there."""

    control_dt_s = STEP_S

    def reset(self, world, car_ids):
        self.n = len(car_ids)

    def act(self, state):
        return np.tile([0.0, -1.0], (self.n, 1))


def test_a_driver_that_stops_is_a_dnf_with_its_reason_not_put_back(small_track):
    timing = time_laps(Parker(), small_track, "hatchback", seeds=[3], laps=2)
    run = timing.runs[0]
    s = timing.summary()
    assert run.laps == [] and s["n_finished"] == 0 and s["best_lap_time_s"] is None and not s["clean"]
    assert run.dnf_reason.startswith("stuck: " + STUCK_RULE.describe())
    # It stopped within a few seconds, was judged over one window and never moved again (no re-placement).
    assert run.time_s < 20.0 and run.distance_m < 100.0
    assert run.time_s == pytest.approx(STUCK_RULE.window_s, abs=8.0)


def test_time_limit_is_a_dnf_and_bad_arguments_are_refused(small_track):
    timing = time_laps(CentreLineFollower(speed_mps=5.0), small_track, "hatchback", seeds=[0], time_limit_s=20.0)
    assert timing.runs[0].dnf_reason.startswith("time limit")
    assert timing.runs[0].time_s == pytest.approx(20.0, abs=0.11)
    with pytest.raises(ValueError, match="whole fraction of it or a whole multiple"):
        odd = CentreLineFollower()
        odd.control_dt_s = 0.03  # neither divides the 0.1 s step nor is a number of 0.02 s ticks
        time_laps(odd, small_track, "hatchback", seeds=[0])
    with pytest.raises(ValueError, match="seeds must differ"):
        time_laps(CentreLineFollower(), small_track, "hatchback", seeds=[1, 1])
    with pytest.raises(ValueError, match="laps"):
        time_laps(CentreLineFollower(), small_track, "hatchback", laps=0)


def test_wall_contact_of_a_car_scraping_the_left_wall_along_the_straight_matches_the_geometry(small_track):
    half_width_m = STADIUM[2]
    straight_m = STADIUM[0]
    # Steered gently to a line 0.5 m from the left wall (closer than half the car) along the bottom straight.
    driver = CentreLineFollower(
        lambda s: np.interp(s, [0, 10, 60, 110, 140], [0, 0, half_width_m - 0.5, half_width_m - 0.5, 0]), 12.0
    )
    timing = time_laps(driver, small_track, "hatchback", seeds=[0], laps=1)
    lap = timing.runs[0].laps[0]
    car = timing.car
    s, lateral, heading = (np.array([seen[k][0] for seen in driver.seen]) for k in range(3))
    # The footprint's reach across the track at its heading (sampled at 10 Hz); touching where it reaches the wall.
    reach = lateral + 0.5 * (car.length_m * np.abs(np.sin(heading)) + car.width_m * np.cos(heading))
    touching = reach >= half_width_m - 1e-3  # a car that reaches the wall is put back exactly onto it
    on_straight = s[touching] < straight_m
    expected_s = STEP_S * touching.sum()
    assert 2.0 < lap.wall_contact_s and on_straight.all()
    assert lap.wall_contact_s == pytest.approx(expected_s, abs=STEP_S + 1e-9)  # within one control step
    assert lap.off_track_s >= lap.wall_contact_s - STEP_S  # against the wall the centre is on the shoulder band
    assert not timing.summary()["clean"]
    # Each run of touching steps begins with a hit, at the 12 m/s the driver holds (a touch may lift for a step).
    begins = int(touching[0]) + int(np.sum(touching[1:] & ~touching[:-1]))
    assert 1 <= begins and abs(lap.wall_hits - begins) <= 1
    assert lap.fastest_wall_hit_kmh == pytest.approx(3.6 * 12.0, abs=2.0)


def test_the_disrupted_ai_leaves_the_line_and_recovers_without_spinning_reproducibly():
    from vision_rl.sim.ai_driver import DisruptionParams

    timing = time_laps(
        BuiltinAI(disruption=DisruptionParams(), seed=0), "technical", "hatchback", seeds=(0, 1), laps=1, record=True
    )
    assert timing.runs[0].laps[0].lap_time_s > 0
    s = timing.summary()
    assert s["n_finished"] == 2, [r.dnf_reason for r in timing.runs]
    track = timing.track
    xy = np.stack([timing.x_m, timing.y_m], axis=-1).reshape(-1, 2)
    proj = track.project(xy)
    heading_deg = np.degrees(
        np.abs(np.mod(timing.yaw_rad.ravel() - track.heading_at(proj.s_m) + np.pi, 2 * np.pi) - np.pi)
    )
    # Measured on this track before the protocol: 28.9 deg at most; a spin (180 deg) is a failure.
    assert 15.0 < heading_deg.max() < 60.0
    left, right = track.width_left_at(proj.s_m), track.width_right_at(proj.s_m)
    share = (proj.lateral_m + right) / (left + right)  # 0 on the right wall, 1 on the left
    assert np.percentile(share, 1) < 0.2 and np.percentile(share, 99) > 0.8  # it uses the whole width
    again = time_laps(BuiltinAI(disruption=DisruptionParams(), seed=0), "technical", "hatchback", seeds=(0, 1), laps=1)
    assert again.summary()["seeds"] == s["seeds"]
    other = time_laps(BuiltinAI(disruption=DisruptionParams(), seed=1), "technical", "hatchback", seeds=(0, 1), laps=1)
    assert other.summary()["seeds"] != s["seeds"]


class HeldTwice:
    """A 0.02 s driver that asks ``inner`` on every other tick and repeats its command in between."""

    control_dt_s = 0.02

    def __init__(self, inner) -> None:
        self.inner, self.ticks, self.command = inner, 0, None

    def reset(self, world, car_ids):
        self.inner.reset(world, car_ids)

    def act(self, state):
        if self.ticks % 2 == 0:
            self.command = self.inner.act(state)
        self.ticks += 1
        return self.command


def test_a_driver_acting_every_004_s_is_asked_every_other_tick_and_its_command_held(small_track):
    slow = CentreLineFollower()
    slow.control_dt_s = 0.04  # not a whole fraction of the 0.1 s step: the world ticks at 0.02 s
    timed = time_laps(slow, small_track, "hatchback", seeds=[0, 1], laps=1, record=True)
    by_hand = HeldTwice(CentreLineFollower())
    held = time_laps(by_hand, small_track, "hatchback", seeds=[0, 1], laps=1, record=True)
    assert [r.laps[0].lap_time_s for r in timed.runs] == [r.laps[0].lap_time_s for r in held.runs]
    np.testing.assert_array_equal(timed.x_m, held.x_m)
    np.testing.assert_array_equal(timed.steer_rad, held.steer_rad)
    # one command per 0.04 s of the run, which lasts as long as its slowest seed
    assert len(slow.seen) == len(by_hand.inner.seen) == pytest.approx(max(r.time_s for r in timed.runs) / 0.04, abs=2)


def test_world_ticks_for_each_driver_step():
    assert world_tick_s(0.1) == (0.1, 1) and world_tick_s(0.02) == (0.02, 1) and world_tick_s(0.05) == (0.05, 1)
    assert world_tick_s(0.04) == (0.02, 2) and world_tick_s(0.06) == (0.02, 3) and world_tick_s(0.2) == (0.02, 10)
    for dt in (0.03, 0.0, -0.1):
        with pytest.raises(ValueError, match="whole multiple"):
            world_tick_s(dt)


class WeavingAtTheWall(CentreLineFollower):
    """At 0.04 s: weaves towards the left wall and back, so its contact starts and ends within held commands."""

    control_dt_s = 0.04

    def __init__(self) -> None:
        super().__init__(target_lateral=lambda s: 4.6 + 1.6 * np.sin(s / 6.0), speed_mps=12.0)
        self.walls_seen: list[np.ndarray] = []

    def act(self, state):
        self.walls_seen.append(state.wall_contact.copy())
        return super().act(state)


def test_a_driver_holding_its_command_sees_the_wall_contact_of_every_tick_since_it_last_acted(small_track, monkeypatch):
    import vision_rl.evaluation.protocol as protocol

    ticks: list[np.ndarray] = []

    class TickRecordingWorld(protocol.World):
        def step(self, *args, **kwargs):
            events = super().step(*args, **kwargs)
            ticks.append(self.state.wall_contact.copy())
            return events

    monkeypatch.setattr(protocol, "World", TickRecordingWorld)
    driver = WeavingAtTheWall()
    time_laps(driver, small_track, "hatchback", seeds=[0], laps=1, time_limit_s=30.0)
    seen = np.array(driver.walls_seen[1:])[:, 0]  # each ask after the first: the two ticks before it
    pairs = np.array(ticks[: 2 * len(seen)]).reshape(len(seen), 2)
    np.testing.assert_array_equal(seen, pairs.any(axis=1))
    assert (pairs[:, 0] & ~pairs[:, 1]).any()  # contacts that ended within a held command were seen, not lost
