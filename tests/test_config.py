"""vision_rl.config: the options a resumed run would ignore, and the ranges an option may take."""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest

from vision_rl.config import Bounds, above, at_least, check_option_bounds, nested, resume_conflicts


@dataclass(frozen=True)
class _Inner:
    track: str = "expressway"
    gamma: float = 0.99
    hidden_units: tuple[int, ...] = (256, 256)


@dataclass(frozen=True)
class _Outer:
    steps: int = 100
    inner: _Inner = nested(_Inner())


def test_an_option_set_away_from_default_and_from_the_run_is_reported():
    kept = {"track": "hairpin", "gamma": 0.98, "hidden_units": [64, 64]}  # as JSON holds them
    names = ("track", "gamma", "hidden_units")
    assert resume_conflicts(_Outer(), kept, names) == []  # left at their defaults: the run's own apply
    same = _Outer(inner=_Inner(track="hairpin", gamma=0.98, hidden_units=(64, 64)))
    assert resume_conflicts(same, kept, names) == []  # the run's own values, a JSON list against a tuple
    other = _Outer(steps=5, inner=_Inner(track="stadium", hidden_units=(32,)))
    assert resume_conflicts(other, kept, names) == [
        "--track 'stadium' (the run's: 'hairpin')",
        "--hidden-units (32,) (the run's: [64, 64])",
    ]
    assert resume_conflicts(other, {}, names) == []  # a run older than a setting does not name it


def test_bounds_hold_their_ends_as_said_and_never_nan():
    assert 0 in at_least(0) and -1e-9 not in at_least(0)
    assert 0 not in above(0) and 1e-9 in above(0)
    gamma = Bounds(0, 1, high_open=True)
    assert 0 in gamma and 0.999 in gamma and 1 not in gamma
    assert math.nan not in Bounds() and math.nan not in at_least(0)
    assert [str(b) for b in (at_least(1), above(0), Bounds(0, 1, high_open=True), Bounds(high=0), Bounds())] == [
        "at least 1",
        "more than 0",
        "at least 0 and less than 1",
        "at most 0",
        "any number",
    ]


def test_the_first_option_out_of_range_is_named_with_its_range():
    bounds = {"cars": Bounds(1, 1000), "gamma": Bounds(0, 1, high_open=True)}
    check_option_bounds({"cars": 1000, "gamma": 0.0}, bounds)
    with pytest.raises(ValueError, match=r"^--cars 0 is out of range: at least 1 and at most 1000$"):
        check_option_bounds({"cars": 0, "gamma": 1.0}, bounds)
    with pytest.raises(ValueError, match=r"^--gamma 1.0 is out of range: at least 0 and less than 1$"):
        check_option_bounds({"cars": 4, "gamma": 1.0}, bounds)
