"""`vision-rl tracks`: the built-in tracks with their length, narrowest width and number of corners."""

from __future__ import annotations

from dataclasses import dataclass

from vision_rl.commands.output import emit


@dataclass(frozen=True)
class TracksOptions:
    """List the built-in tracks with their length, narrowest width and number of corners."""

    json: bool = False
    """Print one JSON list instead of a table."""


def format_tracks(rows: list[dict]) -> list[str]:
    out = [f"{'name':<14}{'length_m':>10}{'min_width_m':>13}{'corners':>9}"]
    out += [f"{r['name']:<14}{r['length_m']:>10.1f}{r['min_width_m']:>13.2f}{r['corners']:>9d}" for r in rows]
    return [*out, "Also: random:SEED (procedural), or the path of a racetrack-database CSV."]


def run_tracks(opts: TracksOptions) -> int:
    from vision_rl.sim.track_library import BUILTIN_TRACKS, load_track, track_summary

    emit([track_summary(load_track(name)) for name in BUILTIN_TRACKS], opts.json, format_tracks)
    return 0
