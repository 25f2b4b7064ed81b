"""The result tables of the README and the docs come from the records: a changed record changes the table, a page's
text outside its markers stays as it was, links resolve from each page, and a missing record or marker is an error."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from vision_rl.evaluation.report import (
    AI_HATCHBACK,
    AI_TT_CUP,
    QUICK_JOB,
    RESULTS,
    TABLE3,
    TABLES,
    ReportError,
    build_tables,
    fill_page,
    gap_text,
    lap_text,
    mean_std_s,
    page_results_href,
    records_read,
    render_pages,
    seal_record_file,
    sealed,
)

RESULTS_DIR = Path(__file__).resolve().parents[2] / "docs" / "results"


@pytest.fixture
def results_copy(tmp_path: Path) -> Path:
    """The committed records (JSON only) in a folder a test may change."""
    target = tmp_path / "docs" / "results"
    shutil.copytree(RESULTS_DIR, target, ignore=shutil.ignore_patterns("*.png", "*.mp4", "*.csv", "*.md", "*.txt"))
    return target


def edit_record(results: Path, relative_path: str, change, seal: bool = True) -> None:
    """``change`` the record in place; sealed again unless ``seal`` is False (an edit behind the seal's back)."""
    path = results / relative_path
    record = json.loads(path.read_text(encoding="utf-8"))
    change(record)
    record.pop("content_sha256", None)
    path.write_text(json.dumps(sealed(record) if seal else record), encoding="utf-8")


def test_laps_and_gaps_read_as_the_papers_write_them():
    assert lap_text(129.29302339) == "2:09.293"
    assert lap_text(59.9996) == "1:00.000" and lap_text(45.5) == "45.500 s" and lap_text(None) == "DNF"
    assert gap_text(129.293, 139.299) == "-7.18 %" and gap_text(110.0, 100.0) == "+10.00 %"
    assert mean_std_s([1.0, 2.0, 3.0]) == (2.0, 1.0) and mean_std_s([4.0]) == (4.0, 0.0)
    with pytest.raises(ReportError):
        mean_std_s([])


def test_the_committed_records_give_the_tables_figures():
    tables = build_tables(RESULTS_DIR)
    assert set(tables) == set(TABLES)
    vision = tables["vision"]
    # the state agent: 6 training seeds pooled from two records, the chosen weights; the AI and the limit from the
    # protocol's evaluation of the AI; the paper's Table 1
    assert "**2:09.293** ± 0.31 s over 6 training seeds, 18/18 starts, clean" in vision
    assert "7.18 % faster than the AI" in vision and "2:19.299" in vision and "2:06.603 (ours +2.12 %)" in vision
    assert "1:39.408 (11.30 % faster than its AI)" in vision and "1:42.717 (8.35 % faster than its AI)" in vision
    assert "**2:10.826** ± 0.70 s over 8 training seeds, 104/104 starts, not clean" in vision
    assert "vision 2:10.560, state 2:12.197 (3/3 starts each) in 10.6 min" in vision
    assert "| 388 s | lap 2:10.560 (3/3 starts) |" in tables["quick"]
    assert "| 0.989 | 0.999 | 0.999 | 0.992 | 0.994 |" in tables["phase1"]
    assert "**89.82 s** (0.893 of the AI's), 9/9 starts finished" in tables["overtaking"]
    assert "9/10, 9/10, 8/10; fastest 28.5, 29.1, 29.2 s" in tables["overtaking"]
    assert "asymmetric **1:46.255** (-0.06 % on the limit, 52.6 s of wall contact)" in tables["ddpg"]
    assert (
        "| symmetric s1 | 200 / 65 | 15,362 / 14,362 | 59 | 2,725 m (farthest 5,330 m) | +15.1 | - |"
        in tables["ddpg-equal-compute"]
    )
    assert (
        "| 40.0 min | 5, 18 / 12, 10 / 29, 9 m | 2.7k, 2.6k / 1.2k, 1.1k / 52.2k, 51.6k |"
        in tables["ddpg-first-trainings"]
    )
    assert (
        "lap 2 1:46.198 (-0.11 % on the limit), worst 1:46.744; 52 s of wall contact"
        in tables["ddpg-state-actor-crashgo"]
    )  # training seed 0's fastest start, not its median (1:46.323)
    assert (
        "| asymmetric, channels_last | 0.71 (1,408 ms; 402 ms of CPU) | 3.75 (267 ms; 78 ms of CPU) | 5.3x"
        in tables["ddpg-bench"]
    )
    assert "Agents 2, 3 over 4 training runs of 3 seeds: 38/40, 31/40 |" in tables["overtaking"]  # setting B, summed
    assert (
        "1.50M against standard SAC's 1.30M (1.15x) (the curriculum over 3 training seeds, standard SAC over 3;"
        in (tables["overtaking"])
    )
    assert (
        "| 100 % (4,281) | 1.30M | 1.50M | 1.15x | 1.30M / 0.60M / 1.50M | 1.60M / 1.40M / 1.20M |"
        in (tables["fig3-reach"])
    )
    assert "| 80 % (3,425) | 0.40M | 0.80M | 2.00x |" in tables["fig3-reach"]  # the mean where every seed has a point
    assert "| PlaNet (as Dreamer) s1 | 94.54 (95.77) | 3/3 | 5.5 | 1,000,000 | 14,503 | - |" in tables["table3-runs"]
    assert (
        "| 1,000,000 | 0.053 | 0.062 / 0.081 | 0.254 / 0.402 | 0.623 / 0.644 | 3.00 / 1.34 | -1.72 (4.34) | heading"
        in tables["dreamer-model"]
    )
    assert (
        "| PlaNet (as Dreamer) s2 | 97.08 (97.14) | 3/3 | 6.0 | 465,900 | 11,926 | - |"
        in (tables["table3-dreamer-interim"])
    )
    assert (
        "| 609,640 | 0.060 | 0.069 / 0.081 | 0.236 / 0.402 | 0.521 / 0.644 | 2.25 / 1.34 | -0.75 (4.34) | heading"
        in (tables["dreamer-model-interim"])
    )
    seeds = tables["overtaking-seeds"]
    assert (
        "| 1 | agent 3 | [9/10](RESULTS/overtaking-expressway-tt_cup/seeds/s1/agent3_setting_A.json) | [8/10]" in seeds
    )
    assert "| A: stuck at 24 s (0 passed); B: stuck at 57 s (0 passed), stuck at 121 s (2 passed) |" in seeds
    assert "| A: stuck at 30 s (1 passed); B: none |" in seeds  # seed 0's Agent 2 misses once, in A only
    assert "| 0 (Fig. 3's run) | agent 3 | [10/10](RESULTS/overtaking-expressway-tt_cup/seeds/s0-fig3/" in seeds
    assert (
        "| B (200 m apart) | agent 2 | 10/10 | 5.0 (5-5) | 165.5 ± 30.2 | 114.9 | 0.4 / 6.9 |"
        in tables["overtaking-settings"]
    )
    assert "| GAIL s1 | 114.60 (114.78) | 3/3 | 37.5 | 1,000,000 | 10,833 | - |" in tables["table3-runs"]
    assert "| BC s1 | 117.02 | 1/3 | 23.4 | - | 28 | 1,073-1,074 m into the lap |" in tables["table3-first-runs"]
    assert "| TD3 s2 | 114.29 | 1/3 | 3.4 | 1,000,000 | 1,054 | 2,054-2,967 m into the lap |" in tables["table3-runs"]
    assert (
        "| SAC, kept from an earlier timing | 89.82 | 176.4 | 0.893 | 0.922 | 91.03 ± 1.06 s over 3 lapping seeds |"
        in tables["table3-summary"]
    )
    assert (
        "| BC, kept from an earlier timing | 105.38 | 150.4 | 1.048 | 1.243 | 110.28 ± 5.17 s over 3 lapping seeds |"
        in (tables["table3-summary"])
    )
    assert (
        "| PlaNet (as Dreamer) | 87.81 | 180.5 | 0.873 | 1.024 | 90.42 ± 3.61 s over 3 lapping seeds | 9/9 | 4.3 |"
        in (tables["table3-summary"])
    )
    assert (
        "**87.81 s** (0.873 of the AI's), 9/9 starts finished ([record](RESULTS/table3-expressway-tt_cup/table3.json))"
        in (tables["overtaking"])
    )
    assert "| 4/9 | 115.7 / 109.8 / 105.4 | 1.048 |" in tables["bc-recipes"]
    assert "| A (50 m apart) | c_r 2 | 10/10 | 5.0 (5-5) | 48.2 ± 26.5 | 27.7 | 1.2 / 2.8 |" in tables["c-r-ablation"]
    pendulum, mountain_car = tables["ddpg-reference-pendulum"], tables["ddpg-reference-mountaincar"]
    assert (
        "| ours-bn (the paper's networks) | -168 ± 93 (-276, -112, -117) | -121 ± 18 | -226 ± 8 | 1,357 |" in pendulum
    )
    assert (
        "| SB3 DDPG | -33.6 ± 57.4 (-0.0, -99.9, -1.0) | -33.9 ± 57.2 | -22.4 ± 31.6 | 285 | 4 of 15 |" in mountain_car
    )
    assert all(f"]({RESULTS}" in table for table in tables.values())  # each table links its records


def test_a_changed_record_changes_its_tables(results_copy):
    before = build_tables(results_copy)
    edit_record(results_copy, AI_HATCHBACK, lambda r: r.update(best_lap_time_s=150.0))
    edit_record(results_copy, QUICK_JOB, lambda r: r["vision"].update(lap_time_s=128.5, train_seconds=401))
    edit_record(results_copy, TABLE3, lambda r: next(x for x in r["rows"] if x["key"] == "sac").update(lap_time_s=88.0))
    first = "docs/results/table3-expressway-tt_cup/first-recipe/table3.json"  # as `table3 --keep` writes it
    edit_record(results_copy, TABLE3, lambda r: next(x for x in r["rows"] if x["key"] == "bc").update(kept_from=first))
    after = build_tables(results_copy)
    assert "| 2:30.000 |" in after["vision"] and "| 2:19.299 |" in before["vision"]
    assert "13.80 % faster than the AI" in after["vision"]  # 2:09.293 against 2:30.000
    assert "vision 2:08.500" in after["vision"] and "| 401 s | lap 2:08.500 (3/3 starts) |" in after["quick"]
    assert "**88.00 s** (0.875 of the AI's), 9/9 starts" in after["overtaking"]
    bc = "**105.38 s** (1.048 of the AI's), 4/9 starts finished ([record](RESULTS/table3-expressway-tt_cup/{}))"
    assert bc.format("imitation/table3.json") in before["overtaking"]  # a kept row links the record it was timed in
    assert bc.format("first-recipe/table3.json") in after["overtaking"]
    assert after["ddpg"] == before["ddpg"] and after["phase1"] == before["phase1"]
    edit_record(
        results_copy,
        "overtaking-expressway-tt_cup/fig3/learning_curves_num_timesteps.json",
        lambda r: r.update(complete=False),
    )
    assert (
        "standard SAC over 3, interim: seeds still training;"
        in build_tables(results_copy, ["overtaking"])["overtaking"]
    )
    for seed in (0, 1, 2):  # SB3 DDPG's training episodes on MountainCar, none of them ending at the goal now
        edit_record(
            results_copy,
            f"ddpg-reference/MountainCarContinuous-v0/sb3-ddpg-s{seed}.json",
            lambda r: [e.update(length=999) for e in r["episodes"]],
        )
    assert "| 4 of 15 |" in before["ddpg-reference-mountaincar"]
    assert (
        "| 285 | 0 of 15 |" in build_tables(results_copy, ["ddpg-reference-mountaincar"])["ddpg-reference-mountaincar"]
    )


def test_a_missing_record_or_figure_is_an_error(results_copy):
    (results_copy / QUICK_JOB).unlink()
    with pytest.raises(ReportError, match=r"job\.json is missing"):
        build_tables(results_copy, ["quick"])
    assert build_tables(results_copy, ["ddpg"])  # the other tables do not need it
    edit_record(results_copy, AI_HATCHBACK, lambda r: r.pop("best_lap_time_s"))
    with pytest.raises(ReportError, match=r"vision table .*ai_expressway_hatchback\.json\): KeyError 'best_lap_"):
        build_tables(results_copy, ["vision"])


def test_the_state_tables_read_the_chosen_and_the_last_weights_each_from_its_own_field(results_copy):
    before = build_tables(results_copy, ["state-agent"])["state-agent"]
    two_million = "state-expressway-hatchback-25hz/dt04-ent4-lrf-select-2m_experiment.json"
    edit_record(results_copy, two_million, lambda r: r["selected"]["per_seed"][0].update(lap_time_s=135.51531380758965))
    after = build_tables(results_copy, ["state-agent"])["state-agent"]
    assert "**2:09.293 ± 0.31 s**" in before and "**2:10.293 ± 2.58 s**" in after  # seed 0's chosen lap 6 s slower
    assert "/ 2:10.115 ± 0.44 s |" in before and "/ 2:10.115 ± 0.44 s |" in after  # the last weights' figure as it was


def test_a_state_or_scaling_table_refuses_a_record_without_its_figures(results_copy):
    snapshots = "state-expressway-hatchback-steer05/baseline_at_400k.json"
    edit_record(results_copy, snapshots, lambda r: [r.pop(seed) for seed in ("0", "1", "2")])
    with pytest.raises(ReportError, match=r"no training seed in .*baseline_at_400k\.json"):
        build_tables(results_copy, ["state-agent"])
    curves = "scaling/staleness/one-process/learning_curves.json"
    edit_record(results_copy, curves, lambda r: r["per_seed"]["2"].update(lap_time_s=[None] * 8))
    with pytest.raises(ReportError, match="never beat the built-in AI's lap"):
        build_tables(results_copy, ["scaling-staleness"])


def test_a_page_keeps_its_text_and_gets_its_tables_with_links_from_its_folder():
    page = (
        "# Title\n\nbefore\n<!-- report:t -->\nold table\n<!-- /report -->\n"
        "after\n<!-- report:u -->\n<!-- /report -->\n"
    )
    tables = {"t": f"| a |\n| --- |\n| [r]({RESULTS}x/y.json) |\n", "u": "| b |\n"}
    filled = fill_page(page, tables, "../results")
    assert filled.startswith("# Title\n\nbefore\n<!-- report:t -->\n| a |")
    assert "[r](../results/x/y.json)" in filled and "old table" not in filled
    assert filled.endswith("after\n<!-- report:u -->\n| b |\n<!-- /report -->\n")
    assert fill_page(filled, tables, "../results") == filled  # filling twice changes nothing
    with pytest.raises(ReportError, match="no table called 'v'"):
        fill_page("<!-- report:v -->\n<!-- /report -->\n", tables, ".")
    with pytest.raises(ReportError, match="without its"):
        fill_page("<!-- report:t -->\nno end\n", tables, ".")


def test_pages_at_different_depths_link_the_same_records(tmp_path, results_copy):
    readme, paper_page = tmp_path / "README.md", tmp_path / "docs" / "papers" / "vision.md"
    paper_page.parent.mkdir(parents=True)
    for page in (readme, paper_page):
        page.write_text("<!-- report:quick -->\n<!-- /report -->\n", encoding="utf-8")
    (tmp_path / "plain.md").write_text("no tables here\n", encoding="utf-8")
    assert page_results_href(readme, results_copy) == "docs/results"
    assert page_results_href(paper_page, results_copy) == "../results"
    rendered = render_pages([readme, paper_page, tmp_path / "plain.md"], results_copy)
    assert set(rendered) == {readme, paper_page}
    assert "(docs/results/make-quick/job.json)" in rendered[readme][1]
    assert "(../results/make-quick/job.json)" in rendered[paper_page][1]


def test_every_committed_record_is_sealed_and_an_edit_behind_its_seal_is_refused(results_copy):
    assert len(records_read(results_copy)) >= 20
    assert not any(seal_record_file(path) for path in records_read(results_copy))  # all sealed already
    path = results_copy / AI_HATCHBACK
    record = json.loads(path.read_text())
    path.write_text(json.dumps({**record, "best_lap_time_s": 99.0}))  # a faster AI, the seal kept
    with pytest.raises(ReportError) as excinfo:
        build_tables(results_copy, ["reference"])
    assert str(excinfo.value).startswith(f"the record {path} has content SHA-256")
    with pytest.raises(ReportError, match="remove its content_sha256"):
        seal_record_file(path)  # the sealer does not vouch for a changed record
    edit_record(results_copy, TABLE3, lambda r: None, seal=False)  # format 1: no seal
    with pytest.raises(ReportError, match=r"table3\.json has no content_sha256 .*scripts/seal_records\.py PATH"):
        build_tables(results_copy, ["overtaking"])
    assert seal_record_file(results_copy / TABLE3) and build_tables(results_copy, ["overtaking"])


def test_an_evaluation_record_is_sealed_without_its_output_paths(results_copy):
    edit_record(results_copy, AI_TT_CUP, lambda r: None)
    path = results_copy / AI_TT_CUP
    record = json.loads(path.read_text())
    path.write_text(json.dumps({**record, "plot": "elsewhere.png"}))  # an output path, added after timing
    assert build_tables(results_copy, ["reference"])


def test_the_vision_logs_tables_read_each_figure_from_its_record(results_copy):
    names = ["vision-log-stuck-ends", "vision-log-critic-state", "vision-log-n-step"]
    tables = build_tables(results_copy, names)
    # seed 10's rule kept the last weights: none of its candidates finished the first 3 held-out starts
    assert "| 7 (150k, none finished) | 10 (150k) | 93/104 |" in tables["vision-log-stuck-ends"]
    # seeds 0 and 12-14 of one record pooled with 15-18 of another: starts, the protocol's starts, the mean lap
    assert "| 5 | 13 | 8 | 88/104 | 19/24 | 2:15.213 ± 2.31 s |" in tables["vision-log-critic-state"]
    state = "RESULTS/state-expressway-hatchback-speed-scaled/rate_scaled_experiment.json"
    assert f"| 2.44 % faster than the AI | 3.32 % slower than its [2:11.537]({state}) |" in tables["vision-log-n-step"]
    stuck = "vision-expressway-hatchback/quick_stuck_ends_starts13.json"
    edit_record(
        results_copy,
        stuck,
        lambda r: [start.update(finished=True) for start in r["seeds"][6]["held_out_starts_100_104"]["150000"]],
    )  # seed 10's last weights now finish their held-out starts
    assert "| 7 (150k) | 10 (150k) | 93/104 |" in build_tables(results_copy, names[:1])["vision-log-stuck-ends"]
    edit_record(results_copy, stuck, lambda r: r["finished_of_13_per_seed"]["last (150k)"].pop())
    with pytest.raises(ReportError, match="7 counts of starts finished for 8 training seeds"):
        build_tables(results_copy, names[:1])


def test_the_selection_table_marks_chosen_weights_that_are_the_last_ones_and_last_weights_not_clean(results_copy):
    two_million = "state-expressway-hatchback-25hz/dt04-ent4-lrf-select-2m_experiment.json"
    before = build_tables(results_copy, ["state-25hz-select-2m"])["state-25hz-select-2m"]
    assert "| 2 | 2:09.452 (0.04 s) | 2:09.452 (0.04 s) | 2M (the last weights) | 18 of 20 |" in before

    def change(record):
        record["selected"]["per_seed"][2].update(kept_at_steps=1_900_000)
        record["per_seed"][2].update(clean=False)

    edit_record(results_copy, two_million, change)
    after = build_tables(results_copy, ["state-25hz-select-2m"])["state-25hz-select-2m"]
    assert "| 2 | 2:09.452 (0.04 s: not clean) | 2:09.452 (0.04 s) | 1.9M | 18 of 20 |" in after


def test_the_plateau_averages_only_the_evaluations_of_its_span(results_copy):
    curves = "state-expressway-hatchback-25hz/dt04_learning_curves.json"
    before = build_tables(results_copy, ["state-25hz-changes"])["state-25hz-changes"]
    assert "| 2:11.34 (2:10.98) |" in before
    edit_record(results_copy, curves, lambda r: r["mean_lap_time_s"].__setitem__(1, 100.0))  # 200k: outside the span
    assert build_tables(results_copy, ["state-25hz-changes"])["state-25hz-changes"] == before
    edit_record(results_copy, curves, lambda r: r["mean_lap_time_s"].__setitem__(2, None))  # 300k: no seed lapped
    assert "| 2:11.31 (2:10.98) |" in build_tables(results_copy, ["state-25hz-changes"])["state-25hz-changes"]


def test_the_vision_driver_table_reads_the_chosen_weights_at_each_seeds_chosen_step(results_copy):
    usable = "vision-expressway-hatchback/quick_steer_usable_starts13.json"
    chosen = "the weights chosen by 3 held-out starts: the protocol's starts {}/24, 13 starts each 96 of 104, {}"
    table = build_tables(results_copy, ["vision-agent"])["vision-agent"]
    assert chosen.format(20, "2:15.162 ± 1.56 s") in table  # seeds 6 and 7 chosen at 125k, the others at 150k
    # seed 6 chosen at 150k: its protocol's starts are those of the 150k weights (3 of 3), not of the 125k (1 of 3)
    edit_record(results_copy, usable, lambda r: r["seeds"][2].update(chosen_steps_by_3_held_out_starts=150000))
    assert chosen.format(22, "2:15.257 ± 1.58 s") in build_tables(results_copy, ["vision-agent"])["vision-agent"]


def test_an_encoder_error_table_bolds_the_smaller_error_and_neither_when_they_read_alike():
    table = build_tables(RESULTS_DIR, ["vision-log-wall-frames-encoder"])["vision-log-wall-frames-encoder"]
    assert "| two policies that finished (5,572 frames) | 0.46 / **0.39** | 0.056 / 0.056 | 3.53 / **3.12** |" in table
    assert "| the same, in wall contact (275 frames) | 1.52 / **0.79** | **0.110** / 0.164 |" in table


def test_the_bench_tables_verdict_reads_the_idle_ratio_against_the_records_target(results_copy):
    assert ">= 1.3x: **missed** |" in build_tables(results_copy, ["scaling-bench"])["scaling-bench"]
    edit_record(
        results_copy, "scaling/bench_scaling_idle.json", lambda r: r["rows"]["capture"]["frames/s"].update(ratio=1.3)
    )
    assert "| 1.30x (1 worker 144 [131-151]" in (
        table := build_tables(results_copy, ["scaling-bench"])["scaling-bench"]
    )
    assert ">= 1.3x: met |" in table
