"""curves: its options are its own (a track and car, the files required) and it reads them."""

from __future__ import annotations

import pytest

import vision_rl.phase2_rl.experiment  # noqa: F401  loaded before time_laps is patched: a module first imported
from vision_rl.commands.main import main  # under the patch would keep the fake for the tests after this one


def test_curves_times_the_ai_on_its_own_track_and_car(monkeypatch, tmp_path, capsys):
    seen = {}

    class _Timing:
        def summary(self):
            return {"limit_lap_time_s": 60.0, "best_lap_time_s": 66.0}

    def time_laps(driver, track, car, seeds):
        seen["track_car"] = (track, car)
        return _Timing()

    def compare(files, names, limit_s, ai_s, out):
        seen["compare"] = (files, names, limit_s, ai_s, out)
        return {"files": {"png": "c.png", "json": "c.json"}}

    monkeypatch.setattr("vision_rl.evaluation.protocol.time_laps", time_laps)
    monkeypatch.setattr("vision_rl.phase2_rl.experiment.compare_learning_curves", compare)
    argv = ["curves", "--files", "a.json,b.json", "--names", "A,B", "--track", "technical", "--car", "gt3"]
    assert main([*argv, "--out", str(tmp_path), "--json"]) == 0
    assert seen == {
        "track_car": ("technical", "gt3"),
        "compare": (["a.json", "b.json"], ["A", "B"], 60.0, 66.0, str(tmp_path)),
    }
    assert main(["curves", "--files", "a.json", "--names", "A,B"]) == 2
    assert "--names gives 2 names for 1 curve files" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["curves"])
    assert "the following arguments are required: --files" in capsys.readouterr().err
