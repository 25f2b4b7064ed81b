"""`table3`: the overtaking paper's Table III (a baseline comparison for the single-car race) on our simulator.

Every row is timed by the one lap-time protocol (:func:`vision_rl.evaluation.protocol.time_laps`): the built-in AI
(:class:`~vision_rl.evaluation.protocol.BuiltinAI`, at its 50 Hz), each trained baseline of train-baseline (bc,
gail, sac, td3; a train-overtaking stage-1 folder counts as sac) and, for the record, the demonstrator of the
imitation baselines (the AI held at 10 Hz, :class:`~vision_rl.overtaking.demos.HeldAIDriver`). A row's figures are
the best scored lap over the protocol's seeds and that lap's average speed (centre-line length over lap time,
km/h); with several runs of one algorithm (training seeds) the fastest run is the row, every run is listed, and
``over_training_seeds`` gives the mean and spread of the runs' best laps. Each row stands beside the paper's as
ratios to their own table's built-in AI. The PlaNet row is timed from ``dreamer`` runs (:mod:`.dreamer` says why).
An algorithm without a run reads "not trained", or keeps its row from an earlier record (``--keep``, marked
``kept_from``) when its runs are gone. Why ratios, and the vision paper's rule: docs/notes/overtaking.md,
"table3.py".
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from vision_rl.config import at_least, check_option_bounds, flat_values
from vision_rl.evaluation.leaderboard import aggregate_seeds
from vision_rl.evaluation.protocol import BuiltinAI, rules, time_laps
from vision_rl.evaluation.report import record_damage
from vision_rl.files import parse_json, sealed_record
from vision_rl.overtaking.baseline_run import BaselineError, baseline_algo, check_table_track
from vision_rl.overtaking.baselines import load_baseline
from vision_rl.overtaking.config import Table3Config
from vision_rl.overtaking.demos import HeldAIDriver
from vision_rl.sim.track_library import load_track
from vision_rl.training.artifact import SIDECAR_NAME, PolicyError

#: The paper's Table III (GT Sport, Audi TT Cup 16 on Tokyo Expressway): lap time s, average speed km/h.
PAPER_TABLE3: dict[str, tuple[float, float]] = {
    "ai": (86.9, 184.4),
    "bc": (108.0, 146.8),
    "gail": (144.9, 109.4),
    "sac": (80.1, 198.2),
    "td3": (80.8, 196.3),
    "planet": (89.0, 178.2),
}
ROW_NAMES = {
    "ai": "Built-in AI",
    "bc": "BC",
    "gail": "GAIL",
    "sac": "SAC",
    "td3": "TD3",
    "planet": "PlaNet (as Dreamer)",
    "demonstrator": "AI held at 10 Hz (demonstrator)",
}
#: The row each train-baseline algorithm fills.
ROW_OF_ALGO = {"bc": "bc", "gail": "gail", "sac": "sac", "td3": "td3", "dreamer": "planet"}


def _split(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]


def find_runs(root: str | os.PathLike[str]) -> list[Path]:
    """Folders under ``root`` (one level) that hold a policy sidecar, sorted."""
    root = Path(root)
    if not root.is_dir():
        return []
    return sorted(p for p in root.iterdir() if (p / SIDECAR_NAME).is_file())


def _figures(summary: dict[str, Any]) -> dict[str, Any]:
    best = summary["best_lap"]
    reasons = sorted({s["dnf_reason"] for s in summary["seeds"] if s["dnf_reason"]})
    return {
        "lap_time_s": None if best is None else best["lap_time_s"],
        "avg_speed_kmh": None if best is None else best["avg_speed_kmh"],
        "median_lap_time_s": summary["median_lap_time_s"],
        "finished": summary["n_finished"],
        "seeds": summary["n_seeds"],
        "clean": summary["clean"],
        "wall_contact_s": None if best is None else best["wall_contact_s"],
        "dnf_reasons": reasons,
    }


def _ratios(row: dict[str, Any], ai: dict[str, Any]) -> None:
    lap, speed = row.get("lap_time_s"), row.get("avg_speed_kmh")
    row["lap_ratio_to_ai"] = None if lap is None or ai.get("lap_time_s") is None else lap / ai["lap_time_s"]
    row["speed_ratio_to_ai"] = None if speed is None or ai.get("avg_speed_kmh") is None else speed / ai["avg_speed_kmh"]


def _timed_row(key: str, figures: dict[str, Any]) -> dict[str, Any]:
    status = "timed" if figures["lap_time_s"] is not None else "DNF"
    return {"key": key, "name": ROW_NAMES[key], "status": status, **figures}


#: ``progress(row_name)`` before each row is timed.
Table3Progress = Callable[[str], None]


def table3(cfg: Table3Config, progress: Table3Progress | None = None) -> dict[str, Any]:
    """Time every row (see the module's docstring); returns the rows with the paper's beside them."""
    check_option_bounds(flat_values(cfg), {"seeds": at_least(1), "laps": at_least(1), "time_limit_s": at_least(0)})
    track = load_track(cfg.track)
    explicit = _split(cfg.runs)
    paths = [Path(p) for p in explicit] if explicit else find_runs(cfg.runs_root)
    repeated = sorted({str(p) for p in paths if paths.count(p) > 1})
    if repeated:
        raise ValueError(f"--runs names {', '.join(repeated)} more than once: each run is one training seed")
    protocol = {**rules(), "seeds": cfg.seeds, "laps": cfg.laps, "time_limit_s": cfg.time_limit_s}
    kept = kept_rows(cfg.keep, track.geometry_hash, cfg.car, protocol) if cfg.keep else {}
    loaded, skipped = _load_runs(paths, cfg, refuse=bool(explicit))

    def timed(driver) -> dict[str, Any]:
        return time_laps(driver, track, cfg.car, range(cfg.seeds), cfg.laps, cfg.time_limit_s).summary()

    if progress is not None:
        progress("ai")
    ai = _timed_row("ai", _figures(timed(BuiltinAI())))
    rows = [ai]
    for algo, key in ROW_OF_ALGO.items():
        row = _algo_row(algo, key, loaded, timed, progress)
        if row["status"] == "not trained" and key in kept:
            # A row the kept record itself kept names the record it was timed in, so provenance survives a chain.
            row = {**kept[key], "kept_from": kept[key].get("kept_from") or cfg.keep}
        rows.append(row)
    if cfg.demonstrator:
        if progress is not None:
            progress("demonstrator")
        rows.append(_timed_row("demonstrator", _figures(timed(HeldAIDriver()))))
    for row in rows:
        _beside_the_paper(row, ai)
    # Sealed: `table3 --json` is the record `vision-rl report` builds Table III from, and it refuses one without.
    return sealed_record(
        {
            "table": "overtaking paper, Table III: a baseline comparison for the single-car race",
            "track": cfg.track,
            "track_name": track.name,
            "track_geometry_hash": track.geometry_hash,
            "car": cfg.car,
            "protocol": protocol,
            "rows": rows,
            "skipped": skipped,
        }
    )


def kept_rows(path: str, geometry_hash: str, car: str, protocol: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The algorithm rows of the sealed table3 record at ``path`` that hold figures, by key; refused in one line when
    the record is damaged or of another track, car or protocol than the table being made."""
    try:
        record = parse_json(Path(path).read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise BaselineError(f"--keep {path}: cannot read it as a table3 record ({exc})") from None
    damage = record_damage(record)  # the reader of every result record: a changed or unsealed one is refused
    if damage:
        raise BaselineError(f"--keep {path} {damage}")
    if not isinstance(record.get("rows"), list):
        raise BaselineError(f"--keep {path}: not a table3 record (no rows)")
    # The protocol's version is its contract (a change of rules bumps it); seeds, laps and limit are the table's.
    terms = ("version", "seeds", "laps", "time_limit_s")
    theirs_protocol = record.get("protocol") if isinstance(record.get("protocol"), dict) else {}
    mine = {"track geometry": geometry_hash, "car": car, **{f"protocol {t}": protocol[t] for t in terms}}
    theirs = {
        "track geometry": record.get("track_geometry_hash"),
        "car": record.get("car"),
        **{f"protocol {t}": theirs_protocol.get(t) for t in terms},
    }
    differ = [f"{name} {theirs[name]} (here {value})" for name, value in mine.items() if theirs[name] != value]
    if differ:
        raise BaselineError(f"--keep {path}: its rows would not compare: {', '.join(differ)}")
    return {
        row["key"]: row
        for row in record["rows"]
        if isinstance(row, dict) and row.get("key") in ROW_OF_ALGO.values() and row.get("status") != "not trained"
    }


def _load_runs(paths: list[Path], cfg: Table3Config, refuse: bool) -> tuple[list[tuple[Path, Any]], list[dict]]:
    """(the runs' policies, the runs skipped and why); with ``refuse`` (runs named by --runs) a run that cannot be
    timed on the table's track and car raises instead."""
    loaded, skipped = [], []
    for path in paths:
        try:
            policy = load_baseline(path)
            check_table_track(policy, cfg.track, cfg.car)
        except (PolicyError, BaselineError) as exc:
            if refuse:
                raise
            skipped.append({"run": str(path), "reason": str(exc)})
            continue
        loaded.append((path, policy))
    return loaded, skipped


def _algo_row(
    algo: str,
    key: str,
    loaded: list[tuple[Path, Any]],
    timed: Callable[[Any], dict[str, Any]],
    progress: Table3Progress | None,
) -> dict[str, Any]:
    """The row of one algorithm: each of its runs timed, the fastest the row's figures."""
    runs, summaries = [], []
    for path, policy in loaded:
        if baseline_algo(policy.spec) != algo:
            continue
        if progress is not None:
            progress(f"{algo} {path}")
        driver = policy.driver()
        try:
            summaries.append(timed(driver))
        finally:
            driver.close()
        runs.append(
            {
                "run": str(path),
                "num_timesteps": policy.spec.num_timesteps,
                "train_time_s": policy.spec.train_time_s,
                "seed": policy.spec.seed,
                **_figures(summaries[-1]),
            }
        )
    if not runs:
        return {"key": key, "name": ROW_NAMES[key], "status": "not trained", "lap_time_s": None, "avg_speed_kmh": None}
    best = min(runs, key=lambda r: math.inf if r["lap_time_s"] is None else r["lap_time_s"])
    return {
        "key": key,
        "name": ROW_NAMES[key],
        "status": "timed" if best["lap_time_s"] is not None else "DNF",
        **{k: v for k, v in best.items() if k != "run"},
        "run": best["run"],
        "runs": runs,
        "over_training_seeds": aggregate_seeds(summaries),
    }


def _beside_the_paper(row: dict[str, Any], ai: dict[str, Any]) -> None:
    """The row's ratios to our built-in AI, and the paper's row with its ratios to the paper's AI."""
    _ratios(row, ai)
    paper, paper_ai = PAPER_TABLE3.get(row["key"]), PAPER_TABLE3["ai"]
    row["paper"] = (
        None
        if paper is None
        else {
            "lap_time_s": paper[0],
            "avg_speed_kmh": paper[1],
            "lap_ratio_to_ai": paper[0] / paper_ai[0],
            "speed_ratio_to_ai": paper[1] / paper_ai[1],
        }
    )


__all__ = ["PAPER_TABLE3", "ROW_OF_ALGO", "Table3Config", "find_runs", "table3"]
