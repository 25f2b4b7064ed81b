"""`ddpg-reference`: the project's DDPG agent (state actor, with and without batch-norm) beside Stable-Baselines3's
DDPG and TD3 on a standard Gymnasium task, same hyper-parameters, several seeds (:mod:`vision_rl.ddpg.reference`)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from vision_rl.commands.options import comma_list
from vision_rl.commands.output import emit, progress_bar, show
from vision_rl.config import nested
from vision_rl.ddpg.config import ReferenceRun


@dataclass(frozen=True)
class DDPGReferenceOptions:
    """Train the project's DDPG agent (ours: no batch-norm, as SB3; ours-bn: the paper's batch-norm) and
    Stable-Baselines3's DDPG and TD3 on a Gymnasium task with the same hyper-parameters, noise and widths; one JSON
    record per run in --out/<task>/ (a record of the same settings there is reused, not trained again), a figure of
    the learning curves (mean and one standard deviation over seeds) and a table of final returns."""

    run: ReferenceRun = nested(
        ReferenceRun(),
        only=("task", "steps", "learning_starts", "eval_every_steps", "eval_episodes", "final_eval_episodes", "hyper"),
    )
    """What every run does: the task, its length, evaluations and hyper-parameters."""
    algos: str = "ours,ours-bn,sb3-ddpg,sb3-td3"
    """Algorithms, comma-separated: ours, ours-bn, sb3-ddpg, sb3-td3."""
    seeds: str = "0,1,2"
    """Seeds, comma-separated."""
    out: str = "runs/ddpg-reference"
    """Folder of the records (<out>/<task>/<algo>-s<seed>.json), the figure and the summary."""
    force: bool = False
    """Train again runs whose records are already in --out."""
    torch_threads: int = 1
    """torch threads (0: torch's default)."""
    progress: bool = True
    """Show a progress bar on stderr."""
    json: bool = False
    """Print the summary as JSON."""


def format_reference(result: dict[str, Any]) -> list[str]:
    lines = [
        f"{result['task']}: returns, mean ± std over seeds: the final evaluation (deterministic), the last 5 "
        "evaluations, the last 10 training episodes"
    ]
    for row in result["rows"]:
        bands = [row[k] for k in ("final_return", "last5_eval_return", "last10_train_return")]
        text = "   ".join(f"{b['mean']:8.1f} ± {b['std']:6.1f}" for b in bands)
        lines.append(
            f"  {row['algo']:<9} {text}   {len(row['seeds'])} seeds x {'/'.join(map(str, row['steps']))} steps, "
            f"{row['train_time_s']['mean']:.0f} s per run"
        )
    return [*lines, f"records: {result['records']}   figure: {result['figure']}"]


def run_ddpg_reference(opts: DDPGReferenceOptions) -> int:
    import torch

    from vision_rl.ddpg.reference import load_or_run, plot_reference, summarise
    from vision_rl.files import sealed_record, write_json

    if opts.torch_threads > 0:
        torch.set_num_threads(opts.torch_threads)
    runs = [replace(opts.run, algo=a, seed=s) for a in comma_list(opts.algos) for s in comma_list(opts.seeds, int)]
    if not runs:
        raise ValueError("--algos and --seeds must name at least one algorithm and one seed")
    records = []
    with progress_bar(len(runs), "run", "ddpg-reference", enabled=opts.progress) as bar:
        for i, run in enumerate(runs):
            show(bar, i, algo=run.algo, seed=run.seed)
            records.append(load_or_run(run, opts.out, opts.force)[0])
        show(bar, len(runs))
    folder = f"{opts.out}/{opts.run.task}"
    result = {
        "task": opts.run.task,
        "rows": summarise(records),
        "records": folder,
        "figure": str(plot_reference(records, f"{folder}/curves.png", max(opts.run.eval_every_steps, 1_000))),
    }
    write_json(f"{folder}/summary.json", sealed_record(result))
    emit(result, opts.json, format_reference)
    return 0
