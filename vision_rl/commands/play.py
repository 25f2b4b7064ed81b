"""`play`: drive the protocol's laps yourself; a leaderboard row "human (alias)" and a demonstrations file."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, ClassVar

from vision_rl.commands.choices import SETTINGS
from vision_rl.commands.output import emit
from vision_rl.overtaking.config import PlayConfig


@dataclass(frozen=True)
class PlayOptions(PlayConfig):
    """Drive with keyboard (arrows or WASD, Escape quits) or gamepad in a pygame window (chase or hood camera); the
    lap is timed by the one protocol and shows on the leaderboard as "human (alias)"; the drive is saved as
    demonstrations for the imitation baselines."""

    option_choices: ClassVar[dict[str, tuple[str, ...]]] = {"setting": ("", *SETTINGS)}

    json: bool = False
    """Print the result as JSON."""


def format_play(result: dict[str, Any]) -> list[str]:
    from vision_rl.evaluation.outputs import format_lap_time

    if result.get("setting"):
        lines = [f"{result['name']} in setting {result['setting']}: {len(result['runs'])} runs"]
        for run in result["runs"]:
            lines.append(
                f"  run {run['run']} (seed {run['seed']}): {run['overtaken']}/5 overtaken in "
                f"{run['travel_time_s']:.1f} s, car contact {run['car_contact_s']:.1f} s, wall "
                f"{run['wall_contact_s']:.1f} s ({run['end']})"
            )
        if result.get("setting_json"):
            lines.append(f"row: {result['setting_json']} (evaluate-overtaking --human)")
        return [*lines, "ended by the player"] if result["quit"] else lines

    lines = [f"{result['name']}: {result['n_transitions']} transitions recorded"]
    if result.get("demos"):
        lines.append(f"demonstrations: {result['demos']}")
    if result.get("quit"):
        return [*lines, "ended by the player before the protocol's laps: no leaderboard row"]
    if result["best_lap_time_s"] is None:
        return [*lines, f"no scored lap ({result['dnf_reason']}); row: {result['evaluation_json']}"]
    gap = 100.0 * (result["best_lap_time_s"] / result["limit_lap_time_s"] - 1.0)
    wall = result["best_lap"]["wall_contact_s"]
    return [
        *lines,
        f"lap {format_lap_time(result['best_lap_time_s'])} ({gap:+.1f} % of the limit, wall "
        f"{wall:.1f} s); row: {result['evaluation_json']}",
    ]


def run_play(opts: PlayOptions) -> int:
    from vision_rl.overtaking.play import play

    cfg = PlayConfig(**{k: v for k, v in asdict(opts).items() if k != "json"})
    emit(play(cfg), opts.json, format_play)
    return 0
