"""The vision pipeline's run log (docs/results/vision-expressway-hatchback/README.md): its experiments of a few
training seeds through the protocol, and its batches of runs each timed from 13 starts, from the records there."""

from __future__ import annotations

import statistics
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from vision_rl.evaluation.report.common import (
    AI_HATCHBACK,
    bold_if,
    faster_text,
    lap_text,
    link,
    markdown_table,
    mean_std_s,
    reference_laps,
    span_text,
)
from vision_rl.evaluation.report.records import Records, ReportError

LOG = "vision-expressway-hatchback"
#: The held-out starts by which `make quick` chose among a run's saved weights.
SELECT_STARTS = 3
#: Where a batch of runs is in its record: the file in :data:`LOG`, the keys down to the batch, and which of its
#: lists of starts finished per training seed (None: a batch of ``per_seed`` rows, or a plain list).
Batch = tuple[str, tuple[str, ...], str | None]


def _dig(record: Any, keys: Iterable[str]) -> Any:
    """The part of ``record`` down ``keys``."""
    for key in keys:
        record = record[key]
    return record


def _protocol_of_3(section: dict[str, Any], chosen: tuple[str, ...]) -> dict[int, tuple[int, float | None]]:
    """Each training seed's starts finished of the protocol's 3 and its lap (the best of them) in a batch of lists of
    counts: the last weights', or with ``chosen`` (the keys down each seed to its chosen step) that step's starts 0-2;
    empty where the record has neither."""
    if not chosen:
        last = section.get("protocol_starts_0_2_last_weights", {"per_seed": []})["per_seed"]
        return {row["seed"]: (row["finished_of_3"], row["lap_time_s"]) for row in last}
    protocol = {}
    for seed in section["seeds"]:
        starts = seed["protocol_starts_0_12"][str(_dig(seed, chosen))][:3]
        laps_s = [start["lap_time_s"] for start in starts if start["finished"]]
        protocol[seed["training_seed"]] = (len(laps_s), min(laps_s, default=None))
    return protocol


def _seed_rows(records: Records, batch: Batch, chosen: tuple[str, ...] = ()) -> list[dict[str, Any]]:
    """Each training seed of a batch: starts finished of 13, of the protocol's 3 (starts 0-2), the protocol's lap and
    the median wall contact of its laps, from either layout the studies wrote (None where absent); ``chosen``: the
    protocol's figures of the weights chosen at the step down those keys (:func:`_protocol_of_3`)."""
    file, keys, counts_key = batch
    section = _dig(records(f"{LOG}/{file}"), keys)
    if "per_seed" in section:
        return [
            {
                "seed": row["seed"],
                "of_13": row["finished_of_13"],
                "of_3": row["protocol_finished_of_3"],
                "lap_s": row["protocol_lap_time_s"],
                "wall_s": row.get("wall_contact_s_median_scored_lap"),
            }
            for row in section["per_seed"]
        ]
    counts = section["finished_of_13_per_seed"]
    counts = counts if counts_key is None else counts[counts_key]
    seeds = [row.get("training_seed", row.get("seed")) for row in section["seeds"]]
    if len(seeds) != len(counts):
        raise ReportError(f"{file}: {len(counts)} counts of starts finished for {len(seeds)} training seeds")
    protocol = _protocol_of_3(section, chosen)
    rows = []
    for seed, of_13 in zip(seeds, counts, strict=True):
        of_3, lap_s = protocol.get(seed, (None, None))
        rows.append({"seed": seed, "of_13": of_13, "of_3": of_3, "lap_s": lap_s, "wall_s": None})
    return rows


def _pooled(records: Records, batches: Sequence[Batch]) -> list[dict[str, Any]]:
    """The seeds of several batches (of one recipe, from several records) as one batch."""
    return [row for batch in batches for row in _seed_rows(records, batch)]


def _batch_extras(rows: list[dict[str, Any]], ai_s: float | None) -> dict[str, str]:
    """A batch's figures beside its starts of 13: the protocol's starts, the mean protocol lap over the seeds with
    one (and against the AI when ``ai_s`` is given), and the mean of the seeds' median wall contact per lap."""
    laps_s = [row["lap_s"] for row in rows if row["lap_s"] is not None]
    mean_s, std_s = mean_std_s(laps_s)
    walls_s = [row["wall_s"] for row in rows if row["wall_s"] is not None]
    against = f" ({faster_text(mean_s, ai_s)})" if ai_s is not None else ""
    return {
        "protocol": f"{sum(row['of_3'] for row in rows)}/{3 * len(rows)}",
        "lap": f"{lap_text(mean_s)} ± {std_s:.2f} s{against}",
        "wall": f"{sum(walls_s) / len(walls_s):.2f} s" if walls_s else "-",
    }


def _starts_row(
    label: str, batches: Sequence[Batch], records: Records, seeds: Sequence[int], extras: Sequence[str], **options: Any
) -> list[str]:
    """A batch's starts finished of 13 per training seed (blank for a seed it has not), all of them, and ``extras``
    (:func:`_batch_extras`); ``bold`` marks the row the section is about, ``ai`` sets its lap against the AI."""
    rows = [row for row in _pooled(records, batches) if row["seed"] in seeds]
    by_seed = {row["seed"]: row["of_13"] for row in rows}
    bold = options.get("bold", False)
    ai_s = reference_laps(records, AI_HATCHBACK)[0] if options.get("ai") else None
    figures = _batch_extras(rows, ai_s) if extras else {}
    all_starts = bold_if(f"{sum(by_seed.values())}/{13 * len(by_seed)}", bold)
    cells = [str(by_seed[s]) if s in by_seed else "" for s in seeds]
    return [bold_if(label, bold), *cells, all_starts, *(bold_if(figures[e], bold and e == "lap") for e in extras)]


def _choice_row(
    label: str,
    batch: Batch,
    chosen_keys: tuple[str, ...],
    records: Records,
    seeds: Sequence[int],
    extras: Sequence[str],
) -> list[str]:
    """Starts finished of 13 by the weights `make quick`'s rule chose, each with its step, and whether none of the
    candidates finished the held-out starts (the rule then keeps the last weights)."""
    section = _dig(records(f"{LOG}/{batch[0]}"), batch[1])
    chosen = {row["training_seed"]: row for row in section["seeds"]}
    cells, total = [], 0
    for row in (row for row in _seed_rows(records, batch) if row["seed"] in seeds):
        step = _dig(chosen[row["seed"]], chosen_keys)
        held_out = chosen[row["seed"]]["held_out_starts_100_104"][str(step)][:SELECT_STARTS]
        none = "" if all(start["finished"] for start in held_out) else ", none finished"
        cells.append(f"{row['of_13']} ({step // 1000}k{none})")
        total += row["of_13"]
    return [label, *cells, f"{total}/{13 * len(cells)}"]


def _steering_row(
    label: str, file: str, keys: tuple[str, str], measure: str, records: Records, seeds: Sequence[int], _: Sequence[str]
) -> list[str]:
    """A steering figure of two batches per training seed, ``a / b``, and its mean over the seeds (the second bold);
    the share of steps reversing across half the usable angle in percent."""
    section = records(f"{LOG}/{file}")["steering_above_130_kmh_last_weights_starts_0_2"]
    percent = measure == "reversals_over_half"
    scale, decimals, mean_decimals = (100.0, 0, 1) if percent else (1.0, 2, 2)
    first, second = ({s: scale * section[key][str(s)][measure] for s in seeds} for key in keys)
    cells = [f"{first[s]:.{decimals}f} / {second[s]:.{decimals}f}" for s in seeds]
    means = [sum(figures.values()) / len(seeds) for figures in (first, second)]
    return [label, *cells, f"{means[0]:.{mean_decimals}f} / **{means[1]:.{mean_decimals}f}**"]


#: A row of a table of seeds: ``(records, seeds, extra columns) -> cells``.
SeedsRow = Callable[[Records, Sequence[int], Sequence[str]], list[str]]


@dataclass(frozen=True)
class SeedsTable:
    """A table of starts finished per training seed: its seeds, rows and records, and the columns beside the seeds
    (:data:`EXTRA_HEADERS`, headers replaced by ``headers``)."""

    seeds: tuple[int, ...]
    rows: tuple[SeedsRow, ...]
    files: tuple[str, ...]
    extras: tuple[str, ...] = ()
    headers: dict[str, str] = field(default_factory=dict)


EXTRA_HEADERS = {"protocol": "protocol's starts", "lap": "lap: mean ± std", "wall": "wall contact per lap"}


def seeds_table(
    records: Records,
    seeds: Sequence[int],
    rows: Sequence[SeedsRow],
    files: Sequence[str],
    extras: Sequence[str] = (),
    headers: dict[str, str] | None = None,
) -> str:
    """Starts finished of 13 per training seed, a row per batch of runs (or a figure of theirs), with links to the
    records ``files`` they are read from."""
    names = {**EXTRA_HEADERS, **(headers or {})}
    header = ("training seed", *map(str, seeds), "all", *(names[e] for e in extras))
    table = markdown_table(header, (row(records, seeds, extras) for row in rows))
    return f"{table}\nRecords: {', '.join(link(file, f'{LOG}/{file}') for file in files)}.\n"


LAST, RULE = "last (150k)", "3_held_out_of_100k_125k_150k (make quick)"
SELECT, ENTROPY, STUCK = (
    "quick_select_starts13.json",
    "quick_entropy_lr_starts13.json",
    "quick_stuck_ends_starts13.json",
)
USABLE, C1 = "quick_steer_usable_starts13.json", "quick_steer_usable_c1_starts13.json"
S4_11, S4_7 = tuple(range(4, 12)), tuple(range(4, 8))
STEER_USABLE = ("stuck_ends_without_it (quick_stuck_ends_starts13.json's runs)", "with_the_penalty")
STEER_C1 = ("c_s_0.5 (quick_steer_usable_starts13.json's runs)", "c_s_1.0")
LAST_WEIGHTS = "last weights (150k)"
CHOSEN = "the weights chosen by 3 held-out starts (step)"


def _last(label: str, file: str, bold: bool = False) -> SeedsRow:
    """The row of a batch's last weights, from its list of starts finished."""
    return partial(_starts_row, label, ((file, (), LAST),), bold=bold)


def _chosen(
    label: str, file: str, counts_key: str = RULE, chosen_keys: tuple[str, ...] = ("chosen_steps", RULE)
) -> SeedsRow:
    """The row of the weights a batch's rule chose (by default `make quick`'s: 3 held-out starts)."""
    return partial(_choice_row, label, (file, (), counts_key), chosen_keys)


LABELS, STATE_LAPS = "quick_labels30_starts13.json", "quick_state_policy_laps_starts13.json"
ON_THE_JOBS_ENCODER = "`make quick`'s recipe on the job's encoder (the section on the penalty)"


def _against_recipe(
    label: str,
    file: str,
    seeds: tuple[int, ...] = S4_11,
    recipe: str = "`make quick`'s recipe (c_s 0.5, the sections above): last weights, starts finished of 13",
    also: tuple[str, str] | None = None,
) -> SeedsTable:
    """A batch's last weights under `make quick`'s recipe of c_s 0.5 on the same training seeds (and ``also`` a
    batch between them: its file and label)."""
    between = (_last(also[1], also[0]),) if also else ()
    files = (USABLE, *(also[:1] if also else ()), file)
    return SeedsTable(
        seeds, (_last(recipe, USABLE), *between, _last(f"{label}: {LAST_WEIGHTS}", file, bold=True)), files
    )


#: The log's tables of starts finished per training seed, 150k steps: (seeds, rows, the records they read).
SEEDS_TABLES: dict[str, SeedsTable] = {
    "vision-log-select": SeedsTable(
        S4_11,
        (
            _last(f"{LAST_WEIGHTS}: starts finished of 13", SELECT),
            _chosen("weights chosen among 100k, 125k, 150k by 3 held-out starts (step)", SELECT),
            _chosen(
                "the same among 100k and 150k only",
                SELECT,
                "3_held_out_of_100k_150k",
                ("chosen_steps", "3_held_out_of_100k_150k"),
            ),
        ),
        (SELECT,),
    ),
    "vision-log-entropy": SeedsTable(
        S4_11,
        (
            _last("the section above: last weights, starts finished of 13", SELECT),
            _chosen("the section above: the weights chosen by 3 held-out starts (step)", SELECT),
            _last(f"entropy target -4, learning rate to 1e-4: {LAST_WEIGHTS}", ENTROPY, bold=True),
            _chosen(f"the same, {CHOSEN}", ENTROPY),
        ),
        (SELECT, ENTROPY),
    ),
    "vision-log-stuck-ends": SeedsTable(
        S4_11,
        (
            _last("the section above: last weights, starts finished of 13", ENTROPY),
            _last(f"stuck cars end their episodes: {LAST_WEIGHTS}", STUCK, bold=True),
            _chosen(f"the same, {CHOSEN}", STUCK),
        ),
        (ENTROPY, STUCK),
    ),
    "vision-log-steer-usable": SeedsTable(
        S4_11,
        (
            _last("stuck ends (the section above): last weights, starts finished of 13", STUCK),
            _last(f"and the penalty against the usable angle, c_s 0.5: {LAST_WEIGHTS}", USABLE, bold=True),
            _chosen(
                f"the same, {CHOSEN}",
                USABLE,
                "chosen (seeds with a finished choice)",
                ("chosen_steps_by_3_held_out_starts",),
            ),
            partial(
                _steering_row,
                "mean change of the wheel per step above 130 km/h, share of the usable angle: stuck ends / and the "
                "penalty",
                USABLE,
                STEER_USABLE,
                "mean_change_share_of_usable",
            ),
            partial(
                _steering_row,
                "steps reversing by more than half the usable angle, %: stuck ends / and the penalty",
                USABLE,
                STEER_USABLE,
                "reversals_over_half",
            ),
        ),
        (STUCK, USABLE),
    ),
    "vision-log-c1": SeedsTable(
        S4_11,
        (
            _last("c_s 0.5 (the section above, `make quick`'s): last weights, starts finished of 13", USABLE),
            _last(f"c_s 1.0: {LAST_WEIGHTS}", C1, bold=True),
            partial(
                _steering_row,
                "mean change of the wheel per step above 130 km/h, share of the usable angle: c_s 0.5 / 1.0",
                C1,
                STEER_C1,
                "mean_change_share_of_usable",
            ),
            partial(
                _steering_row,
                "steps reversing by more than half the usable angle, %: c_s 0.5 / 1.0",
                C1,
                STEER_C1,
                "reversals_over_half",
            ),
        ),
        (USABLE, C1),
    ),
    "vision-log-c025": SeedsTable(
        S4_7,
        (
            _last(
                "c_s 0.5 (`make quick`'s, two sections above, on the earlier encoder): last weights, starts finished "
                "of 13",
                USABLE,
            ),
            _last(f"c_s 0.25: {LAST_WEIGHTS}", "quick_steer_usable_c025_seeds4_7_starts13.json", bold=True),
        ),
        (USABLE, "quick_steer_usable_c025_seeds4_7_starts13.json"),
    ),
    "vision-log-restart": _against_recipe(
        "and half the starts before stuck places", "quick_restart_before_stuck_starts13.json"
    ),
    "vision-log-wall-ends": _against_recipe(
        "and wall contact ends the training episode", "quick_wall_ends_starts13.json"
    ),
    "vision-log-labels": _against_recipe("and the AI's labels, weight 30", LABELS),
    "vision-log-pedal-labels": _against_recipe(
        "the AI's pedal labels alone, weight 30",
        "quick_pedal_labels30_starts13.json",
        also=(LABELS, "the AI's labels, both columns (the section above)"),
    ),
    "vision-log-wall-frames": _against_recipe(
        "on the encoder of frames at 0.6 rad", "quick_wall_frames_starts13.json", S4_7, ON_THE_JOBS_ENCODER
    ),
    "vision-log-state-policy-laps-4-7": _against_recipe(
        "on the encoder that also saw the state policy's laps", STATE_LAPS, S4_7, ON_THE_JOBS_ENCODER
    ),
    "vision-log-state-policy-laps": _against_recipe(
        "on the encoder that also saw the state policy's laps",
        STATE_LAPS,
        recipe="`make quick`'s recipe on the job's encoder",
    ),
}

#: The 200k-step batches on the 200k job's encoder (sha256 5144e91a...; training seeds 0 and 12-18), their records.
STEPS_200K = ("quick_200k_steps_second_encoder_starts13.json", ("steps_200k",), None)
SEEDS_15_18 = ("quick_200k_steps_seeds15_18_starts13.json", (), None)
S0_12_14 = (0, 12, 13, 14)
WALL_MEDIANS = {"wall": "wall contact per lap (mean of the seeds' medians)"}
JOBS_RECIPE = "the job's recipe, c_w 0.005 (above)"


def _batch(label: str, file: str, keys: tuple[str, ...], **options: Any) -> SeedsRow:
    """The row of a batch of ``per_seed`` rows."""
    return partial(_starts_row, label, ((file, keys, None),), **options)


SEEDS_TABLES |= {
    "vision-log-200k": SeedsTable(
        S4_11,
        (
            _last("`make quick`'s recipe, 150k steps, on the earlier encoder", USABLE),
            _batch(
                "the same 150k steps on this encoder",
                "quick_200k_steps_starts13.json",
                ("steps_150k_same_encoder_seeds_4_7",),
            ),
            _batch("200k steps on this encoder", "quick_200k_steps_starts13.json", ("steps_200k",), bold=True),
        ),
        (USABLE, "quick_200k_steps_starts13.json"),
    ),
    "vision-log-200k-second-encoder": SeedsTable(
        S0_12_14,
        (
            _batch("150k steps", STEPS_200K[0], ("steps_150k",)),
            partial(_starts_row, "200k steps", (STEPS_200K,), bold=True, ai=True),
        ),
        (STEPS_200K[0],),
        ("protocol", "lap"),
        {"lap": "lap: mean ± std over the 4 seeds"},
    ),
    "vision-log-200k-c-w": SeedsTable(
        S0_12_14,
        (
            partial(_starts_row, JOBS_RECIPE, (STEPS_200K,)),
            _batch("c_w 0.01", "quick_200k_wall_c_w_001_starts13.json", ("c_w_0_01",)),
        ),
        (STEPS_200K[0], "quick_200k_wall_c_w_001_starts13.json"),
        ("protocol", "lap", "wall"),
        WALL_MEDIANS,
    ),
    "vision-log-300k": SeedsTable(
        S0_12_14,
        (
            partial(_starts_row, "200k steps, the job's recipe (above)", (STEPS_200K,)),
            _batch("the 300k runs' weights at 250k", "quick_300k_steps_starts13.json", ("steps_300k_run_at_250k",)),
            _batch("300k steps, last weights", "quick_300k_steps_starts13.json", ("steps_300k",)),
        ),
        (STEPS_200K[0], "quick_300k_steps_starts13.json"),
        ("protocol", "lap"),
        {"lap": "lap: mean ± std over the 4 seeds"},
    ),
    "vision-log-200k-impact": SeedsTable(
        S0_12_14,
        (
            partial(_starts_row, "the job's recipe, the papers' end speed (above)", (STEPS_200K,)),
            _batch("the impact speed", "quick_200k_wall_impact_starts13.json", ("impact",)),
        ),
        (STEPS_200K[0], "quick_200k_wall_impact_starts13.json"),
        ("protocol", "lap", "wall"),
        {**WALL_MEDIANS, "lap": "lap: mean ± std over the 4 seeds"},
    ),
    "vision-log-critic-state": SeedsTable(
        (0, *range(12, 19)),
        (
            partial(_starts_row, "the job's recipe (above)", (STEPS_200K, SEEDS_15_18)),
            _batch("the critic also reads the state", "quick_critic_state_starts13.json", ("critic_state",), bold=True),
        ),
        (STEPS_200K[0], SEEDS_15_18[0], "quick_critic_state_starts13.json"),
        ("protocol", "lap"),
        {"lap": "lap: mean ± std over the 8 seeds"},
    ),
}


@dataclass(frozen=True)
class ExperimentRow:
    """A row of a table of `vision-rl experiment` records: its label, the record (and learning curves) in
    :data:`LOG`, whether its figures are bold, the state agent's record it is set against (a path under the results),
    and a record of its wall hits when the experiment's own has none."""

    label: str
    file: str
    curves: str | None = None
    bold: bool = False
    state: str | None = None
    hits: str | None = None


def _hits_text(records: Records, row: ExperimentRow, per_seed: list[dict[str, Any]]) -> str:
    """Wall hits in each seed's scored lap and the range of the fastest hit's speed."""
    seeds = records(f"{LOG}/{row.hits}")["seeds"] if row.hits else per_seed
    fastest = [seed["fastest_wall_hit_kmh"] for seed in seeds]
    hits = ", ".join(str(seed["wall_hits"]) for seed in seeds)
    return f"{hits} (fastest {min(fastest):.0f}-{max(fastest):.0f} km/h)"


def _experiment_cells(records: Records, row: ExperimentRow) -> dict[str, str]:
    """The figures of an experiment's final evaluation (the protocol's 3 starts per training seed) a table can show."""
    record = records(f"{LOG}/{row.file}")
    summary, per_seed = record["summary"], record["per_seed"]
    mean_s, std_s = summary["lap_time_mean_s"], summary["lap_time_std_s"]
    walls_s = [seed["wall_contact_s"] for seed in per_seed if seed["wall_contact_s"] is not None]
    done, total = summary["finished"].split("/")
    each = "" if done == total else f" ({', '.join(seed['finished'] for seed in per_seed)})"
    lap = bold_if(f"{lap_text(mean_s)} ± {std_s:.2f} s", row.bold)
    cells = {
        "lap": lap,
        "lap_seeds": f"{lap} ({summary['n_training_seeds_finished']} of {summary['n_training_seeds']} seeds)",
        "best": lap_text(summary["best_lap_time_s"]),
        "starts": bold_if(f"{summary['finished']}{each}", row.bold),
        "wall_range": f"{min(walls_s):.1f}-{max(walls_s):.1f} s ({summary['wall_contact_mean_s']:.2f} ± "
        f"{summary['wall_contact_std_s']:.2f})",
        "wall_seeds": ", ".join("-" if w is None else f"{w:.2f}" for w in (seed["wall_contact_s"] for seed in per_seed))
        + " s",
        "ai": bold_if(faster_text(mean_s, reference_laps(records, AI_HATCHBACK)[0]), row.bold),
    }
    if row.hits or "wall_hits" in per_seed[0]:
        cells["hits"] = _hits_text(records, row, per_seed)
    if row.state:
        state_s = records(row.state)["summary"]["lap_time_mean_s"]
        slower = 100.0 * (mean_s / state_s - 1.0)
        cells["state"] = (
            f"{abs(slower):.2f} % {'slower' if slower > 0 else 'faster'} than its {link(lap_text(state_s), row.state)}"
        )
    return cells


EXPERIMENT_HEADERS = {
    "lap": "lap: mean ± std over 3 training seeds",
    "lap_seeds": "lap: mean ± std over the seeds that finished",
    "best": "best seed",
    "starts": "starts finished",
    "wall_range": "wall contact per lap (mean ± std)",
    "wall_seeds": "wall contact per lap (seeds 0, 1, 2)",
    "hits": "wall hits (seeds 0, 1, 2)",
    "ai": "against the AI ({ai})",
    "state": "against the state agent of the same action",
}


def experiments_table(records: Records, first: str, rows: Sequence[ExperimentRow], columns: Sequence[str]) -> str:
    """One row per experiment (a recipe over training seeds through the protocol), labelled under ``first``, with
    links to its record and curves."""
    body = []
    for row in rows:
        cells = _experiment_cells(records, row)
        links = [link("record", f"{LOG}/{row.file}"), *([link("curves", f"{LOG}/{row.curves}")] if row.curves else [])]
        body.append((f"{bold_if(row.label, row.bold)} ({', '.join(links)})", *(cells[c] for c in columns)))
    ai = lap_text(reference_laps(records, AI_HATCHBACK)[0])
    return markdown_table((first, *(EXPERIMENT_HEADERS[c].format(ai=ai) for c in columns)), body)


def seeds_log_table(records: Records, name: str) -> str:
    """One of :data:`SEEDS_TABLES`."""
    spec = SEEDS_TABLES[name]
    return seeds_table(records, spec.seeds, spec.rows, spec.files, spec.extras, spec.headers)


STEER_SHARE = "quick_steer_share_starts13.json"
#: The two arms of the steering-step screen: (label, the arm's key in :data:`STEER_SHARE`).
STEER_SHARE_ARMS = (
    ("`rate_scaled` (`make quick`)", "qv-base"),
    ("with a step of at most 0.25 of the usable angle", "qv-share25"),
)


def steer_share_table(records: Records) -> str:
    """The screen of a smaller steering step: each policy's starts finished of 13 and the median of its laps."""
    arms = records(f"{LOG}/{STEER_SHARE}")["arms"]
    body = []
    for label, key in STEER_SHARE_ARMS:
        policies = sorted(arms[key]["policies"], key=lambda policy: policy["training_seed"])
        medians_s = [
            statistics.median(start["lap_time_s"] for start in policy["starts"] if start["finished"])
            for policy in policies
        ]
        bold = key == "qv-base"
        body.append(
            (
                label,
                f"{', '.join(str(policy['finished']) for policy in policies)} of 13",
                bold_if(arms[key]["finished"], bold),
                ", ".join(map(lap_text, medians_s)),
            )
        )
    header = ("steering", "starts finished, per training seed (0-3)", "all", "scored laps: each policy's median")
    table = markdown_table(header, body)
    return f"{table}\nRecord: {link(STEER_SHARE, f'{LOG}/{STEER_SHARE}')}.\n"


#: The frame groups of an encoder's error on the policies' own frames: (key, label).
ENCODER_ERROR_GROUPS = (
    ("all", "two policies that finished"),
    ("near_wall", "the same, within 1.5 m of a wall"),
    ("wall_contact", "the same, in wall contact"),
    ("heading_0.2_1.2", "the same, heading 0.2-1.2 rad off the track's"),
)
#: A row of a table of two encoders' errors: (label, the keys down the record's ``encoder`` to the pair, the group).
EncoderErrorRow = tuple[str, tuple[str, ...], str]
WALL_FRAMES = "quick_wall_frames_starts13.json"
WALL_FRAMES_POLICIES = (
    "error_on_policy_frames",
    "two_policies_that_finished (seed 8 of the restart study, seed 5 of the pedal labels)",
)


def _lower_bold(old: float, new: float, decimals: int) -> str:
    """``old / new`` with the smaller of the two in bold (neither when they read alike)."""
    texts = [f"{x:.{decimals}f}" for x in (old, new)]
    if texts[0] != texts[1]:
        low = 0 if old < new else 1
        texts[low] = f"**{texts[low]}**"
    return " / ".join(texts)


def encoder_error_table(
    records: Records, file: str, rows: Sequence[EncoderErrorRow], pair: tuple[str, str] = ("old", "new")
) -> str:
    """The mean absolute error of the job's encoder and a new one on the vision policies' own frames, per group of
    frames (the smaller bold), from the ``encoder`` key of ``file``; ``pair``: the two encoders' keys."""
    body = []
    for label, keys, group in rows:
        old, new = (_dig(records(f"{LOG}/{file}")["encoder"], keys)[key][group] for key in pair)
        if old["frames"] != new["frames"]:
            raise ReportError(f"{file}: the two encoders' errors on {group} are over different frames")
        cells = [
            _lower_bold(old[target], new[target], decimals)
            for target, decimals in (("centre_offset", 2), ("heading", 3), ("edge_rays", 2))
        ]
        body.append((f"{label} ({old['frames']:,} frames)", *cells))
    header = ("frames", "centre offset, m: job's / new", "heading, rad: job's / new", "edge rays, m: job's / new")
    return f"{markdown_table(header, body)}\nRecord: {link(file, f'{LOG}/{file}')}, key `encoder`.\n"


ENCODER_ERROR = "encoder_error.json"
#: The policies of `evaluate --encoder-error`'s record: (label, its run in the record).
ENCODER_ERROR_RUNS = (
    ("3-step, 400k steps, seed 0", "exp/seed-0"),
    ("seed 1", "exp/seed-1"),
    ("seed 2", "exp/seed-2"),
    ("labels + cut, seed 0", "label/seed-0"),
    ("seed 1", "label/seed-1"),
    ("seed 2", "label/seed-2"),
)


def _error_cells(errors: list[dict[str, Any]]) -> list[str]:
    """The encoder's mean absolute error over a lap's frames, near a wall and in wall contact; a range over several
    laps' ``errors``."""

    def span(group: str, target: str, spec: str) -> str:
        return span_text((error[group][target] for error in errors), "", spec).strip()

    contact = (
        "none"
        if not any(error["wall_contact"]["frames"] for error in errors)
        else f"{span('wall_contact', 'frames', 'd')}: {span('wall_contact', 'centre_offset', '.2f')} / "
        f"{span('wall_contact', 'edge_rays', '.2f')}"
    )
    return [
        span("all", "centre_offset", ".2f"),
        span("all", "heading", ".3f"),
        span("all", "edge_rays", ".2f"),
        f"{span('near_wall', 'frames', 'd')}: {span('near_wall', 'centre_offset', '.2f')}",
        contact,
    ]


def policy_encoder_error_table(records: Records) -> str:
    """The quick encoder's error along each policy's best lap, and the range of its error on the built-in AI's lap
    from the same starts: where the policies drive, the encoder errs more than on the AI's laps it learned from."""
    runs = records(f"{LOG}/{ENCODER_ERROR}")["runs"]
    body = [
        (label, f"{runs[key]['wall_contact_s']:.2f}", *_error_cells([runs[key]["encoder_error"]["policy"]]))
        for label, key in ENCODER_ERROR_RUNS
    ]
    ais = [runs[key]["encoder_error"]["built_in_ai"] for _, key in ENCODER_ERROR_RUNS]
    contact = "0" if not any(ai["wall_contact"]["frames"] for ai in ais) else "-"
    skill = span_text((ai["skill"] for ai in ais), "", "g").strip()
    body.append((f"built-in AI, skill {skill}, the same starts", contact, *_error_cells(ais)))
    header = ("recipe, training seed", "wall contact on the lap, s", "centre offset error, m", "heading error, rad")
    header += ("edge-ray error, m", "frames near a wall (< 1.5 m): centre offset error, m")
    table = markdown_table((*header, "frames in wall contact: centre offset / edge-ray error, m"), body)
    return f"{table}\nRecord: {link(ENCODER_ERROR, f'{LOG}/{ENCODER_ERROR}')}.\n"


CRITIC_STATE = "quick_critic_state_starts13.json"
CRITIC_STATE_ENCODER_SEED1 = "quick_critic_state_encoder_seed1_starts13.json"
#: The runs with the critic that reads the state: (label, batch, whether the lap is set against the AI).
CRITIC_STATE_RUNS: tuple[tuple[str, Batch, bool], ...] = (
    ("training seeds 0 and 12-18, the 200k job's encoder (above)", (CRITIC_STATE, ("critic_state",), None), False),
    (
        "the job's own run (seed 0), the same encoder",
        (CRITIC_STATE_ENCODER_SEED1, ("make_quick_job_vision_run",), None),
        False,
    ),
    (
        "training seeds 0-3, the encoder of Phase 1 seed 1",
        (CRITIC_STATE_ENCODER_SEED1, ("critic_state_encoder_seed1",), None),
        True,
    ),
)


def critic_state_runs_table(records: Records) -> str:
    """Every run with the critic that reads the state, by encoder: starts finished of 13, runs losing any, the
    protocol's starts and lap, the seeds' median wall contact, and all the runs together."""
    ai_s = reference_laps(records, AI_HATCHBACK)[0]
    body, runs = [], []
    for label, batch, against_ai in CRITIC_STATE_RUNS:
        rows = _seed_rows(records, batch)
        runs += rows
        laps_s = [row["lap_s"] for row in rows if row["lap_s"] is not None]
        mean_s, std_s = mean_std_s(laps_s)
        lap = lap_text(mean_s) if len(laps_s) == 1 else f"{lap_text(mean_s)} ± {std_s:.2f} s"
        walls_s = [row["wall_s"] for row in rows]
        body.append(
            (
                f"{label} ({link('record', f'{LOG}/{batch[0]}')})",
                ", ".join(str(row["of_13"]) for row in rows),
                f"{sum(row['of_13'] for row in rows)}/{13 * len(rows)}",
                f"{sum(row['of_13'] < 13 for row in rows)} of {len(rows)}",
                f"{sum(row['of_3'] for row in rows)}/{3 * len(rows)}",
                lap + (f" ({faster_text(mean_s, ai_s)})" if against_ai else ""),
                f"{walls_s[0]:.2f} s" if len(walls_s) == 1 else f"{min(walls_s):.1f}-{max(walls_s):.1f} s",
            )
        )
    body.append(
        (
            f"**all {len(runs)} runs, two encoders**",
            "",
            f"**{sum(row['of_13'] for row in runs)}/{13 * len(runs)}**",
            f"**{sum(row['of_13'] < 13 for row in runs)} of {len(runs)}**",
            f"**{sum(row['of_3'] for row in runs)}/{3 * len(runs)}**",
            "",
            "",
        )
    )
    header = ("runs with the critic that reads the state", "starts finished of 13", "all", "runs losing any")
    return markdown_table(
        (*header, "protocol's starts", "lap: mean ± std", "wall contact per lap (the seeds' medians)"), body
    )


STATE_SPEED_SCALED = "state-expressway-hatchback-speed-scaled"
RATE_SCALED = ExperimentRow("`rate_scaled`, 1-step, 200k steps", "rate_scaled_experiment.json")
N_STEP_3 = ExperimentRow("3-step, 400k steps (above)", "rate_scaled_n3_experiment.json")
LABELS_CUT = ExperimentRow("the same with the labels and the cut", "label30_cut3_experiment.json")
#: The log's tables of experiments: (the first column's header, rows, columns of :data:`EXPERIMENT_HEADERS`).
EXPERIMENT_TABLES: dict[str, tuple[str, tuple[ExperimentRow, ...], tuple[str, ...]]] = {
    "vision-log-steer-actions": (
        "recipe",
        (
            ExperimentRow("the papers' steering action", "experiment.json", "learning_curves.png"),
            ExperimentRow(
                "`--steer-action speed_scaled`", "speed_scaled_experiment.json", "speed_scaled_learning_curves.png"
            ),
            ExperimentRow(
                "`--steer-action rate_scaled`", RATE_SCALED.file, "rate_scaled_learning_curves.png", bold=True
            ),
            ExperimentRow(
                "`speed_scaled` with the paper's frame delay, `--frame-delay-s 0.067`",
                "frame_delay_experiment.json",
                "frame_delay_learning_curves.png",
                bold=True,
            ),
        ),
        ("lap_seeds", "best", "starts", "wall_range"),
    ),
    "vision-log-encoder-seed1": (
        "encoder",
        (
            ExperimentRow("Phase 1 seed 0 (the quick encoder)", RATE_SCALED.file),
            ExperimentRow("Phase 1 seed 1", "encoder_seed1_experiment.json", "encoder_seed1_learning_curves.png"),
        ),
        ("lap_seeds", "best", "starts", "wall_range"),
    ),
    "vision-log-n-step": (
        "recipe",
        (
            ExperimentRow(
                RATE_SCALED.label, RATE_SCALED.file, state=f"{STATE_SPEED_SCALED}/rate_scaled_experiment.json"
            ),
            ExperimentRow(
                "`rate_scaled`, 3-step, 400k steps",
                N_STEP_3.file,
                "rate_scaled_n3_learning_curves.png",
                bold=True,
                state=f"{STATE_SPEED_SCALED}/rate_scaled_n3_experiment.json",
            ),
        ),
        ("lap", "best", "starts", "wall_range", "ai", "state"),
    ),
    "vision-log-labels-cut": (
        "recipe",
        (
            ExperimentRow(N_STEP_3.label, N_STEP_3.file, hits="rate_scaled_n3_wall_hits.json"),
            ExperimentRow(LABELS_CUT.label, LABELS_CUT.file, "label30_cut3_learning_curves.png"),
        ),
        ("lap", "best", "starts", "wall_seeds", "hits", "ai"),
    ),
    "vision-log-policy-frames": (
        "encoder (the labelled recipe, 3 training seeds)",
        (
            ExperimentRow("quick (the AI's frames), above", LABELS_CUT.file),
            ExperimentRow(
                "the AI's frames and the labelled policies' own",
                "label30_cut3_policy_frames_experiment.json",
                "label30_cut3_policy_frames_learning_curves.png",
                bold=True,
            ),
        ),
        ("lap", "best", "starts", "wall_seeds", "hits", "ai"),
    ),
}

#: The log's tables, by the name a page marks them with.
VISION_LOG_TABLES: dict[str, Callable[[Records], str]] = {
    **{name: partial(seeds_log_table, name=name) for name in SEEDS_TABLES},
    "vision-log-critic-state-runs": critic_state_runs_table,
    "vision-log-steer-share": steer_share_table,
    "vision-log-state-policy-laps-encoder": partial(
        encoder_error_table,
        file=STATE_LAPS,
        rows=[(label, ("error_on_policy_frames",), key) for key, label in ENCODER_ERROR_GROUPS],
        pair=("job_encoder", "this_encoder"),
    ),
    "vision-log-policy-encoder-error": policy_encoder_error_table,
    "vision-log-wall-frames-encoder": partial(
        encoder_error_table,
        file=WALL_FRAMES,
        rows=[
            *((label, WALL_FRAMES_POLICIES, key) for key, label in ENCODER_ERROR_GROUPS),
            (
                "a policy that stops at the last corner from every start (every 5th frame), heading 0.2-1.2 rad",
                (
                    "error_on_policy_frames",
                    "a_policy_that_stops_at_the_last_corner (seed 4 of the pedal labels, every 5th frame)",
                ),
                "heading_0.2_1.2",
            ),
        ],
    ),
    **{
        name: partial(experiments_table, first=first, rows=rows, columns=columns)
        for name, (first, rows, columns) in EXPERIMENT_TABLES.items()
    },
}
