"""The state agent's tables: each recipe's lap through the protocol over its training seeds beside the physical limit
and the built-in AI (the study's driver table, whose builder the vision study's can share), the n-step comparison and
the steering-change penalty's, and the 25 Hz and clean-laps studies' tables (each seed's laps, the last against the
chosen weights, changes side by side, the periodic evaluations), from the `vision-rl experiment`, probes and
learning-curve records."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import partial
from typing import Any

from vision_rl.evaluation.report.common import (
    AI_HATCHBACK,
    bold_if,
    faster_text,
    gap_text,
    lap_text,
    link,
    markdown_table,
    mean_std_s,
    reference_laps,
    span_text,
    steps_text,
)
from vision_rl.evaluation.report.records import Records, ReportError
from vision_rl.evaluation.report.vision import QUICK_JOB, experiment_seeds, seeds_summary

#: The built-in AI at skill 1.0 through the protocol and both skills' laps before it, transcribed (no JSON was kept).
AI_TRANSCRIBED = "reference-laps/ai_expressway_hatchback_transcribed.json"
#: `make quick`'s state policy on the other occasions of the machine, transcribed from the job's printed summaries.
QUICK_STATE_OCCASIONS = "make-quick/state_occasions.json"


@dataclass(frozen=True)
class Seeds:
    """Training seeds pooled from records: the last weights', or with ``selected`` those chosen by held-out starts;
    ``name`` says which in a row of several sets; ``arm`` the arm of a probes record (``{"arms": [{"arm": ...,
    "per_seed": [...]}]}``)."""

    paths: tuple[str, ...]
    selected: bool = False
    name: str = ""
    arm: str = ""


@dataclass(frozen=True)
class Recipe:
    """A row of a driver table: ``label`` (Markdown), then the mean lap of each set of seeds (``/`` between sets), or
    with ``best`` the fastest seed's (the paper's score); ``study`` a results page the row links; ``curves`` the
    learning-curve records of its seeds (a driver table states their training time per seed, a seeds table links
    them); ``listed``: a seeds table gives each seed's own row above the recipe's; no sets: a link row."""

    label: str
    sets: tuple[Seeds, ...] = ()
    best: bool = False
    bold: bool = False
    study: str = ""
    curves: tuple[str, ...] = ()
    listed: bool = False


def seed_rows(records: Records, seeds: Seeds) -> list[dict[str, Any]]:
    """The per-seed rows of ``seeds``: from `vision-rl experiment` records, or from a record of snapshots keyed by the
    training seed (``{"0": {"lap_time_s": ..., "finished": "3/3", ...}}``)."""
    rows: list[dict[str, Any]] = []
    for path in seeds.paths:
        record = records(path)
        if seeds.arm:
            rows += next(arm["per_seed"] for arm in record["arms"] if arm["arm"] == seeds.arm)
        elif "per_seed" in record:
            rows += experiment_seeds(records, [path], seeds.selected)
        else:
            rows += [{"seed": int(key), **row} for key, row in record.items() if key.isdigit()]
    if not rows:
        raise ReportError(f"no training seed in {', '.join(seeds.paths)}")
    return rows


def wall_text(rows: list[dict[str, Any]]) -> str:
    """Wall contact per scored lap, mean ± std over the seeds with a lap: ``0.10 ± 0.14 s``."""
    wall_s, wall_std_s = mean_std_s(row["wall_contact_s"] for row in rows if row["lap_time_s"] is not None)
    return f"{wall_s:.2f} ± {wall_std_s:.2f} s"


def clean_text(rows: list[dict[str, Any]]) -> str:
    """How many seeds were clean: ``clean for every seed``, ``clean for 2 of 3 seeds``, ``not clean``."""
    clean = sum(bool(row.get("clean")) for row in rows)
    return {len(rows): "clean for every seed", 0: "not clean"}.get(clean, f"clean for {clean} of {len(rows)} seeds")


def seeds_details(rows: list[dict[str, Any]], selected: bool = False) -> str:
    """Starts finished, wall contact per scored lap (mean ± std over the seeds with a lap), how many seeds were clean,
    and with ``selected`` the steps whose weights the held-out starts chose."""
    done, total = (sum(int(row["finished"].split("/")[i]) for row in rows) for i in (0, 1))
    text = f"{done} of {total} starts; {wall_text(rows)} of wall contact per lap, {clean_text(rows)}"
    if selected:
        kept = [row["kept_at_steps"] for row in rows]
        text += f"; chosen at {steps_text(min(kept))}-{steps_text(max(kept))} steps"
    return text


def _laps(rows: list[dict[str, Any]], best: bool) -> tuple[float, str]:
    """The seeds' mean lap with its spread (``2:09.293 ± 0.31 s``, how many lapped if not all), or the best one."""
    laps_s = [row["lap_time_s"] for row in rows if row["lap_time_s"] is not None]
    if best:
        return min(laps_s), lap_text(min(laps_s))
    summary = seeds_summary(rows)
    spread = f" ± {summary['std_s']:.2f} s" if len(laps_s) > 1 else ""
    lapped = f" ({len(laps_s)} of {len(rows)} seeds with a lap)" if len(laps_s) < len(rows) else ""
    return summary["mean_s"], f"{lap_text(summary['mean_s'])}{spread}{lapped}"


def training_minutes(records: Records, paths: Iterable[str]) -> str:
    """The training time of each seed in learning-curve records (its last periodic evaluation), ``53-59 min``."""
    return span_text(
        (seed["train_time_s"][-1] / 60 for path in paths for seed in records(path)["per_seed"].values()), "min"
    )


def recipe_row(records: Records, recipe: Recipe, limit_s: float, ai_s: float) -> tuple[str, ...]:
    """A driver table's row of ``recipe``: its label with each set's details, lap, gap to the limit and to the AI."""
    study = link("study", recipe.study) if recipe.study else ""
    if not recipe.sets:
        return (f"{recipe.label} {study}".rstrip(), "", "", "")
    sets = [(seeds, seed_rows(records, seeds)) for seeds in recipe.sets]
    laps = [_laps(rows, recipe.best) for _, rows in sets]
    label = bold_if(recipe.label, recipe.bold)
    if len(sets) == 1 and not recipe.best and not sets[0][0].name:
        curves = f"{training_minutes(records, recipe.curves)} of training per seed" if recipe.curves else ""
        notes = (seeds_details(sets[0][1], sets[0][0].selected), curves, study)
        label += f" ({'; '.join(n for n in notes if n)})"
    else:
        if not recipe.best:
            label += " " + " / ".join(f"{seeds.name} ({seeds_details(rows, seeds.selected)})" for seeds, rows in sets)
        label += f" ({study})" if study else ""
    return (
        label,
        bold_if(" / ".join(text for _, text in laps), recipe.bold),
        bold_if(" / ".join(gap_text(lap_s, limit_s) for lap_s, _ in laps), recipe.bold),
        bold_if(" / ".join(gap_text(lap_s, ai_s) for lap_s, _ in laps), recipe.bold),
    )


def _reference_rows(records: Records, ai_s: float, limit_s: float) -> list[tuple[str, ...]]:
    """The physical limit, the built-in AI at skill 1.0 and at its default skill, with their records."""
    skill = records(AI_HATCHBACK)["driver"]["skill"]
    transcribed = records(AI_TRANSCRIBED)
    before = transcribed["before_protocol_lap_time_s"]

    def row(label: str, lap_s: float, path: str) -> tuple[str, ...]:
        return (f"{label} ({link('record', path)})", lap_text(lap_s), gap_text(lap_s, limit_s), gap_text(lap_s, ai_s))

    return [
        row("physical limit (QSS)", limit_s, AI_HATCHBACK),
        row(
            f"built-in AI, skill 1.0 (before the protocol, flying start: {lap_text(before['1.0'])})",
            transcribed["skill_1_lap_time_s"],
            AI_TRANSCRIBED,
        ),
        row(
            f"built-in AI, default skill {skill} (before the protocol: {lap_text(before[str(skill)])})",
            ai_s,
            AI_HATCHBACK,
        ),
    ]


def _quick_row(records: Records, stage: str, label: str, limit_s: float, ai_s: float) -> tuple[str, ...]:
    """`make quick`'s policy of ``stage`` (one training seed); for the state policy, its laps on the other occasions
    of the machine in brackets."""
    run = records(QUICK_JOB)[stage]
    others = records(QUICK_STATE_OCCASIONS)["other_occasions_lap_time_s"] if stage == "state" else []

    def cell(text: Iterable[str]) -> str:
        first, *rest = text
        return f"{first} ({', '.join(rest)})" if rest else first

    laps_s = [run["lap_time_s"], *others]
    return (
        f"{label} (one training seed; {run['finished'].replace('/', ' of ')} starts; {link('record', QUICK_JOB)})",
        cell(lap_text(s) for s in laps_s),
        cell(gap_text(s, limit_s) for s in laps_s),
        cell(gap_text(s, ai_s) for s in laps_s),
    )


def driver_table(
    records: Records, recipes: tuple[Any, ...], quick: tuple[str, str], row: Callable[..., tuple[str, ...]] = recipe_row
) -> str:
    """The limit, the built-in AI, `make quick`'s policy of ``quick`` = (stage, label), then each recipe's row (``row``
    writes it: another study's rows of other records too)."""
    ai_s, limit_s = reference_laps(records, AI_HATCHBACK)
    rows = [
        *_reference_rows(records, ai_s, limit_s),
        _quick_row(records, *quick, limit_s, ai_s),
        *(row(records, recipe, limit_s, ai_s) for recipe in recipes),
    ]
    return markdown_table(("driver", "lap", "gap to limit", "gap to AI"), rows)


def curves_compare_table(records: Records, path: str) -> str:
    """The periodic evaluations of the series in a `compare-curves` record side by side: each one's mean lap over its
    seeds at each step, and how many seeds had a lap there."""
    series = records(path)["series"]
    steps = series[0]["num_timesteps"]
    if any(s["num_timesteps"] != steps for s in series):
        raise ReportError(f"the series of {path} were not evaluated at the same steps")

    def cell(s: dict[str, Any], i: int) -> str:
        lap_s = s["mean_lap_time_s"][i]
        return "no seed finished" if lap_s is None else f"{lap_text(lap_s)} ({s['seeds_finished'][i]})"

    rows = [(steps_text(n), *(cell(s, i) for s in series)) for i, n in enumerate(steps)]
    header = ("steps", *(f"{s['name']}: mean lap (seeds with a lap)" for s in series))
    return f"{markdown_table(header, rows)}\n{link('record', path)}\n"


#: The rows a periodic-evaluations table can pick: each evaluation's cell from a learning-curve record.
CURVE_ROWS: dict[str, Callable[[dict[str, Any], int], str]] = {
    "epochs": lambda curves, i: f"{curves['epochs'][i]:.0f}",
    "training, min": lambda curves, i: f"{curves['mean_train_time_s'][i] / 60:.1f}",
    "seeds finished": lambda curves, i: curves["seeds_finished"][i],
    "mean lap": lambda curves, i: lap_text(curves["mean_lap_time_s"][i], 1),
    "spread, s": lambda curves, i: f"{curves['std_lap_time_s'][i]:.2f}",
}


def curves_steps_table(records: Records, path: str, rows: tuple[str, ...], from_steps: int = 0) -> str:
    """The periodic evaluations of a learning-curve record from ``from_steps`` on, one column per evaluation and the
    :data:`CURVE_ROWS` named in ``rows`` (the seeds' mean lap, its spread, training time): how a recipe learned."""
    curves = records(path)
    picked = [i for i, n in enumerate(curves["num_timesteps"]) if n >= from_steps]
    header = ("steps", *(steps_text(curves["num_timesteps"][i]) for i in picked))
    table = markdown_table(header, [(name, *(CURVE_ROWS[name](curves, i) for i in picked)) for name in rows])
    return f"{table}\n{link('record', path)}\n"


def seeds_columns_table(records: Records, columns: tuple[tuple[str, Seeds], ...], steering: str) -> str:
    """Recipes side by side, one column each: the seeds' mean and best lap, starts finished (per seed), wall contact
    on each seed's best lap, and the steering motion per step transcribed in ``steering`` ({column: [low, high]})."""
    sets = [seed_rows(records, seeds) for _, seeds in columns]
    motion = records(steering)

    def row(label: str, cell: Any) -> tuple[str, ...]:
        return (label, *(cell(rows, header) for (header, _), rows in zip(columns, sets, strict=True)))

    def laps(rows: list[dict[str, Any]]) -> list[float]:
        return [r["lap_time_s"] for r in rows if r["lap_time_s"] is not None]

    rows = [
        row("lap, mean ± std of the training seeds' best", lambda rows, _: _laps(rows, best=False)[1]),
        row("best of the seeds", lambda rows, _: lap_text(min(laps(rows)))),
        row(
            "starts finished",
            lambda rows, _: f"{seeds_summary(rows)['finished']} ({', '.join(r['finished'] for r in rows)})",
        ),
        row(
            "wall contact on each seed's best lap",
            lambda rows, _: span_text((r["wall_contact_s"] for r in rows if r["lap_time_s"]), "s", ".1f"),
        ),
        row(
            "mean change of the steering command per step",
            lambda _, h: span_text(motion["change_per_step_rad"][h], "rad", ".2f"),
        ),
        row(
            "sign changes of the steering command", lambda _, h: span_text(motion["sign_changes_pct"][h], "% of steps")
        ),
    ]
    links = ", ".join(link(header, path) for header, seeds in columns for path in seeds.paths)
    table = markdown_table(("", *(header for header, _ in columns)), rows)
    return f"{table}\nRecords: {links}, {link('steering', steering)}.\n"


def _links(recipe: Recipe) -> str:
    """Links to a recipe's records (``record``, or each by its name when several) and its learning curves."""
    paths = list(dict.fromkeys(path for seeds in recipe.sets for path in seeds.paths))
    names = (
        ["record"] if len(paths) == 1 else [path.rsplit("/", 1)[-1].removesuffix("_experiment.json") for path in paths]
    )
    curves = [link("curves", path) for path in recipe.curves]
    return ", ".join([*(link(name, path) for name, path in zip(names, paths, strict=True)), *curves])


def _seed_cells(row: dict[str, Any]) -> tuple[str, ...]:
    """A training seed's lap, starts finished, wall contact per lap and wall hits (the fastest one's speed)."""
    if row["lap_time_s"] is None:
        return (lap_text(None), row["finished"], "-", "-")
    hits = f"{row['wall_hits']} ({row['fastest_wall_hit_kmh']:.0f} km/h)"
    return (lap_text(row["lap_time_s"]), row["finished"], f"{row['wall_contact_s']:.2f} s", hits)


def seeds_table(records: Records, recipes: tuple[Recipe, ...], gaps: bool = False) -> str:
    """Each recipe's row (its seeds' mean lap, starts finished, wall contact) below its seeds' own rows where
    ``listed``, with ``gaps`` its gap to the limit and to the AI: how a recipe's laps spread over its seeds."""
    ai_s, limit_s = reference_laps(records, AI_HATCHBACK)
    header = ("seed", "lap", "starts finished", "wall contact per lap", "wall hits (fastest)")
    header += ("gap to limit", "gap to AI") if gaps else ()
    rows: list[tuple[str, ...]] = []
    for recipe in recipes:
        (seeds,) = recipe.sets
        pooled = seed_rows(records, seeds)
        if recipe.listed:
            rows += [(str(row["seed"]), *_seed_cells(row), *("",) * (len(header) - 5)) for row in pooled]
        lap_s, lap = _laps(pooled, best=False)
        cells = (
            f"{recipe.label} ({_links(recipe)})",
            lap,
            seeds_summary(pooled)["finished"],
            f"{wall_text(pooled)}, {clean_text(pooled)}",
            "",
            *((gap_text(lap_s, limit_s), gap_text(lap_s, ai_s)) if gaps else ()),
        )
        rows.append(tuple(bold_if(cell, recipe.bold) if cell else cell for cell in cells))
    return markdown_table(header, rows)


def _weights_cell(rows: list[dict[str, Any]], limit_s: float, ai_s: float, full: bool) -> str:
    """A set of seeds' mean lap and gap to the limit, and whether every seed was clean; with ``full`` also its starts
    finished, wall contact and gap to the AI."""
    lap_s, lap = _laps(rows, best=False)
    text = f"{lap}, {gap_text(lap_s, limit_s)}"
    if full:
        finished = seeds_summary(rows)["finished"]
        return f"{text}, {finished}, {clean_text(rows)} ({wall_text(rows)}), {faster_text(lap_s, ai_s)}"
    return text if all(row.get("clean") for row in rows) else f"{text}, {clean_text(rows)}"


def _seed_weights(row: dict[str, Any]) -> str:
    """A seed's lap with its wall contact: ``2:09.325 (0.09 s)``, ``: not clean`` where it was not."""
    if row["lap_time_s"] is None:
        return lap_text(None)
    return f"{lap_text(row['lap_time_s'])} ({row['wall_contact_s']:.2f} s{'' if row.get('clean') else ': not clean'})"


def selection_table(records: Records, recipes: tuple[Recipe, ...], held_out: str = "") -> str:
    """Each seed's lap with its last weights and with those its held-out starts chose, and when (with ``held_out``,
    at how many evaluations those starts were clean), then each recipe's means: what choosing the weights gains."""
    ai_s, limit_s = reference_laps(records, AI_HATCHBACK)
    clean_at = records(held_out) if held_out else {}

    def held(seed: int) -> tuple[str, ...]:
        if not held_out:
            return ()
        text = "{} of {}".format(*clean_at["per_seed"][str(seed)])
        other = clean_at.get("one_million_step_run", {}).get(str(seed))
        return (f"{text} (1M run: {other[0]} of {other[1]})" if other else text,)

    rows: list[tuple[str, ...]] = []
    for recipe in recipes:
        if recipe.listed:
            for path in recipe.sets[0].paths:
                steps = records(path)["steps"]
                last, chosen = (seed_rows(records, Seeds((path,), selected)) for selected in (False, True))
                for a, b in zip(last, chosen, strict=True):
                    kept = steps_text(b["kept_at_steps"]) + (
                        " (the last weights)" if b["kept_at_steps"] == steps else ""
                    )
                    rows.append((str(a["seed"]), _seed_weights(a), _seed_weights(b), kept, *held(a["seed"])))
        cells = [
            " / ".join(
                _weights_cell(seed_rows(records, Seeds(seeds.paths, selected)), limit_s, ai_s, recipe.bold)
                for seeds in recipe.sets
            )
            for selected in (False, True)
        ]
        label = f"{recipe.label} ({_links(recipe)})"
        rows.append(tuple(bold_if(c, recipe.bold) for c in (label, *cells)) + ("",) * (1 + bool(held_out)))
    header = ("seed", "last weights: lap (wall contact)", "chosen weights: lap (wall contact)", "chosen at (steps)")
    return markdown_table(header + (("held-out starts clean at (evaluations)",) if held_out else ()), rows)


#: A column of a changes table: its header and its cell from the records, the recipe and its seeds' rows.
Column = tuple[str, Callable[[Records, Recipe, list[dict[str, Any]]], str]]


def per_seed_cell(records: Records, recipe: Recipe, rows: list[dict[str, Any]], key: str, spec: str) -> str:
    """``key`` of each seed with a lap, in seed order (``3.30, 4.17, 3.58``); ``not counted`` where no record has it."""
    values = [row.get(key) for row in rows if row["lap_time_s"] is not None]
    return "not counted" if all(v is None for v in values) else ", ".join(f"{v:{spec}}" for v in values)


def periodic_cell(
    records: Records, recipe: Recipe, rows: list[dict[str, Any]], spans: tuple[tuple[int, int], ...], best: bool = False
) -> str:
    """The seeds' mean lap at the periodic evaluations of each span of steps, averaged (`` / `` between spans), with
    ``best`` the fastest in brackets: where a recipe's plateau sits, not one draw of its last weights."""
    (path,) = recipe.curves
    curves = records(path)
    texts = []
    for low, high in spans:
        laps_s = [
            lap
            for n, lap in zip(curves["num_timesteps"], curves["mean_lap_time_s"], strict=True)
            if low <= n <= high and lap is not None
        ]
        mean_s = mean_std_s(laps_s)[0]
        texts.append(f"{lap_text(mean_s, 2)} ({lap_text(min(laps_s), 2)})" if best else lap_text(mean_s, 2))
    return " / ".join(texts)


def _gap_cell(records: Records, recipe: Recipe, rows: list[dict[str, Any]], to_limit: bool) -> str:
    """The seeds' mean lap against the physical limit or the built-in AI."""
    ai_s, limit_s = reference_laps(records, AI_HATCHBACK)
    return gap_text(_laps(rows, best=False)[0], limit_s if to_limit else ai_s)


def _best_cell(records: Records, recipe: Recipe, rows: list[dict[str, Any]]) -> str:
    """The fastest seed's lap."""
    return lap_text(min(row["lap_time_s"] for row in rows if row["lap_time_s"] is not None))


#: The columns a changes table can pick.
LAP_COLUMN: Column = ("lap: mean ± std", lambda records, recipe, rows: _laps(rows, best=False)[1])
BEST_COLUMN: Column = ("best", _best_cell)
STARTS_COLUMN: Column = ("starts finished", lambda records, recipe, rows: seeds_summary(rows)["finished"])
WALL_COLUMN: Column = ("wall contact per lap", lambda records, recipe, rows: wall_text(rows))
LIMIT_COLUMN: Column = ("gap to limit", partial(_gap_cell, to_limit=True))
AI_COLUMN: Column = ("gap to AI", partial(_gap_cell, to_limit=False))
CLEAN_COLUMN: Column = ("clean", lambda records, recipe, rows: clean_text(rows))
LAPS_COLUMN: Column = (
    "laps (per seed)",
    lambda records, recipe, rows: ", ".join(lap_text(r["lap_time_s"]) for r in rows),
)
TRAINING_COLUMN: Column = ("training per seed", lambda records, recipe, rows: training_minutes(records, recipe.curves))


def changes_table(records: Records, recipes: tuple[Recipe, ...], columns: tuple[Column, ...]) -> str:
    """One row per recipe (its label and records, then ``columns`` over its seeds): changes to a recipe side by side."""
    rows = []
    for recipe in recipes:
        pooled = [row for seeds in recipe.sets for row in seed_rows(records, seeds)]
        cells = (f"{recipe.label} ({_links(recipe)})", *(cell(records, recipe, pooled) for _, cell in columns))
        rows.append(tuple(bold_if(c, recipe.bold) for c in cells))
    return markdown_table(("change", *(header for header, _ in columns)), rows)


H25 = "state-expressway-hatchback-25hz/"
CLEAN = "state-expressway-hatchback-clean/"
SPEED = "state-expressway-hatchback-speed-scaled/"
STEER05 = "state-expressway-hatchback-steer05/"


def _h25(*names: str) -> tuple[str, ...]:
    return tuple(f"{H25}{name}_experiment.json" for name in names)


def _h25_curves(*names: str) -> tuple[str, ...]:
    """The 25 Hz study's learning-curve records of the runs ``names``."""
    return tuple(f"{H25}{name}_learning_curves.json" for name in names)


SELECT_2M = _h25("dt04-ent4-lrf-select-2m", "dt04-ent4-lrf-select-2m-seeds345")
SELECT_1M = _h25("dt04-ent4-lrf-select", "dt04-ent4-lrf-select-seeds345", "dt04-ent4-lrf-select-seeds678")
ENT4_LRF = _h25("dt04-ent4-lrf", "dt04-ent4-lrf-seeds345")
DT04 = _h25("dt04", "dt04-seeds345")
LABEL30_CUT3 = (f"{CLEAN}label30-cut3_experiment.json", f"{CLEAN}label30-cut3-seeds345_experiment.json")
PAPERS_STEERING = ("state-expressway-hatchback/experiment.json",)

#: docs/studies/state-agent.md: the recipes, the best first, each row's recipe adding to the one below it.
STATE_AGENT_RECIPES = (
    Recipe(
        "SAC, state, 400k steps, `rate_scaled`, 3-step returns, 3 training seeds, the state agent beside it",
        (Seeds((f"{SPEED}rate_scaled_n3_experiment.json",)),),
    ),
    Recipe(
        "SAC, state, the recipe of the next row trained for 2M steps (the learning rate falling over them; `make "
        "experiment`), the weights chosen by 3 held-out starts, 6 training seeds",
        (Seeds(SELECT_2M, selected=True),),
        bold=True,
        curves=tuple(path.replace("_experiment", "_learning_curves") for path in SELECT_2M),
        study=f"{H25}README.md#twice-the-steps-every-set-of-3-seeds-under-3--of-the-limit",
    ),
    Recipe(
        "the same,",
        (
            Seeds(SELECT_2M[:1], True, "seeds 0-2 (`make experiment`)"),
            Seeds(SELECT_2M[1:], True, "seeds 3-5"),
            Seeds(SELECT_2M, False, "the last weights of all 6"),
        ),
    ),
    Recipe("the same, best of the 6 seeds' chosen weights (the paper's score)", (Seeds(SELECT_2M, True),), best=True),
    Recipe(
        "SAC, state, the recipe of the next row (25 Hz, the entropy target -4, the falling learning rate), the weights "
        "chosen by 3 held-out starts at the periodic evaluations (`--select-starts 3`, not in the papers), 1M steps, "
        "9 training seeds",
        (Seeds(SELECT_1M, selected=True),),
        bold=True,
        study=f"{H25}README.md#weights-chosen-by-held-out-starts-284--above-the-limit-over-9-seeds-clean-for-every-seed",
    ),
    Recipe(
        "the same,",
        (
            Seeds(SELECT_1M[:1], True, "seeds 0-2 alone (`make experiment`)"),
            Seeds(SELECT_1M[1:2], True, "seeds 3-5"),
            Seeds(SELECT_1M[2:], True, "seeds 6-8"),
            Seeds(SELECT_1M, False, "the last weights of all 9"),
        ),
    ),
    Recipe("the same, best of the 9 seeds' chosen weights (the paper's score)", (Seeds(SELECT_1M, True),), best=True),
    Recipe(
        "SAC, state, the 25 Hz recipe below with the entropy target -4 (`--target-entropy -4`) and the learning rate "
        "falling from 1e-3 to 1e-4 (`--learning-rate-final 1e-4`; neither in the papers), 6 training seeds, of which "
        "`make experiment` runs 0-2",
        (Seeds(ENT4_LRF),),
        bold=True,
        study=f"{H25}README.md#a-falling-learning-rate-with-the-entropy-target--4-within-3--of-the-limit-seeds-0-5",
    ),
    Recipe(
        "the same,",
        (Seeds(ENT4_LRF[:1], name="training seeds 0-2 alone"), Seeds(ENT4_LRF[1:], name="seeds 3-5 alone")),
    ),
    Recipe("the same, best of the 6 seeds (the paper's score)", (Seeds(ENT4_LRF),), best=True),
    Recipe(
        "the same,",
        (
            Seeds(
                _h25("dt04-ent4-lrf-repeat"),
                name="`make experiment` again, seeds 0-2 on another occasion, when the machine's floats differed and "
                "so did the runs",
            ),
            Seeds((*ENT4_LRF, *_h25("dt04-ent4-lrf-repeat")), name="all 9 runs"),
        ),
        study=f"{H25}README.md#seeds-0-2-again-make-experiment-from-a-fresh-clone-on-another-occasion",
    ),
    Recipe(
        "SAC, state, 1M steps of 0.04 s (25 Hz, `--control-dt-s 0.04`), `rate_scaled`, 8-step returns, the AI's labels "
        "(`--guide-label-weight 30`), the 3 s throttle cut, the pedal full at 0.9, c_w 0.002 per step, 6 training "
        "seeds, of which `make experiment` ran 0-2",
        (Seeds(DT04),),
        bold=True,
        study=f"{H25}README.md",
    ),
    Recipe("the same,", (Seeds(DT04[:1], name="training seeds 0-2 alone"),)),
    Recipe("the same, best of the 6 seeds (the paper's score)", (Seeds(DT04),), best=True),
    Recipe(
        "SAC, state, 400k steps, `rate_scaled`, 3-step returns, the built-in AI's labels of the policy's own states "
        "cloned beside SAC (`--guide-label-weight 30`) and a 3 s throttle cut after each wall hit in training "
        "(`--wall-hit-throttle-cut-s 3`; neither in the papers), 6 training seeds",
        (Seeds(LABEL30_CUT3),),
        bold=True,
        study=f"{CLEAN}README.md#clean-the-ais-labels-of-the-policys-own-states",
    ),
    Recipe("the same,", (Seeds(LABEL30_CUT3[:1], name="training seeds 0-2 alone"),)),
    Recipe(
        "the same recipe trained for 1.2M steps, 3 training seeds",
        (Seeds((f"{CLEAN}label30-cut3-1.2M_experiment.json",)),),
        study=f"{CLEAN}README.md#clean-the-ais-labels-of-the-policys-own-states",
    ),
    Recipe(
        "SAC, state observation, 1M steps, cpu preset, the papers' steering action, **3 training seeds**",
        (Seeds(PAPERS_STEERING),),
    ),
    Recipe("the same, best of the 3 seeds (the paper's score)", (Seeds(PAPERS_STEERING),), best=True),
    Recipe(
        "SAC, state, 400k steps, with a steering-change penalty c_s = 0.5, **3 training seeds**",
        (Seeds((f"{STEER05}experiment.json",)),),
    ),
    Recipe(
        "the same recipe without the penalty, its 400k-step snapshots", (Seeds((f"{STEER05}baseline_at_400k.json",)),)
    ),
    Recipe(
        "SAC, state, 400k steps, **speed-scaled steering** (`--steer-action speed_scaled`), **3 training seeds**",
        (Seeds((f"{SPEED}experiment.json",)),),
    ),
    Recipe("the same, best of the 3 seeds", (Seeds((f"{SPEED}experiment.json",)),), best=True),
    Recipe(
        "SAC, state, 400k steps, steering-rate action (`--steer-action rate`), **3 training seeds**",
        (Seeds((f"{SPEED}rate_experiment.json",)),),
    ),
    Recipe(
        "SAC, state, 400k steps, rate within the speed-scaled range (`--steer-action rate_scaled`), 3 training seeds",
        (Seeds((f"{SPEED}rate_scaled_experiment.json",)),),
        bold=True,
    ),
    Recipe(
        "the same, best of the 3 seeds (the paper's score)",
        (Seeds((f"{SPEED}rate_scaled_experiment.json",)),),
        best=True,
    ),
)


def _seeds_recipes(name: str) -> tuple[Recipe, ...]:
    """The 25 Hz study's seeds 0-2 and 3-5 of the recipe ``name``, each seed listed, and the record of all 6."""
    first, second, both = _h25(name, f"{name}-seeds345", f"{name}-6seeds")
    return (
        Recipe("seeds 0-2", (Seeds((first,)),), curves=_h25_curves(name), listed=True),
        Recipe("seeds 3-5", (Seeds((second,)),), listed=True),
        Recipe("all 6 seeds", (Seeds((both,)),), bold=True, curves=_h25_curves(f"{name}-6seeds")),
    )


REPEAT = _h25("dt04-ent4-lrf-repeat")
PROBES = f"{CLEAN}probes.json"


#: Each seed's wall contact per lap, wall hits and the fastest hit's speed.
PER_SEED_WALL_COLUMNS: tuple[Column, ...] = (
    ("wall contact per lap, s (per seed)", partial(per_seed_cell, key="wall_contact_s", spec=".2f")),
    ("wall hits (per seed)", partial(per_seed_cell, key="wall_hits", spec="d")),
    ("fastest hit, km/h (per seed)", partial(per_seed_cell, key="fastest_wall_hit_kmh", spec=".0f")),
)


#: docs/results/state-expressway-hatchback-clean: the ten probes against wall braking, (label, arm of probes.json).
CLEAN_PROBES = (
    ("off-track penalty c_o = 0.002 (`--off-track-penalty-c-o 0.002`)", "state-co0.002"),
    ("off-track penalty c_o = 0.005", "state-co0.005"),
    ("wall penalty at the impact speed, c_w = 0.005 (`--wall-penalty-speed impact`)", "state-impact-cw0.005"),
    ("the same, c_w = 0.01 (`--wall-penalty-c-w 0.01`)", "state-impact-cw0.01"),
    ("wall friction 0.6 instead of 0.4 (`WorldConfig.wall_friction`, changed in code for the probe)", "state-wf0.6"),
    ("wall friction 0.8", "state-wf0.8"),
    (
        "100k transitions of the built-in AI in the replay buffer before the first update (`--guide-steps 100000`)",
        "state-guide",
    ),
    ("the AI's transitions and the impact-speed penalty at c_w = 0.01", "state-guide-impact-cw0.01"),
    (
        "the AI's transitions cloned by the actor: a cloning step of weight 30 after each SAC update (`--guide-steps "
        "100000 --guide-bc-weight 30`)",
        "state-guide-bc30",
    ),
    (
        "the actor cloned to the AI's transitions for 20k steps before SAC starts, and the impact-speed penalty at "
        "c_w = 0.01 (`--guide-steps 100000 --guide-pretrain-steps 20000 --wall-penalty-speed impact "
        "--wall-penalty-c-w 0.01`)",
        "state-guide-pretrain-impact-cw0.01",
    ),
)

STATE_TABLES = {
    "state-25hz-lrf-alone": partial(
        changes_table,
        recipes=(
            Recipe("falling rate alone", (Seeds(_h25("dt04-lrf")),), bold=True, curves=_h25_curves("dt04-lrf")),
            Recipe(
                "falling rate and the entropy target -4 (the repeat above)",
                (Seeds(REPEAT),),
                curves=_h25_curves("dt04-ent4-lrf-repeat"),
            ),
        ),
        columns=(
            LAP_COLUMN,
            LAPS_COLUMN,
            STARTS_COLUMN,
            WALL_COLUMN,
            CLEAN_COLUMN,
            *PER_SEED_WALL_COLUMNS,
            LIMIT_COLUMN,
            (
                "periodic evaluations, mean: 300k-1M / 700k-1M",
                partial(periodic_cell, spans=((300_000, 1_000_000), (700_000, 1_000_000))),
            ),
        ),
    ),
    "state-25hz-curves": partial(
        curves_steps_table,
        path=f"{H25}dt04-6seeds_learning_curves.json",
        rows=("epochs", "training, min", "seeds finished", "mean lap"),
    ),
    "state-25hz-ent4-lrf-curves": partial(
        curves_steps_table,
        path=f"{H25}dt04-ent4-lrf-6seeds_learning_curves.json",
        rows=("epochs", "training, min", "seeds finished", "mean lap", "spread, s"),
    ),
    "state-clean-label30-cut3-1200k-curves": partial(
        curves_steps_table, path=f"{CLEAN}label30-cut3-1.2M_learning_curves.json", rows=("mean lap",)
    ),
    "state-clean-probes": partial(
        changes_table,
        recipes=tuple(Recipe(label, (Seeds((PROBES,), arm=arm),)) for label, arm in CLEAN_PROBES),
        columns=(LAP_COLUMN, STARTS_COLUMN, *PER_SEED_WALL_COLUMNS),
    ),
    "state-clean-labels": partial(
        changes_table,
        recipes=(
            Recipe("labels, W = 30 (`--guide-label-weight 30`)", (Seeds((f"{CLEAN}label30_experiment.json",)),)),
            Recipe(
                "labels, W = 30, and the 3 s throttle cut",
                (Seeds(LABEL30_CUT3[:1]),),
                bold=True,
                curves=(f"{CLEAN}label30-cut3_learning_curves.json",),
            ),
            Recipe("the same, training seeds 3, 4, 5", (Seeds(LABEL30_CUT3[1:]),)),
            Recipe("labels, W = 100, and the cut", (Seeds((f"{CLEAN}label100-cut3_experiment.json",)),)),
            Recipe(
                "for comparison: no change (docs/results/state-expressway-hatchback-speed-scaled)",
                (Seeds((f"{SPEED}rate_scaled_n3_experiment.json",)),),
            ),
        ),
        columns=(LAP_COLUMN, STARTS_COLUMN, *PER_SEED_WALL_COLUMNS),
    ),
    "state-25hz-changes": partial(
        changes_table,
        recipes=tuple(
            Recipe(label, (Seeds(_h25(name)),), bold=name == "dt04-ent4", curves=_h25_curves(name))
            for label, name in (
                ("none (the recipe)", "dt04"),
                ("`--gamma 0.995`", "dt04-gamma0995"),
                ("`--guide-label-weight 60`", "dt04-label60"),
                ("`--target-entropy -4`", "dt04-ent4"),
                ("`--target-entropy -6`", "dt04-ent6"),
            )
        ),
        columns=(
            LAP_COLUMN,
            BEST_COLUMN,
            STARTS_COLUMN,
            WALL_COLUMN,
            LIMIT_COLUMN,
            AI_COLUMN,
            TRAINING_COLUMN,
            (
                "periodic evaluations, 300k-1M: mean (best)",
                partial(periodic_cell, spans=((300_000, 1_000_000),), best=True),
            ),
        ),
    ),
    "state-25hz-select-1m": partial(
        selection_table,
        recipes=(
            Recipe("seeds 0-2", (Seeds(SELECT_1M[:1]),), listed=True),
            Recipe("seeds 3-5", (Seeds(SELECT_1M[1:2]),), listed=True),
            Recipe("seeds 6-8", (Seeds(SELECT_1M[2:]),), listed=True),
            Recipe("all 9", (Seeds(SELECT_1M),), bold=True),
        ),
    ),
    "state-25hz-select-2m": partial(
        selection_table,
        recipes=(
            Recipe("seeds 0-2 (`make experiment`)", (Seeds(SELECT_2M[:1]),), listed=True),
            Recipe("seeds 3-5", (Seeds(SELECT_2M[1:]),), listed=True),
            Recipe("all 6, 2M steps", (Seeds(SELECT_2M),), bold=True),
            Recipe(
                "the 1M runs (above): seeds 0-2 / 3-5 / 6-8 / all 9",
                (Seeds(SELECT_1M[:1]), Seeds(SELECT_1M[1:2]), Seeds(SELECT_1M[2:]), Seeds(SELECT_1M)),
            ),
        ),
        held_out=f"{H25}dt04-ent4-lrf-select-2m_held_out_clean.json",
    ),
    "state-25hz-repeat": partial(
        seeds_table,
        recipes=(
            Recipe("the repeat", (Seeds(REPEAT),), bold=True, curves=_h25_curves("dt04-ent4-lrf-repeat"), listed=True),
            Recipe("the first run of seeds 0-2, above", (Seeds(ENT4_LRF[:1]),)),
            Recipe("all 9 runs: the 6 seeds above and this repeat", (Seeds((*ENT4_LRF, *REPEAT)),)),
        ),
        gaps=True,
    ),
    "state-25hz-seeds": partial(seeds_table, recipes=_seeds_recipes("dt04")),
    "state-25hz-ent4-lrf-seeds": partial(seeds_table, recipes=_seeds_recipes("dt04-ent4-lrf")),
    "state-steer05": partial(
        seeds_columns_table,
        columns=(
            ("c_s = 0 (the papers' reward)", Seeds((f"{STEER05}baseline_at_400k.json",))),
            ("c_s = 0.5", Seeds((f"{STEER05}experiment.json",))),
        ),
        steering=f"{STEER05}steering_motion.json",
    ),
    "state-n-step": partial(curves_compare_table, path=f"{SPEED}n_step_compare.json"),
    "state-agent": partial(
        driver_table,
        recipes=STATE_AGENT_RECIPES,
        quick=(
            "state",
            "SAC, state, 250k steps, `rate_scaled` steering, `make quick`, other occasions of the machine in brackets",
        ),
    ),
}
