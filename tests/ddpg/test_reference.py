"""The reference check in brief: the project's DDPG agent (the state actor's layers, update, noise and replay, through
a VectorTask) learns Pendulum-v1 in a few thousand steps; the seam that lets a flat vector drive it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vision_rl.ddpg.agent import DDPGAgent, DDPGError, DDPGHyper, FrameReplay, VectorTask
from vision_rl.ddpg.config import REFERENCE_HYPER, ReferenceRun
from vision_rl.ddpg.reference import TaskScaling, run_reference

#: The test's run: seed 0, batch-norm (the paper's networks), 3,000 updates at batch 64; measured: the first three
#: episodes -1,437 on average, the final evaluation -88 (a gain of 1,349) in 88 s on a loaded 2-core machine.
QUICK_RUN = ReferenceRun(
    algo="ours-bn",
    seed=0,
    steps=3_500,
    learning_starts=500,
    eval_every_steps=0,
    final_eval_episodes=3,
)
#: The final return must beat the first three episodes' mean by this much; with the actor's gradient zeroed (no
#: learning) the same run gained 198 (the first episodes -1,420, the final evaluation -1,223).
MIN_GAIN = 600.0


def test_vector_task_drives_the_state_actor_and_critic() -> None:
    task = VectorTask((0.0, 0.0, 0.0), (1.0, 1.0, 8.0), action_dim=2)
    agent = DDPGAgent(REFERENCE_HYPER, task, n_cars=1, seed=0)
    rng = np.random.default_rng(0)
    actions = agent.act({"state": rng.normal(size=(1, 3)).astype(np.float32)}, explore=True)
    assert actions.shape == (1, 2) and np.all(np.abs(actions) <= 1.0)
    buffer = FrameReplay(100, 1, None, {"state": 3}, action_dim=2)
    buffer.start({"state": np.zeros((1, 3), np.float32)})
    for step in range(40):
        done = np.array([step % 10 == 9])
        reset = {"state": np.zeros((1, 3), np.float32)} if done[0] else None
        buffer.add(actions, np.ones(1, np.float32), done, {"state": np.full((1, 3), step, np.float32)}, done, reset)
    batch = buffer.sample(16, rng)
    assert batch["obs"]["state"].shape == (16, 3) and batch["action"].shape == (16, 2)
    losses = agent.update(batch)
    assert all(np.isfinite(float(v)) for v in losses.values())
    with pytest.raises(DDPGError, match="state-actor"):
        DDPGAgent(DDPGHyper(variant="asymmetric"), task)


def test_task_scaling_maps_actions_onto_the_bounds() -> None:
    import gymnasium as gym

    scaling = TaskScaling.of(gym.make("Pendulum-v1"))
    assert scaling.obs_scale == (1.0, 1.0, 8.0) and scaling.obs_offset == (0.0, 0.0, 0.0)
    np.testing.assert_allclose(scaling.to_env(np.array([-1.0, 0.0, 1.0])), [-2.0, 0.0, 2.0])


def _gain(record: dict) -> float:
    first = np.mean([e["return"] for e in record["episodes"][:3]])
    return record["final_return"] - first


@pytest.mark.slow
def test_the_agent_learns_pendulum() -> None:
    torch.set_num_threads(1)
    record = run_reference(QUICK_RUN)
    assert _gain(record) > MIN_GAIN, f"no learning: final {record['final_return']:.0f}, gain {_gain(record):.0f}"


def test_a_run_of_an_unknown_task_or_algorithm_is_refused_before_anything_is_made() -> None:
    with pytest.raises(DDPGError, match="'Nope-v0' is not a registered Gymnasium id"):
        ReferenceRun(task="Nope-v0")
    with pytest.raises(DDPGError, match="algo must be one of"):
        ReferenceRun(algo="ppo")
