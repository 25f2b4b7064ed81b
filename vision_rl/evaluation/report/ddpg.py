"""The DDPG paper's tables: the paper beside our trainings, the first trainings, the reference check, the cpu trunk's
bench, the state actor's screens and the equal-compute study."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from vision_rl.evaluation.report.common import AI_GT3, gap_text, lap_text, link, markdown_table, reference_laps, span_m
from vision_rl.evaluation.report.records import Records

DDPG_PAPER = "papers/pcars2-ddpg-asymmetric-actor-critic.json"
#: The equal-compute study (issue 64, step 4): compare-ddpg's record of the six runs and each run's protocol laps.
DDPG_EVALUATIONS = "ddpg-equal-compute/evaluation-{variant}-s{seed}.json"
DDPG_COMPARE = "ddpg-equal-compute/compare.json"
DDPG_VARIANTS = ("asymmetric", "symmetric", "state-actor")
DDPG_STATE_ACTOR_DIR = "ddpg-state-actor-catalunya-gt3"
DDPG_STATE_ACTOR = f"{DDPG_STATE_ACTOR_DIR}/evaluation-crashgo50k-s{{seed}}.json"
#: diagnose-ddpg's records: each run's critic against its bound, its keys, and how it drives the protocol.
DDPG_DIAGNOSES = (
    "ddpg-equal-compute/diagnosis.json",
    f"{DDPG_STATE_ACTOR_DIR}/diagnosis.json",
    f"{DDPG_STATE_ACTOR_DIR}/diagnosis-lrswap.json",
)
#: The straight driver (full throttle, never steering) through the protocol on Catalunya in the gt3.
STRAIGHT_GT3 = "reference-laps/straight_catalunya_gt3.json"


def _best_lap(evaluations: dict[str, str], records: Records, limit_s: float) -> tuple[str | None, str]:
    """The fastest lap 2 among the evaluation records ``{label: path}``: (its label, ``**lap** (gap on the limit, wall
    contact)``), or (None, ``DNF (at most D m)``) when none finished a start."""
    read = {label: records(path) for label, path in evaluations.items()}
    lapped = [label for label, e in read.items() if e["best_lap_time_s"] is not None]
    if not lapped:
        farthest_m = max(seed["distance_m"] for e in read.values() for seed in e["seeds"])
        return None, f"DNF (at most {farthest_m:,.0f} m)"
    best = min(lapped, key=lambda label: read[label]["best_lap_time_s"])
    lap_s, wall_s = read[best]["best_lap_time_s"], read[best]["best_lap"]["wall_contact_s"]
    return best, f"**{lap_text(lap_s)}** ({gap_text(lap_s, limit_s)} on the limit, {wall_s:.1f} s of wall contact)"


def _ddpg_laps(records: Records, limit_s: float) -> str:
    """Each variant's best start over its two training seeds through the protocol, linked to that run's record."""
    parts = []
    for variant in DDPG_VARIANTS:
        paths = {str(seed): DDPG_EVALUATIONS.format(variant=variant, seed=seed) for seed in (0, 1)}
        seed, text = _best_lap(paths, records, limit_s)
        shown = paths.items() if seed is None else [(seed, paths[seed])]  # a DNF links every seed's record
        parts.append(f"{variant} {text} ({', '.join(link(f'record s{k}', path) for k, path in shown)})")
    return "; ".join(parts)


def ddpg_table(records: Records) -> str:
    """The DDPG paper beside our trainings: the equal-compute study's laps through the protocol and distance per
    training episode, and the state actor's laps."""
    paper = records(DDPG_PAPER)
    ai_s, limit_s = reference_laps(records, AI_GT3)
    compare = records(DDPG_COMPARE)
    distances = _by_variant(compare, "mean_distance_last_m", lambda m: f"{m:.0f}")
    rows = [
        (
            "lap 2 through the protocol, the best start of 2 training seeds, one core-hour of training each (cpu "
            "trunk, sigmoid pedals, crashes penalised and not ending an episode)",
            "no lap time (a reward plot over laps 1-3)",
            _ddpg_laps(records, limit_s),
            lap_text(ai_s),
            lap_text(limit_s),
            "`vision-rl evaluate-ddpg --agent RUN`",
        ),
        (
            f"distance per training episode, last third of {compare['common_minutes']:.0f} training minutes (a third "
            "of a core each), asymmetric / symmetric / state-actor (seeds 0, 1)",
            f"the asymmetric agent learns in about {paper['training_episodes']} episodes "
            f"(more than {paper['training_hours_at_least']:.0f} h)",
            f"{distances} m ({link('record', DDPG_COMPARE)})",
            "-",
            "-",
            "`vision-rl train-ddpg --variant V`, `vision-rl compare-ddpg`",
        ),
    ]
    rows.append(_ddpg_state_actor_row(records, ai_s, limit_s))
    rows.append(_straight_row(records, ai_s, limit_s))
    return markdown_table(
        ("result", "paper (Project Cars 2)", "ours", "built-in AI", "physical limit", "command"), rows
    )


def _straight_row(records: Records, ai_s: float, limit_s: float) -> tuple[str, ...]:
    """The straight driver's lap (full throttle, the wheels straight) and how the DDPG runs that lap drive: each
    lapping run's share of protocol steps with the wheels straight, from the diagnosis records."""
    straight = records(STRAIGHT_GT3)
    lap_s, wall_s = straight["best_lap_time_s"], straight["best_lap"]["wall_contact_s"]
    lapping = [
        run["protocol_start"]
        for path in DDPG_DIAGNOSES
        for run in records(path)["runs"]
        if any(run["protocol_start"]["laps"])
    ]
    straight_shares = [run["wheels_straight_share"] for run in lapping]
    diagnoses = ", ".join(link("diagnosis", path) for path in DDPG_DIAGNOSES)
    return (
        "the straight driver: full throttle with the wheels straight, no learning (the floor)",
        "-",
        f"**{lap_text(lap_s)}** ({gap_text(lap_s, limit_s)} on the limit, {wall_s:.1f} s of wall contact: the walls "
        f"steer it), {straight['n_finished']}/{straight['n_seeds']} starts ({link('record', STRAIGHT_GT3)}); every "
        f"DDPG run above that laps drives so: {len(lapping)} runs, the wheels straight on "
        f"{100 * min(straight_shares):.0f}-{100 * max(straight_shares):.0f} % of their steps ({diagnoses})",
        lap_text(ai_s),
        lap_text(limit_s),
        "`vision-rl drive --driver straight`, `vision-rl diagnose-ddpg`",
    )


def _ddpg_state_actor_row(records: Records, ai_s: float, limit_s: float) -> tuple[str, ...]:
    """The state actor on the task whose training episodes go on after a crash: starts finished per training seed,
    and the best lap 2 with its wall contact."""
    paths = {str(seed): DDPG_STATE_ACTOR.format(seed=seed) for seed in (0, 1, 2)}
    finished = " / ".join(f"{e['n_finished']}/{e['n_seeds']}" for e in map(records, paths.values()))
    seed, text = _best_lap(paths, records, limit_s)
    lap = "no lap" if seed is None else f"best lap 2 {text.replace(' (', f' (training seed {seed}, ', 1)}"
    return (
        "state actor, training episodes that go on after a crash (beta 10), 50,000 transitions: starts finished, "
        "training seeds 0 / 1 / 2",
        "-",
        f"{finished}; {lap} ({link('record', paths[seed or '0'])})",
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
                link("record", path),
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
    for (variant, preset, layout), paper in rows_by_key.items():
        if preset == "cpu":  # beside its paper-trunk row
            continue
        cpu = rows_by_key.get((variant, "cpu", layout))
        ratio = (
            "-"
            if cpu is None
            else f"{cpu['updates_per_s'] / paper['updates_per_s']:.1f}x updates/s, "
            f"{paper['cpu_ms_per_update'] / cpu['cpu_ms_per_update']:.1f}x less CPU time"
        )
        cells = (f"{variant}, {layout}", rate(paper), "-" if cpu is None else rate(cpu), ratio)
        rows.append((*cells, link("record", DDPG_BENCH)))
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
    "ddpg-state-actor-truncate": (
        ("training seed", "the stuck end a termination (beta 10, 50,000 transitions)", "a truncation (bootstrapped)"),
        tuple((f"{seed}", (f"evaluation-crashgo50k-s{seed}", f"evaluation-trunc50k-s{seed}")) for seed in (0, 1, 2)),
    ),
    "ddpg-state-actor-lrswap": (
        (
            "training seed",
            "the paper's rates, actor 1e-3 and critic 1e-4 (50,000 transitions)",
            "Lillicrap et al.'s, actor 1e-4 and critic 1e-3",
        ),
        tuple((f"{seed}", (f"evaluation-crashgo50k-s{seed}", f"evaluation-lrswap50k-s{seed}")) for seed in (0, 1, 2)),
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
    finished = link(f"{evaluation['n_finished']} of {evaluation['n_seeds']}", path)
    laps_s = sorted(seed["lap_time_s"] for seed in evaluation["seeds"] if seed["finished"])
    if not laps_s:
        return f"{finished} ({span_m([seed['distance_m'] for seed in evaluation['seeds']])})"
    wall_s = evaluation["best_lap"]["wall_contact_s"]
    worst = f", worst {lap_text(laps_s[-1])}" if len(laps_s) > 1 else ""
    return (
        f"**{finished}**: lap 2 {lap_text(laps_s[0])} ({gap_text(laps_s[0], limit_s)} on the limit){worst}; "
        f"{wall_s:.0f} s of wall contact"
    )


def ddpg_state_actor_table(records: Records, name: str) -> str:
    """One of the state actor's screens: each row's evaluations through the protocol (:func:`_starts_text`)."""
    _, limit_s = reference_laps(records, AI_GT3)
    header, rows = DDPG_STATE_ACTOR_SCREENS[name]
    return markdown_table(
        header,
        [
            (label, *(_starts_text(records, f"{DDPG_STATE_ACTOR_DIR}/{n}.json", limit_s) for n in names))
            for label, names in rows
        ],
    )


def ddpg_equal_compute_table(records: Records) -> str:
    """Each run of the study: the compute it got, how far its training episodes went, and its protocol laps."""
    _, limit_s = reference_laps(records, AI_GT3)
    compare = records(DDPG_COMPARE)
    rows = []
    for run in sorted(compare["runs"], key=lambda r: (DDPG_VARIANTS.index(r["variant"]), r["seed"])):
        path = DDPG_EVALUATIONS.format(variant=run["variant"], seed=run["seed"])
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
        rows.append([*cells, ", ".join(link(f"s{seed}", p) for seed, p in zip(row["seeds"], paths, strict=True))])
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
