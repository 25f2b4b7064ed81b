"""`leaderboard`: lap times of the built-in AI, the physical limit and every evaluated policy on one track and car,
with gaps in percent to the limit and to the AI (the shape of the vision paper's Table 1).

``gap_to_limit_pct = 100 (t - t_limit) / t_limit`` and ``gap_to_ai_pct = 100 (t - t_ai) / t_ai``: negative means
faster (the paper's vision agent is about -8.4 % against the AI). A policy's lap time is its best scored lap over
seeds (the papers' "best lap score"); its median is listed beside it. Policies come from the ``evaluation.json``
files that ``evaluate`` writes beside them, matched to the track by geometry hash and to the car by name.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vision_rl.config import doc
from vision_rl.phase2_rl.evaluate import EVALUATION_FORMAT, format_lap_time


def gap_pct(lap_time_s: float | None, reference_s: float | None) -> float | None:
    """100 (t - reference) / reference, or None when either is missing."""
    if lap_time_s is None or reference_s is None or not math.isfinite(lap_time_s) or reference_s <= 0:
        return None
    return 100.0 * (lap_time_s - reference_s) / reference_s


def make_rows(entries: Iterable[dict[str, Any]], limit_s: float | None, ai_s: float | None) -> list[dict[str, Any]]:
    """Rows with ``name``, ``lap_time_s``, ``gap_to_limit_pct``, ``gap_to_ai_pct`` (plus the entry's other keys),
    fastest first; rows without a lap time (DNF) last, in input order."""
    rows = []
    for entry in entries:
        t = entry.get("lap_time_s")
        rows.append({**entry, "gap_to_limit_pct": gap_pct(t, limit_s), "gap_to_ai_pct": gap_pct(t, ai_s)})
    return sorted(rows, key=lambda r: (r["lap_time_s"] is None, r["lap_time_s"] or 0.0))


def find_evaluations(runs: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Every readable ``*evaluation.json`` under ``runs`` (unreadable or foreign files are skipped)."""
    found = []
    root = Path(runs)
    if not root.is_dir():
        return found
    for path in sorted(root.rglob("*evaluation.json")):
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if isinstance(data, dict) and data.get("format") == EVALUATION_FORMAT:
            found.append({**data, "evaluation_json": str(path)})
    return found


def reference_lap_times(track: str, car: str, ai_seed: int = 0) -> dict[str, Any]:
    """The QSS limit lap time and the built-in AI's at default skill, from :mod:`vision_rl.sim.driving`: the
    limit profile's lap, and the second of two flying laps of ``drive_ai`` (its own protocol: a start 100 m before
    the line at its target speed, 50 Hz control)."""
    from vision_rl.sim import driving

    limit = driving.compute_limit(track, car)["lap_time_s"]
    ai_laps = driving.drive_ai(track, car, laps=2, seed=ai_seed)["lap_times_s"]
    return {
        "limit_lap_time_s": float(limit),
        "ai_lap_time_s": float(ai_laps[1]) if len(ai_laps) >= 2 else None,
        "source": "vision_rl.sim.driving (compute_limit, drive_ai lap 2)",
    }


def leaderboard(track: str = "expressway", car: str = "hatchback", runs: str = "runs") -> dict[str, Any]:
    """The table for (track, car): the AI, the limit and every policy evaluated on them under ``runs``."""
    from vision_rl.sim.track_library import load_track

    geometry = load_track(track).geometry_hash
    refs = reference_lap_times(track, car)
    limit_s, ai_s = refs["limit_lap_time_s"], refs["ai_lap_time_s"]
    entries = [
        {"name": "built-in AI (default skill)", "kind": "ai", "lap_time_s": ai_s},
        {"name": "physical limit (QSS)", "kind": "limit", "lap_time_s": limit_s},
    ]
    for ev in find_evaluations(runs):
        if ev.get("track_geometry_hash") != geometry or ev.get("car") != car:
            continue
        entries.append(
            {
                "name": ev.get("name", "?"),
                "kind": f"policy ({ev.get('observation', '?')})",
                "lap_time_s": ev.get("best_lap_time_s"),
                "median_lap_time_s": ev.get("median_lap_time_s"),
                "wall_contact_s": ev.get("wall_contact_s"),
                "finished": f"{ev.get('n_finished', 0)}/{ev.get('n_seeds', 0)}",
                "num_timesteps": ev.get("num_timesteps"),
                "train_time_s": ev.get("train_time_s"),
                "evaluation_json": ev["evaluation_json"],
            }
        )
    return {"track": track, "car": car, "references_from": refs["source"], "rows": make_rows(entries, limit_s, ai_s)}


def format_leaderboard(result: dict[str, Any]) -> list[str]:
    def pct(v: float | None) -> str:
        return "-" if v is None else f"{v:+.2f}"

    width = max(26, *(len(r["name"]) for r in result["rows"]))
    lines = [
        f"{result['track']} / {result['car']}",
        f"{'name':<{width}}  {'lap':>9}  {'vs limit %':>10}  {'vs AI %':>8}  {'median':>9}  {'finished':>8}",
    ]
    for r in result["rows"]:
        median = format_lap_time(r["median_lap_time_s"]) if "median_lap_time_s" in r else ""
        lines.append(
            f"{r['name']:<{width}}  {format_lap_time(r['lap_time_s']):>9}  {pct(r['gap_to_limit_pct']):>10}  "
            f"{pct(r['gap_to_ai_pct']):>8}  {median:>9}  {r.get('finished', ''):>8}"
        )
    return lines


@dataclass
class LeaderboardConfig:
    """Lap-time table: built-in AI, physical limit and every evaluated policy (Table 1 of the vision paper)."""

    track: str = field(default="expressway", metadata=doc("track: built-in name, random:SEED or CSV path"))
    car: str = field(default="hatchback", metadata=doc("car preset"))
    runs: str = field(default="runs", metadata=doc("folder searched for evaluation.json files"))
    json: bool = field(default=False, metadata=doc("print the table as JSON"))


def run_leaderboard(cfg: LeaderboardConfig) -> int:
    result = leaderboard(cfg.track, cfg.car, cfg.runs)
    print(json.dumps(result, indent=2) if cfg.json else "\n".join(format_leaderboard(result)))
    return 0
