"""pipeline_phase2 --tiny: both policies trained, evaluated and on the leaderboard."""

from __future__ import annotations

from tests.phase2_rl.conftest import renderer_available
from vision_rl.phase2_rl import leaderboard as lb
from vision_rl.phase2_rl.pipeline import pipeline_phase2


def test_pipeline_tiny(small_track, tiny_encoders, tmp_path, monkeypatch):
    monkeypatch.setattr(lb, "reference_lap_times",
                        lambda track, car: {"limit_lap_time_s": 25.0, "ai_lap_time_s": 28.0, "source": "test"})
    encoder = "" if renderer_available() else str(tiny_encoders[0])  # vision needs the renderer
    summary = pipeline_phase2(encoder, track=small_track, runs=str(tmp_path / "runs"), tiny=True, device="cpu")
    assert summary["mode"] == "tiny"
    assert summary["state"]["num_timesteps"] == 200 and summary["state"]["n_seeds"] == 1
    assert (tmp_path / "runs" / "policy" / "pipeline-state" / "evaluation.json").is_file()
    names = [r["name"] for r in summary["leaderboard"]]
    assert {"physical limit (QSS)", "built-in AI (default skill)", "pipeline-state"} <= set(names)
    if encoder:
        assert summary["vision"]["num_timesteps"] == 120 and "pipeline-vision" in names
    else:
        assert "skipped" in summary["vision"]
