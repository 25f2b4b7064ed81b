"""vision_rl.config: the options a resumed run would ignore."""

from __future__ import annotations

from dataclasses import dataclass

from vision_rl.config import nested, resume_conflicts


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
