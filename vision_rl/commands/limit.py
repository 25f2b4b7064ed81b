"""`vision-rl limit`: the physical-limit (QSS) lap time of a car on a track, and the racing line's length."""

from __future__ import annotations

from dataclasses import dataclass

from vision_rl.commands.output import emit


@dataclass(frozen=True)
class LimitOptions:
    """Physical-limit lap time of a car on a track: the QSS speed profile on the minimum-curvature line."""

    track: str = "expressway"
    """Track: built-in name, random:SEED or CSV path."""
    car: str = "hatchback"
    """Car preset."""
    json: bool = False
    """Print the figures as JSON."""


def run_limit(opts: LimitOptions) -> int:
    from vision_rl.sim.driving import compute_limit

    emit(compute_limit(opts.track, opts.car), opts.json)
    return 0
