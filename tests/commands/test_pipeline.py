"""`vision-rl pipeline --tiny`: Phase 2 alone (both policies trained, evaluated and on the leaderboard), then the
whole job from capture to leaderboard."""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import sys

import pytest

from tests.helpers.rendering import renderer_available
from vision_rl.commands.pipeline import (
    SIZES,
    STATE_POLICY_CARS,
    PipelineOptions,
    _captured,
    _in_second_process,
    format_phase2,
    format_pipeline,
    pipeline_phase2,
    run_pipeline_stages,
    sampler_processes,
)
from vision_rl.sim.driving import line_and_profile
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import get_preset
from vision_rl.training.artifact import SIDECAR_NAME, PolicySpec


def test_pipeline_tiny(small_track, tiny_encoders, tmp_path):
    encoder = "" if renderer_available() else str(tiny_encoders[0])  # vision needs the renderer
    summary = pipeline_phase2(
        encoder, SIZES["tiny"], mode="tiny", track=small_track, runs=str(tmp_path / "runs"), device="cpu"
    )
    assert summary["mode"] == "tiny"
    assert summary["state"]["num_timesteps"] == 200 and summary["state"]["n_seeds"] == 1
    assert (tmp_path / "runs" / "policy" / "pipeline-state" / "evaluation.json").is_file()
    names = [r["name"] for r in summary["leaderboard"]["rows"]]
    assert {"built-in AI (default skill)", "pipeline-state"} <= set(names)
    if encoder:
        vision = summary["vision"]
        assert vision["num_timesteps"] == 120 and "pipeline-vision" in names
        run = tmp_path / "runs" / "policy" / "pipeline-vision"
        assert vision["policy"] == str(run / "policy.pt") and (run / "evaluation.json").is_file()
        # The vision run alone takes the entropy target, the falling rate, the stuck ends, the steering penalty and
        # the critic that reads the state.
        specs = {
            k: PolicySpec.read(tmp_path / "runs" / "policy" / f"pipeline-{k}" / SIDECAR_NAME)
            for k in ("state", "vision")
        }
        sac = {k: spec.sac for k, spec in specs.items()}
        assert (sac["vision"]["target_entropy"], sac["vision"]["learning_rate_final"]) == (-4.0, 1e-4)
        assert (sac["state"]["target_entropy"], sac["state"]["learning_rate_final"]) == (0.0, 0.0)
        assert specs["vision"].config.terminate_when_stuck and not specs["state"].config.terminate_when_stuck
        penalty = {
            k: (spec.config.steer_change_penalty_c_s, spec.config.steer_change_penalty_scale)
            for k, spec in specs.items()
        }
        assert penalty["vision"] == (0.5, "usable") and penalty["state"][0] == 0.0
        assert specs["vision"].config.critic_state and specs["vision"].fingerprint["obs_dim"] == 64 + 11 + 38
    else:
        assert "skipped" in summary["vision"]


def test_pipeline_vision_policy_samples_in_a_sampler_process(ray_local, small_track, tiny_encoders, tmp_path):
    reason = renderer_available()
    if reason:
        pytest.skip(reason)
    sizes = dataclasses.replace(SIZES["tiny"], vision_workers=1)
    summary = pipeline_phase2(
        str(tiny_encoders[0]), sizes, mode="tiny", track=small_track, runs=str(tmp_path / "runs"), device="cpu"
    )
    vision, state = summary["vision"], summary["state"]
    assert vision["num_timesteps"] == 120 and vision["n_seeds"] == 1
    assert vision["sampling"]["workers"] == 1 and vision["sampling"]["samplers_alive"] == 1
    assert vision["sampling"]["transitions"] >= 120 and vision["sampling"]["updates"] > 0
    assert state["sampling"] is None  # the state policy samples in its own process
    assert "pipeline-vision" in [r["name"] for r in summary["leaderboard"]["rows"]]
    assert ", 1 sampler process; lap 2 best" in "\n".join(format_phase2(summary))


def test_without_ray_the_vision_policy_samples_in_the_learners_process(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray now raises ImportError
    assert sampler_processes(SIZES["quick"]) == 0


def test_whole_pipeline_tiny_capture_to_leaderboard(small_track, tmp_path, capsys):
    reason = renderer_available()
    if reason:
        pytest.skip(reason)
    from vision_rl.capture.h5format import open_capture

    runs = tmp_path / "runs"
    opts = PipelineOptions(tiny=True, track=small_track, runs=str(runs), state_policy_laps=1)
    summary = run_pipeline_stages(opts)
    lines = stage_lines(capsys.readouterr().err)
    for stage in ("state policy", "capture", "capture of the clean laps", "the state policy's laps", "train-repr"):
        assert lines.count(f"{stage}: started") == lines.count(f"{stage}: done") == 1, (stage, lines)
    assert lines.index("capture: started") < lines.index("capture: done") < lines.index("train-repr: started")
    with open_capture(summary["capture"]["train"]) as f:
        assert f.complete and f.image_hw_px == (64, 96)
    # Driven by the state policy just trained; one of 200 steps may not lap, and its capture ends at the protocol's
    # time limit (3 x the limit lap), not never.
    limit_lap_s = line_and_profile(load_track(small_track), get_preset("hatchback"))[1].lap_time_s
    with open_capture(summary["state_policy_capture"]["path"]) as f:
        assert f.attrs["driver"]["policy"] == summary["phase2"]["state"]["policy"]
        # (the cut is checked after each step of the cars' frames)
        assert 0 < f.n_frames < math.ceil(3 * limit_lap_s * SIZES["tiny"].capture_fps) + STATE_POLICY_CARS
    assert (runs / "repr" / "pipeline" / "ckpt.pt").is_file()
    assert summary["train_repr"]["n_train_frames"] > 0 and summary["train_repr"]["n_val_frames"] > 0
    names = [r["name"] for r in summary["phase2"]["leaderboard"]["rows"]]
    assert {"pipeline-state", "pipeline-vision"} <= set(names)
    # A second call finds every stage's output and does not redo the capture or Phase 1.
    again = run_pipeline_stages(opts)
    assert "train_repr" not in again and again["capture"]["seconds"] < 1.0
    text = "\n".join(format_pipeline(summary))
    # (tiny stops after 3 optimiser steps, before a validation epoch)
    assert "frames, no epoch scored" in text and "pipeline-vision" in text and "done in" in text
    assert "the state policy's laps" in text
    assert "kept the existing encoder" in "\n".join(format_pipeline(again))


def test_a_missing_or_unreadable_capture_is_captured_from_the_start(tmp_path):
    assert _captured(tmp_path / "train.h5") == "none"
    (tmp_path / "train.h5").write_bytes(b"not an HDF5 file")
    assert _captured(tmp_path / "train.h5") == "none"


def test_a_second_process_returns_its_result_raises_its_error_and_never_waits_for_a_dead_one():
    with _in_second_process(divmod, 7, 2) as result:
        assert result() == (3, 1)
    with _in_second_process(int, "seven") as result, pytest.raises(ValueError, match="seven"):
        result()
    with _in_second_process(os._exit, 3) as result, pytest.raises(RuntimeError, match="exit code 3 and no result"):
        result()  # killed, out of memory: a pool would wait for its result for ever


@pytest.mark.parametrize("state_policy_laps", [0, 1])
def test_the_state_policy_trains_from_the_start_beside_the_captures(monkeypatch, tmp_path, state_policy_laps, capsys):
    """It needs neither frames nor encoder, so it takes the cores the captures leave idle; Phase 1 waits for it
    where it captures the state policy's laps (else it trains beside Phase 1 too), and Phase 2 waits for that same
    run rather than starting another."""
    import vision_rl.commands.pipeline as pipeline
    import vision_rl.phase1_repr.train as phase1

    events = []

    @contextlib.contextmanager
    def state_process(*stage):
        events.append("state starts")
        yield lambda: events.append("state waited for") or {"num_timesteps": 200}
        events.append("state stopped")

    def capture(opts, sizes, name, laps, disrupt, progress=None):
        events.append(f"capture {name}" + " disrupted" * disrupt)
        return pipeline._capture_path(opts, name)

    def phase2(encoder, sizes, *, state, report, **kwargs):
        events.append("phase 2")
        return {"state": state()}

    monkeypatch.setattr(pipeline, "state_in_second_process", state_process)
    monkeypatch.setattr(
        pipeline, "_in_second_process", lambda fn, *args, **kw: contextlib.nullcontext(lambda: fn(*args))
    )
    monkeypatch.setattr(pipeline, "_capture", capture)
    monkeypatch.setattr(
        pipeline,
        "_capture_state_policy",
        lambda opts, sizes: capture(opts, sizes, "state_policy", opts.state_policy_laps, False),
    )
    monkeypatch.setattr(
        phase1, "train_repr", lambda cfg, progress=None: events.append(f"train-repr on {cfg.data}") or {}
    )
    monkeypatch.setattr(pipeline, "pipeline_phase2", phase2)
    summary = run_pipeline_stages(PipelineOptions(tiny=True, runs=str(tmp_path), state_policy_laps=state_policy_laps))
    captures = tmp_path / "capture"
    if state_policy_laps:
        assert events == [
            "state starts",
            "capture train disrupted",
            "capture eval",
            "state waited for",
            "capture state_policy",
            f"train-repr on {captures / 'train.h5'},{captures}/state_policy.h5",
            "phase 2",
            "state stopped",
        ]
        assert summary["state_policy_capture"]["path"] == str(captures / "state_policy.h5")
    else:
        assert events == [
            "state starts",
            "capture train disrupted",
            "capture eval",
            f"train-repr on {captures / 'train.h5'}",
            "phase 2",
            "state waited for",
            "state stopped",
        ]
    assert summary["phase2"]["state"] == {"num_timesteps": 200}


def stage_lines(text: str) -> list[str]:
    """The pipeline's stage lines, ``name: started``/``name: done``, without the clock and the details."""
    return [
        line.split("] ", 1)[1].split(" (")[0].split(" in ")[0]
        for line in text.splitlines()
        if line.startswith("[pipeline ")
    ]


def test_each_stage_says_when_it_starts_and_ends(monkeypatch, tmp_path, capsys):
    """A start and an end line per stage on stderr, in the order they run (the state policy and the clean laps in
    second processes end when their results arrive); stdout keeps the summary alone."""
    import vision_rl.commands.pipeline as pipeline
    import vision_rl.phase1_repr.train as phase1

    @contextlib.contextmanager
    def state_process(*stage):
        yield lambda: {"num_timesteps": 200}

    def policy_stage(kind, encoder, *stage, progress=None):
        progress(100, 200, None)
        return {"kind": kind}

    monkeypatch.setattr(pipeline, "state_in_second_process", state_process)
    monkeypatch.setattr(
        pipeline, "_in_second_process", lambda fn, *args, **kw: contextlib.nullcontext(lambda: fn(*args))
    )
    monkeypatch.setattr(pipeline, "_capture", lambda opts, sizes, name, *a, **kw: pipeline._capture_path(opts, name))
    monkeypatch.setattr(phase1, "train_repr", lambda cfg, progress=None: progress(1, 3, {}) or {})
    monkeypatch.setattr(pipeline, "_policy_stage", policy_stage)
    monkeypatch.setattr("vision_rl.evaluation.leaderboard.leaderboard", lambda *a: {"rows": []})
    summary = run_pipeline_stages(PipelineOptions(tiny=True, runs=str(tmp_path)))
    assert summary["phase2"]["vision"] == {"kind": "vision"}
    out, err = capsys.readouterr()
    assert stage_lines(err) == [
        "state policy: started",
        "capture of the clean laps: started",
        "capture: started",
        "capture: done",
        "capture of the clean laps: done",
        "train-repr: started",
        "train-repr: done",
        "vision policy: started",
        "vision policy: done",
        "state policy: done",
        "leaderboard: started",
        "leaderboard: done",
    ]
    assert "[pipeline 0 s] capture: started (1 disrupted laps)" in err and out == ""
