"""`vision-rl tracks`: the built-in tracks and the racetrack-database circuits with their length, narrowest width,
number of corners and wall trim; `--check` drives each with the built-in AI through the lap-time protocol."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from vision_rl.commands.options import comma_list
from vision_rl.commands.output import emit, progress_bar, show
from vision_rl.files import first_line


@dataclass(frozen=True)
class TracksOptions:
    """List the built-in tracks and the racetrack-database circuits with their length, narrowest width, number of
    corners and wall trim (how far a wall that would fold on the inside of a hairpin was cut back)."""

    check: bool = False
    """Also drive every listed track with the built-in AI through the lap-time protocol (one seed) and report its
    lap time or DNF; a few seconds per track for its racing line, once (cached)."""
    car: str = "hatchback"
    """Car preset of --check."""
    laps: int = 1
    """Laps per track of --check (>= 1); the last one is reported."""
    render: bool = True
    """With --check, also draw the driver's view at each track's tightest corner (the road must fill part of it)."""
    only: str = ""
    """Comma-separated track names to list (default: all built-in and database tracks)."""
    json: bool = False
    """Print one JSON list instead of a table."""
    progress: bool = True
    """Show a progress bar on stderr during --check."""


def _lap(value: Any) -> str:
    return "-" if value is None else f"{value:.2f}"


def format_tracks(rows: list[dict]) -> list[str]:
    check = any("lap_time_s" in r for r in rows)
    head = f"{'name':<14}{'source':<20}{'length_m':>10}{'min_width_m':>13}{'corners':>9}{'wall_trim_m':>13}"
    if check:
        head += f"{'limit_lap_s':>13}{'ai_lap_s':>10}{'wall_s':>8}{'road_px':>9}  result"
    out = [head]
    for r in rows:
        line = (
            f"{r['name']:<14}{r['source']:<20}{r['length_m']:>10.1f}{r['min_width_m']:>13.2f}{r['corners']:>9d}"
            f"{r['wall_trim_m']:>13.2f}"
        )
        if check:
            result = "finished" if r["finished"] else f"DNF ({r['dnf_reason']})"
            if r.get("render_error"):
                result += f"; render failed: {r['render_error']}"
            road = "-" if r.get("road_share") is None else f"{100 * r['road_share']:.0f}%"
            line += f"{_lap(r['limit_lap_time_s']):>13}{_lap(r['lap_time_s']):>10}{_lap(r['wall_contact_s']):>8}"
            line += f"{road:>9}  {result}"
        out.append(line)
    if check:
        done = sum(r["finished"] for r in rows)
        out.append(f"{done} of {len(rows)} tracks driven to the end of lap {rows[0]['laps'] if rows else 0}.")
    return [*out, "Also: random:SEED (procedural), or the path of a racetrack-database CSV."]


def check_track(name: str, car: str, laps: int) -> dict[str, Any]:
    """One built-in AI run (seed 0) of ``laps`` laps on track ``name``: the figures of the last lap, or the DNF."""
    from vision_rl.evaluation.protocol import BuiltinAI, time_laps

    timing = time_laps(BuiltinAI(), name, car, seeds=(0,), laps=laps)
    lap = timing.scored(0)
    return {
        "car": timing.car.name,
        "laps": laps,
        "limit_lap_time_s": round(timing.limit_lap_time_s, 3),
        "lap_time_s": None if lap is None else round(lap.lap_time_s, 3),
        "wall_contact_s": None if lap is None else round(lap.wall_contact_s, 2),
        "finished": lap is not None,
        "dnf_reason": timing.runs[0].dnf_reason,
    }


def render_check(name: str) -> dict[str, Any]:
    """The driver's view 20 m before the track's tightest corner, on the centre line: the share of road pixels
    (road, lines and kerbs) in the lower half of the frame, or the renderer's error."""
    import numpy as np

    from vision_rl.render import Renderer
    from vision_rl.render.scene import Label
    from vision_rl.sim.track_library import load_track

    track = load_track(name)
    s = np.array([track.s_m[int(np.argmax(np.abs(track.curvature_1pm)))] - 20.0])
    xy = track.position_at(s, 0.0)
    try:
        with Renderer(track) as renderer:
            labels = renderer.render_labels(xy[:, 0], xy[:, 1], track.heading_at(s))[0]
    except Exception as exc:  # reported per track: one track that cannot be drawn must not hide the others
        return {"road_share": None, "render_error": f"{type(exc).__name__}: {first_line(exc)}"}
    lower = labels[labels.shape[0] // 2 :]
    road = np.isin(lower, [Label.ROAD, Label.LINE, Label.KERB]).mean()
    return {"road_share": round(float(road), 3), "render_error": None}


def run_tracks(opts: TracksOptions) -> int:
    from vision_rl.sim.track_library import BUILTIN_TRACKS, DATABASE_TRACKS, load_track, track_summary

    if opts.laps < 1:
        raise ValueError(f"--laps must be >= 1, got {opts.laps}")
    names = [(n, "built-in") for n in BUILTIN_TRACKS] + [(n, "racetrack-database") for n in DATABASE_TRACKS]
    if opts.only:
        wanted = comma_list(opts.only)
        by_key = {n.lower(): (n, src) for n, src in names}
        unknown = [w for w in wanted if w.lower() not in by_key]
        if unknown:
            raise ValueError(f"--only: unknown track {unknown[0]!r}; `vision-rl tracks` lists the names")
        names = [by_key[w.lower()] for w in wanted]
    rows = [{**track_summary(load_track(name)), "source": source} for name, source in names]
    if opts.check:
        with progress_bar(len(rows), "track", "driving", enabled=opts.progress) as bar:
            for k, row in enumerate(rows):
                row.update(check_track(row["name"], opts.car, opts.laps))
                if opts.render:
                    row.update(render_check(row["name"]))
                show(bar, k + 1, name=row["name"])
    emit(rows, opts.json, format_tracks)
    ok = all(r.get("finished", True) and not r.get("render_error") for r in rows)
    return 0 if ok else 1
