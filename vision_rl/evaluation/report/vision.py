"""The vision paper's tables: Table 1 beside our state and vision agents, `make quick`'s job, Phase 1's R^2."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from vision_rl.evaluation.report.common import (
    AI_HATCHBACK,
    faster_text,
    gap_text,
    lap_text,
    link,
    markdown_table,
    mean_std_s,
    reference_laps,
)
from vision_rl.evaluation.report.records import Records

VISION_PAPER = "papers/gts-vision-representation-sac.json"
STATE_2M = (
    "state-expressway-hatchback-25hz/dt04-ent4-lrf-select-2m_experiment.json",
    "state-expressway-hatchback-25hz/dt04-ent4-lrf-select-2m-seeds345_experiment.json",
)

VISION_25HZ = tuple(f"vision-expressway-hatchback/dt04_seed{seed}_experiment.json" for seed in (0, 1, 2))
VISION_QUICK_8_SEEDS = "vision-expressway-hatchback/quick_critic_state_starts13.json"
QUICK_JOB = "make-quick/job.json"
PHASE1_R2 = "phase1-expressway-hatchback/r2.json"
R2_GROUPS = ("edge_distances", "min_edge_distances", "centre_offset", "heading_angle", "curvature_ahead")


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


def _paper_lap(seconds: float, paper_ai_s: float) -> str:
    return f"{lap_text(seconds)} ({faster_text(seconds, paper_ai_s).replace('the AI', 'its AI')})"


def _vision_cells(records: Records) -> dict[str, Any]:
    """The figures of the vision paper's table: its laps, ours, the AI and the limit."""
    paper = records(VISION_PAPER)["lap_time_s"]
    ai_s, limit_s = reference_laps(records, AI_HATCHBACK)
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
        f"starts, {clean} ({link('record', record)}); {faster_text(summary['mean_s'], c['ai_s'])}"
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
            f"({job['vision']['finished']} starts each) in {job['job_minutes']:.1f} min ({link('record', QUICK_JOB)})",
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
            f"target {job['target_minutes']:.0f} min ({link('record', QUICK_JOB)})",
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
    return f"{table}\nR² per target group of the kept epoch on a clean lap ({link('record', PHASE1_R2)}).\n"
