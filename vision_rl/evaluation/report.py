"""The result tables of the README and of the docs site, built from the JSON records under docs/results/.

A page marks a table's place with ``<!-- report:NAME -->`` and ``<!-- /report -->``; :func:`fill_page` writes between
them the table that :data:`TABLES` builds from the records, so every figure such a table states is its record's, and
a changed record leaves the page stale until ``vision-rl report`` runs again (``--check`` fails on a stale page).
A table links its records as ``RESULTS/...``, resolved against each page's own folder.

The papers' own figures are records too (``docs/results/papers/``), the built-in AI's lap and the physical limit come
from the protocol's evaluations of the AI (``docs/results/reference-laps/``), and the figures that exist only as a
command's printed summary are transcribed into a record that says so (``make-quick/job.json``,
``phase1-expressway-hatchback/r2.json``).
"""

from __future__ import annotations

import os
import re
import statistics
from collections.abc import Callable, Iterable, Mapping
from functools import partial
from pathlib import Path
from typing import Any

from vision_rl.evaluation.leaderboard import EVALUATION_FORMAT, OUTPUT_PATH_KEYS, seal_evaluation
from vision_rl.files import CONTENT_KEY, atomic_write, content_damage, json_text, parse_json, sealed_record

#: How a table names the results folder in its links; :func:`fill_page` puts the page's path to it there.
RESULTS = "RESULTS/"
#: A generated table's place on a page: the opening marker names the table, the closing one ends it.
MARKER = re.compile(r"(?P<open><!-- report:(?P<name>[\w-]+) -->\n)(?P<body>.*?)(?P<close><!-- /report -->)", re.S)

VISION_PAPER = "papers/gts-vision-representation-sac.json"
OVERTAKING_PAPER = "papers/gts-overtaking-curriculum-sac.json"
DDPG_PAPER = "papers/pcars2-ddpg-asymmetric-actor-critic.json"
AI_HATCHBACK = "reference-laps/ai_expressway_hatchback.json"
AI_TT_CUP = "reference-laps/ai_expressway_tt_cup.json"
AI_GT3 = "reference-laps/ai_catalunya_gt3.json"
STATE_2M = (
    "state-expressway-hatchback-25hz/dt04-ent4-lrf-select-2m_experiment.json",
    "state-expressway-hatchback-25hz/dt04-ent4-lrf-select-2m-seeds345_experiment.json",
)
VISION_25HZ = tuple(f"vision-expressway-hatchback/dt04_seed{seed}_experiment.json" for seed in (0, 1, 2))
VISION_QUICK_8_SEEDS = "vision-expressway-hatchback/quick_critic_state_starts13.json"
QUICK_JOB = "make-quick/job.json"
PHASE1_R2 = "phase1-expressway-hatchback/r2.json"
TABLE3 = "table3-expressway-tt_cup/table3.json"
SETTINGS = "overtaking-expressway-tt_cup/{agents}_setting_{setting}.json"
CURRICULUM_CURVES = "overtaking-expressway-tt_cup/learning_curves_num_timesteps.json"
OPPONENT_SKILL = "overtaking-expressway-tt_cup/opponent-skill/skill-{skill}/overtaking_setting_{setting}.json"
DDPG_EVALUATIONS = "ddpg-catalunya-gt3/evaluation_set3/{variant}-s{seed}.json"
DDPG_COMPARE = "ddpg-catalunya-gt3/standing_start_sigmoid_compare.json"
DDPG_VARIANTS = ("asymmetric", "symmetric", "state-actor")
DDPG_STATE_ACTOR = "ddpg-state-actor-catalunya-gt3/evaluation-crashgo50k-s{seed}.json"
R2_GROUPS = ("edge_distances", "min_edge_distances", "centre_offset", "heading_angle", "curvature_ahead")
#: The command that seals a record written before records were sealed (or transcribed by hand) once it is checked.
SEAL_COMMAND = ".venv/bin/python scripts/seal_records.py"


class ReportError(ValueError):
    """A record is missing or lacks a figure a table states, or a page's markers do not pair."""


class Records:
    """The JSON records under ``results_dir``, each read once, by their path relative to it."""

    def __init__(self, results_dir: str | os.PathLike[str], check: bool = True) -> None:
        self.results_dir = Path(results_dir)
        self.check = check
        """Refuse a record without its seal (:func:`record_damage`); off only to list the records a table reads."""
        self._read: dict[str, Any] = {}
        self.last: Path | None = None
        """The record read last: where a table that fails on a record's content was reading."""

    def __call__(self, relative_path: str) -> Any:
        if relative_path not in self._read:
            path = self.results_dir / relative_path
            if not path.is_file():
                raise ReportError(f"the record {path} is missing")
            try:
                record = parse_json(path.read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                raise ReportError(f"the record {path} is not readable JSON: {exc}") from None
            damage = record_damage(record) if self.check else None
            if damage is not None:
                raise ReportError(f"the record {path} {damage}")
            self._read[relative_path] = record
        self.last = self.results_dir / relative_path
        return self._read[relative_path]


def record_damage(record: Any) -> str | None:
    """None when ``record`` is a JSON object carrying the SHA-256 of its content, else what is wrong and what to do,
    as the end of a sentence naming the file. Records of format 1 (before seals, and every transcribed record until
    sealed) have no hash: a table states nothing an edit or a flipped bit could have changed unseen."""
    if not isinstance(record, dict):
        return f"is {type(record).__name__}, not a JSON object"
    if CONTENT_KEY not in record:
        return f"has no {CONTENT_KEY} (format 1, before records were sealed): check it, then `{SEAL_COMMAND} PATH`"
    damage = content_damage(record, OUTPUT_PATH_KEYS if record.get("format") == EVALUATION_FORMAT else ())
    return (
        None
        if damage is None
        else f"{damage}; measure it again, or if the edit was meant, seal it with `{SEAL_COMMAND} PATH`"
    )


def sealed(record: dict[str, Any]) -> dict[str, Any]:
    """``record`` sealed the way its kind is read back: an evaluation without its output paths
    (:func:`~vision_rl.evaluation.leaderboard.seal_evaluation`), any other over all of it."""
    if record.get("format") == EVALUATION_FORMAT:
        return seal_evaluation(dict(record))
    return sealed_record(record)


def seal_record_file(path: str | os.PathLike[str]) -> bool:
    """Seal the record at ``path`` in place (:func:`sealed`), keeping its layout (indented or one line); False when it
    was sealed and whole already. A sealed record whose content changed is refused: a hand edit is sealed on
    purpose, after removing its old ``content_sha256``."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    try:
        record = parse_json(text)
    except ValueError as exc:
        raise ReportError(f"{path}: not readable JSON: {exc}") from None
    if not isinstance(record, dict):
        raise ReportError(f"{path}: not a JSON object, not a record")
    if CONTENT_KEY in record:
        damage = record_damage(record)
        if damage is not None:
            raise ReportError(f"{path}: {damage.split(';')[0]}; remove its {CONTENT_KEY} to seal it as it is now")
        return False
    lines = text.lstrip().splitlines()
    indent = len(lines[1]) - len(lines[1].lstrip(" ")) if len(lines) > 1 else None
    sealed_text = json_text(sealed(record), indent=indent) + ("\n" if text.endswith("\n") else "")
    atomic_write(path, lambda tmp: tmp.write_text(sealed_text, encoding="utf-8"))
    return True


def lap_text(seconds: float | None) -> str:
    """A lap as the papers write it: ``2:09.293``; ``DNF`` for none."""
    if seconds is None:
        return "DNF"
    minutes, rest_s = divmod(round(seconds * 1000) / 1000, 60.0)
    return f"{int(minutes)}:{rest_s:06.3f}" if minutes else f"{rest_s:.3f} s"


def gap_pct(seconds: float, reference_s: float) -> float:
    """How much longer ``seconds`` is than ``reference_s``, in percent (negative: faster)."""
    return 100.0 * (seconds / reference_s - 1.0)


def gap_text(seconds: float, reference_s: float) -> str:
    return f"{gap_pct(seconds, reference_s):+.2f} %"


def faster_text(seconds: float, ai_s: float) -> str:
    """``7.18 % faster than the AI`` (or slower)."""
    gap = gap_pct(seconds, ai_s)
    return f"{abs(gap):.2f} % {'faster' if gap < 0 else 'slower'} than the AI"


def mean_std_s(laps_s: Iterable[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for one value) of lap times, s."""
    laps_s = list(laps_s)
    if not laps_s:
        raise ReportError("no lap to average")
    return statistics.fmean(laps_s), statistics.stdev(laps_s) if len(laps_s) > 1 else 0.0


def _row(cells: Iterable[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def markdown_table(header: Iterable[str], rows: Iterable[Iterable[str]]) -> str:
    header = list(header)
    lines = [_row(header), _row("---" for _ in header), *(_row(row) for row in rows)]
    return "\n".join(lines) + "\n"


def _link(text: str, relative_path: str) -> str:
    return f"[{text}]({RESULTS}{relative_path})"


def experiment_seeds(records: Records, paths: Iterable[str], selected: bool = False) -> list[dict[str, Any]]:
    """The per-seed rows of ``vision-rl experiment`` records, pooled: the last weights', or with ``selected`` those of
    the weights chosen by held-out starts."""
    rows: list[dict[str, Any]] = []
    for path in paths:
        record = records(path)
        part = record["selected"] if selected else record
        rows += part["per_seed"]
    return rows


def seeds_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean and spread of the seeds that lapped, starts finished and whether every seed was clean."""
    laps_s = [row["lap_time_s"] for row in rows if row.get("lap_time_s") is not None]
    mean_s, std_s = mean_std_s(laps_s)
    done, total = (sum(int(row["finished"].split("/")[i]) for row in rows) for i in (0, 1))
    return {
        "mean_s": mean_s,
        "std_s": std_s,
        "seeds": len(rows),
        "finished": f"{done}/{total}",
        "clean": all(row.get("clean") for row in rows),
    }


def _reference(records: Records, path: str) -> tuple[float, float]:
    """The built-in AI's protocol lap and the physical limit (QSS) of a track and car, s."""
    ai = records(path)
    return ai["best_lap_time_s"], ai["limit_lap_time_s"]


def _paper_lap(seconds: float, paper_ai_s: float) -> str:
    return f"{lap_text(seconds)} ({faster_text(seconds, paper_ai_s).replace('the AI', 'its AI')})"


def _vision_cells(records: Records) -> dict[str, Any]:
    """The figures of the vision paper's table: its laps, ours, the AI and the limit."""
    paper = records(VISION_PAPER)["lap_time_s"]
    ai_s, limit_s = _reference(records, AI_HATCHBACK)
    state = seeds_summary(experiment_seeds(records, STATE_2M, selected=True))
    vision_25hz = seeds_summary(experiment_seeds(records, VISION_25HZ))
    quick8 = records(VISION_QUICK_8_SEEDS)["critic_state"]
    return {
        "paper": paper,
        "ai_s": ai_s,
        "limit_s": limit_s,
        "state": state,
        "vision_25hz": vision_25hz,
        "quick8": {**quick8, "mean_s": quick8["protocol_lap_mean_s"], "std_s": quick8["protocol_lap_std_s"]},
        "job": records(QUICK_JOB),
    }


def _lap_row(
    result: str, paper_cell: str, summary: Mapping[str, Any], record: str, c: Mapping[str, Any], command: str
) -> tuple[str, ...]:
    """A row of the vision table for a recipe over training seeds: its mean lap, spread, starts and cleanness."""
    spread = f" ± {summary['std_s']:.2f} s" if summary.get("std_s") else ""
    clean = "clean" if summary.get("clean") else "not clean"
    ours = (
        f"**{lap_text(summary['mean_s'])}**{spread} over {summary['seeds']} training seeds, {summary['finished']} "
        f"starts, {clean} ({_link('record', record)}); {faster_text(summary['mean_s'], c['ai_s'])}"
    )
    limit = f"{lap_text(c['limit_s'])} (ours {gap_text(summary['mean_s'], c['limit_s'])})"
    return (result, paper_cell, ours, lap_text(c["ai_s"]), limit, command)


def vision_table(records: Records) -> str:
    """The vision paper (Table 1 and Phase 1) beside our runs: paper, ours, the built-in AI, the limit, command."""
    c = _vision_cells(records)
    paper, job, state, quick8 = c["paper"], c["job"], c["state"], c["quick8"]
    vision_paper = _paper_lap(paper["vision"], paper["built_in_ai"])
    r2 = job["train_repr"]["r2_clean_laps"]
    rows = [
        _lap_row(
            "state SAC (the 38-D state of Fuchs et al.), lap 2",
            _paper_lap(paper["state_fuchs_et_al"], paper["built_in_ai"]),
            state,
            STATE_2M[0],
            c,
            "`make experiment`",
        ),
        _lap_row(
            "vision SAC (64-D embedding + 11 features), `make quick`'s recipe",
            vision_paper,
            {**quick8, "seeds": len(quick8["per_seed"]), "clean": False},
            VISION_QUICK_8_SEEDS,
            c,
            "`make quick` (its vision stage, 8 seeds)",
        ),
        _lap_row(
            "vision SAC, the state agent's 25 Hz recipe",
            vision_paper,
            c["vision_25hz"],
            VISION_25HZ[0],
            c,
            "`capture --policy`, `train-repr`, `experiment`",
        ),
        (
            "the vision agent's gap to the state agent",
            gap_text(paper["vision"], paper["state_fuchs_et_al"]),
            f"{gap_text(quick8['mean_s'], state['mean_s'])} (`make quick`'s recipe against the state row)",
            "-",
            "-",
            "-",
        ),
        (
            "`make quick`'s own run, one training seed each",
            "-",
            f"vision {lap_text(job['vision']['lap_time_s'])}, state {lap_text(job['state']['lap_time_s'])} "
            f"({job['vision']['finished']} starts each) in {job['job_minutes']:.1f} min ({_link('record', QUICK_JOB)})",
            lap_text(job["built_in_ai_lap_time_s"]),
            lap_text(job["limit_lap_time_s"]),
            "`make quick`",
        ),
        (
            "Phase 1: R² of the 27 targets on a clean lap, per group",
            "not reported",
            f"{min(r2.values()):.3f}-{max(r2.values()):.3f} (`make quick`'s encoder)",
            "-",
            "-",
            "`make quick`",
        ),
    ]
    return markdown_table(("result", "paper (GT Sport)", "ours", "built-in AI", "physical limit", "command"), rows)


def quick_table(records: Records) -> str:
    """`make quick`'s stages: what each does, its time, what it gave."""
    job = records(QUICK_JOB)
    cap, rep, state, vision = job["capture"], job["train_repr"], job["state"], job["vision"]
    r2 = rep["r2_clean_laps"]
    rows = [
        ("capture", f"{cap['train']}; {cap['eval']}", f"{cap['seconds']} s", f"{cap['train_frames']:,} frames"),
        (
            "Phase 1 (`train-repr`)",
            f"the 64-D encoder, {rep['epochs']} epochs",
            f"{rep['seconds']} s",
            f"R² {min(r2.values()):.3f}-{max(r2.values()):.3f} on the clean lap",
        ),
        (
            "Phase 2, state",
            f"SAC on the 38-D state, {state['steps']:,} steps of {state['cars']} cars",
            f"{state['train_seconds']} s",
            f"lap {lap_text(state['lap_time_s'])} ({state['finished']} starts)",
        ),
        (
            "Phase 2, vision",
            f"SAC on the embedding + 11 features, {vision['steps']:,} steps of {vision['cars']} cars",
            f"{vision['train_seconds']} s",
            f"lap {lap_text(vision['lap_time_s'])} ({vision['finished']} starts)",
        ),
        (
            "the whole job",
            "the stages above, the state run beside the others",
            f"{job['job_minutes']:.1f} min ({job['job_with_setup_minutes']:.1f} with the set-up)",
            f"target {job['target_minutes']:.0f} min ({_link('record', QUICK_JOB)})",
        ),
    ]
    return markdown_table(("stage", "what", "time", "result"), rows)


def phase1_table(records: Records) -> str:
    """Phase 1's R² per target group for each training set-up."""
    record = records(PHASE1_R2)
    rows = [
        (
            row["training_data"],
            row["frame"],
            str(row["epochs"]),
            *(f"{row['r2'][group]:.3f}" for group in R2_GROUPS),
            row["train_time"],
        )
        for row in record["rows"]
    ]
    header = ("training data", "frame", "epochs", "edge rays", "min. edge distances", "centre offset", "heading")
    table = markdown_table((*header, "curvature ahead", "training time"), rows)
    return f"{table}\nR² per target group of the kept epoch on a clean lap ({_link('record', PHASE1_R2)}).\n"


def _span_m(distances_m: Iterable[float]) -> str:
    """The range of distances in whole metres, ``a-b m``, or ``a m`` when they round alike."""
    low, high = f"{min(distances_m):,.0f}", f"{max(distances_m):,.0f}"
    return f"{low} m" if low == high else f"{low}-{high} m"


#: GAIL on the DART-style demonstrations, timed alone (issue 65): a table3 record of its own.
TABLE3_GAIL_DART40 = "table3-expressway-tt_cup/gail-dart40/table3-s0.json"


def _table3_rows(records: Records) -> list[tuple[str, ...]]:
    paper = records(OVERTAKING_PAPER)["table3"]["lap_time_s"]
    ai_s, limit_s = _reference(records, AI_TT_CUP)
    rows = {row["key"]: row for row in records(TABLE3)["rows"]}
    names = {"sac": "SAC", "td3": "TD3", "bc": "BC", "gail": "GAIL", "planet": "PlaNet (ours: as Dreamer)"}
    out = []
    for key, name in names.items():
        row, seeds = rows[key], rows[key]["over_training_seeds"]
        lap_s = row["lap_time_s"]
        ours = "DNF" if lap_s is None else f"**{lap_s:.2f} s** ({lap_s / ai_s:.3f} of the AI's)"
        if row.get("kept_from"):  # `table3 --keep`: a row whose runs were not timed again
            ours += ", kept from an earlier timing of the table"
        out.append(
            (
                f"Table III, {name}: lap 2, the best start of {seeds['n_training_seeds']} training "
                + ("seed" if seeds["n_training_seeds"] == 1 else "seeds"),
                f"{paper[key]:.1f} s ({paper[key] / paper['built_in_ai']:.3f} of its AI's {paper['built_in_ai']} s)",
                f"{ours}, {seeds['finished']} starts finished ({_link('record', TABLE3)})",
                f"{ai_s:.2f} s",
                f"{limit_s:.2f} s" + ("" if lap_s is None else f" (ours {gap_text(lap_s, limit_s)})"),
                f"`vision-rl train-baseline --algo {'dreamer' if key == 'planet' else key}`, `vision-rl table3`",
            )
        )
    return out


#: Where a DNF reason of the protocol says a start stopped.
_STOPPED_AT = re.compile(r"(\d+) m into the lap")


def table3_summary_table(records: Records, path: str = TABLE3) -> str:
    """Every driver of a table3 record: the best start's lap 2 against the AI and the paper's, and the learner's
    figures over its training seeds."""
    rows = []
    for row in records(path)["rows"]:
        if row["status"] not in ("timed", "DNF"):
            continue
        seeds, paper, lap_s = row.get("over_training_seeds"), row.get("paper"), row["lap_time_s"]
        over = "-"
        if seeds and seeds["lap_time_mean_s"] is not None:
            spread = "" if seeds["lap_time_std_s"] is None else f" +- {seeds['lap_time_std_s']:.2f}"
            lapping = seeds["n_training_seeds_finished"]
            over = f"{seeds['lap_time_mean_s']:.2f}{spread} s over {lapping} lapping seed{'s' if lapping > 1 else ''}"
        rows.append(
            (
                row["name"] + (" (kept from an earlier timing)" if row.get("kept_from") else ""),
                "DNF" if lap_s is None else f"{lap_s:.2f}",
                "-" if lap_s is None else f"{row['avg_speed_kmh']:.1f}",
                "-" if lap_s is None else f"{row['lap_ratio_to_ai']:.3f}",
                "-" if paper is None else f"{paper['lap_ratio_to_ai']:.3f}",
                over,
                seeds["finished"] if seeds else f"{row['finished']}/{row['seeds']}",
                "-" if row["wall_contact_s"] is None else f"{row['wall_contact_s']:.1f}",
            )
        )
    header = (
        "driver",
        "lap 2, s (best start)",
        "km/h",
        "lap / AI",
        "the paper's lap / AI",
        "over the training seeds",
        "starts finished",
        "wall contact, s per lap (best start)",
    )
    return markdown_table(header, rows) + f"\nRecord: {_link(path.rsplit('/', 1)[-1], path)}.\n"


def table3_runs_table(records: Records, path: str = TABLE3) -> str:
    """Each training run of a table3 record: its lap 2 (best and median start), starts finished, wall contact,
    training time, and where the starts that did not finish stopped."""
    rows = []
    for row in records(path)["rows"]:
        for run in row.get("runs") or ():
            stopped_m = [float(m) for reason in run["dnf_reasons"] for m in _STOPPED_AT.findall(reason)]
            lap_s, median_s = run["lap_time_s"], run["median_lap_time_s"]
            rows.append(
                (
                    f"{row['name']} s{run['seed']}",
                    "DNF" if lap_s is None else f"{lap_s:.2f}" + ("" if median_s is None else f" ({median_s:.2f})"),
                    f"{run['finished']}/{run['seeds']}",
                    "-" if run["wall_contact_s"] is None else f"{run['wall_contact_s']:.1f}",
                    f"{run['train_time_s']:,.0f}",
                    "-" if not stopped_m else f"{_span_m(stopped_m)} into the lap",
                )
            )
    header = (
        "run",
        "lap 2, s: best (median) start",
        "starts finished",
        "wall contact, s per lap",
        "training, s",
        "the other starts stopped",
    )
    return markdown_table(header, rows) + f"\nRecord: {_link(path.rsplit('/', 1)[-1], path)}.\n"


#: BC's recipes on the race (issue 65): (recipe, demonstrations, its table3 record).
BC_RECIPES = (
    ("before (the Table III record)", "AI, 20 laps, noise 0.1", TABLE3),
    (
        "DART-style noise 0.3, label smoothed",
        "AI, 40 laps, noise 0.3",
        "overtaking-bc-expressway-tt_cup/bc_dart.json",
    ),
    (
        "DART-style, two skills, label smoothed",
        "the 40 laps above plus 40 laps of the AI at skill 0.85, noise 0.3 (`--include`)",
        "overtaking-bc-expressway-tt_cup/bc_dart_two_skills.json",
    ),
    (
        "DAgger, 3 rounds, label smoothed",
        "AI 20 laps noise 0.1, then 3 x 10 laps of bc driving, AI labelling",
        "overtaking-bc-expressway-tt_cup/bc_dagger.json",
    ),
)


def bc_recipes_table(records: Records) -> str:
    """BC's starts finished and laps per training seed under each recipe, through the protocol."""
    rows = []
    for recipe, demos, path in BC_RECIPES:
        bc = next(row for row in records(path)["rows"] if row["key"] == "bc")
        laps = " / ".join("DNF" if r["lap_time_s"] is None else f"{r['lap_time_s']:.1f}" for r in bc["runs"])
        ratio = "-" if bc["lap_time_s"] is None else f"{bc['lap_ratio_to_ai']:.3f}"
        rows.append((recipe, demos, bc["over_training_seeds"]["finished"], laps, ratio, _link("record", path)))
    header = ("recipe", "demonstrations", "starts finished", "lap 2, s (s0 / s1 / s2)", "best lap / AI", "record")
    return markdown_table(header, rows)


def _settings_rows(records: Records) -> list[tuple[str, ...]]:
    separation = records(OVERTAKING_PAPER)["settings"]["separation_m"]
    out = []
    for setting in ("A", "B"):
        drivers = [
            driver
            for agents in ("agent1", "agents23")
            for driver in records(SETTINGS.format(agents=agents, setting=setting))["drivers"]
        ]
        agents = [d for d in drivers if not d["reference"]]
        ai = next(d for d in drivers if d["reference"])["summary"]
        counts = ", ".join(f"{d['summary']['all_overtaken_runs']}/{d['summary']['runs']}" for d in agents)
        fastest = ", ".join(f"{d['summary']['fastest_all_five_s']:.1f}" for d in agents)
        out.append(
            (
                f"setting {setting} (5 cars {separation[setting]:.0f} m ahead): runs with all five overtaken, "
                "Agents 1, 2, 3 (one training seed)",
                "all five, by each agent (Figs. 4-5)",
                f"{counts}; fastest {fastest} s "
                f"({_link('record', SETTINGS.format(agents='agents23', setting=setting))})",
                f"{ai['all_overtaken_runs']}/{ai['runs']} (in the agent's car)",
                "-",
                f"`vision-rl evaluate-overtaking --setting {setting} --runs 10 --policy ...`",
            )
        )
    return out


def overtaking_table(records: Records) -> str:
    """The overtaking paper (Table III, settings A and B, Fig. 3) beside our runs."""
    curves = records(CURRICULUM_CURVES)
    rows = [*_table3_rows(records), *_settings_rows(records)]
    rows.append(
        (
            "Fig. 3: curriculum (Agent 3) against standard SAC, steps to standard SAC's final overtaking return",
            "fewer for the curriculum",
            f"{curves['curriculum_steps_to_standard_final'] / 1e6:.2f}M, "
            f"{curves['share_of_standard_steps']:.2f}x standard SAC's (one training seed; "
            f"{_link('record', CURRICULUM_CURVES)})",
            "-",
            "-",
            "`vision-rl evaluate-overtaking --curves ...`",
        )
    )
    return markdown_table(("result", "paper (GT Sport)", "ours", "built-in AI", "physical limit", "command"), rows)


#: Column heads of a driver's row of settings A/B (:func:`_driver_cells`).
DRIVER_HEADER = (
    "all five overtaken",
    "cars passed, mean (range)",
    "travel time, s",
    "fastest run with all five, s",
    "car / wall contact, s",
)


def _driver_cells(driver: dict[str, Any]) -> tuple[str, ...]:
    """One driver's summary over the runs of a setting, as :data:`DRIVER_HEADER` names it."""
    s = driver["summary"]
    fastest = s["fastest_all_five_s"]
    return (
        f"{s['all_overtaken_runs']}/{s['runs']}",
        f"{s['overtaken']['mean']:.1f} ({s['overtaken']['min']}-{s['overtaken']['max']})",
        f"{s['travel_time_s']['mean']:.1f} +- {s['travel_time_s']['std']:.1f}",
        "-" if fastest is None else f"{fastest:.1f}",
        f"{s['car_contact_s']['mean']:.1f} / {s['wall_contact_s']['mean']:.1f}",
    )


def opponent_skill_table(records: Records) -> str:
    """Settings A and B for one agent with the opponents at our skills (0.80-0.88) and at Table III's AI's (0.92)."""
    rows = []
    for setting in ("A", "B"):
        for skill in ("0.80-0.88", "0.92"):
            path = OPPONENT_SKILL.format(skill=skill, setting=setting)
            record = records(path)
            agent = next(d for d in record["drivers"] if not d["reference"])
            rows.append(
                (
                    f"{setting} ({record['separation_m']:.0f} m apart)",
                    f"{agent['name']}",
                    "-".join(f"{x:.2f}" for x in sorted(set(record["opponent_skill_range"]))),
                    *_driver_cells(agent),
                    _link("record", path),
                )
            )
    return markdown_table(("setting", "agent", "opponents' skill", *DRIVER_HEADER, "record"), rows)


def settings_drivers_table(records: Records, paths: Iterable[str]) -> str:
    """Every driver of each settings record in ``paths``, in order (the built-in AI in the agent's car too)."""
    rows = []
    for path in paths:
        record = records(path)
        rows.extend(
            (
                f"{record['setting']} ({record['separation_m']:.0f} m apart)",
                d["name"],
                *_driver_cells(d),
                _link("record", path),
            )
            for d in record["drivers"]
        )
    return markdown_table(("setting", "driver", *DRIVER_HEADER, "record"), rows)


#: Agents 2 and 3 of each training seed in settings A and B (10 runs each): the record and the driver's name there.
OVERTAKING_SEEDS = {
    (0, "agent 2"): (SETTINGS.format(agents="agents23", setting="{setting}"), "agent 2"),
    (0, "agent 3"): (SETTINGS.format(agents="agents23", setting="{setting}"), "agent 3"),
    (1, "agent 2"): (OPPONENT_SKILL.format(skill="0.80-0.88", setting="{setting}"), "agent2-s1"),
    (1, "agent 3"): ("overtaking-expressway-tt_cup/seeds/s1/agent3_setting_{setting}.json", "agent3-s1"),
}


def overtaking_seeds_table(records: Records) -> str:
    """Runs with all five overtaken by Agents 2 and 3 in settings A and B, per training seed (issue 65's target: at
    least 9/10 in each, on every seed)."""
    rows = []
    for (seed, agent), (pattern, name) in OVERTAKING_SEEDS.items():
        cells = []
        for setting in ("A", "B"):
            path = pattern.format(setting=setting)
            driver = next(d for d in records(path)["drivers"] if d["name"] == name)
            cells.append(_link(_driver_cells(driver)[0], path))
        rows.append((f"{seed}", agent, *cells))
    return markdown_table(("training seed", "agent", "setting A: all five overtaken", "setting B"), rows)


def _ddpg_laps(records: Records, limit_s: float) -> str:
    """Each variant's best start over its two training seeds through the protocol."""
    parts = []
    for variant in DDPG_VARIANTS:
        evaluations = [records(DDPG_EVALUATIONS.format(variant=variant, seed=seed)) for seed in (0, 1)]
        lapped = [e for e in evaluations if e["best_lap_time_s"] is not None]
        if lapped:
            best = min(lapped, key=lambda e: e["best_lap_time_s"])
            lap_s, wall_s = best["best_lap_time_s"], best["best_lap"]["wall_contact_s"]
            parts.append(
                f"{variant} **{lap_text(lap_s)}** ({gap_text(lap_s, limit_s)} on the limit, "
                f"{wall_s:.1f} s of wall contact)"
            )
        else:
            farthest_m = max(seed["distance_m"] for e in evaluations for seed in e["seeds"])
            parts.append(f"{variant} DNF (at most {farthest_m:,.0f} m)")
    return "; ".join(parts)


def ddpg_table(records: Records) -> str:
    """The DDPG paper beside our first trainings: laps through the protocol, distance per training episode."""
    paper = records(DDPG_PAPER)
    ai_s, limit_s = _reference(records, AI_GT3)
    compare = records(DDPG_COMPARE)
    distances = _by_variant(compare, "mean_distance_last_m", lambda m: f"{m:.0f}")
    rows = [
        (
            "lap 2 through the protocol, the best start of 2 training seeds (standing starts, sigmoid pedals)",
            "no lap time (a reward plot over laps 1-3)",
            f"{_ddpg_laps(records, limit_s)} ({_link('record', DDPG_EVALUATIONS.format(variant='symmetric', seed=0))})",
            lap_text(ai_s),
            lap_text(limit_s),
            "`vision-rl evaluate-ddpg --agent RUN`",
        ),
        (
            f"distance per training episode, last third of {compare['common_minutes']:.0f} training minutes, "
            "asymmetric / symmetric / state-actor (seeds 0, 1)",
            f"the asymmetric agent learns in about {paper['training_episodes']} episodes "
            f"(more than {paper['training_hours_at_least']:.0f} h)",
            f"{distances} m ({_link('record', DDPG_COMPARE)})",
            "-",
            "-",
            "`vision-rl train-ddpg --variant V`, `vision-rl compare-ddpg`",
        ),
    ]
    rows.append(_ddpg_state_actor_row(records, ai_s, limit_s))
    return markdown_table(
        ("result", "paper (Project Cars 2)", "ours", "built-in AI", "physical limit", "command"), rows
    )


def _ddpg_state_actor_row(records: Records, ai_s: float, limit_s: float) -> tuple[str, ...]:
    """The state actor on the task whose training episodes go on after a crash: starts finished per training seed,
    and the best lap 2 with its wall contact."""
    evaluations = {seed: records(DDPG_STATE_ACTOR.format(seed=seed)) for seed in (0, 1, 2)}
    finished = " / ".join(f"{e['n_finished']}/{e['n_seeds']}" for e in evaluations.values())
    lapped = [seed for seed, e in evaluations.items() if e["best_lap_time_s"] is not None]
    lap, shown = "no lap", 0
    if lapped:
        shown = min(lapped, key=lambda seed: evaluations[seed]["best_lap_time_s"])
        best = evaluations[shown]
        lap_s = best["best_lap_time_s"]
        lap = (
            f"best lap 2 **{lap_text(lap_s)}** (training seed {shown}, {gap_text(lap_s, limit_s)} on the limit, "
            f"{best['best_lap']['wall_contact_s']:.1f} s of wall contact)"
        )
    return (
        "state actor, training episodes that go on after a crash (beta 10), 50,000 transitions: starts finished, "
        "training seeds 0 / 1 / 2",
        "-",
        f"{finished}; {lap} ({_link('record', DDPG_STATE_ACTOR.format(seed=shown))})",
        lap_text(ai_s),
        lap_text(limit_s),
        "`vision-rl train-ddpg --variant state-actor --no-terminate-on-crash --crash-penalty-beta 10 "
        "--max-line-distance-m 15`",
    )


#: The first trainings of the three variants (docs/studies/ddpg.md): each set's compare-ddpg record.
DDPG_FIRST_SETS = (
    ("rolling start at the AI's speed, relu (the paper's)", "ddpg-catalunya-gt3/rolling_start_compare.json"),
    ("standing start on the line, relu", "ddpg-catalunya-gt3/standing_start_relu_compare.json"),
    (
        "standing start on the line, sigmoid (`--pedal-activation sigmoid`, not in the paper)",
        "ddpg-catalunya-gt3/standing_start_sigmoid_compare.json",
    ),
)


def _by_variant(compare: dict[str, Any], key: str, text: Callable[[Any], str]) -> str:
    """One figure of each run of a compare-ddpg record, seeds by variant: ``a0, a1 / s0, s1 / ...``."""
    return " / ".join(
        ", ".join(
            text(r[key]) for r in sorted((r for r in compare["runs"] if r["variant"] == v), key=lambda r: r["seed"])
        )
        for v in DDPG_VARIANTS
    )


def ddpg_first_trainings_table(records: Records) -> str:
    """The three variants x 2 seeds at equal training time in each of the first sets of trainings."""
    rows = []
    for name, path in DDPG_FIRST_SETS:
        compare = records(path)
        rows.append(
            (
                name,
                f"{compare['common_minutes']:.1f} min",
                f"{_by_variant(compare, 'mean_distance_last_m', lambda m: f'{m:.0f}')} m",
                _by_variant(compare, "updates", lambda n: f"{n / 1000:.1f}k"),
                _link("record", path),
            )
        )
    header = (
        "set (start of an episode, pedal outputs)",
        "training time per run",
        "distance per episode, last third: asymmetric / symmetric / state-actor (seeds 0, 1)",
        "updates per run",
        "record",
    )
    return markdown_table(header, rows)


#: `bench ddpg --presets paper,cpu --layouts channels_last,eager --profile` on the 2-core CPU.
DDPG_BENCH = "ddpg-bench/bench_ddpg_presets_run1.json"


def ddpg_bench_table(records: Records) -> str:
    """Updates/s of each variant and layout with the paper's trunk and the cpu trunk, and their ratio."""
    rows_by_key = {(r["variant"], r["preset"], r["layout"]): r for r in records(DDPG_BENCH)["rows"]}

    def rate(row: dict[str, Any]) -> str:
        return f"{row['updates_per_s']:.2f} ({row['ms_per_update']:,.0f} ms; {row['cpu_ms_per_update']:,.0f} ms of CPU)"

    rows = []
    for variant, preset, layout in rows_by_key:
        if preset == "cpu":
            continue
        paper = rows_by_key[variant, preset, layout]
        cpu = rows_by_key.get((variant, "cpu", layout))
        ratio = (
            "-"
            if cpu is None
            else f"{cpu['updates_per_s'] / paper['updates_per_s']:.1f}x updates/s, "
            f"{paper['cpu_ms_per_update'] / cpu['cpu_ms_per_update']:.1f}x less CPU time"
        )
        cells = (f"{variant}, {layout}", rate(paper), "-" if cpu is None else rate(cpu), ratio)
        rows.append((*cells, _link("record", DDPG_BENCH)))
    header = ("variant, layout", "paper trunk: updates/s (wall; CPU)", "cpu trunk", "cpu / paper", "record")
    return markdown_table(header, rows)


#: The state actor's screens on Catalunya (docs/notes/ddpg.md): rows of (label, evaluation records), one column each.
DDPG_STATE_ACTOR_SCREENS: dict[str, tuple[tuple[str, ...], tuple[tuple[str, tuple[str, ...]], ...]]] = {
    "ddpg-state-actor-15min": (
        ("training seed", "15 training minutes: protocol starts finished"),
        tuple((f"{seed}", (f"evaluation-s{seed}",)) for seed in (0, 1)),
    ),
    "ddpg-state-actor-seed1": (
        ("training seed 1 with", "protocol starts finished"),
        (
            ("nothing (the paper's task)", ("evaluation-s1",)),
            (
                "`--goal-frame body` (the racing-line point relative to the car, not in world coordinates: the "
                "critic need not learn the track's geometry to read the line)",
                ("evaluation-body-s1",),
            ),
            (
                "`--start-speed-share 0.5` (rolling starts at half the AI's speed: more time to correct before the "
                "5 m end)",
                ("evaluation-slow-s1",),
            ),
        ),
    ),
    "ddpg-state-actor-body": (
        ("training seed", "10,000 transitions: starts finished", "20,000 transitions"),
        tuple((f"{seed}", (f"evaluation-body10k-s{seed}", f"evaluation-body20k-s{seed}")) for seed in (0, 1, 2)),
    ),
    "ddpg-state-actor-crashgo": (
        ("training seed", "beta 10, 10,000 transitions: starts finished", "30,000", "50,000", "beta 0, 50,000"),
        tuple(
            (
                f"{seed}",
                tuple(f"evaluation-crashgo{n}-s{seed}" for n in ("10k", "30k", "50k", "-beta0-50k")),
            )
            for seed in (0, 1, 2)
        ),
    ),
}


def _starts_text(records: Records, path: str, limit_s: float) -> str:
    """Starts finished through the protocol, linked to the record; with a lap, the best and worst lap 2 against the
    limit and the best lap's wall contact, else how far the starts went."""
    evaluation = records(path)
    finished = _link(f"{evaluation['n_finished']} of {evaluation['n_seeds']}", path)
    laps_s = sorted(seed["lap_time_s"] for seed in evaluation["seeds"] if seed["finished"])
    if not laps_s:
        return f"{finished} ({_span_m([seed['distance_m'] for seed in evaluation['seeds']])})"
    wall_s = evaluation["best_lap"]["wall_contact_s"]
    worst = f", worst {lap_text(laps_s[-1])}" if len(laps_s) > 1 else ""
    return (
        f"**{finished}**: lap 2 {lap_text(laps_s[0])} ({gap_text(laps_s[0], limit_s)} on the limit){worst}; "
        f"{wall_s:.0f} s of wall contact"
    )


def ddpg_state_actor_table(records: Records, name: str) -> str:
    """One of the state actor's screens: each row's evaluations through the protocol (:func:`_starts_text`)."""
    _, limit_s = _reference(records, AI_GT3)
    header, rows = DDPG_STATE_ACTOR_SCREENS[name]
    folder = "ddpg-state-actor-catalunya-gt3"
    return markdown_table(
        header,
        [(label, *(_starts_text(records, f"{folder}/{n}.json", limit_s) for n in names)) for label, names in rows],
    )


#: The equal-compute study (issue 64, step 4): compare-ddpg's record of the six runs and each run's protocol laps.
DDPG_EQUAL_COMPUTE = "ddpg-equal-compute/compare.json"
DDPG_EQUAL_COMPUTE_LAPS = "ddpg-equal-compute/evaluation-{variant}-s{seed}.json"


def ddpg_equal_compute_table(records: Records) -> str:
    """Each run of the study: the compute it got, how far its training episodes went, and its protocol laps."""
    _, limit_s = _reference(records, AI_GT3)
    compare = records(DDPG_EQUAL_COMPUTE)
    rows = []
    for run in sorted(compare["runs"], key=lambda r: (DDPG_VARIANTS.index(r["variant"]), r["seed"])):
        path = DDPG_EQUAL_COMPUTE_LAPS.format(variant=run["variant"], seed=run["seed"])
        first_lap = (
            "-"
            if run["first_lap_episode"] is None
            else f"episode {run['first_lap_episode']} ({run['first_lap_minutes']:.0f} min)"
        )
        rows.append(
            (
                f"{run['variant']} s{run['seed']}",
                f"{run['train_minutes']:.0f} / {run['train_cpu_minutes']:.0f}",
                f"{run['steps']:,} / {run['updates']:,}",
                f"{run['episodes']:,}",
                f"{run['mean_distance_last_m']:,.0f} m (farthest {run['best_distance_m']:,.0f} m)",
                f"{run['reward_per_step_last']:+.1f}",
                first_lap,
                _starts_text(records, path, limit_s),
            )
        )
    header = (
        "run",
        "training minutes / CPU minutes",
        "transitions / updates",
        f"training episodes in {compare['common_minutes']:.0f} min",
        "distance per training episode, last third",
        "reward per step, last third",
        "first lap in training",
        "protocol starts finished, best lap 2",
    )
    return markdown_table(header, rows)


#: The reference check (issue 64, step 1): ours beside SB3 on a Gymnasium task, a summary and a record per run.
DDPG_REFERENCE = "ddpg-reference/{task}/{name}.json"
DDPG_REFERENCE_ALGOS = {
    "ours-bn": "ours-bn (the paper's networks)",
    "ours": "ours (no batch-norm)",
    "sb3-ddpg": "SB3 DDPG",
    "sb3-td3": "SB3 TD3",
}


def _spread(figure: dict[str, float], per_seed: Iterable[float] = (), decimals: int = 0) -> str:
    seeds = ", ".join(f"{x:.{decimals}f}" for x in per_seed)
    return f"{figure['mean']:.{decimals}f} ± {figure['std']:.{decimals}f}" + (f" ({seeds})" if seeds else "")


def ddpg_reference_table(records: Records, task: str, decimals: int = 0, time_limit_steps: int | None = None) -> str:
    """Each algorithm over its seeds: the final evaluation (with each seed's), the last evaluations, the last training
    episodes and the wall-clock per run, returns to ``decimals``; with ``time_limit_steps``, the training episodes
    that reached the goal (ended before the task's time limit)."""
    summary = records(DDPG_REFERENCE.format(task=task, name="summary"))
    rows = []
    for algo in (a for a in DDPG_REFERENCE_ALGOS if any(row["algo"] == a for row in summary["rows"])):
        row = next(row for row in summary["rows"] if row["algo"] == algo)
        paths = [DDPG_REFERENCE.format(task=task, name=f"{algo}-s{seed}") for seed in row["seeds"]]
        runs = [records(path) for path in paths]
        cells = [
            DDPG_REFERENCE_ALGOS[algo],
            _spread(row["final_return"], [run["final_return"] for run in runs], decimals),
            _spread(row["last5_eval_return"], decimals=decimals),
            _spread(row["last10_train_return"], decimals=decimals),
            f"{row['train_time_s']['mean']:,.0f}",
        ]
        if time_limit_steps is not None:
            goals = [sum(e["length"] < time_limit_steps for e in run["episodes"]) for run in runs]
            cells.append(f"{sum(goals)} of {sum(len(run['episodes']) for run in runs)}")
        rows.append([*cells, ", ".join(_link(f"s{seed}", p) for seed, p in zip(row["seeds"], paths, strict=True))])
    header = [
        "algorithm",
        "final evaluation (10 episodes; each seed's)",
        "mean of the last 5 evaluations",
        "last 10 training episodes (all, if fewer)",
        "s per run",
    ]
    if time_limit_steps is not None:
        header.append("training episodes that reached the goal")
    return markdown_table([*header, "records"], rows)


def reference_table(records: Records) -> str:
    """The built-in AI's protocol lap and the physical limit of each track and car the papers' tables use."""
    rows = []
    for path, pair in (
        (AI_HATCHBACK, "expressway, hatchback"),
        (AI_TT_CUP, "expressway, tt_cup"),
        (AI_GT3, "Catalunya, gt3"),
    ):
        ai_s, limit_s = _reference(records, path)
        skill = records(path)["driver"]["skill"]
        rows.append(
            (
                pair,
                f"{lap_text(ai_s)} (skill {skill})",
                lap_text(limit_s),
                gap_text(ai_s, limit_s),
                _link("record", path),
            )
        )
    return markdown_table(("track, car", "built-in AI", "physical limit", "the AI above the limit", "record"), rows)


#: Every table a page can name in a marker, built from the records.
TABLES: dict[str, Callable[[Records], str]] = {
    "reference": reference_table,
    "vision": vision_table,
    "quick": quick_table,
    "phase1": phase1_table,
    "overtaking": overtaking_table,
    "opponent-skill": opponent_skill_table,
    "overtaking-settings": partial(
        settings_drivers_table,
        paths=[SETTINGS.format(agents=a, setting=x) for x in ("A", "B") for a in ("agent1", "agents23")],
    ),
    "c-r-ablation": partial(
        settings_drivers_table,
        paths=[f"overtaking-expressway-tt_cup/c_r_ablation/setting_{x}.json" for x in ("A", "B")],
    ),
    "table3-summary": table3_summary_table,
    "table3-runs": table3_runs_table,
    "table3-gail-dart40": partial(table3_runs_table, path=TABLE3_GAIL_DART40),
    "bc-recipes": bc_recipes_table,
    "overtaking-seeds": overtaking_seeds_table,
    "ddpg": ddpg_table,
    "ddpg-first-trainings": ddpg_first_trainings_table,
    "ddpg-reference-pendulum": lambda records: ddpg_reference_table(records, "Pendulum-v1"),
    "ddpg-reference-mountaincar": lambda records: ddpg_reference_table(records, "MountainCarContinuous-v0", 1, 999),
    "ddpg-bench": ddpg_bench_table,
    **{name: partial(ddpg_state_actor_table, name=name) for name in DDPG_STATE_ACTOR_SCREENS},
}


def build_tables(results_dir: str | os.PathLike[str], names: Iterable[str] | None = None) -> dict[str, str]:
    """The tables named (all of :data:`TABLES` by default) from the records under ``results_dir``."""
    records = Records(results_dir)
    tables = {}
    for name in TABLES if names is None else names:
        try:
            tables[name] = TABLES[name](records)
        except ReportError:
            raise
        except (KeyError, TypeError, ValueError, IndexError, AttributeError, ArithmeticError) as exc:
            # A record of another shape than the table's (edited, damaged or of an older writer).
            raise ReportError(
                f"the {name} table cannot read its records (the last read: {records.last}): {type(exc).__name__} {exc}"
            ) from None
    return tables


def records_read(results_dir: str | os.PathLike[str]) -> list[Path]:
    """Every record the tables of :data:`TABLES` read under ``results_dir``, their seals not checked: what
    ``scripts/seal_records.py`` seals when named no file."""
    records = Records(results_dir, check=False)
    for table in TABLES.values():
        table(records)
    return sorted(records.results_dir / relative for relative in records._read)


def marked_tables(text: str) -> list[str]:
    """The names of the tables a page marks, in order; :class:`ReportError` on a marker without its end."""
    names = [m.group("name") for m in MARKER.finditer(text)]
    if text.count("<!-- report:") != len(names) or text.count("<!-- /report -->") != len(names):
        raise ReportError("a <!-- report:NAME --> marker without its <!-- /report --> (or the other way round)")
    return names


def fill_page(text: str, tables: Mapping[str, str], results_href: str) -> str:
    """``text`` with every marked table replaced by ``tables[name]``, its record links made relative to the page
    (``results_href``: the page's path to the results folder)."""
    marked_tables(text)
    href = results_href.rstrip("/") + "/"

    def table(match: re.Match) -> str:
        name = match.group("name")
        if name not in tables:
            raise ReportError(f"no table called {name!r}; known: {', '.join(sorted(tables))}")
        body = tables[name].replace(RESULTS, href)
        return f"{match.group('open')}{body}{match.group('close')}"

    return MARKER.sub(table, text)


def page_results_href(page: str | os.PathLike[str], results_dir: str | os.PathLike[str]) -> str:
    """The relative path from ``page``'s folder to ``results_dir``, with forward slashes."""
    return Path(os.path.relpath(Path(results_dir).resolve(), Path(page).resolve().parent)).as_posix()


def render_pages(
    pages: Iterable[str | os.PathLike[str]],
    results_dir: str | os.PathLike[str],
    extra_tables: Mapping[str, str] | None = None,
) -> dict[Path, tuple[str, str]]:
    """``{page: (text now, text with its tables regenerated)}`` for each page that marks a table."""
    texts = {Path(p): Path(p).read_text(encoding="utf-8") for p in pages}
    marked = {page: text for page, text in texts.items() if marked_tables(text)}
    wanted = {name for text in marked.values() for name in marked_tables(text)} - set(extra_tables or {})
    tables = {**build_tables(results_dir, sorted(wanted & set(TABLES))), **(extra_tables or {})}
    return {
        page: (text, fill_page(text, tables, page_results_href(page, results_dir))) for page, text in marked.items()
    }
