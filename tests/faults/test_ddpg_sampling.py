"""train-ddpg --workers: a sampler killed mid-run, a resume with other workers, bad sampling options."""

from __future__ import annotations

import json

import pytest

from tests.helpers.ddpg import ddpg_config
from tests.helpers.processes import sampler_killer
from tests.helpers.tracks import STADIUM, stadium_csv
from vision_rl.ddpg.agent import DDPGError
from vision_rl.ddpg.train import train_ddpg
from vision_rl.training.distributed import DistributedError


@pytest.fixture(scope="module")
def track(tmp_path_factory) -> str:
    return str(stadium_csv(tmp_path_factory.mktemp("track") / "stadium.csv", *STADIUM))


def test_a_killed_ddpg_sampler_leaves_the_learner_going_with_the_other(ray_local, gl_available, track, tmp_path, fault):
    out = tmp_path / "run"
    progress, killed = sampler_killer(ray_local, 12, 1)
    result = train_ddpg(ddpg_config(track, out, workers=2, steps=40, variant="state-actor", max_staleness=1), progress)
    assert len(killed) == 1 and result["num_steps"] == 40  # the other sampler collected the rest
    lost = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["event"] for r in lost] == ["sampler_lost"] and result["sampling"]["samplers_alive"] == 1
    fault.recovered(
        "one of two DDPG sampler actors SIGKILLed mid-run",
        f"the learner went on with the other to {result['num_steps']} steps; logged: {lost[0]['reason']}",
    )


def test_a_run_resumes_only_with_the_workers_it_was_trained_with(ray_local, gl_available, track, tmp_path, fault):
    out = tmp_path / "run"
    train_ddpg(ddpg_config(track, out, steps=8, variant="state-actor"))
    with pytest.raises(DDPGError, match=r"trained with --workers 1.*resume it with the same --workers") as excinfo:
        train_ddpg(ddpg_config(track, out, steps=16, variant="state-actor", workers=None, resume=True))
    fault.refused("train-ddpg --resume without the --workers the run was trained with", str(excinfo.value))
    resumed = train_ddpg(ddpg_config(track, out, steps=16, variant="state-actor", resume=True))
    assert resumed["num_steps"] == 16 and resumed["buffer_restored"] == 8


@pytest.mark.parametrize(
    "change,message",
    [
        (dict(workers=0), "--workers"),
        (dict(workers=None, address="auto"), "--address auto needs --workers"),
        (dict(max_staleness=-1), "--max-staleness"),
    ],
)
def test_bad_sampling_options_are_refused_before_anything_is_written(track, tmp_path, change, message, fault):
    out = tmp_path / "run"
    with pytest.raises((ValueError, DistributedError), match=message) as excinfo:
        train_ddpg(ddpg_config(track, out, **change))
    assert not out.exists()
    fault.refused(f"train-ddpg {change}", str(excinfo.value))
