"""train-policy --workers at tiny sizes (2 cars, a few hundred steps) on the session's local Ray cluster: the
pacing rules, transitions from a sampler actor in the learner's buffer, the staleness bound, determinism of the
synchronous single-worker run, Ctrl-C and resume."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile

import numpy as np
import pytest

from tests.helpers.policies import tiny_train_config
from tests.helpers.processes import kill_and_read
from vision_rl.config import replace_flat
from vision_rl.phase2_rl.train import _TrainingLoop, train_policy
from vision_rl.training.artifact import PolicySpec, load_policy
from vision_rl.training.distributed import Pacer, Pacing, worker_seed
from vision_rl.training.presets import PRESETS
from vision_rl.training.sac import read_metrics
from vision_rl.training.sampling_bench import BENCH_SAC, bench_sampling


def _pacing(**kw) -> Pacing:
    base = dict(
        workers=1,
        n_cars=2,
        gradient_steps=1,
        learning_starts=50,
        start_timesteps=0,
        total_timesteps=400,
        version_every_updates=4,
        max_staleness=1,
    )
    return Pacing(**{**base, **kw})


@pytest.mark.parametrize("workers,staleness,gradient_steps", [(1, 0, 1), (1, 1, 1), (3, 1, 2), (2, 0, 3), (2, 4, 1)])
def test_pacer_keeps_the_ratio_and_the_staleness_bound_in_any_order(workers, staleness, gradient_steps):
    """Chunks finish in a random order and the learner updates whenever the pacer lets it: no sampler ever acts
    with weights more than K versions old, random actions cover exactly the start steps, and the session ends
    with the single-process loop's number of updates."""
    rng = np.random.default_rng(workers * 10 + staleness)
    pacing = _pacing(workers=workers, max_staleness=staleness, gradient_steps=gradient_steps)
    pacer = Pacer(pacing)
    idle, inflight, next_id, random_steps = list(range(workers)), {}, 0, 0
    for _ in range(100_000):
        while idle and (planned := pacer.next_chunk()) is not None:
            steps, rnd = planned
            assert rnd == 0 or pacer.launched + rnd <= pacer.random_steps
            random_steps += rnd
            pacer.launch(next_id, steps)
            inflight[next_id] = (idle.pop(), steps)
            next_id += 1
        if pacer.done:
            break
        if inflight and (rng.random() < 0.3 or not pacer.can_update()):
            chunk = list(inflight)[rng.integers(len(inflight))]
            worker, steps = inflight.pop(chunk)
            pacer.receive(chunk, steps)
            idle.append(worker)
        elif pacer.can_update():
            pacer.updated()
        assert all(pacer.version - v <= staleness for v in pacer.inflight.values())
    assert pacer.done and not inflight
    assert pacer.max_staleness_seen <= staleness
    assert random_steps == pacer.random_steps == 25  # 50 start transitions of 2 cars
    assert pacer.updates == gradient_steps * (200 - 25)  # as SB3: each vector step after the start steps
    if staleness > 0 and workers == 1:
        assert pacer.max_staleness_seen >= 1  # the bound is reached, not only kept by never overlapping


def test_synchronous_pacing_alternates():
    """K = 0 with one worker: one chunk of one version's data at a time, never overlapping the learner."""
    pacer = Pacer(_pacing(learning_starts=0, max_staleness=0))
    assert pacer.next_chunk() == (4, 0)
    pacer.launch(0, 4)
    assert pacer.next_chunk() is None and not pacer.can_update()
    pacer.receive(0, 4)
    for _ in range(4):
        assert pacer.next_chunk() is None and pacer.can_update()
        pacer.updated()
    assert not pacer.can_update() and pacer.next_chunk() == (4, 0) and pacer.version == 1


@pytest.mark.parametrize("label_weight", [0.0, 10.0])
def test_a_samplers_transitions_reach_the_buffer_as_its_world_gives_them(
    ray_local, small_track, tmp_path, label_weight
):
    """One synchronous sampler: the replay buffer holds, in order, what a world of the same seed returns for the
    stored actions (observations, next observations with the last one of an episode where it ended, rewards,
    dones and time-limit flags; with --guide-label-weight the built-in AI's label of each state an action was
    chosen in), and the learner made the single-process loop's number of updates."""
    from vision_rl.envs.vector import make_sb3_vec_env
    from vision_rl.phase2_rl.guide import LABEL_SKILL

    out = tmp_path / "run"
    result = train_policy(
        tiny_train_config(small_track, out, workers=1, max_staleness=0, episode_s=3.0, guide_label_weight=label_weight)
    )
    assert result["num_timesteps"] == 200 and result["n_updates"] == (200 - 50) // 2
    sampling = result["sampling"]
    assert sampling["workers"] == 1 and sampling["samplers_lost"] == [] and sampling["max_staleness_seen"] == 0
    assert [m["num_timesteps"] for m in read_metrics(out / "metrics.jsonl")] == [100, 200]
    spec = PolicySpec.read(out / "policy.json")
    assert spec.train_config["workers"] == 1 and spec.num_timesteps == 200
    with np.load(out / "replay_buffer.npz", allow_pickle=False) as data:
        buffer = {
            name: data[name]
            for name in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")
        }
        assert ("ai_labels" in data) == (label_weight > 0)
        labels = data["ai_labels"] if label_weight > 0 else None
    assert buffer["observations"].shape == (100, 2, 38)
    env = make_sb3_vec_env(spec.config, seed=worker_seed(0, 0))
    env.core.observer.normalizer = spec.normalizer
    env.core.label_with_ai(LABEL_SKILL)
    low, high = env.action_space.low.astype(np.float64), env.action_space.high.astype(np.float64)
    obs = env.reset()
    for k in range(100):
        np.testing.assert_array_equal(buffer["observations"][k], obs)
        if labels is not None:
            np.testing.assert_array_equal(
                labels[k], (2.0 * (env.core.ai_actions() - low) / (high - low) - 1.0).astype(np.float32)
            )
        action = low + 0.5 * (buffer["actions"][k].astype(np.float64) + 1.0) * (high - low)
        obs, rewards, dones, infos = env.step(action)
        expected = obs.copy()
        for i in np.flatnonzero(dones):
            expected[i] = infos[i]["terminal_observation"]
        np.testing.assert_array_equal(buffer["next_observations"][k], expected)
        np.testing.assert_array_equal(buffer["rewards"][k], rewards)
        np.testing.assert_array_equal(buffer["dones"][k], dones)
        np.testing.assert_array_equal(
            buffer["timeouts"][k], [i["TimeLimit.truncated"] if d else False for i, d in zip(infos, dones, strict=True)]
        )
    assert buffer["dones"].sum() == 2 * 3  # 3 s episodes: 30 steps, ended 3 times per car in 100 steps
    assert np.abs(buffer["actions"][:25]).max() <= 1.0 and buffer["actions"][:25].std() > 0.4  # random start steps
    assert load_policy(out).spec.num_timesteps == 200


def test_one_synchronous_worker_repeats_a_run_of_the_same_seed(ray_local, small_track, tmp_path):
    runs = []
    for name in ("a", "b"):
        out = tmp_path / name
        train_policy(
            tiny_train_config(
                small_track, out, workers=1, max_staleness=0, eval_every_steps=0, checkpoint_every_steps=0
            )
        )
        runs.append(out)
    a, b = (PolicySpec.read(out / "policy.json") for out in runs)
    with np.load(runs[0] / "replay_buffer.npz") as x, np.load(runs[1] / "replay_buffer.npz") as y:
        np.testing.assert_array_equal(x["observations"], y["observations"])
        np.testing.assert_array_equal(x["actions"], y["actions"])
    assert a.weights_sha256 == b.weights_sha256


def test_staleness_stays_within_the_bound_with_two_workers(ray_local, small_track, tmp_path):
    """Many weight versions (one per 2 updates), two samplers: K = 1 is reached but never exceeded."""
    result = train_policy(
        tiny_train_config(
            small_track,
            tmp_path / "run",
            workers=2,
            max_staleness=1,
            version_every_updates=2,
            steps=300,
            eval_every_steps=0,
            checkpoint_every_steps=0,
        )
    )
    sampling = result["sampling"]
    assert result["num_timesteps"] == 300 and result["n_updates"] == (300 - 50) // 2
    assert sampling["weight_versions"] == 125 // 2 and sampling["chunk_steps"] == 1
    assert sampling["max_staleness_seen"] <= 1 and sampling["samplers_alive"] == 2


def test_ctrl_c_with_workers_saves_and_resume_restarts_the_samplers(ray_local, small_track, tmp_path, monkeypatch):
    original = _TrainingLoop._on_step

    def interrupt(self):
        if self.num_timesteps >= 120:
            raise KeyboardInterrupt
        return original(self)

    monkeypatch.setattr(_TrainingLoop, "_on_step", interrupt)
    out = tmp_path / "run"
    config = tiny_train_config(small_track, out, workers=1, eval_every_steps=0)
    result = train_policy(config)
    assert result["interrupted"] and result["num_timesteps"] == 120
    assert PolicySpec.read(out / "policy.json").num_timesteps == 120
    monkeypatch.setattr(_TrainingLoop, "_on_step", original)
    resumed = train_policy(replace_flat(config, resume=True, steps=300))
    assert resumed["num_timesteps"] == 300 and resumed["buffer_restored"] == 60
    assert resumed["n_updates"] == result["n_updates"] + (300 - 120) // 2  # the buffer came back: no random phase
    assert resumed["sampling"]["workers"] == 1
    # A run sampled with workers resumes in one process too (the same files).
    single = train_policy(replace_flat(config, resume=True, steps=340, workers=None))
    assert single["num_timesteps"] == 340 and single["sampling"] is None


def test_bench_sampling_reports_the_learner_against_its_standalone_rate(ray_local, small_track, tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    result = bench_sampling(1, 1.0, 0, cars=2, track=small_track, prefill_transitions=400)
    assert not list(tmp_path.glob("SB3-*"))  # no empty SB3 logger folder left behind
    assert result["workers"] == 1 and result["standalone_updates_per_s"] > 0 and result["learner_updates_per_s"] > 0
    assert result["learner_share_of_standalone"] == pytest.approx(
        result["learner_updates_per_s"] / result["standalone_updates_per_s"], rel=1e-2
    )
    assert result["sampled_transitions_per_s"] > 0 and result["max_staleness_seen"] <= 1


def test_the_bench_learner_is_the_cpu_preset():
    cpu = PRESETS["cpu"]
    assert {k: getattr(cpu, k) for k in BENCH_SAC} == BENCH_SAC


@pytest.mark.parametrize("critic_state", [False, True])
def test_vision_samplers_embed_frames_with_the_runs_encoder(
    ray_local, gl_available, tiny_encoders, small_track, tmp_path, critic_state
):
    """A vision run with a sampler actor: the sampler renders and embeds with the run's encoder and normalisation
    (and, for a state-reading critic, appends the state observation), so its observations match what the learner's
    own world gives at the same state (the first one after reset)."""
    from vision_rl.phase2_rl.train import _Run

    out = tmp_path / "run"
    config = tiny_train_config(
        small_track,
        out,
        encoder=str(tiny_encoders[0]),
        workers=1,
        steps=100,
        eval_every_steps=0,
        checkpoint_every_steps=0,
        stats_steps=5,
        critic_state=critic_state,
    )
    result = train_policy(config)
    assert result["observation"] == "vision" and result["num_timesteps"] == 100 and result["n_updates"] == 25
    with np.load(out / "replay_buffer.npz", allow_pickle=False) as data:
        observations = data["observations"]
    assert observations.shape == (50, 2, 64 + 11 + (38 if critic_state else 0))
    run = _Run(replace_flat(config, resume=True))
    run.build()
    core = run.venv.core
    core.seed(worker_seed(0, 0))  # the sampler's world: same seed, so the same start points
    core.reset_groups(np.arange(2))
    np.testing.assert_allclose(core.observation(), observations[0], rtol=1e-4, atol=1e-4)
    run.close()


def test_train_overtaking_with_a_worker_ends_stage_one_at_its_criterion_and_samples_stage_two(
    ray_local, small_track, tmp_path, monkeypatch
):
    import vision_rl.overtaking.curriculum as ot
    from tests.helpers.overtaking import tiny_overtaking_config

    class Timing:  # every driver laps in 30 s: the policy is within 5 % of the AI at the first evaluation
        def summary(self):
            return {"best_lap_time_s": 30.0, "n_finished": 1}

    monkeypatch.setattr(ot, "time_laps", lambda *a, **k: Timing())
    out = tmp_path / "run"
    result = ot.train_overtaking(
        tiny_overtaking_config(
            small_track, out, agent="1", stage2_steps=40, eval_episodes=0, workers=1, max_staleness=0
        )
    )
    stage1, stage2 = result["stages"]
    # The criterion's False stops the samplers' session as it stops SB3's learn: at the evaluation's step.
    assert stage1["end_steps"] == 100 and stage1["criterion"]["met_at_steps"] == 100
    assert stage2["status"] == "done" and (stage2["start_steps"], stage2["end_steps"]) == (100, 140)
    spec = ot.read_overtaking_spec(out / "stage2" / "policy.json")
    assert spec.num_timesteps == 140 and spec.racing_config["scenario"] == "stage2"
    records = [json.loads(line) for line in (out / "stage1" / "metrics.jsonl").read_text().splitlines()]
    assert [r.get("num_timesteps") for r in records] == [100]  # one evaluation, no lost sampler


def test_train_overtaking_refuses_bad_sampling_options_before_writing(small_track, tmp_path):
    from tests.helpers.overtaking import tiny_overtaking_config
    from vision_rl.overtaking.curriculum import train_overtaking

    for change, message in [
        ({"workers": 0}, "--workers 0"),
        ({"address": "auto"}, "needs --workers"),
        ({"workers": 1, "max_staleness": -1}, "--max-staleness -1"),
    ]:
        with pytest.raises(ValueError, match=message):
            train_overtaking(tiny_overtaking_config(small_track, tmp_path / "run", **change))
        assert not (tmp_path / "run").exists()


_NICENESS = """
import os, ray
from vision_rl.training.distributed import connect
cluster = connect("", 1)
print(ray.get(ray.remote(num_cpus=1)(lambda: os.nice(0)).remote()))
cluster.close()
"""


def test_a_local_cluster_runs_its_samplers_at_the_learners_priority():
    """Ray's default is nice 15, where anything else on the machine takes a sampler's core first."""
    pytest.importorskip("ray", reason="Ray is not installed: pip install 'vision_rl[ray]'")
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_worker_niceness", "RAY_ADDRESS")}
    process = subprocess.Popen(
        [sys.executable, "-c", _NICENESS],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=True,
    )
    try:
        stdout, stderr = process.communicate(timeout=180)
    except subprocess.TimeoutExpired:  # the cluster's processes too: they hold the pipes
        raise AssertionError(f"no answer within 180 s: {kill_and_read(process)[-2000:]}") from None
    assert process.returncode == 0, stderr[-2000:]
    assert int(stdout.split()[-1]) == os.nice(0)
