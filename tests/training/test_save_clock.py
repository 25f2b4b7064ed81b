"""When the trainers save: full saves on step multiples, light ones on the minute clock."""

from vision_rl.training import sac
from vision_rl.training.sac import SaveClock, next_multiple


def test_next_multiple_is_the_first_after_and_zero_means_never():
    assert next_multiple(0, 100) == 100 and next_multiple(100, 100) == 200 and next_multiple(150, 100) == 200
    assert next_multiple(150, 0) is None


def test_full_saves_on_step_multiples_light_saves_on_minutes_and_a_save_restarts_the_minutes(monkeypatch):
    now = [0.0]
    monkeypatch.setattr(sac.time, "perf_counter", lambda: now[0])
    clock = SaveClock(start_steps=250, every_steps=100, every_min=1.0)  # a resumed run: the next full is at 300
    assert clock.due(299) is None
    assert clock.due(300) == "full"
    now[0] = 59.0
    assert clock.due(310) is None
    now[0] = 61.0
    assert clock.due(320) == "light"
    now[0] = 100.0
    assert clock.due(400) == "full"  # both due: the full save, which restarts the minutes
    now[0] = 150.0
    assert clock.due(410) is None
    now[0] = 161.0
    assert clock.due(420) == "light"


def test_zero_turns_either_off(monkeypatch):
    now = [0.0]
    monkeypatch.setattr(sac.time, "perf_counter", lambda: now[0])
    steps_only, minutes_only = SaveClock(0, 100, 0.0), SaveClock(0, 0, 1.0)
    now[0] = 1e6
    assert steps_only.due(50) is None and steps_only.due(100) == "full"
    assert minutes_only.due(10**9) == "light"
