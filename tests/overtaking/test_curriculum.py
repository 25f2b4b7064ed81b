"""train-overtaking at tiny sizes: the stage chain, the stage transitions (kept buffer, re-initialised exploration,
opponent 200 m ahead, FIFO eviction), the stage-1 criterion, an interrupted stage that continues, learning curves."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer

import vision_rl.overtaking.curriculum as ot
from tests.helpers.overtaking import tiny_overtaking_config
from vision_rl.envs import RacingConfig, RacingCore
from vision_rl.evaluation.protocol import time_laps
from vision_rl.overtaking.curriculum import (
    copy_newest,
    learning_curve,
    load_overtaking_policy,
    reinit_exploration,
    train_overtaking,
)


@pytest.fixture(scope="module")
def curriculum(tmp_path_factory, small_track) -> tuple[Path, dict]:
    """Agents 3 then 2 of one tiny run folder (Agent 2 branches off the shared stages 1-2)."""
    out = tmp_path_factory.mktemp("overtaking") / "run"
    third = train_overtaking(tiny_overtaking_config(small_track, out, agent="3"))
    second = train_overtaking(tiny_overtaking_config(small_track, out, agent="2"))
    return out, {"3": third, "2": second}


def test_agents_share_stages_one_and_two_and_record_their_boundaries(curriculum):
    out, results = curriculum
    third, second = results["3"], results["2"]
    assert third["trained_now"] == ["stage1", "stage2", "agent3-stage3"] and third["done"]
    assert second["trained_now"] == ["agent2-stage3"]  # stages 1-2 were not repeated
    stages = {b["stage"]: b for b in third["stages"]}
    assert (stages["stage1"]["start_steps"], stages["stage1"]["end_steps"]) == (0, 200)  # the cap: criterion unmet
    assert stages["stage1"]["criterion"]["met"] is False
    assert (stages["stage2"]["start_steps"], stages["stage2"]["end_steps"]) == (200, 300)
    assert (stages["agent3-stage3"]["start_steps"], stages["agent3-stage3"]["end_steps"]) == (300, 400)
    assert stages["stage2"]["start_train_time_s"] == stages["stage1"]["end_train_time_s"] > 0
    assert stages["agent3-stage3"]["penalty_c"] == 0.01
    assert {b["stage"]: b["penalty_c"] for b in second["stages"]}["agent2-stage3"] == 0.005
    record = json.loads((out / "agent3.json").read_text())
    assert record["policy"].endswith("agent3-stage3") and [s["stage"] for s in record["stages"]] == list(stages)
    # Stage 2 trains on Eq. 2 with one opponent 200 m ahead along the centre line, c_w = c_c = 0.005.
    spec = load_overtaking_policy(out / "stage2").spec
    cfg = spec.config
    assert (cfg.scenario, cfg.wall_penalty_c_w, cfg.car_penalty_c_c, cfg.observation) == (
        "stage2",
        0.005,
        0.005,
        "overtaking",
    )
    core = RacingCore(cfg, seed=3)
    core.reset_groups(np.arange(cfg.n_groups))
    np.testing.assert_allclose(core.start_gap_m, 200.0, atol=1e-6)
    assert load_overtaking_policy(out / "stage1").spec.config.scenario == "stage1"


def test_stage_two_keeps_the_buffer_and_stage_three_evicts_it(curriculum):
    out, _ = curriculum
    stage2 = json.loads((out / "stage2" / "stage.json").read_text())
    assert stage2["buffer_at_start"] == 200  # every stage-1 transition went on into stage 2
    assert stage2["stage"]["reinit_exploration"] and not stage2["stage"]["fifo_from_previous"]
    stage3 = json.loads((out / "agent3-stage3" / "stage.json").read_text())
    assert stage3["stage"]["buffer_size"] == 50 and stage3["buffer_at_start"] == 50  # half of its 100 steps
    with np.load(out / "agent3-stage3" / "replay_buffer.npz", allow_pickle=False) as data:
        meta = json.loads(str(data["meta"]))
        assert meta["full"] and meta["capacity"] == 25  # per car: stage 3 wrote 100 > 50 transitions


def test_copy_newest_keeps_the_newest_in_order_and_they_leave_first():
    obs, act = spaces.Box(-1, 1, (3,)), spaces.Box(-1, 1, (2,))
    source = ReplayBuffer(10, obs, act, device="cpu", n_envs=1)
    for i in range(13):  # wraps: rows hold 3..12
        source.add(np.full((1, 3), i), np.full((1, 3), i), np.zeros((1, 2)), np.zeros(1), np.zeros(1), [{}])
    target = ReplayBuffer(4, obs, act, device="cpu", n_envs=1)
    assert copy_newest(source, target) == 4
    assert target.observations[:, 0, 0].tolist() == [9, 10, 11, 12] and target.full and target.pos == 0
    for i in range(100, 104):  # four fresh transitions evict all four old ones, oldest first
        target.add(np.full((1, 3), i), np.full((1, 3), i), np.zeros((1, 2)), np.zeros(1), np.zeros(1), [{}])
        old = sorted(v for v in target.observations[:, 0, 0].tolist() if v < 100)
        assert old == list(range(10 + i - 100, 13))
    assert sorted(target.observations[:, 0, 0].tolist()) == [100, 101, 102, 103]


def test_reinit_exploration_resets_the_entropy_coefficient_and_log_std(small_track):
    from stable_baselines3 import SAC

    from vision_rl.envs.vector import make_sb3_vec_env

    torch.set_num_threads(1)
    env = make_sb3_vec_env(RacingConfig(track=small_track, observation="overtaking", scenario="stage1", n_groups=1))
    model = SAC("MlpPolicy", env, buffer_size=100, learning_starts=0, batch_size=8, device="cpu", seed=0)
    model.learn(16)
    with torch.no_grad():
        model.log_ent_coef.fill_(-3.0)
    before = model.actor.log_std.weight.detach().clone()
    assert any(p in model.actor.optimizer.state for p in model.actor.log_std.parameters())
    reinit_exploration(model)
    assert model.log_ent_coef.item() == 0.0
    assert model.ent_coef_optimizer.param_groups[0]["params"][0] is model.log_ent_coef
    assert not torch.equal(before, model.actor.log_std.weight)
    assert not any(p in model.actor.optimizer.state for p in model.actor.log_std.parameters())
    env.close()


def test_stage_one_ends_at_the_lap_time_criterion(small_track, tmp_path, monkeypatch):
    class Timing:  # every driver laps in 30 s: the policy is within 5 % of the AI at the first evaluation
        def summary(self):
            return {"best_lap_time_s": 30.0, "n_finished": 1}

    monkeypatch.setattr(ot, "time_laps", lambda *a, **k: Timing())
    result = train_overtaking(
        tiny_overtaking_config(small_track, tmp_path / "run", agent="1", stage2_steps=20, eval_episodes=0)
    )
    stage1 = result["stages"][0]
    assert stage1["end_steps"] == 100 < 200 and stage1["criterion"]["met_at_steps"] == 100
    assert result["stages"][1]["start_steps"] == 100


def test_an_interrupted_stage_continues_with_its_buffer(small_track, tmp_path, monkeypatch):
    original = ot._StageLoop._on_step

    def interrupt(self):
        if self.session.stage.name == "stage2" and self.num_timesteps >= 250:
            raise KeyboardInterrupt
        return original(self)

    monkeypatch.setattr(ot._StageLoop, "_on_step", interrupt)
    cfg = tiny_overtaking_config(small_track, tmp_path / "run", agent="1", eval_every_steps=0)
    first = train_overtaking(cfg)
    assert first["interrupted"] and [b["status"] for b in first["stages"]] == ["done", "running"]
    monkeypatch.setattr(ot._StageLoop, "_on_step", original)
    with np.load(tmp_path / "run" / "stage2" / "replay_buffer.npz", allow_pickle=False) as data:
        # 200 kept + 48 of stage 2, per car: SB3 stores a step's transitions after the callback that interrupted
        assert len(data["observations"]) == 124
    second = train_overtaking(cfg)
    assert second["trained_now"] == ["stage2"] and second["stages"][1]["start_steps"] == 200
    assert second["stages"][1]["end_steps"] == 300


def test_the_policy_drives_the_protocol_and_the_curve_spans_the_stages(curriculum, small_track):
    out, _ = curriculum
    policy = load_overtaking_policy(out / "agent3-stage3")
    driver = policy.driver()
    timing = time_laps(driver, small_track, "tt_cup", seeds=[0], laps=1, time_limit_s=5.0)
    assert timing.runs[0].distance_m > 0
    curve = learning_curve(out, "3")
    steps = [r["num_timesteps"] for r in curve["records"]]
    assert steps == [100, 200, 300, 400] and all(r["overtaking_return"] is not None for r in curve["records"])
    assert [r["stage"] for r in curve["records"]] == ["stage1", "stage1", "stage2", "agent3-stage3"]
    assert curve["stage_switches"] == [
        {"stage": "stage2", "num_timesteps": 200},
        {"stage": "agent3-stage3", "num_timesteps": 300},
    ]


def test_evaluate_times_an_overtaking_policy_like_any_other(curriculum):
    from vision_rl.training.evaluate import evaluate_policy

    out, _ = curriculum
    record = evaluate_policy(out / "agent3-stage3", laps=1, seeds=1, time_limit_s=5.0)
    assert record["driver"]["observation"] == "overtaking" and record["protocol"]["version"] >= 1
    assert (out / "agent3-stage3" / "evaluation.json").is_file()


def test_a_c_r_ablation_starts_from_another_runs_stage_one(curriculum, small_track, tmp_path):
    out, _ = curriculum
    ablation = tmp_path / "c_r-2"
    cfg = tiny_overtaking_config(small_track, ablation, agent="1", overtake_gain_c_r=2.0, stage1_from=str(out))
    result = train_overtaking(cfg)
    assert result["trained_now"] == ["stage2"] and result["done"]  # stage 1 was not trained again
    assert (ablation / "stage1" / "policy.pt").stat().st_ino == (out / "stage1" / "policy.pt").stat().st_ino
    run = json.loads((ablation / "run.json").read_text())
    assert run["settings"]["overtake_gain_c_r"] == 2.0 and run["stage1_from"] == str(out)
    assert run["ai_lap_time_s"] == json.loads((out / "run.json").read_text())["ai_lap_time_s"]
    assert load_overtaking_policy(ablation / "stage2").spec.config.overtake_gain_c_r == 2.0
    again = train_overtaking(cfg)  # continued like any run folder: nothing left to do
    assert again["trained_now"] == [] and again["done"]
    with pytest.raises(ot.OvertakingRunError, match="its seed is 0, not 1"):
        train_overtaking(
            tiny_overtaking_config(small_track, tmp_path / "seed1", agent="1", seed=1, stage1_from=str(out))
        )
    with pytest.raises(ot.OvertakingRunError, match=r"no run\.json there"):
        train_overtaking(tiny_overtaking_config(small_track, tmp_path / "none", agent="1", stage1_from=str(tmp_path)))
