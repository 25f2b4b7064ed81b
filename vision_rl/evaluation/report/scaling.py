"""The scaling page's tables: state SAC learning in one process against a learner fed by a sampler process at
staleness bounds 0, 1 and 4, from each condition's experiment and learning-curve records."""

from __future__ import annotations

import statistics
from functools import partial
from typing import Any

from vision_rl.evaluation.report.common import AI_HATCHBACK, lap_text, link, markdown_table, mean_std_s
from vision_rl.evaluation.report.records import Records, ReportError

#: `vision-rl experiment --out CONDITION` under docs/results/scaling/staleness, in the order the tables list them.
STALENESS = "scaling/staleness/{condition}/{name}.json"
STALENESS_CONDITIONS = (
    ("one process", "one-process"),
    ("sampler process, staleness 0", "workers1-staleness0"),
    ("sampler process, staleness 1 (default)", "workers1-staleness1"),
    ("sampler process, staleness 4", "workers1-staleness4"),
)


def _first_under_ai(seed: dict[str, Any], ai_s: float) -> tuple[int, float]:
    """The steps and training time of a seed's first periodic evaluation whose mean lap beat the AI's."""
    for steps, train_s, lap_s in zip(seed["num_timesteps"], seed["train_time_s"], seed["lap_time_s"], strict=True):
        if lap_s is not None and lap_s < ai_s:
            return steps, train_s
    raise ReportError("a seed never beat the built-in AI's lap at a periodic evaluation")


def _condition(records: Records, condition: str, ai_s: float) -> dict[str, Any]:
    """A condition's figures: training time to the last step and to the first evaluation under the AI, per seed."""
    experiment = records(STALENESS.format(condition=condition, name="experiment"))
    seeds = records(STALENESS.format(condition=condition, name="learning_curves"))["per_seed"].values()
    firsts = [_first_under_ai(seed, ai_s) for seed in seeds]
    return {
        "summary": experiment["summary"],
        "train_s": [seed["train_time_s"][-1] for seed in seeds],
        "first_steps": [steps for steps, _ in firsts],
        "first_s": [train_s for _, train_s in firsts],
    }


def staleness_table(records: Records, per_seed: bool = False) -> str:
    """Each condition's training time to its last step, when it first beat the AI's lap, its final lap and starts;
    with ``per_seed``, each seed's times, the best lap and the wall contact too (the records' page)."""
    ai_s = records(AI_HATCHBACK)["best_lap_time_s"]
    rows = []
    base: dict[str, float] = {}
    for label, condition in STALENESS_CONDITIONS:
        c = _condition(records, condition, ai_s)
        s = c["summary"]
        train_s, first_s = mean_std_s(c["train_s"]), statistics.fmean(c["first_s"])
        base = base or {"train_s": train_s[0], "first_s": first_s}
        ratio = {
            k: "" if not rows else f" ({v / base[k]:.2f}x)" for k, v in (("train_s", train_s[0]), ("first_s", first_s))
        }
        cells = [f"{label} ({link('record', STALENESS.format(condition=condition, name='experiment'))})"]
        lap = f"{lap_text(s['lap_time_mean_s'])} ± {s['lap_time_std_s']:.2f} s"
        if per_seed:
            cells += [
                f"{train_s[0]:.1f} ± {train_s[1]:.1f} s ({', '.join(f'{x:.1f}' for x in c['train_s'])})",
                f"{', '.join(f'{n // 1000}k' for n in c['first_steps'])}; {first_s:.1f} s "
                f"({', '.join(f'{x:.1f}' for x in c['first_s'])})",
                f"{lap}, {lap_text(s['best_lap_time_s'])}",
                s["finished"],
                f"{s['wall_contact_mean_s']:.1f} ± {s['wall_contact_std_s']:.1f} s",
            ]
        else:
            train = f"{train_s[0]:.1f} ± {train_s[1]:.1f} s{ratio['train_s']}"
            cells += [train, f"{first_s:.1f} s{ratio['first_s']}", lap, s["finished"]]
        rows.append(cells)
    if per_seed:
        header = (
            "condition",
            "training time to 200k steps, mean ± std (per seed)",
            "first evaluation under the AI's lap: steps, training time (per seed)",
            "final lap: mean ± std over 3 seeds, best",
            "starts finished",
            "wall contact per lap",
        )
    else:
        header = (
            "condition",
            "training time to 200k steps (against one process)",
            "first beats the AI's lap (training time)",
        )
        header += ("final lap, mean ± std", "starts finished")
    return markdown_table(header, rows)


SCALING_TABLES = {
    "scaling-staleness": staleness_table,
    "scaling-staleness-seeds": partial(staleness_table, per_seed=True),
}
