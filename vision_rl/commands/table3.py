"""`table3`: the overtaking paper's Table III on our simulator, beside the paper's, as ratios to each table's AI."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from vision_rl.commands.output import emit, note, number_text
from vision_rl.files import write_json
from vision_rl.overtaking.config import Table3Config


@dataclass(frozen=True)
class Table3Options(Table3Config):
    """Time the built-in AI and every trained Table III baseline through the lap-time protocol (lap time and
    average speed), beside the paper's row, as ratios to each table's built-in AI."""

    out: str = ""
    """Also write the record (the --json document, sealed) to this file once every row is timed, in one atomic
    write, so that --keep may name the file it replaces."""
    json: bool = False
    """Print the result as JSON."""


def format_table3(result: dict[str, Any]) -> list[str]:
    p = result["protocol"]
    lines = [
        f"Table III (single-car race) on {result['track_name']} with {result['car']}: protocol v{p['version']}, "
        f"best of {p['seeds']} seeds, lap {p['laps']} scored",
        f"  {'':<32} {'lap s':>7} {'km/h':>7} {'lap/AI':>7} {'spd/AI':>7} | {'paper lap':>9} {'km/h':>6} "
        f"{'lap/AI':>7} {'spd/AI':>7}",
    ]
    for row in result["rows"]:
        paper = row["paper"] or {}
        if row["status"] in ("timed", "DNF") and row.get("lap_time_s") is not None:
            ours = (
                f"{number_text(row['lap_time_s']):>7} {number_text(row['avg_speed_kmh']):>7} "
                f"{number_text(row['lap_ratio_to_ai'], 3):>7} {number_text(row['speed_ratio_to_ai'], 3):>7}"
            )
        else:
            word = "DNF" if row["status"] in ("timed", "DNF") else row["status"]
            ours = f"{word:>31}"
        theirs = (
            f"{number_text(paper.get('lap_time_s')):>9} {number_text(paper.get('avg_speed_kmh')):>6} "
            f"{number_text(paper.get('lap_ratio_to_ai'), 3):>7} {number_text(paper.get('speed_ratio_to_ai'), 3):>7}"
            if paper
            else f"{'':>32}"
        )
        lines.append(f"  {row['name']:<32} {ours} | {theirs}")
    for row in result["rows"]:
        if row["status"] == "DNF" or row.get("dnf_reasons"):
            lines.append(
                f"  {row['name']}: {row.get('finished')}/{row.get('seeds')} starts finished; "
                + "; ".join(row.get("dnf_reasons") or [])
            )
        if row.get("reason"):
            lines.append(f"  {row['name']}: {row['reason']}")
        if row.get("kept_from"):
            lines.append(f"  {row['name']}: kept from {row['kept_from']} (not timed again)")
        over = row.get("over_training_seeds")
        if over:
            spread = "" if over["lap_time_std_s"] is None else f" +- {number_text(over['lap_time_std_s'])}"
            mean_s = over["lap_time_mean_s"]
            mean = (
                "no lap"
                if mean_s is None
                else f"lap mean {number_text(mean_s)}{spread} s (of the {over['n_training_seeds_finished']} with a lap)"
            )
            lines.append(
                f"  {row['name']}: over {over['n_training_seeds']} training seed(s), {mean}, "
                f"starts finished {over['finished']}"
            )
        for run in row.get("runs") or []:
            lap = "DNF" if run["lap_time_s"] is None else f"{number_text(run['lap_time_s'])} s"
            steps = f", {run['num_timesteps']} steps" if run["num_timesteps"] else ""  # bc trains on no env steps
            lines.append(f"  {row['name']}: {run['run']} (seed {run['seed']}{steps}): {lap}")
    for skip in result["skipped"]:
        lines.append(f"  skipped {skip['run']}: {skip['reason']}")
    return lines


def run_table3(opts: Table3Options) -> int:
    import dataclasses

    from vision_rl.overtaking.table3 import table3

    fields = {f.name for f in dataclasses.fields(Table3Config)}
    cfg = Table3Config(**{k: v for k, v in dataclasses.asdict(opts).items() if k in fields})
    result = table3(cfg)
    if opts.out:
        write_json(opts.out, result)
        note(f"wrote {opts.out}")
    emit(result, opts.json, format_table3)
    return 0
