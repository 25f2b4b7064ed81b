"""The records the leaderboard reads (``evaluation.json``, ``experiment.json``): an edited lap, a lap faster than
the physical limit allows, a string lap time, deep nesting, records written before content hashes, and seeded
single-bit flips over each."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from tests.helpers.bitflips import check_flips, sample_flips
from vision_rl.evaluation import leaderboard as lb
from vision_rl.evaluation.protocol import BuiltinAI, time_laps
from vision_rl.evaluation.report import CURRICULUM_CURVES, SETTINGS, TABLE3, Records, ReportError, build_tables, sealed
from vision_rl.files import CONTENT_KEY, sealed_record


@pytest.fixture(scope="module")
def timed(small_track):
    """The built-in AI's protocol record on the small track, as ``evaluate`` stores it."""
    timing = time_laps(BuiltinAI(), small_track, "hatchback", seeds=(0, 1))
    return lb.evaluation_record(timing, {"driver": "policy", "observation": "state", "policy": "runs/x"}, "x")


def _store(record: dict, path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=2))


def _edited(record: dict, lap_s, reseal: bool) -> dict:
    """``record`` with its best lap set to ``lap_s`` everywhere it appears, its hash made anew when ``reseal``."""
    data = json.loads(json.dumps(record))
    best = data["best_seed"]
    data["best_lap_time_s"] = data["best_lap"]["lap_time_s"] = lap_s
    for seed in data["seeds"]:
        if seed["seed"] == best:
            seed["lap_time_s"] = lap_s
    return lb.seal_evaluation(data) if reseal else data


def test_an_edited_lap_is_refused_and_one_under_the_limit_never_tops_the_table(timed, small_track, tmp_path, fault):
    runs = tmp_path / "runs"
    path = runs / "x" / "evaluation.json"
    _store(_edited(timed, 59.999, reseal=False), path)
    result = lb.leaderboard(small_track, "hatchback", str(runs))
    (refused,) = result["refused"]
    assert (
        "evaluation.json: the evaluation record has content SHA-256" in refused and len(result["rows"]) == 2
    )  # the AI and the straight driver
    fault.refused("evaluation.json's best lap edited to 59.999 s", refused)
    fast_s = 0.5 * result["limit_lap_time_s"]  # the 59.999 s on the expressway: -52.6 % of its limit
    _store(_edited(timed, fast_s, reseal=True), path)
    result = lb.leaderboard(small_track, "hatchback", str(runs))
    (refused,) = result["refused"]
    assert "50.0 % under the physical limit" in refused and [r["kind"] for r in result["rows"]] == ["ai", "straight"]
    fault.refused("evaluation.json (sealed anew) with a lap 50 % under the physical limit", refused)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"best_lap_time_s": "59.999"}, "best_lap_time_s is '59.999', not a lap time in seconds or null"),
        ({"n_finished": 7}, "n_finished and n_seeds are [7, 2]"),
        ({"seeds": None}, "seeds is not a list of starts"),
        ({"best_lap": None}, "best_lap is not the lap of best_lap_time_s"),
        ({"clean": "yes"}, "clean is 'yes', not true or false"),
        ({"driver": [1]}, "driver is not an object"),
    ],
)
def test_a_sealed_record_of_bad_fields_is_refused_in_one_line(timed, tmp_path, change, message, fault):
    path = tmp_path / "runs" / "x" / "evaluation.json"
    _store(lb.seal_evaluation({**json.loads(json.dumps(timed)), **change}), path)
    with pytest.raises(lb.RecordError) as excinfo:
        lb.read_evaluation(path)
    assert message in str(excinfo.value) and "evaluation.json" in str(excinfo.value)
    assert "re-measure it: vision-rl evaluate --policy" in str(excinfo.value)
    fault.refused(f"evaluation.json (sealed) with {change}", str(excinfo.value))


@pytest.mark.parametrize(
    "name, text",
    [
        ("evaluation.json", '{"a":' * 50_000 + "1" + "}" * 50_000),
        ("experiment.json", "[" * 100_000 + "]" * 100_000),
        ("evaluation.json", "[1, 2]"),
    ],
)
def test_a_record_that_is_not_a_json_object_is_refused_in_one_line(small_track, tmp_path, name, text, fault):
    runs = tmp_path / "runs"
    (runs / "x").mkdir(parents=True)
    (runs / "x" / name).write_text(text)
    (refused,) = lb.leaderboard(small_track, "hatchback", str(runs))["refused"]
    assert name in refused and "\n" not in refused
    fault.refused(f"{name} of {len(text):,} characters: {text[:12]}...", refused)


def test_records_written_before_content_hashes_are_refused_with_the_command_that_remeasures_them(
    timed, small_track, tmp_path, fault
):
    runs = tmp_path / "runs"
    old = {k: v for k, v in timed.items() if k != CONTENT_KEY}
    _store(old, runs / "x" / "evaluation.json")
    experiment = {
        "format": lb.EXPERIMENT_FORMAT,
        "name": "e",
        "observation": "state",
        "summary": lb.aggregate_seeds([timed]),
    }
    _store(experiment, runs / "e" / "experiment.json")
    refused = lb.leaderboard(small_track, "hatchback", str(runs))["refused"]
    assert any("evaluation.json: the evaluation record has no content_sha256" in r for r in refused)
    assert any("experiment.json: the experiment record has no content_sha256" in r for r in refused)
    assert all(("vision-rl evaluate --policy runs/x" in r) or ("vision-rl experiment --out" in r) for r in refused)
    fault.refused(
        "evaluation.json written before content hashes", refused[1] if "evaluation" in refused[1] else refused[0]
    )
    fault.refused("experiment.json written before content hashes", next(r for r in refused if "experiment.json" in r))


def test_single_bit_flips_of_an_evaluation_record_read_the_same_or_are_refused(timed, tmp_path, fault):
    original = tmp_path / "original.json"
    _store(timed, original)
    expected = json.loads(original.read_text())
    flips = sample_flips([range(original.stat().st_size)], 500, seed=5)
    counts = check_flips(original, flips, tmp_path / "evaluation.json", lb.read_evaluation, expected, lb.RecordError)
    assert counts.refused >= 480  # 'e' -> 'E' in an exponent is one bit and the same number
    fault.refused(
        f"500 single-bit flips of evaluation.json: {counts.refused} refused, {counts.unchanged} read the same",
        counts.example,
    )


def test_single_bit_flips_of_an_experiment_record_read_the_same_or_are_refused(timed, tmp_path, fault):
    record = sealed_record(
        {
            "format": lb.EXPERIMENT_FORMAT,
            "name": "e",
            "observation": "state",
            "seeds": [0],
            "summary": lb.aggregate_seeds([timed]),
        }
    )
    original = tmp_path / "original.json"
    _store(record, original)
    runs = tmp_path / "runs"
    (runs / "e").mkdir(parents=True)
    target = runs / "e" / "experiment.json"

    def load(path):
        found, refused = lb.find_experiments(runs)
        if refused:
            raise lb.RecordError(refused[0])
        (only,) = found  # a record the table drops without a word would fail here
        return {k: v for k, v in only.items() if k != "experiment_json"}

    flips = sample_flips([range(original.stat().st_size)], 300, seed=6)
    counts = check_flips(original, flips, target, load, json.loads(original.read_text()), lb.RecordError)
    assert counts.refused >= 280
    shutil.copyfile(original, target)
    assert load(target)["summary"] == record["summary"]
    fault.refused(
        f"300 single-bit flips of experiment.json: {counts.refused} refused, {counts.unchanged} read the same",
        counts.example,
    )


@pytest.mark.parametrize(
    "text, message",
    [
        ("[" * 100_000 + "]" * 100_000, "ai_expressway_hatchback.json is not readable JSON: nested too deeply"),
        ("{half a record", "ai_expressway_hatchback.json is not readable JSON"),
        (None, "the reference table cannot read its records (the last read: "),
    ],
)
def test_a_damaged_result_record_stops_the_report_in_one_line(tmp_path, text, message, fault):
    results = Path(__file__).resolve().parents[2] / "docs" / "results"
    copy = tmp_path / "results"
    shutil.copytree(results / "reference-laps", copy / "reference-laps")
    record = copy / "reference-laps" / "ai_expressway_hatchback.json"
    if text is None:  # a record of the right shape but a lap time as text
        text = json.dumps(sealed({**json.loads(record.read_text()), "best_lap_time_s": "2:19.299"}))
    record.write_text(text)
    with pytest.raises(ReportError) as excinfo:
        build_tables(copy, ["reference"])
    assert message in str(excinfo.value) and "ai_expressway_hatchback.json" in str(excinfo.value)
    fault.refused(f"vision-rl report over a result record: {text[:24]}...", str(excinfo.value))


@pytest.mark.parametrize(
    "relative",
    [TABLE3, SETTINGS.format(agents="agents23", setting="A"), CURRICULUM_CURVES],
    ids=lambda p: p.split("/")[-1],
)
def test_single_bit_flips_of_a_result_record_read_the_same_or_stop_the_report(relative, tmp_path, fault):
    original = Path(__file__).resolve().parents[2] / "docs" / "results" / relative
    target = tmp_path / "results" / relative
    target.parent.mkdir(parents=True)
    expected = json.loads(original.read_text())
    flips = sample_flips([range(original.stat().st_size)], 200, seed=7)
    counts = check_flips(
        original, flips, target, lambda path: Records(tmp_path / "results")(relative), expected, ReportError
    )
    assert counts.refused >= 190  # a flip in the layout's white space, or 'e' -> 'E' in an exponent, reads the same
    fault.refused(
        f"200 single-bit flips of the result record {target.name}: {counts.refused} refused, {counts.unchanged} read "
        "the same",
        counts.example,
    )


def test_a_leaderboard_of_runs_that_is_a_file_is_refused(small_track, tmp_path, fault):
    """leaderboard --runs FILE showed the built-in AI's row alone, as if no run had been evaluated."""
    runs = tmp_path / "demos.npz"
    runs.write_bytes(b"PK\x03\x04")
    with pytest.raises(lb.RecordError, match="is a file, not the folder of runs") as excinfo:
        lb.leaderboard(small_track, "hatchback", str(runs))
    fault.refused("leaderboard --runs a regular file", str(excinfo.value))
