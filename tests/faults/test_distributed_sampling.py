"""train-policy --workers: sampler actors killed mid-run, bad sampling options, no Ray."""

from __future__ import annotations

import dataclasses
import sys

import pytest

from tests.helpers.policies import tiny_train_config
from tests.helpers.processes import sampler_killer
from vision_rl.config import replace_flat
from vision_rl.phase2_rl.train import train_policy
from vision_rl.training.artifact import PolicySpec
from vision_rl.training.distributed import RAY_MISSING, DistributedError, SamplersLostError
from vision_rl.training.sac import read_metrics


def test_a_killed_sampler_leaves_the_learner_going_with_the_other(ray_local, small_track, tmp_path, fault):
    out = tmp_path / "run"
    progress, killed = sampler_killer(ray_local, 100, 1)
    config = tiny_train_config(small_track, out, workers=2, steps=300, eval_every_steps=0)
    result = train_policy(config, progress)
    assert len(killed) == 1
    assert result["num_timesteps"] == 300 and result["n_updates"] == (300 - 50) // 2  # no step was lost
    sampling = result["sampling"]
    assert sampling["samplers_alive"] == 1 and len(sampling["samplers_lost"]) == 1
    events = [r for r in read_metrics(out / "metrics.jsonl", events=True) if r.get("event") == "sampler_lost"]
    assert len(events) == 1 and events[0]["samplers_alive"] == 1 and events[0]["num_timesteps"] >= 100
    assert read_metrics(out / "metrics.jsonl") == [
        r for r in read_metrics(out / "metrics.jsonl", events=True) if "event" not in r
    ]
    fault.recovered(
        "one of 2 sampler actors SIGKILLed mid-run",
        f"the learner finished the 300 steps with the other; metrics.jsonl: {events[0]['reason'][:80]}",
    )


def test_all_samplers_killed_saves_the_run_and_stops_with_one_line(ray_local, small_track, tmp_path, fault):
    out = tmp_path / "run"
    progress, killed = sampler_killer(ray_local, 100, 2)
    config = tiny_train_config(small_track, out, workers=2, steps=300, eval_every_steps=0, checkpoint_every_steps=0)
    with pytest.raises(SamplersLostError, match="all 2 sampler actors died") as excinfo:
        train_policy(config, progress)
    assert len(killed) == 2 and "--resume" in str(excinfo.value)
    saved = PolicySpec.read(out / "policy.json").num_timesteps
    assert 100 <= saved < 300 and (out / "replay_buffer.npz").is_file()
    resumed = train_policy(replace_flat(config, resume=True), None)
    assert resumed["num_timesteps"] == 300 and resumed["buffer_restored"] == saved // 2
    fault.refused("every sampler actor SIGKILLed mid-run (the run is saved, --resume finishes it)", str(excinfo.value))


@pytest.mark.parametrize(
    "options,what,message",
    [
        ({"workers": 0}, "--workers 0", "at least 1 sampler"),
        ({"workers": -2}, "--workers -2", "at least 1 sampler"),
        ({"workers": 1, "max_staleness": -1}, "--max-staleness -1", "max-staleness"),
        ({"workers": 1, "version_every_updates": 0}, "--version-every-updates 0", "version-every-updates"),
        ({"address": "auto"}, "--address without --workers", "needs --workers"),
    ],
)
def test_bad_sampling_options_are_refused_before_the_run_folder(small_track, tmp_path, fault, options, what, message):
    out = tmp_path / "run"
    with pytest.raises(ValueError, match=message) as excinfo:
        train_policy(tiny_train_config(small_track, out, **options))
    assert not out.exists()
    fault.refused(what, str(excinfo.value))


def test_more_workers_than_the_clusters_cpus_is_refused(ray_local, small_track, tmp_path, fault):
    out = tmp_path / "run"
    with pytest.raises(DistributedError, match="more than the 2 CPUs") as excinfo:
        train_policy(tiny_train_config(small_track, out, workers=3))
    assert not out.exists() and ray_local.is_initialized()  # the test's cluster is left alone
    fault.refused("--workers 3 on a Ray cluster of 2 CPUs", str(excinfo.value))


def test_no_ray_is_one_line_naming_the_extra(small_track, tmp_path, monkeypatch, fault, capsys):
    from vision_rl.commands.main import main

    monkeypatch.setitem(sys.modules, "ray", None)  # ``import ray`` fails as if it were not installed
    with pytest.raises(DistributedError) as excinfo:
        train_policy(tiny_train_config(small_track, tmp_path / "run", workers=1))
    assert str(excinfo.value) == RAY_MISSING
    code = main(["train-policy", "--track", small_track, "--workers", "1", "--out", str(tmp_path / "cli")])
    err = capsys.readouterr().err
    assert code == 2 and err.strip() == f"vision-rl train-policy: error: {RAY_MISSING}"
    fault.refused("train-policy --workers 1 without Ray installed", err.strip())


def test_a_sampler_with_another_track_refuses_to_start(ray_local, small_track, tmp_path, monkeypatch, fault):
    """A node whose copy of the track differs from the learner's (simulated by the fingerprint the learner sends):
    the sampler refuses to build, and with no sampler left the run stops with the reason."""
    import vision_rl.training.distributed as distributed

    original = distributed.start_samplers

    def other_track(cluster, setup, workers):
        fingerprint = {**setup.fingerprint, "track_geometry_hash": "0" * 16}
        return original(cluster, dataclasses.replace(setup, fingerprint=fingerprint), workers)

    monkeypatch.setattr(distributed, "start_samplers", other_track)
    with pytest.raises(SamplersLostError, match="track_geometry_hash") as excinfo:
        train_policy(tiny_train_config(small_track, tmp_path / "run", workers=1))
    assert "ValueError: sampler 0 was built for track_geometry_hash" in str(excinfo.value)
    fault.refused("a sampler whose track differs from the learner's", str(excinfo.value))
