"""`train-baseline --algo bc`: behaviour cloning, the supervised Table III baseline.

The demonstrator's actions (:mod:`.demos`: its ``expert_actions``) are regressed by the actor of a Stable-Baselines3
SAC policy used deterministically (``tanh`` of a linear layer on the 2 x 256 MLP, scaled to the action bounds):
mean squared error in the policy's [-1, 1] action units, Adam, mini-batches. One episode in five is held out, and
training stops at convergence: when the held-out error has not improved by ``bc_min_improvement`` (relative) for
``bc_patience`` epochs, or at ``steps`` gradient updates; the best held-out epoch's weights are kept. Fast
(minutes), so it is not resumable: it starts over. Notes: docs/notes/overtaking.md, "baselines.py".
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from vision_rl.overtaking.baseline_run import (
    HIDDEN_UNITS,
    METRICS_NAME,
    BaselineError,
    Progress,
    RunFolder,
    TrainBaselineConfig,
    append_metrics,
    baseline_fingerprint,
    policy_spec,
    total_steps,
)
from vision_rl.overtaking.config import race_config
from vision_rl.overtaking.demos import OBS_DIM, Demos, load_demos_for
from vision_rl.training.artifact import MODEL_NAME, SIDECAR_NAME, sac_policy
from vision_rl.training.persist import write_agent_state
from vision_rl.training.sac import torch_device


def actor_mean(policy, obs: torch.Tensor) -> torch.Tensor:
    """The deterministic action of an SB3 SAC policy in its [-1, 1] units: tanh of the actor's mean."""
    mean, _, _ = policy.actor.get_action_dist_params(obs)
    return torch.tanh(mean)


def split_episodes(demos: Demos, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train, held-out) transition indices: one episode in five held out (at least one when there are two or
    more episodes; with one episode, its last 10 %)."""
    slices = demos.episode_slices()
    if len(slices) >= 2:
        order = np.random.default_rng(seed).permutation(len(slices))
        n_val = max(1, len(slices) // 5)
        val = np.concatenate([np.arange(slices[i].start, slices[i].stop) for i in order[:n_val]])
    else:
        n = demos.n_transitions
        val = np.arange(n - max(1, n // 10), n)
    train = np.setdiff1d(np.arange(demos.n_transitions), val)
    if len(train) == 0:
        raise BaselineError(f"{demos.path}: too few transitions to hold some out ({demos.n_transitions})")
    return train, val


def smoothed_labels(demos: Demos, steps: int) -> np.ndarray:
    """The demonstrator's labels with the steering replaced by the mean of its last ``steps`` labels in the same
    episode (fewer at an episode's start). The AI held at 10 Hz alternates its steering from one step to the next
    (the wheel's lag and rate limit filter it out); an actor regressing the raw labels learns that alternation
    from the previous-steering input and, in closed loop, swings to full lock."""
    labels = demos.expert_actions.astype(np.float64).copy()
    if steps <= 1:
        return labels
    for part in demos.episode_slices():
        steer = labels[part, 0]
        total = np.concatenate([[0.0], np.cumsum(steer)])
        idx = np.arange(len(steer))
        lo = np.maximum(idx + 1 - steps, 0)
        labels[part, 0] = (total[idx + 1] - total[lo]) / (idx + 1 - lo)
    return labels


def fit_bc(
    policy,
    observations: np.ndarray,
    actions_scaled: np.ndarray,
    train_idx: np.ndarray,
    val_idx: np.ndarray,
    *,
    learning_rate: float,
    batch_size: int,
    max_updates: int,
    max_epochs: int,
    patience: int,
    min_improvement: float,
    seed: int,
    on_epoch: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """Regress ``actions_scaled`` (in [-1, 1]) on ``observations`` with the actor of ``policy`` (MSE, Adam) until
    the held-out error stops improving; ``policy`` ends with the best held-out epoch's weights. Returns the fit's
    figures (epochs, updates, best and last errors, why it stopped)."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    device = policy.device
    obs = torch.as_tensor(observations, dtype=torch.float32, device=device)
    act = torch.as_tensor(np.clip(actions_scaled, -1.0, 1.0), dtype=torch.float32, device=device)
    params = list(policy.actor.latent_pi.parameters()) + list(policy.actor.mu.parameters())
    optimizer = torch.optim.Adam(params, lr=learning_rate)

    def held_out_mse() -> np.ndarray:
        with torch.no_grad():
            err = actor_mean(policy, obs[val_idx]) - act[val_idx]
            return (err**2).mean(dim=0).cpu().numpy()

    best = float("inf")
    best_state = {k: v.clone() for k, v in policy.state_dict().items()}
    best_epoch, since_best, updates, epoch = 0, 0, 0, 0
    stop = "max epochs"
    policy.set_training_mode(True)
    for epoch in range(1, max_epochs + 1):
        order = rng.permutation(train_idx)
        losses = []
        for start in range(0, len(order), batch_size):
            batch = torch.as_tensor(order[start : start + batch_size], device=device)
            loss = ((actor_mean(policy, obs[batch]) - act[batch]) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            losses.append(float(loss.detach()))
            updates += 1
            if updates >= max_updates:
                break
        per_action = held_out_mse()
        val = float(per_action.mean())
        record = {
            "epoch": epoch,
            "updates": updates,
            "train_mse": float(np.mean(losses)),
            "held_out_mse": val,
            "held_out_mse_steer": float(per_action[0]),
            "held_out_mse_omega": float(per_action[1]),
        }
        if val < (1.0 - min_improvement) * best:
            best, best_epoch, since_best = val, epoch, 0
            best_state = {k: v.clone() for k, v in policy.state_dict().items()}
        else:
            since_best += 1
        record["best_held_out_mse"] = best
        if on_epoch is not None:
            on_epoch(record)
        if since_best >= patience:
            stop = f"converged: no {min_improvement:.0%} better held-out error for {patience} epochs"
            break
        if updates >= max_updates:
            stop = "max updates"
            break
    policy.load_state_dict(best_state)
    policy.set_training_mode(False)
    return {"epochs": epoch, "updates": updates, "best_epoch": best_epoch, "best_held_out_mse": best, "stopped": stop}


def train_bc(cfg: TrainBaselineConfig, progress: Progress | None = None) -> dict[str, Any]:
    """Behaviour cloning on the demonstrations (see the module's docstring); writes the run folder."""
    racing = race_config(cfg.racing.track, cfg.racing.car)
    demos = load_demos_for(cfg.demos, cfg.racing.track, cfg.racing.car)
    run = RunFolder(cfg, demos)
    if run.record.get("status") == "done" and run.record.get("steps") == total_steps(cfg):
        return {**run.record, "out": str(run.out), "trained_now": False}
    (run.out / METRICS_NAME).unlink(missing_ok=True)  # bc starts over: its epochs are its own
    torch.set_num_threads(1)
    device = torch_device(cfg.device)
    torch.manual_seed(cfg.seed)  # the network's initial weights too: a seed gives one policy
    policy = sac_policy(OBS_DIM, list(HIDDEN_UNITS), device)
    train_idx, val_idx = split_episodes(demos, cfg.seed)
    scaled = policy.scale_action(smoothed_labels(demos, cfg.bc_smooth_steps)).astype(np.float32)
    max_epochs = cfg.bc_max_epochs
    t0 = time.perf_counter()

    def on_epoch(record: dict[str, Any]) -> None:
        record["train_time_s"] = round(time.perf_counter() - t0, 2)
        append_metrics(run.out, record)
        if progress is not None:
            progress("epoch", record["epoch"], max_epochs, record)

    interrupted = False
    try:
        fit = fit_bc(
            policy,
            demos.observations,
            scaled,
            train_idx,
            val_idx,
            learning_rate=cfg.sac.learning_rate or 1e-3,
            batch_size=cfg.sac.batch_size or 256,
            max_updates=total_steps(cfg),
            max_epochs=max_epochs,
            patience=cfg.bc_patience,
            min_improvement=cfg.bc_min_improvement,
            seed=cfg.seed,
            on_epoch=on_epoch,
        )
    except KeyboardInterrupt:
        interrupted = True
        fit = {"stopped": "interrupted"}
    train_time_s = time.perf_counter() - t0
    if interrupted:
        run.update(status="interrupted")
        return {**run.record, "out": str(run.out), "trained_now": True, "interrupted": True}
    fingerprint = baseline_fingerprint(racing, "bc")
    state = {
        "policy": policy.state_dict(),
        "optimizers": {},
        "counters": {"num_timesteps": 0, "n_updates": int(fit["updates"]), "episode_num": 0},
    }
    sha = write_agent_state(state, run.out / MODEL_NAME, fingerprint)
    normalizer = _demo_normalizer(demos)
    policy_spec(cfg, racing, normalizer, fingerprint, sha, _recipe(cfg), 0, train_time_s, run.settings).write(
        run.out / SIDECAR_NAME
    )
    rmse = np.sqrt(fit["best_held_out_mse"])
    run.update(
        status="done",
        steps=total_steps(cfg),
        fit=fit,
        train_time_s=round(train_time_s, 2),
        demos={
            "path": str(demos.path),
            "sha256": demos.sha256,
            "n_transitions": demos.n_transitions,
            "n_train": len(train_idx),
            "n_held_out": len(val_idx),
        },
        held_out_rmse_scaled=float(rmse),
        updates_per_s=round(fit["updates"] / max(train_time_s, 1e-9), 1),
    )
    return {**run.record, "out": str(run.out), "policy": str(run.out), "trained_now": True, "interrupted": False}


def _recipe(cfg: TrainBaselineConfig) -> dict[str, Any]:
    return {
        "learning_rate": cfg.sac.learning_rate or 1e-3,
        "batch_size": cfg.sac.batch_size or 256,
        "loss": "mse of tanh actions in [-1, 1]",
        "steering_label": f"mean of the demonstrator's last {cfg.bc_smooth_steps} labels",
    }


def _demo_normalizer(demos: Demos):
    from vision_rl.envs.observations import ObsNormalizer

    return ObsNormalizer.from_dict(demos.meta["normalizer"])


__all__ = ["actor_mean", "fit_bc", "smoothed_labels", "split_episodes", "train_bc"]
