"""The vision study's driver table (docs/studies/vision-agent.md): the state study's rows (:func:`recipe_row`) for
`vision-rl experiment` records, and rows of batches timed from 13 starts per training seed, read as the run log
reads them, so each recipe's lap beside the limit and the AI comes from its record."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

from vision_rl.evaluation.report.common import bold_if, gap_text, lap_text, link, mean_std_s, span_text
from vision_rl.evaluation.report.records import Records
from vision_rl.evaluation.report.state import Recipe, Seeds, driver_table, recipe_row
from vision_rl.evaluation.report.vision import VISION_25HZ
from vision_rl.evaluation.report.vision_log import (
    CRITIC_STATE,
    LOG,
    SEEDS_15_18,
    STEPS_200K,
    USABLE,
    Batch,
    ExperimentRow,
    _batch_extras,
    _hits_text,
    _seed_rows,
)

#: Another set of a batch row's seeds, in its notes: (its name, batches, the training seeds kept (all if none), the
#: keys down each seed to the step whose weights were chosen (the last weights if none)).
OtherSet = tuple[str, tuple[Batch, ...], tuple[int, ...], tuple[str, ...]]


@dataclass(frozen=True)
class Batches:
    """A driver-table row of batches timed from 13 starts per training seed (the run log's records): the protocol's
    starts, all 13 starts, the seeds' median wall contact and the mean protocol lap, then ``others`` in its notes."""

    label: str
    batches: tuple[Batch, ...]
    bold: bool = False
    study: str = ""
    others: tuple[OtherSet, ...] = ()


@dataclass(frozen=True)
class NotedRecipe(Recipe):
    """A :class:`Recipe` whose label carries figures of other records: ``notes`` write them."""

    notes: tuple[Callable[[Records], str], ...] = ()


def _set_rows(
    records: Records, batches: tuple[Batch, ...], seeds: tuple[int, ...] = (), chosen: tuple[str, ...] = ()
) -> list[dict[str, Any]]:
    """The training seeds of ``batches`` pooled (only ``seeds`` if given), their weights chosen down ``chosen``."""
    rows = [row for batch in batches for row in _seed_rows(records, batch, chosen)]
    return [row for row in rows if not seeds or row["seed"] in seeds]


def _other_text(records: Records, other: OtherSet) -> str:
    """``name: the protocol's starts a/b, 13 starts each c of d, lap``."""
    name, batches, seeds, chosen = other
    rows = _set_rows(records, batches, seeds, chosen)
    extras = _batch_extras(rows, None)
    of_13 = f"{sum(row['of_13'] for row in rows)} of {13 * len(rows)}"
    return f"{name}: the protocol's starts {extras['protocol']}, 13 starts each {of_13}, {extras['lap']}"


def batches_row(records: Records, recipe: Batches, limit_s: float, ai_s: float) -> tuple[str, ...]:
    """A driver table's row of batches timed from 13 starts: label with its starts and notes, lap and gaps."""
    rows = _set_rows(records, recipe.batches)
    laps_s = [row["lap_s"] for row in rows if row["lap_s"] is not None]
    mean_s = mean_std_s(laps_s)[0]
    lapped = "every seed a lap" if len(laps_s) == len(rows) else f"{len(laps_s)} of {len(rows)} seeds with a lap"
    walls_s = [row["wall_s"] for row in rows if row["wall_s"] is not None]
    notes = [
        f"the protocol's starts: {sum(row['of_3'] for row in rows)} of {3 * len(rows)}, {lapped}",
        f"13 starts each: **{sum(row['of_13'] for row in rows)} of {13 * len(rows)}**",
        *([f"{span_text(walls_s, 's', '.1f')} of wall contact per lap (the seeds' medians)"] if walls_s else []),
        *(_other_text(records, other) for other in recipe.others),
        *([link("study", recipe.study)] if recipe.study else []),
    ]
    lap = f"{bold_if(_batch_extras(rows, None)['lap'], recipe.bold)} over the {len(rows)} seeds"
    return (
        f"{bold_if(recipe.label, recipe.bold)} ({'; '.join(notes)})",
        f"{lap} (best seed {lap_text(min(laps_s))})",
        gap_text(mean_s, limit_s),
        bold_if(gap_text(mean_s, ai_s), recipe.bold),
    )


def vision_agent_row(records: Records, recipe: Any, limit_s: float, ai_s: float) -> tuple[str, ...]:
    """A row of the vision study's driver table: of batches timed from 13 starts, or of experiments (with notes)."""
    if isinstance(recipe, Batches):
        return batches_row(records, recipe, limit_s, ai_s)
    notes = "".join(f"; {note(records)}" for note in getattr(recipe, "notes", ()))
    return recipe_row(records, replace(recipe, label=recipe.label + notes), limit_s, ai_s)


def _periodic_text(records: Records, path: str, steps: tuple[int, ...]) -> str:
    """The mean lap ± std over the seeds at some of a learning-curve record's periodic evaluations."""
    curves = records(f"{LOG}/{path}")
    cells = []
    for n in steps:
        i = curves["num_timesteps"].index(n)
        cells.append(
            f"at {n // 1000}k steps {lap_text(curves['mean_lap_time_s'][i])} ± {curves['std_lap_time_s'][i]:.2f} s"
        )
    return ", ".join(cells)


def _hits_note(records: Records, path: str) -> str:
    """Each seed's wall hits in its scored lap and the range of the fastest hit's speed, from ``path``."""
    return f"wall hits per scored lap {_hits_text(records, ExperimentRow('', '', hits=path), [])}"


STUDY = f"{LOG}/README.md"
STEPS_200K_4_11 = ("quick_200k_steps_starts13.json", ("steps_200k",), None)


def _vision(name: str) -> Seeds:
    """The training seeds of the log's experiment ``name``."""
    return Seeds((f"{LOG}/{name}_experiment.json",))


#: docs/studies/vision-agent.md: the recipes, `make quick`'s first.
VISION_AGENT_RECIPES: tuple[Any, ...] = (
    Batches(
        "SAC, vision, `make quick`'s vision stage with the critic that also reads the state (`--critic-state`, the "
        "recipe `make quick` now trains: 200k steps at 10 Hz), 8 training seeds on one encoder, last weights",
        ((CRITIC_STATE, ("critic_state",), None),),
        bold=True,
        study=f"{STUDY}#the-critic-also-reads-the-state---critic-state-adopted-in-make-quick",
    ),
    Batches(
        "SAC, vision, `make quick`'s vision stage at 200k steps (its recipe before the critic read the state), 8 "
        "training seeds, last weights",
        (STEPS_200K_4_11,),
        study=f"{STUDY}#200k-steps-instead-of-150k-adopted-in-make-quick",
        others=(
            ("seeds 12-14 on another encoder", (STEPS_200K,), (12, 13, 14), ()),
            ("so the 11", (STEPS_200K_4_11, STEPS_200K), tuple(range(4, 15)), ()),
            ("with seeds 0 and 15-18 on that encoder the 16", (STEPS_200K_4_11, STEPS_200K, SEEDS_15_18), (), ()),
        ),
    ),
    Batches(
        "SAC, vision, `make quick`'s vision stage with the steering-change penalty against the usable angle "
        "(`--steer-change-penalty-c-s 0.5 --steer-change-penalty-scale usable`; with the stuck ends, the entropy "
        "target and the falling rate: the recipe `make quick` trained at 150k steps), 8 training seeds, last weights",
        ((USABLE, (), "last (150k)"),),
        study=f"{STUDY}#a-steering-change-penalty-against-the-usable-angle-adopted-in-make-quick",
        others=(
            (
                "the weights chosen by 3 held-out starts",
                ((USABLE, (), "chosen (seeds with a finished choice)"),),
                (),
                ("chosen_steps_by_3_held_out_starts",),
            ),
        ),
    ),
    Recipe(
        "earlier recipes of `make quick`'s policies, one training seed or 8: "
        + link("their lap times", "make-quick/README.md#the-lap-of-each-earlier-recipe")
    ),
    Recipe(
        "SAC, vision observation, 200k steps (the quick recipe), **3 training seeds**",
        (Seeds((f"{LOG}/experiment.json",)),),
        study=STUDY,
    ),
    Recipe(
        "SAC, vision, 200k steps (quick recipe), speed-scaled steering, **3 training seeds**",
        (_vision("speed_scaled"),),
    ),
    Recipe(
        "SAC, vision, 200k steps (quick recipe), `rate_scaled` steering, 3 training seeds",
        (_vision("rate_scaled"),),
        bold=True,
        study=STUDY,
    ),
    Recipe(
        "SAC, vision, `make quick`'s recipe before the held-out choice and the entropy target (frames in a sampler "
        "process), **3 training seeds**, at 200k steps",
        (_vision("quick_sampler_n1"),),
        study=f"{STUDY}#make-quicks-recipe-at-cba7343-frames-in-a-sampler-process-3-step-returns-150k-steps",
    ),
    NotedRecipe(
        "SAC, vision, 400k steps, `rate_scaled` steering, 3-step returns (`--n-step 3`), 3 training seeds",
        (_vision("rate_scaled_n3"),),
        bold=True,
        study=f"{STUDY}#3-step-returns-400k-steps",
        notes=(partial(_hits_note, path="rate_scaled_n3_wall_hits.json"),),
    ),
    Recipe("the same, best of the 3 seeds (the paper's score)", (_vision("rate_scaled_n3"),), best=True),
    Recipe(
        "SAC, vision, 400k steps, `rate_scaled`, 3-step returns, the same labels and throttle cut, 3 training seeds",
        (_vision("label30_cut3"),),
        study=f"{STUDY}#the-ais-labels-and-the-throttle-cut-the-clean-state-recipe-400k-steps",
    ),
    Recipe(
        "the same, on an encoder trained on the AI's frames and those labelled policies' own (`capture --policy`), 3 "
        "training seeds",
        (_vision("label30_cut3_policy_frames"),),
        bold=True,
        study=f"{STUDY}#phase-1-on-the-policies-own-frames",
    ),
    NotedRecipe(
        "SAC, vision, the state agent's 25 Hz recipe (1M steps of 0.04 s; 8-step returns, the labels, the throttle "
        "cut, the pedal map), on an encoder trained on the AI's frames and the 25 Hz state policies' own (236x140 "
        "frames), 3 training seeds",
        (Seeds(VISION_25HZ),),
        bold=True,
        study=f"{STUDY}#25-hz-the-state-agents-recipe-on-an-encoder-that-saw-the-state-agents-laps",
        notes=(partial(_periodic_text, path="dt04_learning_curves.json", steps=(800_000, 900_000)),),
    ),
    Recipe("the same, best of the 3 seeds (the paper's score)", (Seeds(VISION_25HZ),), best=True),
    Recipe(
        "SAC, vision, 200k steps, speed-scaled steering, the paper's 67 ms frame delay (`--frame-delay-s 0.067`), "
        "**3 training seeds**",
        (_vision("frame_delay"),),
    ),
)

VISION_AGENT_TABLES = {
    "vision-agent": partial(
        driver_table,
        recipes=VISION_AGENT_RECIPES,
        quick=(
            "vision",
            "SAC, vision, `make quick` now: 200k steps, the critic that also reads the state, the steering-change "
            "penalty against the usable angle, a stuck car ending its training episode, the entropy target -4 and the "
            "learning rate falling to 1e-4, the last weights, a fresh clone",
        ),
        row=vision_agent_row,
    ),
}
