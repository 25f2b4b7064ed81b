"""The lap-time table of one track and car (the shape of the vision paper's Table 1), built only from results of
the lap-time protocol: the built-in AI's row is measured with it when the table is made, each policy's comes
from the ``evaluation.json`` that ``evaluate`` wrote with it.

``gap_to_limit_pct = 100 (t - t_limit) / t_limit`` and ``gap_to_ai_pct = 100 (t - t_ai) / t_ai``: negative means
faster (the paper's vision agent is about -8.4 % against the AI). The physical limit (the QSS lap on the racing
line) is the reference of the first gap, not a driven lap. An evaluation written under another protocol version
is refused with the command that re-measures it; one of another track geometry or car is not this table's.
"""

from __future__ import annotations

import json
import math
import os
import statistics
from pathlib import Path
from typing import Any

from vision_rl.evaluation.protocol import PROTOCOL_VERSION, BuiltinAI, LapTiming, time_laps

EVALUATION_FORMAT = "vision_rl.evaluation"
#: Seeds of the built-in AI's row: the same starts as ``evaluate``'s default.
AI_SEEDS = (0, 1, 2)


def evaluation_record(timing: LapTiming, driver: dict[str, Any], name: str) -> dict[str, Any]:
    """What ``evaluation.json`` holds: the protocol's summary, the driver's identity and the row's name."""
    return {"format": EVALUATION_FORMAT, "name": name, "driver": driver, **timing.summary()}


def gap_pct(lap_time_s: float | None, reference_s: float | None) -> float | None:
    """100 (t - reference) / reference, or None when either is missing."""
    if lap_time_s is None or reference_s is None or not math.isfinite(lap_time_s) or reference_s <= 0:
        return None
    return 100.0 * (lap_time_s - reference_s) / reference_s


def row(record: dict[str, Any], kind: str) -> dict[str, Any]:
    """A table row of an evaluation record."""
    return {
        "name": record["name"],
        "kind": kind,
        "lap_time_s": record["best_lap_time_s"],
        "median_lap_time_s": record["median_lap_time_s"],
        "finished": f"{record['n_finished']}/{record['n_seeds']}",
        "clean": record["clean"],
        "wall_contact_s": None if record["best_lap"] is None else record["best_lap"]["wall_contact_s"],
        "protocol_version": record["protocol"]["version"],
        "track_geometry_hash": record["track_geometry_hash"],
        "car": record["car"],
        "driver": record["driver"],
    }


EXPERIMENT_FORMAT = "vision_rl.experiment"


def _sample_std(values: list[float]) -> float | None:
    return float(statistics.stdev(values)) if len(values) >= 2 else None


def aggregate_seeds(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Training seeds summarised from their evaluation records (one policy per training seed, each timed from
    the same start seeds): the mean and sample standard deviation of the seeds' best scored laps (over the seeds
    that finished a lap), the best of them (the vision paper's score, Sec. 4: "the fastest time was used"), the
    share of starts that finished, and the wall contact of the scored laps."""
    if not records:
        raise ValueError("no training seeds to summarise")
    versions = {r["protocol"]["version"] for r in records}
    if len(versions) != 1:
        raise ValueError(f"the seeds were timed under different protocol versions {sorted(versions)}")
    for key in ("track_geometry_hash", "car"):
        if len({r[key] for r in records}) != 1:
            raise ValueError(f"the seeds' evaluations mix {key}s: {sorted({str(r[key]) for r in records})}")
    laps = [r["best_lap_time_s"] for r in records if r["best_lap_time_s"] is not None]
    walls = [r["best_lap"]["wall_contact_s"] for r in records if r["best_lap"] is not None]
    starts = sum(r["n_seeds"] for r in records)
    return {
        "n_training_seeds": len(records),
        "n_training_seeds_finished": len(laps),
        "lap_time_mean_s": float(statistics.fmean(laps)) if laps else None,
        "lap_time_std_s": _sample_std(laps),
        "best_lap_time_s": min(laps) if laps else None,
        "finish_rate": sum(r["n_finished"] for r in records) / starts,
        "finished": f"{sum(r['n_finished'] for r in records)}/{starts}",
        "wall_contact_mean_s": float(statistics.fmean(walls)) if walls else None,
        "wall_contact_std_s": _sample_std(walls),
        "clean": all(r["clean"] for r in records),
        "protocol_version": versions.pop(),
        "track_geometry_hash": records[0]["track_geometry_hash"],
        "car": records[0]["car"],
    }


def find_experiments(runs: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Every finished ``experiment.json`` under ``runs`` (see :mod:`vision_rl.phase2_rl.experiment`)."""
    found = []
    root = Path(runs)
    for path in sorted(root.rglob("experiment.json")) if root.is_dir() else []:
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if isinstance(data, dict) and data.get("format") == EXPERIMENT_FORMAT and data.get("summary"):
            found.append({**data, "experiment_json": str(path)})
    return found


def remeasure_hint(record: dict[str, Any]) -> str:
    """How to time a record's driver again: an outside agent's record says so itself (``driver.remeasure``,
    :mod:`vision_rl.training.outside`), a train-policy run's is ``vision-rl evaluate --policy``."""
    driver = record.get("driver") or {}
    if driver.get("remeasure"):
        return str(driver["remeasure"])
    return f"vision-rl evaluate --policy {driver.get('policy') or record.get('policy') or 'POLICY'}"


def row_kind(driver: dict[str, Any]) -> str:
    """A policy row's kind: ``human``, ``agent (<observation>)`` for an agent trained outside the project (timed by
    ``vision_rl.evaluate``) or ``policy (<observation>)``."""
    if driver.get("driver") == "human":
        return "human"
    who = "agent" if driver.get("agent") == "outside" else "policy"
    return f"{who} ({driver.get('observation', '?')})"


def find_evaluations(runs: str | os.PathLike[str]) -> tuple[list[dict[str, Any]], list[str]]:
    """(records of this protocol version, refusals) from every ``*evaluation.json`` under ``runs``. A refusal
    names the file and how to re-measure it; unreadable or foreign JSON files are not evaluations and are skipped."""
    found, refused = [], []
    root = Path(runs)
    if not root.is_dir():
        return found, refused
    for path in sorted(root.rglob("*evaluation.json")):
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(data, dict) or data.get("format") != EVALUATION_FORMAT:
            continue
        version = (data.get("protocol") or {}).get("version")
        if version != PROTOCOL_VERSION:
            refused.append(
                f"{path}: measured under protocol version {version or 'none (before versions)'}, this is version "
                f"{PROTOCOL_VERSION}; re-measure it: {remeasure_hint(data)}"
            )
            continue
        found.append({**data, "evaluation_json": str(path)})
    return found, refused


def leaderboard(track: str = "expressway", car: str = "hatchback", runs: str = "runs") -> dict[str, Any]:
    """The table for (track, car): the limit, the built-in AI at its default skill and every policy evaluated on
    them under ``runs``, fastest first; DNF rows last."""
    ai = time_laps(BuiltinAI(), track, car, seeds=AI_SEEDS)
    ai_record = evaluation_record(ai, BuiltinAI().identity, "built-in AI (default skill)")
    limit_s, ai_s = ai.limit_lap_time_s, ai_record["best_lap_time_s"]
    rows = [row(ai_record, "ai")]
    records, refused = find_evaluations(runs)
    experiments = [e for e in find_experiments(runs) if e["summary"]["protocol_version"] == PROTOCOL_VERSION]
    inside = [Path(e["experiment_json"]).parent for e in experiments]
    for record in records:
        path = Path(record["evaluation_json"])
        if any(path.is_relative_to(f) and path.relative_to(f).parts[0].startswith("seed-") for f in inside):
            continue  # a training seed of an experiment (its last or its selected weights): the experiment's rows
        if record["track_geometry_hash"] == ai.track.geometry_hash and record["car"] == ai.car.name:
            rows.append({**row(record, row_kind(record["driver"])), "evaluation_json": record["evaluation_json"]})
    for e in experiments:
        # The weights chosen by held-out starts get a row of their own, beside the last weights'.
        for summary, chosen in ((e["summary"], ""), ((e.get("selected") or {}).get("summary"), ", selected")):
            ours = summary is not None and (summary["track_geometry_hash"], summary["car"]) == (
                ai.track.geometry_hash,
                ai.car.name,
            )
            if not ours:
                continue
            rows.append(
                {
                    "name": f"{e['name']} ({summary['n_training_seeds']} seeds{chosen})",
                    "kind": f"experiment ({e['observation']})",
                    "lap_time_s": summary["best_lap_time_s"],
                    "median_lap_time_s": None,
                    "lap_time_mean_s": summary["lap_time_mean_s"],
                    "lap_time_std_s": summary["lap_time_std_s"],
                    "finished": summary["finished"],
                    "clean": summary["clean"],
                    "wall_contact_s": summary["wall_contact_mean_s"],
                    "protocol_version": summary["protocol_version"],
                    "track_geometry_hash": summary["track_geometry_hash"],
                    "car": summary["car"],
                    "experiment_json": e["experiment_json"],
                }
            )
    for r in rows:
        r.update(gap_to_limit_pct=gap_pct(r["lap_time_s"], limit_s), gap_to_ai_pct=gap_pct(r["lap_time_s"], ai_s))
    rows.sort(key=lambda r: (r["lap_time_s"] is None, r["lap_time_s"] or 0.0))
    return {
        "track": ai.track.name,
        "track_geometry_hash": ai.track.geometry_hash,
        "car": ai.car.name,
        "protocol_version": PROTOCOL_VERSION,
        "limit_lap_time_s": limit_s,
        "rows": rows,
        "refused": refused,
    }
