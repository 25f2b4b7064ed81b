"""`vision-rl drive`: the built-in AI through the lap-time protocol: lap times, contact, speed, a plot."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

from vision_rl.commands.evaluate import format_timing
from vision_rl.commands.output import emit


@dataclass(frozen=True)
class DriveOptions:
    """Drive the built-in AI (or the straight driver: full throttle, never steering) through the lap-time protocol
    (the rules every lap time of the project follows)."""

    option_choices: ClassVar[dict[str, tuple[str, ...]]] = {"driver": ("ai", "straight")}

    track: str = "expressway"
    """Track: built-in name, random:SEED or CSV path."""
    car: str = "hatchback"
    """Car preset."""
    driver: str = "ai"
    """Who drives: ai (the built-in AI) or straight (full throttle, the wheels straight: the floor a learner must
    beat); policies are driven by `evaluate`."""
    skill: float = field(default=0.0, metadata={"max": 1.0})
    """Share of the limit speed profile the AI aims for, in (0, 1] (0: the AI's default, 0.92; 0.65 disrupted)."""
    laps: int = 2
    """Consecutive laps; the last one is scored (the papers: 2)."""
    seeds: int = 3
    """Start seeds (one car each, driven at once)."""
    seed: int = 0
    """First seed."""
    disrupt: bool = False
    """Add the data-collection disruptions (random command offsets)."""
    plot: str = ""
    """Write a PNG of the walls and the best seed's scored lap, coloured by speed."""
    json: bool = False
    """Print the figures as JSON."""


def run_drive(opts: DriveOptions) -> int:
    from vision_rl.evaluation.leaderboard import evaluation_record
    from vision_rl.evaluation.outputs import format_lap_time, plot_trajectory
    from vision_rl.evaluation.protocol import BuiltinAI, StraightDriver, time_laps
    from vision_rl.sim.ai_driver import DisruptionParams

    if opts.driver not in DriveOptions.option_choices["driver"]:
        raise ValueError(f"--driver {opts.driver!r}: ai or straight are built in; policies are driven by `evaluate`")
    if opts.driver == "straight" and (opts.skill or opts.disrupt):
        raise ValueError("--skill and --disrupt are the built-in AI's: the straight driver has neither")
    if opts.seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {opts.seeds}")
    if opts.driver == "straight":
        driver, name = StraightDriver(), "straight driver"
    else:
        disruption = DisruptionParams() if opts.disrupt else None
        driver = BuiltinAI(opts.skill or None, disruption, seed=opts.seed)
        name = "built-in AI" + (" (disrupted)" if opts.disrupt else "")
    timing = time_laps(
        driver, opts.track, opts.car, range(opts.seed, opts.seed + opts.seeds), opts.laps, record=bool(opts.plot)
    )
    result: dict[str, Any] = evaluation_record(timing, driver.identity, name)
    if opts.plot:
        best = timing.best_index()
        who = f"AI skill {driver.skill:g}" if isinstance(driver, BuiltinAI) else "straight driver"
        title = (
            f"{timing.track.name}, {timing.car.name}, {who}: lap {opts.laps} "
            f"{format_lap_time(result['best_lap_time_s'])}"
        )
        result["plot"] = str(plot_trajectory(timing, best, opts.plot, title))
    emit(result, opts.json, format_timing)
    return 0
