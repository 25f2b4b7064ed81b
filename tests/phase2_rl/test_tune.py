"""The recipe search: the score on hand-made laps, refusals, a tiny study that resumes, a pruned trial."""

from __future__ import annotations

import json

import pytest

from tests.helpers.policies import tiny_train_config
from vision_rl.phase2_rl.config import SEARCH_SPACE
from vision_rl.phase2_rl.tune import TuneConfig, TuneError, check_tune, recipe_flags, run_tune, score


def test_the_score_charges_a_dnf_and_wall_contact():
    # (100 + 2 x 90 + 110) / 3 starts, plus 2 s per s of the 1.5 s of wall contact over 3 starts
    assert score([100.0, None, 110.0], [1.0, 0.0, 0.5], 90.0, wall_weight=2.0) == pytest.approx(131.0)
    assert score([100.0], [4.0], 90.0) == 100.0  # wall contact is free at weight 0
    with pytest.raises(TuneError):
        score([], [], 90.0)
    assert recipe_flags({"steer_action": "rate", "batch_size": 128}) == "--batch-size 128 --steer-action rate"


def test_bad_searches_are_refused(small_track, tmp_path):
    base = tiny_train_config(small_track, tmp_path)
    for space, match in (((), "empty"), (("gamma", "width"), "width: choose from"), (("gamma", "gamma"), "repeated")):
        with pytest.raises(TuneError, match=match):
            check_tune(base, TuneConfig(space=space))
    with pytest.raises(TuneError, match="leave out --resume"):
        check_tune(tiny_train_config(small_track, tmp_path, resume=True), TuneConfig())


def _study(small_track, tmp_path, trials, space=("learning_rate", "steer_action")):
    base = tiny_train_config(small_track, tmp_path / "unused", steps=200, eval_every_steps=100)
    return run_tune(base, TuneConfig(trials=trials, space=space, eval_starts=1, prune_after_steps=0), tmp_path / "s")


def test_a_tiny_study_scores_its_trials_and_resumes(small_track, tmp_path):
    first = _study(small_track, tmp_path, 2)
    assert [t["state"] for t in first["trials"]] == ["COMPLETE", "COMPLETE"]
    # the evaluation at the last step (after training's last update) is reported too
    assert [t["last_reported_step"] for t in first["trials"]] == [200, 200]
    for t in first["trials"]:
        low, high = SEARCH_SPACE["learning_rate"].values
        assert (
            low <= t["params"]["learning_rate"] <= high
            and t["params"]["steer_action"] in SEARCH_SPACE["steer_action"].values
        )
        evaluation = json.loads((tmp_path / "s" / f"trial-{t['number']}" / "evaluation.json").read_text())
        laps = [s["lap_time_s"] for s in evaluation["seeds"]]
        assert t["score_s"] == pytest.approx(score(laps, [0.0], evaluation["limit_lap_time_s"]))
    assert first["best"]["score_s"] == min(t["score_s"] for t in first["trials"])
    again = _study(small_track, tmp_path, 3)  # continues to 3 trials, keeping the first two
    assert len(again["trials"]) == 3 and again["trials"][:2] == first["trials"]
    with pytest.raises(TuneError, match="another space"):
        _study(small_track, tmp_path, 3, space=("gamma",))


def test_a_pruned_trial_stops_at_its_report(small_track, tmp_path, monkeypatch):
    import optuna

    monkeypatch.setattr(optuna.trial.Trial, "should_prune", lambda self: True)
    result = _study(small_track, tmp_path, 1)
    (trial,) = result["trials"]
    assert trial["state"] == "PRUNED" and trial["last_reported_step"] == 100 and result["best"] is None
    run = tmp_path / "s" / "trial-0"
    assert (run / "policy.pt").is_file() and not (run / "evaluation.json").exists()
    assert not (run / "replay_buffer.npz").exists()  # trials do not keep their buffers
