"""The lap-time table of one track and car (the shape of the vision paper's Table 1), built only from results of
the lap-time protocol: the built-in AI's row is measured with it when the table is made, each policy's comes
from the ``evaluation.json`` that ``evaluate`` wrote with it.

``gap_to_limit_pct = 100 (t - t_limit) / t_limit`` and ``gap_to_ai_pct = 100 (t - t_ai) / t_ai``: negative means
faster (the paper's vision agent is about -8.4 % against the AI). The physical limit (the QSS lap on the racing
line) is the reference of the first gap, not a driven lap. An evaluation written under another protocol version
is refused with the command that re-measures it; one of another track geometry or car is not this table's.

Every record carries the SHA-256 of its content (:func:`seal_evaluation`); the table refuses, in one line naming the
file, a record without it or whose content no longer has it, a field of the wrong type, and a lap more than
:data:`LIMIT_TOLERANCE_PCT` under the physical limit.
"""

from __future__ import annotations

import json
import math
import os
import statistics
from pathlib import Path
from typing import Any

from vision_rl.evaluation.protocol import PROTOCOL_VERSION, BuiltinAI, LapTiming, StraightDriver, time_laps
from vision_rl.files import CONTENT_KEY, content_damage, content_sha256, first_line, parse_json

EVALUATION_FORMAT = "vision_rl.evaluation"
#: What writers add to a record after it is sealed: where its outputs went, not figures. Left out of its hash.
OUTPUT_PATH_KEYS = ("plot", "video", "trace", "reward_plot", "evaluation_json")
#: How far under the physical limit a lap may be and still enter the table, %. The limit (the QSS lap on the racing
#: line) is a steady-state estimate, not a bound: the project's fastest genuine lap is 3.97 % under it (Dreamer on
#: expressway, tt_cup, Table III, on the walls 4.3 s of its lap). docs/protocol.md says why 10.
LIMIT_TOLERANCE_PCT = 10.0


class RecordError(ValueError):
    """A record the table cannot take (damaged, changed, of another version, implausible); the message names the
    file and says how to measure it again."""


#: Seeds of the built-in AI's row: the same starts as ``evaluate``'s default.
AI_SEEDS = (0, 1, 2)


def evaluation_record(timing: LapTiming, driver: dict[str, Any], name: str) -> dict[str, Any]:
    """What ``evaluation.json`` holds: the protocol's summary, the driver's identity and the row's name, sealed
    (:func:`seal_evaluation`; a writer that adds figures seals it again)."""
    return seal_evaluation({"format": EVALUATION_FORMAT, "name": name, "driver": driver, **timing.summary()})


def seal_evaluation(record: dict[str, Any]) -> dict[str, Any]:
    """``record`` with the SHA-256 of its content (all but :data:`OUTPUT_PATH_KEYS`) under ``content_sha256``."""
    record[CONTENT_KEY] = content_sha256(json.loads(json.dumps(record, default=str)), OUTPUT_PATH_KEYS)
    return record


def read_evaluation(path: str | os.PathLike[str]) -> dict[str, Any]:
    """An ``evaluation.json`` of this protocol version whose content has its recorded SHA-256 and whose figures
    have their types, or a one-line :class:`RecordError` naming the file and how to re-measure it."""
    try:
        data = parse_json(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise RecordError(f"{path}: not a readable evaluation record: {first_line(exc)}") from None
    if not isinstance(data, dict) or data.get("format") != EVALUATION_FORMAT:
        raise RecordError(f"{path}: not an evaluation record (no format {EVALUATION_FORMAT!r})")
    protocol = data.get("protocol")
    version = protocol.get("version") if isinstance(protocol, dict) else None
    if version != PROTOCOL_VERSION:
        raise RecordError(
            f"{path}: measured under protocol version {version or 'none (before versions)'}, this is version "
            f"{PROTOCOL_VERSION}; re-measure it: {remeasure_hint(data)}"
        )
    damage = content_damage(data, OUTPUT_PATH_KEYS)
    if damage is not None:
        raise RecordError(f"{path}: the evaluation record {damage}; re-measure it: {remeasure_hint(data)}")
    problem = evaluation_problem(data)
    if problem is not None:
        raise RecordError(f"{path}: {problem}; re-measure it: {remeasure_hint(data)}")
    return data


def _seconds(value: Any) -> bool:
    """Whether ``value`` is a finite number of seconds, >= 0."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value >= 0


def _lap_or_none(value: Any) -> bool:
    return value is None or (_seconds(value) and value > 0)


def evaluation_problem(record: dict[str, Any]) -> str | None:
    """What makes a record's figures unusable (a field of another type, a best lap that is not its starts'
    best), or None."""
    for key in ("name", "track_geometry_hash", "car"):
        if not isinstance(record.get(key), str):
            return f"{key} is {record.get(key)!r}, not text"
    if not isinstance(record.get("driver"), dict):
        return "driver is not an object"
    for key in ("best_lap_time_s", "median_lap_time_s"):
        if not _lap_or_none(record.get(key)):
            return f"{key} is {record.get(key)!r}, not a lap time in seconds or null"
    counts = [record.get(k) for k in ("n_finished", "n_seeds")]
    if not all(isinstance(c, int) and not isinstance(c, bool) and c >= 0 for c in counts) or counts[0] > counts[1]:
        return f"n_finished and n_seeds are {counts}, not two counts of starts"
    seeds = record.get("seeds")
    if not isinstance(seeds, list) or not all(isinstance(s, dict) and _lap_or_none(s.get("lap_time_s")) for s in seeds):
        return "seeds is not a list of starts with their lap times"
    laps = [s["lap_time_s"] for s in seeds if s["lap_time_s"] is not None]
    best, best_lap = record["best_lap_time_s"], record.get("best_lap")
    if best != (min(laps) if laps else None) or len(laps) != counts[0] or len(seeds) != counts[1]:
        return f"best_lap_time_s {best!r} and n_finished are not those of its {len(seeds)} starts"
    if best is not None and not (isinstance(best_lap, dict) and best_lap.get("lap_time_s") == best):
        return "best_lap is not the lap of best_lap_time_s"
    if best is not None and not _seconds(best_lap.get("wall_contact_s")):
        return "best_lap.wall_contact_s is not a time in seconds"
    if not isinstance(record.get("clean"), bool):
        return f"clean is {record.get('clean')!r}, not true or false"
    return None


def limit_problem(lap_time_s: float | None, limit_s: float) -> str | None:
    """Why a lap cannot be believed against the physical limit ``limit_s`` (more than :data:`LIMIT_TOLERANCE_PCT`
    under it), or None."""
    gap = gap_pct(lap_time_s, limit_s)
    if gap is None or gap >= -LIMIT_TOLERANCE_PCT:
        return None
    return (
        f"its lap {lap_time_s:.3f} s is {-gap:.1f} % under the physical limit {limit_s:.3f} s, more than the "
        f"{LIMIT_TOLERANCE_PCT:g} % a driven lap can beat that steady-state estimate by"
    )


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


def find_experiments(runs: str | os.PathLike[str]) -> tuple[list[dict[str, Any]], list[str]]:
    """(finished records, refusals) of every ``experiment.json`` under ``runs`` (see
    :mod:`vision_rl.phase2_rl.experiment`); one not finished yet (no summary) is neither."""
    found, refused = [], []
    root = Path(runs)
    for path in sorted(root.rglob("experiment.json")) if root.is_dir() else []:
        try:
            data = parse_json(path.read_text())
        except (OSError, ValueError) as exc:
            refused.append(f"{path}: not a readable experiment record: {first_line(exc)}")
            continue
        if not isinstance(data, dict) or (data.get("format") != EXPERIMENT_FORMAT and CONTENT_KEY not in data):
            continue  # another program's file of that name
        rerun = f"run its `vision-rl experiment --out {path.parent}` again (it keeps the trained seeds)"
        damage = content_damage(data)
        if damage is None and data.get("format") == EXPERIMENT_FORMAT and not data.get("summary"):
            continue  # an experiment under way: no summary yet
        problem = f"the experiment record {damage}" if damage else _summary_problem(data)
        if problem is not None:
            refused.append(f"{path}: {problem}; {rerun}")
            continue
        found.append({**data, "experiment_json": str(path)})
    return found, refused


def _summary_problem(record: dict[str, Any]) -> str | None:
    """What makes an experiment's summaries unusable for a row, or None."""
    if record.get("format") != EXPERIMENT_FORMAT:
        return f"not an experiment record (no format {EXPERIMENT_FORMAT!r})"
    for summary in (record["summary"], (record.get("selected") or {}).get("summary")):
        if summary is None:
            continue
        if not isinstance(summary, dict) or not all(
            _lap_or_none(summary.get(k)) for k in ("best_lap_time_s", "lap_time_mean_s")
        ):
            return "a summary's lap times are not lap times in seconds or null"
        if not all(isinstance(summary.get(k), str) for k in ("track_geometry_hash", "car")):
            return "a summary has no track geometry hash or car"
    return None


def remeasure_hint(record: dict[str, Any]) -> str:
    """How to time a record's driver again: an outside agent's record says so itself (``driver.remeasure``,
    :mod:`vision_rl.training.outside`), a train-policy run's is ``vision-rl evaluate --policy``."""
    driver = record.get("driver") if isinstance(record.get("driver"), dict) else {}
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
    """(records, refusals) of every ``*evaluation.json`` under ``runs`` (:func:`read_evaluation`). A refusal names
    the file, the damage and how to re-measure it."""
    found, refused = [], []
    root = Path(runs)
    if not root.is_dir():
        return found, refused
    for path in sorted(root.rglob("*evaluation.json")):
        try:
            found.append({**read_evaluation(path), "evaluation_json": str(path)})
        except RecordError as exc:
            refused.append(str(exc))
    return found, refused


def leaderboard(track: str = "expressway", car: str = "hatchback", runs: str = "runs") -> dict[str, Any]:
    """The table for (track, car): the limit, the built-in AI at its default skill, the straight driver (the floor a
    learner must beat) and every policy evaluated on them under ``runs``, fastest first; DNF rows last. A row more
    than :data:`LIMIT_TOLERANCE_PCT` under the limit is refused, naming its file."""
    if Path(runs).exists() and not Path(runs).is_dir():  # a file here gave the AI's row alone, without a word
        raise RecordError(f"--runs {runs} is a file, not the folder of runs to search for evaluation.json")
    ai = time_laps(BuiltinAI(), track, car, seeds=AI_SEEDS)
    ai_record = evaluation_record(ai, BuiltinAI().identity, "built-in AI (default skill)")
    limit_s, ai_s = ai.limit_lap_time_s, ai_record["best_lap_time_s"]
    ours = (ai.track.geometry_hash, ai.car.name)
    records, refused = find_evaluations(runs)
    experiments, refused_experiments = find_experiments(runs)
    refused += refused_experiments
    experiments = [e for e in experiments if e["summary"]["protocol_version"] == PROTOCOL_VERSION]
    inside = [Path(e["experiment_json"]).parent for e in experiments]
    candidates = []
    for record in records:
        path = Path(record["evaluation_json"])
        if any(path.is_relative_to(f) and path.relative_to(f).parts[0].startswith("seed-") for f in inside):
            continue  # a training seed of an experiment (its last or its selected weights): the experiment's rows
        if (record["track_geometry_hash"], record["car"]) == ours:
            candidates.append({**row(record, row_kind(record["driver"])), "evaluation_json": record["evaluation_json"]})
    candidates += [r for e in experiments for r in experiment_rows(e) if (r["track_geometry_hash"], r["car"]) == ours]
    straight = time_laps(StraightDriver(), track, car, seeds=AI_SEEDS)
    straight_record = evaluation_record(
        straight, StraightDriver.identity, "straight driver (full throttle, no steering)"
    )
    rows = [row(ai_record, "ai"), row(straight_record, "straight")]  # the floor: the walls steer it round
    for r in candidates:
        problem = limit_problem(r["lap_time_s"], limit_s)
        if problem is None:
            rows.append(r)
        else:
            refused.append(f"{r.get('evaluation_json') or r.get('experiment_json')}: {problem}")
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


def experiment_rows(experiment: dict[str, Any]) -> list[dict[str, Any]]:
    """An experiment's rows: its last weights' and, when held-out starts chose weights, the chosen ones'."""
    rows = []
    for summary, chosen in (
        (experiment["summary"], ""),
        ((experiment.get("selected") or {}).get("summary"), ", selected"),
    ):
        if summary is None:
            continue
        rows.append(
            {
                "name": f"{experiment['name']} ({summary['n_training_seeds']} seeds{chosen})",
                "kind": f"experiment ({experiment['observation']})",
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
                "experiment_json": experiment["experiment_json"],
            }
        )
    return rows
