"""The overtaking paper's tables: Table III and its runs, BC's recipes, settings A and B per driver and per training
seed, the opponents' skill, Fig. 3's steps."""

from __future__ import annotations

import re
from collections.abc import Iterable
from typing import Any

from vision_rl.evaluation.report.common import (
    AI_TT_CUP,
    gap_text,
    link,
    markdown_table,
    reference_laps,
    span_m,
)
from vision_rl.evaluation.report.records import Records

OVERTAKING_PAPER = "papers/gts-overtaking-curriculum-sac.json"
TABLE3 = "table3-expressway-tt_cup/table3.json"
SETTINGS = "overtaking-expressway-tt_cup/{agents}_setting_{setting}.json"
CURRICULUM_CURVES = "overtaking-expressway-tt_cup/learning_curves_num_timesteps.json"
#: Fig. 3 over 3 training seeds (issue 65): the reading the README gives.
CURVES_OVER_SEEDS = "overtaking-expressway-tt_cup/fig3/learning_curves_num_timesteps.json"
#: The straight driver (full throttle, never steering) through the protocol on Table III's track and car.
STRAIGHT_TT_CUP = "reference-laps/straight_expressway_tt_cup.json"
OPPONENT_SKILL = "overtaking-expressway-tt_cup/opponent-skill/skill-{skill}/overtaking_setting_{setting}.json"

#: Table III's first timing: BC and GAIL on 20 laps of the AI with noise 0.1, the rows SAC, TD3 and PlaNet keep.
TABLE3_FIRST = "table3-expressway-tt_cup/first-recipe/table3.json"
#: Dreamer's training seeds timed through the protocol mid-training (issue 65), and its world model's error on
#: held-out laps of the AI at the same checkpoints (`vision-rl dreamer-model`), one record per seed.
TABLE3_DREAMER_INTERIM = "table3-expressway-tt_cup/dreamer-interim/table3.json"
DREAMER_MODEL_INTERIM = tuple(f"table3-expressway-tt_cup/dreamer-interim/model-s{seed}.json" for seed in (0, 2))
#: Each of Dreamer's three training seeds' world model at the end of its 1M steps, the runs of Table III's PlaNet row.
DREAMER_MODEL = tuple(f"table3-expressway-tt_cup/dreamer-model/model-s{seed}.json" for seed in (0, 1, 2))


def _table3_rows(records: Records) -> list[tuple[str, ...]]:
    paper = records(OVERTAKING_PAPER)["table3"]["lap_time_s"]
    ai_s, limit_s = reference_laps(records, AI_TT_CUP)
    rows = {row["key"]: row for row in records(TABLE3)["rows"]}
    names = {"sac": "SAC", "td3": "TD3", "bc": "BC", "gail": "GAIL", "planet": "PlaNet (ours: as Dreamer)"}
    out = []
    for key, name in names.items():
        row, seeds = rows[key], rows[key]["over_training_seeds"]
        lap_s = row["lap_time_s"]
        ours = "DNF" if lap_s is None else f"**{lap_s:.2f} s** ({lap_s / ai_s:.3f} of the AI's)"
        # `table3 --keep`: a row whose runs were not timed again links the record it was timed in
        record = row["kept_from"].removeprefix("docs/results/") if row.get("kept_from") else TABLE3
        out.append(
            (
                f"Table III, {name}: lap 2, the best start of {seeds['n_training_seeds']} training "
                + ("seed" if seeds["n_training_seeds"] == 1 else "seeds"),
                f"{paper[key]:.1f} s ({paper[key] / paper['built_in_ai']:.3f} of its AI's {paper['built_in_ai']} s)",
                f"{ours}, {seeds['finished']} starts finished ({link('record', record)})",
                f"{ai_s:.2f} s",
                f"{limit_s:.2f} s" + ("" if lap_s is None else f" (ours {gap_text(lap_s, limit_s)})"),
                f"`vision-rl train-baseline --algo {'dreamer' if key == 'planet' else key}`, `vision-rl table3`",
            )
        )
    return out


#: Where a DNF reason of the protocol says a start stopped.
_STOPPED_AT = re.compile(r"(\d+) m into the lap")


def table3_summary_table(records: Records, path: str = TABLE3) -> str:
    """Every driver of a table3 record: the best start's lap 2 against the AI and the paper's, and the learner's
    figures over its training seeds."""
    rows = []
    for row in records(path)["rows"]:
        if row["status"] not in ("timed", "DNF"):
            continue
        seeds, paper, lap_s = row.get("over_training_seeds"), row.get("paper"), row["lap_time_s"]
        over = "-"
        if seeds and seeds["lap_time_mean_s"] is not None:
            spread = "" if seeds["lap_time_std_s"] is None else f" ± {seeds['lap_time_std_s']:.2f}"
            lapping = seeds["n_training_seeds_finished"]
            over = f"{seeds['lap_time_mean_s']:.2f}{spread} s over {lapping} lapping seed{'s' if lapping > 1 else ''}"
        rows.append(
            (
                row["name"] + (", kept from an earlier timing" if row.get("kept_from") else ""),
                "DNF" if lap_s is None else f"{lap_s:.2f}",
                "-" if lap_s is None else f"{row['avg_speed_kmh']:.1f}",
                "-" if lap_s is None else f"{row['lap_ratio_to_ai']:.3f}",
                "-" if paper is None else f"{paper['lap_ratio_to_ai']:.3f}",
                over,
                seeds["finished"] if seeds else f"{row['finished']}/{row['seeds']}",
                "-" if row["wall_contact_s"] is None else f"{row['wall_contact_s']:.1f}",
            )
        )
    rows.append(_straight_row(records))
    header = (
        "driver",
        "lap 2, s (best start)",
        "km/h",
        "lap / AI",
        "the paper's lap / AI",
        "over the training seeds",
        "starts finished",
        "wall contact, s per lap (best start)",
    )
    records_line = f"Records: {link(path.rsplit('/', 1)[-1], path)}, {link('the straight driver', STRAIGHT_TT_CUP)}."
    return markdown_table(header, rows) + f"\n{records_line}\n"


def _straight_row(records: Records) -> tuple[str, ...]:
    """The straight driver (full throttle, never steering; the walls steer it) as a row of Table III: the floor."""
    straight, ai_s = records(STRAIGHT_TT_CUP), reference_laps(records, AI_TT_CUP)[0]
    lap_s, best = straight["best_lap_time_s"], straight["best_lap"]
    return (
        "straight driver (full throttle, never steering: the floor)",
        "DNF" if lap_s is None else f"{lap_s:.2f}",
        "-" if lap_s is None else f"{best['avg_speed_kmh']:.1f}",
        "-" if lap_s is None else f"{lap_s / ai_s:.3f}",
        "-",
        "-",
        f"{straight['n_finished']}/{straight['n_seeds']}",
        "-" if lap_s is None else f"{best['wall_contact_s']:.1f}",
    )


def table3_runs_table(records: Records, paths: tuple[str, ...] = (TABLE3,)) -> str:
    """Each training run of table3 records: its lap 2 (best and median start), starts finished, wall contact,
    training time, and where the starts that did not finish stopped."""
    rows = []
    for row in (row for path in paths for row in records(path)["rows"]):
        for run in row.get("runs") or ():
            stopped_m = [float(m) for reason in run["dnf_reasons"] for m in _STOPPED_AT.findall(reason)]
            lap_s, median_s = run["lap_time_s"], run["median_lap_time_s"]
            rows.append(
                (
                    f"{row['name']} s{run['seed']}",
                    "DNF" if lap_s is None else f"{lap_s:.2f}" + ("" if median_s is None else f" ({median_s:.2f})"),
                    f"{run['finished']}/{run['seeds']}",
                    "-" if run["wall_contact_s"] is None else f"{run['wall_contact_s']:.1f}",
                    f"{run['num_timesteps']:,}" if run["num_timesteps"] else "-",
                    f"{run['train_time_s']:,.0f}",
                    "-" if not stopped_m else f"{span_m(stopped_m)} into the lap",
                )
            )
    header = (
        "run",
        "lap 2, s: best (median) start",
        "starts finished",
        "wall contact, s per lap",
        "environment steps",
        "training, s",
        "the other starts stopped",
    )
    named = ", ".join(link(path.rsplit("/", 1)[-1], path) for path in paths)
    return markdown_table(header, rows) + f"\n{'Record' if len(paths) == 1 else 'Records'}: {named}.\n"


def _steps_text(steps: float | None) -> str:
    return "not reached" if steps is None else f"{steps / 1e6:.2f}M"


def fig3_reach_table(records: Records) -> str:
    """Fig. 3's reading at several levels, as the curves record holds it (``reach``): the steps at which the mean
    curves (where every seed has a point) and each seed's own curve first reach a share of standard SAC's final mean
    return, and the curriculum's against standard SAC's; the last level is the target's."""
    curves = records(CURVES_OVER_SEEDS)
    rows = []
    for entry in curves["reach"]:
        standard, curriculum = (entry[label]["mean_x"] for label in ("standard", "curriculum"))
        per_seed = [" / ".join(map(_steps_text, entry[label]["per_seed_x"])) for label in ("standard", "curriculum")]
        ratio = "-" if standard is None or curriculum is None else f"{curriculum / standard:.2f}x"
        rows.append(
            (
                f"{entry['share'] * 100:.0f} % ({entry['level']:,.0f})",
                _steps_text(standard),
                _steps_text(curriculum),
                ratio,
                *per_seed,
            )
        )
    header = (
        "share of standard SAC's final mean return",
        "standard SAC, mean",
        f"curriculum (Agent {curves['curriculum_agent']}), mean",
        "curriculum / standard SAC",
        "standard SAC, each seed",
        "curriculum, each seed",
    )
    return (
        markdown_table(header, rows) + f"\nRecord: {link('learning_curves_num_timesteps.json', CURVES_OVER_SEEDS)}.\n"
    )


#: The horizons (control steps) the world-model table reports, of those `dreamer-model` records.
MODEL_HORIZONS_STEPS = (1, 10, 50)


def dreamer_model_table(records: Records, paths: Iterable[str] = DREAMER_MODEL) -> str:
    """Each Dreamer checkpoint's world model on held-out laps: open-loop prediction error against holding the last
    observation, per horizon, and the groups of entries it predicts worse than that at the longest."""
    rows, longest_steps = [], MODEL_HORIZONS_STEPS[-1]
    for path in paths:
        record = records(path)
        by_steps = {h["horizon_steps"]: h for h in record["horizons"]}
        observation = [
            f"{by_steps[n]['model']['observation_rmse']:.3f} / {by_steps[n]['hold_last']['observation_rmse']:.3f}"
            for n in MODEL_HORIZONS_STEPS
        ]
        model, hold = by_steps[longest_steps]["model"], by_steps[longest_steps]["hold_last"]
        worse = [group for group, rmse in model["groups"].items() if rmse > hold["groups"][group]]
        rows.append(
            (
                link(path.rsplit("/", 1)[-1], path),
                f"{record['num_timesteps']:,}",
                f"{record['reconstruction']['observation_rmse']:.3f}",
                *observation,
                f"{model['reward_rmse']:.2f} / {hold['reward_rmse']:.2f}",
                f"{model['reward_bias']:+.2f} ({by_steps[longest_steps]['true_reward_mean']:.2f})",
                ", ".join(worse) or "none",
            )
        )
    header = (
        "record",
        "environment steps",
        "observation RMSE, reconstructed",
        *(f"observation RMSE {n} step{'s' * (n > 1)} ahead, model / hold last" for n in MODEL_HORIZONS_STEPS),
        f"reward RMSE {longest_steps} steps ahead, model / hold last",
        f"the model's reward less the true one {longest_steps} steps ahead, mean (the true reward's)",
        f"groups predicted worse than holding the last, {longest_steps} steps ahead",
    )
    units = "Observations in the normalised units the model sees; reward per step (Eq. 1); a step is 0.1 s."
    return markdown_table(header, rows) + f"\n{units}\n"


#: BC's recipes on the race (issue 65): (recipe, demonstrations, its table3 record).
BC_RECIPES = (
    ("before (Table III's first timing)", "AI, 20 laps, noise 0.1", TABLE3_FIRST),
    (
        "DART-style noise 0.3, label smoothed",
        "AI, 40 laps, noise 0.3",
        "overtaking-bc-expressway-tt_cup/bc_dart.json",
    ),
    (
        "DART-style, two skills, label smoothed",
        "the 40 laps above plus 40 laps of the AI at skill 0.85, noise 0.3 (`--include`)",
        "overtaking-bc-expressway-tt_cup/bc_dart_two_skills.json",
    ),
    (
        "DAgger, 3 rounds, label smoothed",
        "AI 20 laps noise 0.1, then 3 x 10 laps of bc driving, AI labelling",
        "overtaking-bc-expressway-tt_cup/bc_dagger.json",
    ),
)


def bc_recipes_table(records: Records) -> str:
    """BC's starts finished and laps per training seed under each recipe, through the protocol."""
    rows = []
    for recipe, demos, path in BC_RECIPES:
        bc = next(row for row in records(path)["rows"] if row["key"] == "bc")
        laps = " / ".join("DNF" if r["lap_time_s"] is None else f"{r['lap_time_s']:.1f}" for r in bc["runs"])
        ratio = "-" if bc["lap_time_s"] is None else f"{bc['lap_ratio_to_ai']:.3f}"
        rows.append((recipe, demos, bc["over_training_seeds"]["finished"], laps, ratio, link("record", path)))
    header = ("recipe", "demonstrations", "starts finished", "lap 2, s (s0 / s1 / s2)", "best lap / AI", "record")
    return markdown_table(header, rows)


def _settings_rows(records: Records) -> list[tuple[str, ...]]:
    separation = records(OVERTAKING_PAPER)["settings"]["separation_m"]
    out = []
    for setting in ("A", "B"):
        drivers = [
            driver
            for agents in ("agent1", "agents23")
            for driver in records(SETTINGS.format(agents=agents, setting=setting))["drivers"]
        ]
        agents = [d for d in drivers if not d["reference"]]
        ai = next(d for d in drivers if d["reference"])["summary"]
        counts = ", ".join(f"{d['summary']['all_overtaken_runs']}/{d['summary']['runs']}" for d in agents)
        fastest = ", ".join(f"{d['summary']['fastest_all_five_s']:.1f}" for d in agents)
        over_seeds = ", ".join(_over_seeds(records, agent, setting) for agent in ("agent 2", "agent 3"))
        out.append(
            (
                f"setting {setting} (5 cars {separation[setting]:.0f} m ahead): runs with all five overtaken, "
                "Agents 1, 2, 3 (one training seed)",
                "all five, by each agent (Figs. 4-5)",
                f"{counts}; fastest {fastest} s "
                f"({link('record', SETTINGS.format(agents='agents23', setting=setting))}); "
                f"Agents 2, 3 over {_training_runs()}: {over_seeds}",
                f"{ai['all_overtaken_runs']}/{ai['runs']} (in the agent's car)",
                "-",
                f"`vision-rl evaluate-overtaking --setting {setting} --runs 10 --policy ...`",
            )
        )
    return out


def _training_runs() -> str:
    """The training runs of :data:`OVERTAKING_SEEDS`, in words: "3 training seeds" or "4 training runs of 3 seeds"."""
    seeds, runs = {seed for seed, _, _ in OVERTAKING_SEEDS}, {(seed, run) for seed, run, _ in OVERTAKING_SEEDS}
    return (
        f"{len(seeds)} training seeds"
        if len(runs) == len(seeds)
        else f"{len(runs)} training runs of {len(seeds)} seeds"
    )


def _seed_driver(records: Records, pattern: str, name: str, setting: str) -> dict[str, Any]:
    """The driver ``name`` of the settings record ``pattern`` (an :data:`OVERTAKING_SEEDS` entry) in ``setting``."""
    return next(d for d in records(pattern.format(setting=setting))["drivers"] if d["name"] == name)


def _over_seeds(records: Records, agent: str, setting: str) -> str:
    """Runs with all five overtaken by ``agent`` in ``setting``, summed over :data:`OVERTAKING_SEEDS`."""
    drivers = [
        _seed_driver(records, pattern, name, setting)["summary"]
        for (_, _, which), (pattern, name) in OVERTAKING_SEEDS.items()
        if which == agent
    ]
    return f"{sum(d['all_overtaken_runs'] for d in drivers)}/{sum(d['runs'] for d in drivers)}"


def overtaking_table(records: Records) -> str:
    """The overtaking paper (Table III, settings A and B, Fig. 3) beside our runs."""
    curves = records(CURVES_OVER_SEEDS)
    counts = {kind: curves[kind]["seeds_with_data"] for kind in ("curriculum", "standard")}
    seeds = f"the curriculum over {counts['curriculum']} training seeds, standard SAC over {counts['standard']}"
    # A reading taken while seeds still train says so: its final return is that of the last step every seed reached.
    interim = "" if curves.get("complete", True) else ", interim: seeds still training"
    reach = curves["curriculum_steps_to_standard_final"]
    rows = [*_table3_rows(records), *_settings_rows(records)]
    rows.append(
        (
            "Fig. 3: curriculum (Agent 3) against standard SAC, steps to standard SAC's final overtaking return",
            "fewer for the curriculum",
            (
                f"{reach / 1e6:.2f}M against standard SAC's {curves['standard_steps_to_final'] / 1e6:.2f}M"
                f" ({curves['share_of_standard_steps']:.2f}x)"
                if reach
                else "not reached"
            )
            + f" ({seeds}{interim}; {link('record', CURVES_OVER_SEEDS)})",
            "-",
            "-",
            "`vision-rl evaluate-overtaking --curves ...`",
        )
    )
    return markdown_table(("result", "paper (GT Sport)", "ours", "built-in AI", "physical limit", "command"), rows)


#: Column heads of a driver's row of settings A/B (:func:`_driver_cells`).
DRIVER_HEADER = (
    "all five overtaken",
    "cars passed, mean (range)",
    "travel time, s",
    "fastest run with all five, s",
    "car / wall contact, s",
)


def _driver_cells(driver: dict[str, Any]) -> tuple[str, ...]:
    """One driver's summary over the runs of a setting, as :data:`DRIVER_HEADER` names it."""
    s = driver["summary"]
    fastest = s["fastest_all_five_s"]
    return (
        f"{s['all_overtaken_runs']}/{s['runs']}",
        f"{s['overtaken']['mean']:.1f} ({s['overtaken']['min']}-{s['overtaken']['max']})",
        f"{s['travel_time_s']['mean']:.1f} ± {s['travel_time_s']['std']:.1f}",
        "-" if fastest is None else f"{fastest:.1f}",
        f"{s['car_contact_s']['mean']:.1f} / {s['wall_contact_s']['mean']:.1f}",
    )


def opponent_skill_table(records: Records) -> str:
    """Settings A and B for one agent with the opponents at our skills (0.80-0.88) and at Table III's AI's (0.92)."""
    rows = []
    for setting in ("A", "B"):
        for skill in ("0.80-0.88", "0.92"):
            path = OPPONENT_SKILL.format(skill=skill, setting=setting)
            record = records(path)
            agent = next(d for d in record["drivers"] if not d["reference"])
            rows.append(
                (
                    f"{setting} ({record['separation_m']:.0f} m apart)",
                    f"{agent['name']}",
                    "-".join(f"{x:.2f}" for x in sorted(set(record["opponent_skill_range"]))),
                    *_driver_cells(agent),
                    link("record", path),
                )
            )
    return markdown_table(("setting", "agent", "opponents' skill", *DRIVER_HEADER, "record"), rows)


def settings_drivers_table(records: Records, paths: Iterable[str]) -> str:
    """Every driver of each settings record in ``paths``, in order (the built-in AI in the agent's car too)."""
    rows = []
    for path in paths:
        record = records(path)
        rows.extend(
            (
                f"{record['setting']} ({record['separation_m']:.0f} m apart)",
                d["name"],
                *_driver_cells(d),
                link("record", path),
            )
            for d in record["drivers"]
        )
    return markdown_table(("setting", "driver", *DRIVER_HEADER, "record"), rows)


#: Agents 2 and 3 of each training seed in settings A and B (10 runs each): the record and the driver's name there.
#: Settings A and B of Agents 2 and 3 per training run: (seed, which run of it, agent) -> (record pattern, driver name).
#: Seed 0 trained twice: its first run (folder since lost) and the run Fig. 3 reads.
OVERTAKING_SEEDS = {
    (0, "first run", "agent 2"): (SETTINGS.format(agents="agents23", setting="{setting}"), "agent 2"),
    (0, "first run", "agent 3"): (SETTINGS.format(agents="agents23", setting="{setting}"), "agent 3"),
    (0, "Fig. 3's run", "agent 2"): (
        "overtaking-expressway-tt_cup/seeds/s0-fig3/agent2_setting_{setting}.json",
        "agent2-s0",
    ),
    (0, "Fig. 3's run", "agent 3"): (
        "overtaking-expressway-tt_cup/seeds/s0-fig3/agent3_setting_{setting}.json",
        "agent3-s0",
    ),
    (1, "", "agent 2"): (OPPONENT_SKILL.format(skill="0.80-0.88", setting="{setting}"), "agent2-s1"),
    (1, "", "agent 3"): ("overtaking-expressway-tt_cup/seeds/s1/agent3_setting_{setting}.json", "agent3-s1"),
    (2, "", "agent 2"): ("overtaking-expressway-tt_cup/seeds/s2/agent2_setting_{setting}.json", "agent2-s2"),
    (2, "", "agent 3"): ("overtaking-expressway-tt_cup/seeds/s2/agent3_setting_{setting}.json", "agent3-s2"),
}


def _missed_runs(driver: dict[str, Any]) -> str:
    """How each run that did not overtake all five ended: the protocol's reason, when, and the cars passed."""
    return ", ".join(
        f"{run['end'].split(':')[0]} at {run['travel_time_s']:.0f} s ({run['overtaken']} passed)"
        for run in driver["runs"]
        if not run["all_overtaken"]
    )


def overtaking_seeds_table(records: Records) -> str:
    """Runs with all five overtaken by Agents 2 and 3 in settings A and B, per training seed (issue 65's target: at
    least 9/10 in each, on every seed), and how the other runs ended."""
    rows = []
    for (seed, run, agent), (pattern, name) in OVERTAKING_SEEDS.items():
        cells, missed = [], []
        for setting in ("A", "B"):
            driver = _seed_driver(records, pattern, name, setting)
            cells.append(link(_driver_cells(driver)[0], pattern.format(setting=setting)))
            missed.append(f"{setting}: {_missed_runs(driver) or 'none'}")
        rows.append((f"{seed} ({run})" if run else f"{seed}", agent, *cells, "; ".join(missed)))
    header = ("training seed", "agent", "setting A: all five overtaken", "setting B", "the other runs ended")
    return markdown_table(header, rows)
