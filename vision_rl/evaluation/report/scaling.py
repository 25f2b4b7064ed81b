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


BENCH_IDLE = "scaling/bench_scaling_idle.json"
#: The loaded machine's ratios, transcribed from the page (their runs' JSON was not kept).
BENCH_LOADED = "scaling/bench_scaling_loaded.json"


def _median_span(figure: dict[str, float], spec: str = ".0f") -> str:
    """``144 [131-151]``: a figure's median over the repeats, their range in brackets."""
    return f"{figure['median']:{spec}} [{figure['min']:{spec}}-{figure['max']:{spec}}]"


def _verdict(ratio: float, target: str) -> str:
    """Whether ``ratio`` reaches a target written ``>= 1.3``: ``met`` or ``**missed**``."""
    sign, threshold = target.split()
    if sign != ">=":
        raise ReportError(f"a target of another form than '>= X': {target!r}")
    return "met" if ratio >= float(threshold) else "**missed**"


def bench_table(records: Records) -> str:
    """`bench scaling`'s ratios of 2 workers over 1 on the idle machine (medians, the repeats' range) beside those
    under load, and the verdict of the idle ratios against the targets."""
    idle, targets = records(BENCH_IDLE)["rows"], records(BENCH_IDLE)["targets"]
    loaded = records(BENCH_LOADED)["rows"]
    capture, inside, cpu = (idle["capture"][k] for k in ("frames/s", "frames/s inside the shards", "CPU ms per frame"))
    train, share = idle["train"]["training frames/s"], idle["sampling"]["learner share of standalone"]
    capture_target, share_target = targets["capture frames/s"], targets["sampling learner share of standalone"]
    cpu_low, cpu_high = loaded["capture"]["CPU ms per frame ratio, lowest and highest run"]
    one_low, one_high = loaded["train"]["training frames/s with 1 process, lowest and highest repeat"]
    one_mean, one_std = mean_std_s(loaded["sampling"]["learner share of standalone, 1 sampler, per run"])
    two_mean, two_std = loaded["sampling"]["learner share of standalone, 2 samplers, mean and std over the runs"]
    runs = loaded["capture"]["frames/s ratio per run"]
    rows = [
        (
            "capture frames/s (1,200 frames, 280x470)",
            f"{capture['ratio']:.2f}x (1 worker {_median_span(capture['workers_1'])}, 2: "
            f"{_median_span(capture['workers_2'])}); inside the shards {inside['ratio']:.2f}x; CPU per frame "
            f"{cpu['workers_1']['median']:.1f} vs {cpu['workers_2']['median']:.1f} ms ({cpu['ratio']:.2f}x)",
            f"{', '.join(f'{r:.2f}x' for r in runs)} ({len(runs)} runs); CPU per frame {cpu_low:.2f}-{cpu_high:.2f}x "
            "higher",
            f"{capture_target}x: {_verdict(capture['ratio'], capture_target)}",
        ),
        (
            "train-repr training frames/s, 2 DDP processes / 1",
            f"{train['ratio']:.2f}x ({_median_span(train['workers_1'])} vs {_median_span(train['workers_2'])})",
            f"{loaded['train']['training frames/s ratio']:.2f}x ({loaded['train']['runs']} run; 1 process: "
            f"{one_low:.1f}-{one_high:.1f} frames/s)",
            "-",
        ),
        (
            "learner's update rate with sampling in other processes, share of its standalone rate",
            f"1 sampler: {_median_span(share['workers_1'], '.2f')}; 2 samplers: "
            f"{_median_span(share['workers_2'], '.2f')}",
            f"1 sampler: {one_mean:.2f} ± {one_std:.2f} "
            f"({', '.join(f'{r:.2f}' for r in loaded['sampling']['learner share of standalone, 1 sampler, per run'])}"
            f"); 2 samplers: {two_mean:.2f} ± {two_std:.2f}",
            f"{share_target}: {_verdict(share['workers_1']['median'], share_target)} with 1 sampler, "
            f"{_verdict(share['workers_2']['median'], share_target)} with 2",
        ),
    ]
    header = ("job", "2 workers / 1, idle machine", "2 workers / 1, loaded", "target")
    records_text = f"{link('idle', BENCH_IDLE)}, {link('loaded', BENCH_LOADED)} (transcribed)"
    return f"{markdown_table(header, rows)}\nRecords: {records_text}.\n"


SCALING_TABLES = {
    "scaling-bench": bench_table,
    "scaling-staleness": staleness_table,
    "scaling-staleness-seeds": partial(staleness_table, per_seed=True),
}
