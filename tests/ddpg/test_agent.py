"""DDPG with an asymmetric actor-critic: the networks' shapes, OU noise, the frame-once replay buffer and its
incremental files, one update, save/load, the protocol driver and a tiny train-ddpg run with resume."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.helpers.ddpg import timed_ddpg_config
from tests.helpers.tracks import STADIUM, stadium_csv
from vision_rl.ddpg.agent import (
    ConvTrunk,
    DDPGAgent,
    DDPGError,
    DDPGHyper,
    FrameReplay,
    FrameSizeError,
    OUNoise,
    PixelActor,
    StateActor,
    ddpg_fingerprint,
    load_agent,
    load_replay,
    save_agent_file,
    save_replay,
)
from vision_rl.ddpg.bench import BENCH_LAYOUTS, bench_updates, profile_update, update_flops
from vision_rl.envs.pixel_racing import PixelRacingConfig

HW = (32, 48)  # the smallest convenient frame for four conv + pool stages


@pytest.fixture(scope="module")
def track(tmp_path_factory) -> str:
    return str(stadium_csv(tmp_path_factory.mktemp("track") / "stadium.csv", *STADIUM))


def _env(track: str, **kw) -> PixelRacingConfig:
    return PixelRacingConfig(**{"track": track, "image_hw_px": HW, **kw})


def _obs(n: int, rng: np.random.Generator, hw=HW) -> dict[str, np.ndarray]:
    return {
        "image": rng.integers(0, 256, (n, *hw, 3), dtype=np.uint8),
        "motion": rng.normal(size=(n, 15)).astype(np.float32),
        "goal": rng.normal(size=(n, 3)).astype(np.float32),
    }


def _batch(n: int, rng: np.random.Generator) -> dict:
    return {
        "obs": _obs(n, rng),
        "next_obs": _obs(n, rng),
        "action": rng.uniform(0, 1, (n, 4)).astype(np.float32),
        "reward": rng.normal(30, 5, n).astype(np.float32),
        "terminated": rng.random(n) < 0.1,
    }


def test_actor_shapes_output_ranges_and_small_initial_outputs():
    torch.manual_seed(0)
    actor = PixelActor((89, 120)).eval()
    assert actor.trunk.out_dim == 32 * 4 * 6
    frames = torch.randint(0, 256, (5, 89, 120, 3), dtype=torch.uint8)
    with torch.no_grad():
        keys = actor({"image": frames})
    assert keys.shape == (5, 4)
    assert (keys[:, [0, 3]] >= 0).all() and (keys[:, 1:3].abs() <= 1).all()
    assert keys.abs().max() < 0.2  # the output layer starts at variance scaling 1e-2


def test_a_relu_pedal_below_zero_has_no_gradient_and_a_sigmoid_pedal_has_one():
    """Why the paper's relu pedals die: once the accelerate pre-activation is negative, the actor outputs 0 and the
    critic's push towards pressing it reaches no weight. A sigmoid pedal starts half pressed and keeps a gradient."""
    torch.manual_seed(0)
    h = torch.randn(5, 300)
    for activation, grad_nonzero in (("relu", False), ("sigmoid", True)):
        actor = StateActor(np.zeros(18), np.ones(18), pedal_activation=activation)
        with torch.no_grad():
            actor.head.out.bias[0] = -1.0  # the accelerate pre-activation below zero for every input
        keys = actor.head(h)
        keys[:, 0].sum().backward()  # the critic asks for more throttle
        assert (actor.head.out.weight.grad[0].abs().sum() > 0) == grad_nonzero
        assert (keys[:, 0] > 0).all() == grad_nonzero
    fresh = StateActor(np.zeros(18), np.ones(18), pedal_activation="sigmoid").head(h)
    np.testing.assert_allclose(fresh[:, [0, 3]].detach().numpy(), 0.5, atol=0.1)  # both pedals about half the step
    with pytest.raises(DDPGError, match="pedal_activation must be one of"):
        DDPGHyper(pedal_activation="softplus")


def test_ou_noise_reverts_to_the_mean_with_theta_0_8():
    noise = OUNoise(20_000, 1, theta=0.8, sigma=0.3, seed=0)
    noise.x[:] = 1.0
    first = noise()
    assert first.mean() == pytest.approx(0.2, abs=0.01)  # E[x1 | x0 = 1] = (1 - theta) x0
    assert first.std() == pytest.approx(0.3, abs=0.01)
    for _ in range(30):
        x = noise()
    assert x.mean() == pytest.approx(0.0, abs=0.01)
    assert x.std() == pytest.approx(0.3 / np.sqrt(1 - 0.2**2), abs=0.01)  # stationary std of the AR(1)
    noise.reset(np.array([0, 1]))
    assert (noise.x[:2] == 0).all()


def test_replay_stores_each_frame_once_and_next_is_the_following_row(tmp_path):
    rng = np.random.default_rng(0)
    buf = FrameReplay(capacity=20, n_cars=2, image_hw_px=HW)
    assert buf.image.shape == (2, 10, *HW, 3)
    o0 = _obs(2, rng)
    buf.start(o0)
    o1, final, fresh = _obs(2, rng), _obs(2, rng), _obs(1, rng)
    buf.add(np.ones((2, 4)), np.array([1.0, 2.0]), np.array([False, False]), o1, np.array([False, False]))
    # car 1 finishes: its final observation gets a row, then the new episode's first
    final["image"][0] = o1["image"][0]
    buf.add(np.zeros((2, 4)), np.array([3.0, 4.0]), np.array([False, True]), final, np.array([False, True]), fresh)
    assert buf.size == 4 and buf.pos.tolist() == [2, 3]
    np.testing.assert_array_equal(buf.image[1, 3], fresh["image"][0])
    s = buf.sample(200, rng)
    for i in range(200):
        if s["reward"][i] == 4.0:  # car 1's last step: next is its final observation, terminated
            assert s["terminated"][i]
            np.testing.assert_array_equal(s["next_obs"]["image"][i], final["image"][1])
        if s["reward"][i] == 1.0:
            np.testing.assert_array_equal(s["obs"]["image"][i], o0["image"][0])
            np.testing.assert_array_equal(s["next_obs"]["image"][i], o1["image"][0])
    # the files: only chunks written since the last save are rewritten; a reload gives the same arrays
    fingerprint = {"variant": "asymmetric"}
    assert save_replay(buf, tmp_path / "replay", fingerprint) == len(buf.dirty)
    assert save_replay(buf, tmp_path / "replay", fingerprint) == 0
    again = FrameReplay(capacity=20, n_cars=2, image_hw_px=HW)
    assert load_replay(again, tmp_path / "replay", fingerprint) == 4
    for name in FrameReplay.ARRAYS:
        np.testing.assert_array_equal(getattr(again, name), getattr(buf, name))
    assert again.pos.tolist() == buf.pos.tolist()


@pytest.mark.parametrize("variant", ["asymmetric", "symmetric", "state-actor"])
def test_one_training_step_changes_the_weights(track, variant):
    torch.set_num_threads(1)
    agent = DDPGAgent(DDPGHyper(variant=variant), _env(track, frames=variant != "state-actor"), seed=0)
    before = {
        name: [p.detach().clone() for p in getattr(agent, name).parameters()]
        for name in ("actor", "critic", "actor_target", "critic_target")
    }
    stats = agent.update(_batch(32, np.random.default_rng(0)))
    assert np.isfinite(list(stats.values())).all() and agent.n_updates == 1
    for name in ("actor", "critic"):
        changed = [not torch.equal(a, b) for a, b in zip(before[name], getattr(agent, name).parameters(), strict=True)]
        assert all(changed), f"{name}: {changed.count(False)} tensors unchanged"
    # targets moved by tau of the way to the updated networks
    for t0, t1, online in zip(
        before["critic_target"], agent.critic_target.parameters(), agent.critic.parameters(), strict=True
    ):
        torch.testing.assert_close(t1, t0 + 0.01 * (online.detach() - t0))


def test_a_saved_and_loaded_agent_acts_identically(track, tmp_path):
    rng = np.random.default_rng(1)
    env = _env(track)
    agent = DDPGAgent(DDPGHyper(), env, seed=3)
    for _ in range(2):
        agent.update(_batch(8, rng))
    path = tmp_path / "ddpg.pt"
    save_agent_file(agent, path, ddpg_fingerprint(agent.hyper, env), {"num_steps": 10})
    loaded = load_agent(path, variant="asymmetric")
    obs = _obs(4, rng)
    np.testing.assert_array_equal(agent.act(obs), loaded.act(obs))
    assert loaded.n_updates == 2 and loaded.counters["num_steps"] == 10


def test_train_ddpg_tiny_run_evaluates_saves_and_resumes(gl_available, track, tmp_path):
    from vision_rl.config import from_flat
    from vision_rl.ddpg.train import TrainDDPGConfig, evaluate_ddpg, train_ddpg

    out = tmp_path / "run"
    base = dict(
        track=track,
        cars=2,
        steps=24,
        out=str(out),
        image_hw_px=HW,
        buffer_size=200,
        learning_starts=8,
        batch_size=8,
        eval_every_steps=0,
        eval_seeds=1,
        eval_laps=1,
        eval_time_limit_s=3.0,
        checkpoint_every_steps=10,
    )
    result = train_ddpg(from_flat(TrainDDPGConfig, base))
    assert result["num_steps"] == 24 and result["n_updates"] > 0 and not result["interrupted"]
    assert result["last_eval"]["distance_m"] > 10.0  # the actor drove the protocol's car
    metrics = json.loads((out / "metrics.jsonl").read_text().splitlines()[-1])  # the critic beside the lap
    assert math.isfinite(metrics["q_mean"]) and metrics["critic_loss"] > 0.0
    side = json.loads((out / "ddpg.json").read_text())
    assert side["counters"]["num_steps"] == 24 and side["hyper"]["variant"] == "asymmetric"
    assert (out / "replay" / "index.json").is_file()
    episodes = (out / "episodes.jsonl").read_text().splitlines()
    assert all({"return", "distance_m", "end"} <= set(json.loads(line)) for line in episodes)

    stop_at = {"n": 0}

    def interrupt(steps, total, last_eval):
        stop_at["n"] += 1
        if stop_at["n"] == 3:
            raise KeyboardInterrupt

    resumed = train_ddpg(from_flat(TrainDDPGConfig, {**base, "steps": 60, "resume": True}), interrupt)
    assert resumed["interrupted"] and resumed["num_steps"] == 30 and resumed["buffer_restored"] > 0
    assert resumed["n_updates"] == result["n_updates"] + 3  # updates go on at once on the restored buffer
    assert json.loads((out / "ddpg.json").read_text())["counters"]["num_steps"] == 30

    timing = evaluate_ddpg(
        out, seeds=1, laps=1, time_limit_s=2.0, video=str(tmp_path / "best.mp4"), plot=str(tmp_path / "best.png")
    )
    assert timing["n_seeds"] == 1 and timing["driver"]["variant"] == "asymmetric"
    import imageio.v2 as imageio

    with imageio.get_reader(timing["video"]) as reader:  # 2 s at the protocol's 10 Hz, the game screen's size
        frames = [frame for frame in reader]
    assert len(frames) == 20 and frames[0].shape == (280, 470, 3) and frames[0].std() > 5
    assert (tmp_path / "best.png").stat().st_size > 1000
    from vision_rl.evaluation.leaderboard import find_evaluations

    (found,), refused = find_evaluations(out)  # the leaderboard reads it like a policy's
    assert found["name"] == "ddpg asymmetric" and not refused

    from vision_rl.commands.main import main

    png = tmp_path / "reward.png"
    assert (
        main(
            [
                "evaluate-ddpg",
                "--agent",
                str(out),
                "--seeds",
                "1",
                "--laps",
                "1",
                "--time-limit-s",
                "2",
                "--no-save",
                "--reward-plot",
                str(png),
                "--reward-laps",
                "2",
            ]
        )
        == 0
    )
    profile = json.loads(png.with_suffix(".json").read_text())
    assert png.stat().st_size > 1000 and [lap["lap"] for lap in profile["laps"]] == [1, 2]


def test_bench_times_each_layout_and_refuses_an_unknown_one(track):
    """Eager, channels-last and compiled trunks each complete timed updates; a misspelt layout is one clear error."""
    env = _env(track)
    for layout in BENCH_LAYOUTS:
        figures = bench_updates(DDPGHyper(batch_size=4), env, updates=1, warmup=1, layout=layout)
        assert figures["updates_per_s"] > 0
        assert figures["ms_per_update"] == pytest.approx(1000 / figures["updates_per_s"])
    with pytest.raises(DDPGError, match="layout must be one of"):
        bench_updates(DDPGHyper(batch_size=4), env, updates=1, layout="channels-last")


def test_the_cpu_preset_cuts_an_update_s_flops_five_to_tenfold_and_names_its_smallest_frame(track):
    """Issue 64's CPU preset: the pixel actor's update at the paper's 89x120 costs a fifth to a tenth of the paper
    trunk's operations; a frame too small for its strides is one clear error that says the size it takes."""
    env = _env(track, image_hw_px=(89, 120))
    flops = {t: update_flops(DDPGHyper(batch_size=2, trunk=t), env) for t in ("paper", "cpu")}
    assert 5 <= flops["paper"] / flops["cpu"] <= 10
    assert ConvTrunk((89, 120), preset="cpu").out_dim == 32 * 3 * 5
    with pytest.raises(FrameSizeError, match=r"too small for the cpu trunk.*at least 48x48"):
        ConvTrunk(HW, preset="cpu")
    with pytest.raises(DDPGError, match="trunk must be one of"):
        DDPGHyper(trunk="gpu")


def test_a_packed_upload_gives_back_every_array_whole():
    """The GPU path's upload (one buffer per dtype, one copy each), run on the CPU: every array comes back with its
    shape, dtype and values, frames next to floats."""
    from vision_rl.ddpg.agent import _batch_arrays, _upload

    arrays = _batch_arrays(_batch(3, np.random.default_rng(2)))
    packed = _upload(arrays, torch.device("cpu"), pack=True)
    assert packed.keys() == arrays.keys()
    for key, array in arrays.items():
        np.testing.assert_array_equal(packed[key].numpy(), array)
        assert packed[key].numpy().dtype == array.dtype
    assert packed["obs.image"].dtype == torch.uint8 and packed["alive"].dtype == torch.float32


def test_an_update_reads_no_scalar_back_outside_adam(track):
    """The host-side count of an update (torch.profiler): its losses come back as tensors, so the only .item()
    calls are Adam's reads of its host-side step counters, one per parameter tensor, none a wait for a GPU."""
    env = _env(track)
    figures = profile_update(DDPGHyper(batch_size=4), env, updates=1)
    agent = DDPGAgent(DDPGHyper(batch_size=4), env)
    n_params = len(list(agent.actor.parameters())) + len(list(agent.critic.parameters()))
    assert figures["item_reads"] == n_params
    assert figures["leaf_ops"] > figures["optimizer_ops"] > 0 and figures["kernel_launches"] == 0
    assert all(isinstance(v, torch.Tensor) for v in agent.update(_batch(4, np.random.default_rng(0))).values())


def test_train_minutes_stop_a_run_and_a_resume_with_more_continues_it(track, tmp_path):
    """The equal wall-clock budget: a run stops when its training time reaches --train-minutes, long before its
    steps, and a resume with a larger budget trains on from where it stopped."""
    from vision_rl.ddpg.train import train_ddpg

    run = tmp_path / "run"
    first = train_ddpg(timed_ddpg_config(track, run))
    assert first["stopped_by"] == "train_minutes" and 0 < first["num_steps"] < 10**7
    assert 1.2 <= first["train_time_s"] < 10.0
    with pytest.raises(ValueError, match=r"--gamma 0.5 \(the run's: 0.98\)"):  # not ignored without a word
        train_ddpg(timed_ddpg_config(track, run, train_minutes=0.04, resume=True, gamma=0.5))
    second = train_ddpg(timed_ddpg_config(track, run, train_minutes=0.04, resume=True))
    assert second["stopped_by"] == "train_minutes" and second["num_steps"] > first["num_steps"]
    assert 2.4 <= second["train_time_s"] < 12.0
    assert 0 < first["train_cpu_s"] < second["train_cpu_s"]  # CPU time adds up over sessions too
    with pytest.raises(ValueError, match="--train-minutes -1"):
        train_ddpg(timed_ddpg_config(track, run, train_minutes=-1.0, force=True))


def test_the_default_run_folder_is_under_runs_ddpg_with_the_track_path_flattened(track, tmp_path, monkeypatch):
    """Without --out a run goes to runs/ddpg/<variant>-<track>-<car>-s<seed>: a track given as a CSV path adds no
    folders, and the runs/ddpg folders stay (the name was once flattened whole into ./runs_ddpg_...)."""
    from vision_rl.ddpg.config import TrainDDPGConfig
    from vision_rl.ddpg.train import _Run

    monkeypatch.chdir(tmp_path)
    run = _Run(TrainDDPGConfig(variant="state-actor", env=_env(track)))
    assert run.out.parent == Path("runs/ddpg")
    assert run.out.name == f"state-actor-{track.replace(os.sep, '_')}-gt3-s0" and run.out.is_dir()


def test_the_diagnosis_tells_a_diverged_critic_and_saturated_keys(track):
    """A fresh state actor passes every key's gradient and its critic is near 0; an output bias of 10 saturates a
    pedal, and a critic whose output lies beyond what any policy earns or loses, either side, is called diverged."""
    from vision_rl.ddpg.diagnose import critic_and_keys

    torch.set_num_threads(1)
    agent = DDPGAgent(DDPGHyper(variant="state-actor", pedal_activation="sigmoid"), _env(track, frames=False), seed=0)
    fresh = critic_and_keys(agent, starts=8)
    assert not fresh["diverged"] and abs(fresh["q_mean"]) < fresh["q_bound"] / 100
    assert all(key["saturated_share"] == 0.0 for key in fresh["keys"].values())
    with torch.no_grad():
        agent.actor.head.out.bias[3] = 10.0  # brake
        agent.critic.merge[-1].bias += 2 * fresh["q_bound"]
    broken = critic_and_keys(agent, starts=8)
    assert broken["diverged"] and broken["keys"]["brake"]["saturated_share"] == 1.0
    assert broken["keys"]["accelerate"]["saturated_share"] == 0.0
    with torch.no_grad():
        agent.critic.merge[-1].bias -= 4 * fresh["q_bound"]  # as far below 0 as no policy can lose
    assert critic_and_keys(agent, starts=8)["diverged"]
