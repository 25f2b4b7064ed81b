"""table3: the built-in AI and the trained baselines through the lap-time protocol, beside the paper's Table III as
ratios to each table's AI; rows without a run read "not trained" (PlaNet's is filled by dreamer runs)."""

from __future__ import annotations

import json

import pytest

from tests.helpers.overtaking import tiny_baseline_config
from vision_rl.commands.main import main
from vision_rl.evaluation.protocol import BuiltinAI, time_laps
from vision_rl.evaluation.report import record_damage
from vision_rl.overtaking.baselines import train_baseline
from vision_rl.overtaking.config import Table3Config
from vision_rl.overtaking.table3 import PAPER_TABLE3, table3


@pytest.fixture(scope="module")
def bc_run(tmp_path_factory, small_track, small_demos):
    demos, _ = small_demos
    out = tmp_path_factory.mktemp("table3") / "bc-small"
    train_baseline(tiny_baseline_config(small_track, demos, out, algo="bc"))
    return out


def test_the_table_times_the_ai_and_the_runs_beside_the_paper(bc_run, small_track):
    result = table3(
        Table3Config(runs=str(bc_run), track=small_track, car="tt_cup", seeds=1, laps=1, demonstrator=False)
    )
    rows = {row["key"]: row for row in result["rows"]}
    assert list(rows) == ["ai", "bc", "gail", "sac", "td3", "planet"]
    ai_lap = time_laps(BuiltinAI(), small_track, "tt_cup", seeds=[0], laps=1).summary()["best_lap"]
    assert rows["ai"]["lap_time_s"] == ai_lap["lap_time_s"] and rows["ai"]["avg_speed_kmh"] == ai_lap["avg_speed_kmh"]
    assert rows["ai"]["lap_ratio_to_ai"] == 1.0 and rows["ai"]["paper"]["lap_ratio_to_ai"] == 1.0
    bc = rows["bc"]
    assert bc["run"] == str(bc_run) and bc["status"] in ("timed", "DNF") and len(bc["runs"]) == 1
    if bc["lap_time_s"] is not None:
        assert bc["lap_ratio_to_ai"] == pytest.approx(bc["lap_time_s"] / rows["ai"]["lap_time_s"])
    over = bc["over_training_seeds"]
    assert over["n_training_seeds"] == 1 and over["finished"] == f"{bc['finished']}/1"
    assert over["lap_time_mean_s"] == bc["lap_time_s"] and over["lap_time_std_s"] is None
    assert bc["paper"]["lap_ratio_to_ai"] == pytest.approx(108.0 / 86.9)
    assert bc["paper"]["speed_ratio_to_ai"] == pytest.approx(146.8 / 184.4)
    for key in ("gail", "sac", "td3", "planet"):
        assert rows[key]["status"] == "not trained" and rows[key]["lap_time_s"] is None
        assert rows[key]["paper"]["lap_time_s"] == PAPER_TABLE3[key][0]
    assert result["protocol"]["version"] == 1 and result["protocol"]["seeds"] == 1


def test_found_runs_of_another_track_are_skipped_with_the_reason(bc_run, tmp_path, small_track, capsys):
    # The default is every run under --runs-root; the bc run is of the small track, so on expressway it is skipped.
    code = main(
        [
            "table3",
            "--runs-root",
            str(bc_run.parent),
            "--seeds",
            "1",
            "--laps",
            "1",
            "--no-demonstrator",
            "--time-limit-s",
            "1",
            "--json",
        ]
    )
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["skipped"][0]["run"] == str(bc_run) and "not 'expressway'" in result["skipped"][0]["reason"]
    assert {row["key"]: row["status"] for row in result["rows"]}["bc"] == "not trained"
    assert result["rows"][0]["status"] == "DNF" and result["rows"][0]["lap_time_s"] is None  # 1 s: no lap


def test_a_run_named_twice_is_refused_as_one_training_seed(bc_run, small_track):
    with pytest.raises(ValueError, match="more than once"):
        table3(Table3Config(runs=f"{bc_run},{bc_run}", track=small_track, car="tt_cup", seeds=1, laps=1))


def test_kept_rows_stand_in_for_algorithms_without_a_run_and_a_foreign_or_changed_record_is_refused(
    bc_run, small_track, tmp_path
):
    """--keep: a row of an earlier record fills an algorithm with no run here (marked as kept), a run given here is
    timed again, and a record of other protocol terms or changed after it was written is refused in one line."""
    from vision_rl.files import write_json

    table = dict(track=small_track, car="tt_cup", seeds=1, laps=1, demonstrator=False)
    earlier = table3(Table3Config(runs=str(bc_run), **table))
    kept_path = tmp_path / "earlier.json"
    write_json(kept_path, earlier)
    (tmp_path / "none").mkdir()
    rows = {
        r["key"]: r
        for r in table3(Table3Config(runs_root=str(tmp_path / "none"), keep=str(kept_path), **table))["rows"]
    }
    assert rows["bc"]["kept_from"] == str(kept_path) and rows["bc"]["runs"] == earlier["rows"][1]["runs"]
    assert rows["gail"]["status"] == "not trained" and "kept_from" not in rows["ai"]
    again = {r["key"]: r for r in table3(Table3Config(runs=str(bc_run), keep=str(kept_path), **table))["rows"]}
    assert "kept_from" not in again["bc"] and again["bc"]["run"] == str(bc_run)
    # Kept again from a record that kept it: the row still names the record it was timed in.
    chained_path = tmp_path / "chained.json"
    write_json(chained_path, table3(Table3Config(runs_root=str(tmp_path / "none"), keep=str(kept_path), **table)))
    chained = {
        r["key"]: r
        for r in table3(Table3Config(runs_root=str(tmp_path / "none"), keep=str(chained_path), **table))["rows"]
    }
    assert chained["bc"]["kept_from"] == str(kept_path)
    # --out writes the record once timed, so --keep may name the file it replaces (a shell's > would empty it first).
    args = ["table3", "--runs-root", str(tmp_path / "none"), "--track", small_track, "--seeds", "1", "--laps", "1"]
    assert main([*args, "--no-demonstrator", "--keep", str(chained_path), "--out", str(chained_path)]) == 0
    rewritten = {r["key"]: r for r in json.loads(chained_path.read_text())["rows"]}
    assert (
        rewritten["bc"]["kept_from"] == str(kept_path) and record_damage(json.loads(chained_path.read_text())) is None
    )
    with pytest.raises(ValueError, match=r"would not compare: protocol laps 1 \(here 2\)"):
        table3(Table3Config(runs=str(bc_run), keep=str(kept_path), **{**table, "laps": 2}))
    earlier["rows"][1]["lap_time_s"] = 1.0
    write_json(kept_path, earlier)
    with pytest.raises(ValueError, match="changed after it was written"):
        table3(Table3Config(runs=str(bc_run), keep=str(kept_path), **table))
