"""The state agent's tables: each recipe's lap through the protocol over its training seeds beside the physical limit
and the built-in AI (the study's driver table, whose builder the vision study's can share), the n-step comparison and
the steering-change penalty's, from the `vision-rl experiment` and learning-curve records."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import partial
from typing import Any

from vision_rl.evaluation.report.common import (
    AI_HATCHBACK,
    gap_text,
    lap_text,
    link,
    markdown_table,
    mean_std_s,
    reference_laps,
    span_text,
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
    ``name`` says which in a row of several sets."""

    paths: tuple[str, ...]
    selected: bool = False
    name: str = ""


@dataclass(frozen=True)
class Recipe:
    """A row of a driver table: ``label`` (Markdown), then the mean lap of each set of seeds (``/`` between sets), or
    with ``best`` the fastest seed's (the paper's score); ``study`` a results page the row links; ``curves`` the
    learning-curve records whose training time per seed the row states; no sets: a link row."""

    label: str
    sets: tuple[Seeds, ...] = ()
    best: bool = False
    bold: bool = False
    study: str = ""
    curves: tuple[str, ...] = ()


def seed_rows(records: Records, seeds: Seeds) -> list[dict[str, Any]]:
    """The per-seed rows of ``seeds``: from `vision-rl experiment` records, or from a record of snapshots keyed by the
    training seed (``{"0": {"lap_time_s": ..., "finished": "3/3", ...}}``)."""
    rows: list[dict[str, Any]] = []
    for path in seeds.paths:
        record = records(path)
        if "per_seed" in record:
            rows += experiment_seeds(records, [path], seeds.selected)
        else:
            rows += [{"seed": int(key), **row} for key, row in record.items() if key.isdigit()]
    if not rows:
        raise ReportError(f"no training seed in {', '.join(seeds.paths)}")
    return rows


def steps_text(steps: int) -> str:
    """``400k``, ``1.2M``, ``2M``."""
    return f"{steps / 1e6:g}M" if steps >= 1_000_000 else f"{steps / 1e3:g}k"


def seeds_details(rows: list[dict[str, Any]], selected: bool = False) -> str:
    """Starts finished, wall contact per scored lap (mean ± std over the seeds with a lap), how many seeds were clean,
    and with ``selected`` the steps whose weights the held-out starts chose."""
    done, total = (sum(int(row["finished"].split("/")[i]) for row in rows) for i in (0, 1))
    wall_s, wall_std_s = mean_std_s(row["wall_contact_s"] for row in rows if row["lap_time_s"] is not None)
    clean = sum(bool(row.get("clean")) for row in rows)
    clean_text = {len(rows): "clean for every seed", 0: "not clean"}.get(
        clean, f"clean for {clean} of {len(rows)} seeds"
    )
    text = f"{done} of {total} starts; {wall_s:.2f} ± {wall_std_s:.2f} s of wall contact per lap, {clean_text}"
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


def _bold(text: str, bold: bool) -> str:
    return f"**{text}**" if bold else text


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
    label = _bold(recipe.label, recipe.bold)
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
        _bold(" / ".join(text for _, text in laps), recipe.bold),
        _bold(" / ".join(gap_text(lap_s, limit_s) for lap_s, _ in laps), recipe.bold),
        _bold(" / ".join(gap_text(lap_s, ai_s) for lap_s, _ in laps), recipe.bold),
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


H25 = "state-expressway-hatchback-25hz/"
CLEAN = "state-expressway-hatchback-clean/"
SPEED = "state-expressway-hatchback-speed-scaled/"
STEER05 = "state-expressway-hatchback-steer05/"


def _h25(*names: str) -> tuple[str, ...]:
    return tuple(f"{H25}{name}_experiment.json" for name in names)


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
                name="`make experiment` again, seeds 0-2 on another evening, when the machine's floats differed and "
                "so did the runs",
            ),
            Seeds((*ENT4_LRF, *_h25("dt04-ent4-lrf-repeat")), name="all 9 runs"),
        ),
        study=f"{H25}README.md#seeds-0-2-again-make-experiment-from-a-fresh-clone-another-evening",
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

STATE_TABLES = {
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
