"""train-policy at tiny sizes: the artifact, resume, Ctrl-C, refusal of an existing run, the presets."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from tests.helpers.policies import script_held_out_laps, tiny_train_config
from vision_rl.config import flat_values, from_flat, replace_flat
from vision_rl.envs import RacingConfig
from vision_rl.envs.observations import STATE_OBS_NAMES
from vision_rl.phase2_rl.train import _TrainingLoop, train_policy
from vision_rl.training.artifact import PolicyError, PolicySpec, load_policy
from vision_rl.training.evaluate import evaluate_policy
from vision_rl.training.presets import PRESETS, SACOverrides, resolve_preset
from vision_rl.training.sac import read_metrics


def test_train_writes_a_policy_that_evaluate_loads(state_run, small_track):
    out, result = state_run
    assert result["num_timesteps"] == 200 and not result["interrupted"]
    assert result["n_updates"] == (200 - 50) // 2  # one update per vector step of 2 cars after 50 random steps
    spec = PolicySpec.read(out / "policy.json")
    assert spec.observation == "state" and spec.num_timesteps == 200 and spec.encoder is None
    assert spec.config == RacingConfig(track=small_track, n_groups=2)
    assert len(spec.obs_normalizer["offset"]) == len(STATE_OBS_NAMES) == 38
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == [
        "policy_100.json",
        "policy_100.pt",
        "policy_200.json",
        "policy_200.pt",
    ]
    assert (out / "replay_buffer.npz").is_file() and any((out / "tensorboard").iterdir())
    metrics = read_metrics(out / "metrics.jsonl")
    assert [m["num_timesteps"] for m in metrics] == [100, 200]
    assert all(m["distance_m"] != 0.0 for m in metrics)
    # The last point of the curve timed the saved weights, not those of one update before (SB3 updates once more
    # after the rollout that reaches the last step).
    assert metrics[-1]["n_updates"] == result["n_updates"]
    again = evaluate_policy(out, laps=1, seeds=1, write=False)
    assert again["seeds"][0]["distance_m"] == metrics[-1]["distance_m"]

    policy = load_policy(out)
    assert policy.spec.num_timesteps == 200 and policy.weights_path == out / "policy.pt"
    snapshot = load_policy(out / "checkpoints" / "policy_100.pt")
    assert snapshot.spec.num_timesteps == 100 and snapshot.spec.weights_sha256 != policy.spec.weights_sha256
    np.testing.assert_allclose(policy.spec.normalizer.scale, spec.obs_normalizer["scale"])
    ev = evaluate_policy(out, laps=2, seeds=2, time_limit_s=20.0)
    assert ev["driver"]["observation"] == "state" and ev["n_seeds"] == 2 and ev["protocol"]["scored_lap"] == 2
    assert ev["protocol"]["start"] == "rolling"
    stored = json.loads((out / "evaluation.json").read_text())
    assert stored["best_lap_time_s"] == ev["best_lap_time_s"] and stored["name"] == "tiny-state"


def test_resume_continues_the_step_count(state_run, tmp_path):
    src, first = state_run
    out = tmp_path / "resumed"
    shutil.copytree(src, out)
    track = PolicySpec.read(src / "policy.json").config.track
    with pytest.raises(PolicyError, match=r"--track 'elsewhere' \(the run's: "):  # not ignored without a word
        train_policy(tiny_train_config("elsewhere", out, steps=300, resume=True))
    result = train_policy(tiny_train_config(track, out, steps=300, resume=True))
    assert result["resumed_from_steps"] == 200 and result["num_timesteps"] == 300
    assert result["n_updates"] == first["n_updates"] + 100 // 2  # the buffer came back: no new random phase
    assert result["buffer_restored"] == 200 // 2  # transitions per car
    spec = PolicySpec.read(out / "policy.json")
    assert spec.num_timesteps == 300 and spec.train_time_s > PolicySpec.read(src / "policy.json").train_time_s
    assert spec.train_config == PolicySpec.read(src / "policy.json").train_config  # the run's own settings
    assert [m["num_timesteps"] for m in read_metrics(out / "metrics.jsonl")] == [100, 200, 300]
    again = train_policy(tiny_train_config(track, out, steps=300, resume=True))  # nothing left to do
    assert again["num_timesteps"] == 300


def test_ctrl_c_saves_and_resume_finishes(small_track, tmp_path, monkeypatch):
    original = _TrainingLoop._on_step

    def interrupt(self):
        if self.num_timesteps >= 120:
            raise KeyboardInterrupt
        return original(self)

    monkeypatch.setattr(_TrainingLoop, "_on_step", interrupt)
    out = tmp_path / "run"
    result = train_policy(tiny_train_config(small_track, out, eval_every_steps=0))
    assert result["interrupted"] and result["num_timesteps"] == 120
    assert PolicySpec.read(out / "policy.json").num_timesteps == 120
    assert load_policy(out).spec.num_timesteps == 120
    monkeypatch.setattr(_TrainingLoop, "_on_step", original)
    assert train_policy(tiny_train_config(small_track, out, resume=True))["num_timesteps"] == 200


def test_every_record_and_log_the_trainer_writes_is_strict_json(state_run):
    """No bare NaN (a tiny run drives no whole lap, so its mean wall contact per lap is missing: null)."""

    def refuse(constant: str):
        raise AssertionError(f"not JSON: {constant}")

    out, _ = state_run
    files = sorted(p for p in out.rglob("*") if p.suffix in (".json", ".jsonl"))
    assert out / "metrics.jsonl" in files and out / "policy.json" in files
    for path in files:
        text = path.read_text()
        lines = text.splitlines() if path.suffix == ".jsonl" else [text]
        for line in lines:
            json.loads(line, parse_constant=refuse)
    assert any(m["wall_contact_per_lap_s"] is None for m in read_metrics(out / "metrics.jsonl"))


def test_existing_run_and_missing_run_are_refused(state_run, tmp_path):
    out, _ = state_run
    with pytest.raises(FileExistsError, match="--resume"):
        train_policy(tiny_train_config("technical", out))
    with pytest.raises(FileNotFoundError, match="nothing to resume"):
        train_policy(tiny_train_config("technical", tmp_path / "empty", resume=True))
    with pytest.raises(ValueError, match="preset"):
        train_policy(tiny_train_config("technical", out, preset="gpu", force=True))
    with pytest.raises(FileNotFoundError, match="encoder checkpoint"):
        train_policy(tiny_train_config("technical", out, encoder=str(tmp_path / "no.pt"), force=True))
    with pytest.raises(ValueError, match="encoder runtime"):
        train_policy(tiny_train_config("technical", out, encoder_runtime="tensorrt", force=True))
    assert (out / "policy.pt").is_file()  # a bad option with --force left the run alone


def test_light_checkpoints_on_time_survive_a_crash_and_resume_refills_the_buffer(small_track, tmp_path, monkeypatch):
    """A crash that saves nothing (as a SIGKILL) after light checkpoints: the weights of the last one remain, with
    no buffer, and resume collects fresh random transitions before it updates again."""
    original = _TrainingLoop._on_step

    def crash(self):
        if self.num_timesteps >= 150:
            raise SystemExit("killed")
        return original(self)

    monkeypatch.setattr(_TrainingLoop, "_on_step", crash)
    out = tmp_path / "run"
    config = tiny_train_config(
        small_track, out, eval_every_steps=0, checkpoint_every_steps=0, checkpoint_every_min=1e-9
    )
    with pytest.raises(SystemExit):
        train_policy(config)
    assert PolicySpec.read(out / "policy.json").num_timesteps == 148  # the last step before the crash
    assert not (out / "replay_buffer.npz").exists() and not list(out.glob(".*.tmp"))
    monkeypatch.setattr(_TrainingLoop, "_on_step", original)
    result = train_policy(replace_flat(config, resume=True, steps=300, checkpoint_every_min=10.0))
    assert result["buffer_restored"] == 0 and result["num_timesteps"] == 300
    new_updates = result["n_updates"] - (148 - 50) // 2
    assert abs(new_updates - (300 - 148 - 50) // 2) <= 1  # a new random phase of 50 steps (76 updates without)


def test_presets_and_overrides():
    paper = PRESETS["paper"]
    assert (paper.hidden_units, paper.batch_size, paper.buffer_size, paper.learning_starts) == (
        (256, 256),
        4096,
        1_000_000,
        40_000,
    )
    assert (paper.learning_rate, paper.gamma) == (1e-3, 0.99)
    cpu = resolve_preset(SACOverrides(preset="cpu"))
    assert cpu == PRESETS["cpu"] and cpu.torch_threads == 1
    custom = resolve_preset(SACOverrides(preset="paper", batch_size=64, learning_starts=0, learning_rate=3e-4))
    assert (custom.batch_size, custom.learning_starts, custom.learning_rate, custom.buffer_size) == (
        64,
        0,
        3e-4,
        1_000_000,
    )


def test_the_learning_rate_falls_linearly_to_its_final_value_over_the_run(small_track, state_run, tmp_path):
    from vision_rl.training.persist import read_agent

    def actor_lr(path) -> float:
        return read_agent(path)["optimizers"]["actor"]["param_groups"][0]["lr"]

    out = tmp_path / "decay"
    train_policy(tiny_train_config(small_track, out, learning_rate=1e-3, learning_rate_final=1e-4))
    assert PolicySpec.read(out / "policy.json").sac["learning_rate_final"] == 1e-4
    # Halfway (the checkpoint at 100 of 200 steps, saved after the update at 98 or 100): 1e-3 - 0.9e-3 * 0.5.
    assert actor_lr(out / "checkpoints" / "policy_100.pt") == pytest.approx(5.5e-4, rel=0.02)
    assert actor_lr(out / "policy.pt") == pytest.approx(1e-4)
    assert actor_lr(state_run[0] / "policy.pt") == pytest.approx(1e-3)  # the default: constant
    with pytest.raises(ValueError, match="--learning-rate-final -1"):
        train_policy(tiny_train_config(small_track, tmp_path / "bad", learning_rate_final=-1))


def test_the_entropy_target_is_sacs_and_a_resumed_run_keeps_its_own(small_track, state_run, tmp_path):
    from vision_rl.phase2_rl.train import _Run

    assert PolicySpec.read(state_run[0] / "policy.json").sac["target_entropy"] == 0.0  # SB3's auto: -2
    out = tmp_path / "low"
    train_policy(tiny_train_config(small_track, out, steps=100, target_entropy=-6.0))
    for cfg in (
        tiny_train_config(small_track, out, steps=200, resume=True),  # the run's -6, not the default's
        tiny_train_config(small_track, tmp_path / "auto", steps=100),
    ):
        run = _Run(cfg)
        try:
            assert run.build().target_entropy == (-6.0 if cfg.resume else -2.0)
        finally:
            run.close()
    with pytest.raises(ValueError, match="--target-entropy 1"):
        train_policy(tiny_train_config(small_track, tmp_path / "bad", target_entropy=1.0))


def test_sigterm_saves_like_ctrl_c(small_track, tmp_path, monkeypatch, capsys):
    import os
    import signal

    from vision_rl.commands.train_policy import TrainPolicyOptions, run_train_policy

    original = _TrainingLoop._on_step

    def terminate(self):
        if self.num_timesteps >= 100:
            os.kill(os.getpid(), signal.SIGTERM)
        return original(self)

    monkeypatch.setattr(_TrainingLoop, "_on_step", terminate)
    handler = signal.getsignal(signal.SIGTERM)
    out = tmp_path / "run"
    config = tiny_train_config(small_track, out, eval_every_steps=0)
    assert run_train_policy(from_flat(TrainPolicyOptions, flat_values(config), progress=False)) == 130
    assert "interrupted: saved" in capsys.readouterr().out
    assert 100 <= PolicySpec.read(out / "policy.json").num_timesteps < 200
    assert signal.getsignal(signal.SIGTERM) == handler  # the command's handler is gone again


def test_n_step_returns_sum_the_rewards_before_the_critics_bootstrap(small_track, tmp_path):
    from vision_rl.phase2_rl.train import _Run

    run = _Run(tiny_train_config(small_track, tmp_path / "n3", n_step=3))
    model = run.build()
    try:
        buffer, gamma = model.replay_buffer, model.gamma
        assert type(buffer).__name__ == "NStepReplayBuffer" and buffer.n_steps == 3
        obs = np.zeros((buffer.n_envs, *buffer.obs_shape), dtype=np.float32)
        action = np.zeros((buffer.n_envs, 2), dtype=np.float32)
        no_end = np.zeros(buffer.n_envs, dtype=bool)
        for reward in (1.0, 2.0, 3.0, 4.0):
            buffer.add(obs, obs, action, np.full(buffer.n_envs, reward), no_end, [{}] * buffer.n_envs)
        batch = buffer._get_samples(np.array([0, 1]))
        np.testing.assert_allclose(
            batch.rewards.numpy().ravel(), [1 + 2 * gamma + 3 * gamma**2, 2 + 3 * gamma + 4 * gamma**2], rtol=1e-6
        )
        np.testing.assert_allclose(batch.discounts.numpy().ravel(), gamma**3, rtol=1e-6)
    finally:
        run.close()
    with pytest.raises(ValueError, match="--n-step 3 needs one car's steps in a row"):
        train_policy(tiny_train_config(small_track, tmp_path / "w2", n_step=3, workers=2))


def test_held_out_starts_keep_the_fastest_clean_weights_and_a_resumed_run_goes_on_from_them(
    small_track, tmp_path, monkeypatch
):
    asked = script_held_out_laps(monkeypatch, [None, 30.0, 29.0, 29.5, 29.2, 28.0])
    out = tmp_path / "run"
    cfg = tiny_train_config(small_track, out, steps=400, select_starts=2, checkpoint_every_steps=0)
    train_policy(cfg)
    assert asked == [[100, 101]] * 4  # at every periodic evaluation, never the protocol's starts 0, 1
    selection = [m["selection"] for m in read_metrics(out / "metrics.jsonl")]
    assert [s["kept"] for s in selection] == [False, True, True, False]
    assert selection[0]["mean_lap_time_s"] is None and not selection[0]["clean"]
    assert selection[2]["mean_lap_time_s"] == pytest.approx(29.0) and selection[2]["finished"] == 2
    best = load_policy(out / "best")
    assert best.spec.num_timesteps == 300 and best.spec.selection["start_seeds"] == [100, 101]
    assert best.spec.selection["mean_lap_time_s"] == pytest.approx(29.0)
    last = load_policy(out)
    assert last.spec.selection is None and last.spec.weights_sha256 != best.spec.weights_sha256
    assert evaluate_policy(out / "best", laps=1, seeds=1, time_limit_s=5.0)["name"] == "run/best"

    # 29.2 is slower than the 29.0 the run kept before it was resumed; 28.0 is faster.
    train_policy(replace_flat(cfg, steps=600, resume=True))
    assert [m["selection"]["kept"] for m in read_metrics(out / "metrics.jsonl")][-2:] == [False, True]
    assert load_policy(out / "best").spec.num_timesteps == 600
    with pytest.raises(ValueError, match="--select-starts"):
        train_policy(replace_flat(cfg, out=str(tmp_path / "other"), eval_every_steps=0))
    with pytest.raises(ValueError, match="--eval-seeds 101 would time the held-out starts"):
        train_policy(replace_flat(cfg, out=str(tmp_path / "other"), eval_seeds=101))
    with pytest.raises(ValueError, match="--select-starts -1 is out of range"):
        train_policy(replace_flat(cfg, out=str(tmp_path / "other"), select_starts=-1))


def test_without_select_clean_held_out_starts_keep_the_fastest_weights_that_finished_every_start(
    small_track, tmp_path, monkeypatch
):
    # Laps with wall contact: the default (clean) keeps nothing; --no-select-clean keeps the fastest weights whose
    # starts all finished, never those that lost one start however fast the others were.
    script_held_out_laps(monkeypatch, [30.0, [27.0, None], 29.0, 29.5], clean=False)
    cfg = tiny_train_config(small_track, tmp_path / "clean", steps=400, select_starts=2, checkpoint_every_steps=0)
    train_policy(cfg)
    assert not (tmp_path / "clean" / "best").exists()
    script_held_out_laps(monkeypatch, [30.0, [27.0, None], 29.0, 29.5], clean=False)
    out = tmp_path / "finished"
    train_policy(replace_flat(cfg, out=str(out), select_clean=False))
    selection = [m["selection"] for m in read_metrics(out / "metrics.jsonl")]
    assert [s["kept"] for s in selection] == [True, False, True, False]
    assert selection[1]["finished"] == 1 and selection[1]["mean_lap_time_s"] is None
    best = load_policy(out / "best").spec
    assert best.num_timesteps == 300 and best.selection["mean_lap_time_s"] == pytest.approx(29.0)
    assert best.selection["clean_wall_contact_s"] is None  # chosen without the clean rule, and it says so
    with pytest.raises(ValueError, match="--no-select-clean sets the rule of --select-starts"):
        train_policy(replace_flat(cfg, out=str(tmp_path / "other"), select_starts=0, select_clean=False))


def test_read_metrics_drops_the_evaluations_a_resume_replaced(tmp_path):
    # killed after the 300-step evaluation, resumed from the 200-step checkpoint: the first 300 is another policy's
    lines = [
        {"num_timesteps": 100, "lap_time_s": 99.0},
        {"num_timesteps": 200, "lap_time_s": 98.0},
        {"event": "sampler_lost", "num_timesteps": 250},
        {"num_timesteps": 300, "lap_time_s": 90.0},
        {"num_timesteps": 300, "lap_time_s": 97.0},
        {"num_timesteps": 400, "lap_time_s": 96.0},
    ]
    path = tmp_path / "metrics.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in lines) + '{"num_timesteps": 5')  # a torn last line
    records = read_metrics(path)
    assert [(r["num_timesteps"], r["lap_time_s"]) for r in records] == [
        (100, 99.0),
        (200, 98.0),
        (300, 97.0),
        (400, 96.0),
    ]
    assert [r.get("event") for r in read_metrics(path, events=True)] == [None, None, "sampler_lost", None, None]


@pytest.mark.parametrize("stuck_ends_episode, scale, restart_share", [(False, "usable", 0.0), (True, "limit", 0.5)])
def test_stuck_ends_episode_and_the_steering_penalty_scale_reach_the_training_env(
    small_track, tmp_path, stuck_ends_episode, scale, restart_share
):
    from vision_rl.phase2_rl.train import _Run

    config = tiny_train_config(
        small_track,
        tmp_path / "run",
        stuck_ends_episode=stuck_ends_episode,
        steer_change_penalty_scale=scale,
        restart_before_stuck_share=restart_share,
        restart_before_stuck_m=150.0,
    )
    run = _Run(config)
    assert run.racing.terminate_when_stuck is stuck_ends_episode
    assert run.racing.steer_change_penalty_scale == scale
    assert (run.racing.restart_before_stuck_share, run.racing.restart_before_stuck_m) == (restart_share, 150.0)


def test_a_finer_control_step_keeps_the_discount_per_second_and_is_timed_at_its_own_rate(small_track, tmp_path):
    from vision_rl.phase2_rl.train import _Run
    from vision_rl.training.sac import gamma_per_step

    assert gamma_per_step(0.99, 0.1) == 0.99
    assert gamma_per_step(0.99, 0.04) == pytest.approx(0.995988, abs=1e-6)  # 0.99 ** 0.4: one 0.1 s is 2.5 steps
    assert gamma_per_step(0.99, 0.04) ** 5 == pytest.approx(0.99**2)
    run = _Run(tiny_train_config(small_track, tmp_path / "dt04", control_dt_s=0.04, episode_s=4.0))
    model = run.build()
    try:
        assert model.gamma == pytest.approx(0.99**0.4) and run.racing.control_dt_s == 0.04
        assert run.racing.max_episode_steps == 100  # 4 s of 0.04 s steps
    finally:
        run.close()
    out = tmp_path / "dt04-trained"
    train_policy(tiny_train_config(small_track, out, control_dt_s=0.04, steps=100, eval_every_steps=100))
    spec = PolicySpec.read(out / "policy.json")
    assert spec.config.control_dt_s == 0.04 and load_policy(out).driver().control_dt_s == 0.04
