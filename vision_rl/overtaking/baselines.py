"""`train-baseline`: the overtaking paper's Table III baselines on the single-car race (the curriculum's stage 1:
alone, Eq. 1 with ``c_w`` 0.005, the 96-D ``overtaking`` observation), all with the paper's network, an MLP of
2 x 256 ReLU units.

- **bc** (behaviour cloning): supervised regression of the demonstrator's actions (:mod:`.demos`: its
  ``expert_actions``, which differ from the applied actions only in a noise-injected recording) by the actor of a
  Stable-Baselines3 SAC policy used deterministically: ``tanh`` of a linear layer on the 2 x 256 MLP, scaled to
  the action bounds. Mean squared error in the policy's [-1, 1] action units, Adam, mini-batches; one episode in
  five is held out, and training stops at convergence: when the held-out error has not improved by
  ``bc_min_improvement`` (relative) for ``bc_patience`` epochs, or at ``steps`` gradient updates. The weights of
  the best held-out epoch are kept. Fast (minutes), so it is not resumable: it starts over.
- **gail**: Generative Adversarial Imitation Learning with an off-policy learner. A discriminator ``D(o, a)``
  (the same 2 x 256 MLP, one logit) learns by logistic regression to tell the demonstrations' (observation,
  action) pairs (label 1) from the learner's (label 0, drawn from its replay buffer); the learner is SB3's SAC
  whose reward is the discriminator's log-odds ``log D - log(1 - D)`` (its logit, clipped to +-``REWARD_CLIP``),
  recomputed with the current discriminator whenever a batch is sampled (:class:`GAILReplayBuffer`), so no stored
  reward goes stale. The discriminator takes ``gail_disc_updates`` steps every ``gail_disc_every_steps``
  transitions. The ``imitation`` library (1.0.1) was not used: ``pip install --dry-run imitation`` here would
  downgrade gymnasium 1.4.0 to 0.29.1 and Stable-Baselines3 2.9.2 to 2.2.1.
- **td3**: SB3's TD3 with Gaussian exploration noise (``td3_noise`` of each action's half range), the same
  network, and the same recipe and budget as our SAC stage 1 (train-overtaking's ``cpu`` preset: batch, buffer,
  random start steps, learning rate, gamma, tau, one update per vector step, 20 cars, 1M steps).
- **sac**: SB3's SAC as train-overtaking's stage 1, for a fixed number of steps (no stopping criterion).
- **dreamer** (the PlaNet row): PlaNet's recurrent world model with Dreamer's actor and value learned in
  imagination instead of PlaNet's per-step CEM planner (:mod:`.dreamer` says why), one update of all three every
  ``dreamer_train_every_steps`` transitions after the preset's random start steps, the preset's buffer size spread
  over the cars' sequences; ``batch_size`` and ``learning_rate`` override its sequences per update and its world
  model's step size.

The run folder (``--out``, default ``runs/baselines/<algo>-<track>-<car>-s<seed>``): ``policy.pt`` (an agent file
without pickle, :mod:`vision_rl.training.persist`, whose fingerprint adds ``algo`` to the policy fingerprint;
gail's holds the discriminator too) + ``policy.json`` (the policy sidecar, :class:`~.artifact.PolicySpec`),
``baseline.json`` (settings, status, figures), ``metrics.jsonl`` (bc: one line per epoch; online: one per periodic
protocol evaluation), and for the online algorithms ``replay_buffer.npz``. bc, gail and sac policies load with
:func:`~.artifact.load_policy` like every SAC policy; :func:`load_baseline` loads all four, checking the algorithm.

The online algorithms save light checkpoints (weights, optimisers, counters) every ``checkpoint_every_min``
minutes, full ones (with the buffer) every ``checkpoint_every_steps`` and on Ctrl-C (SIGTERM where the command
maps it); the same command continues a run from what it saved (``--steps`` may grow), other settings are refused.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.vec_env import VecMonitor
from torch import nn

from vision_rl.envs.core import RacingConfig
from vision_rl.envs.racing_env import action_space
from vision_rl.envs.vector import make_sb3_vec_env
from vision_rl.evaluation.protocol import time_laps
from vision_rl.files import atomic_write, write_json
from vision_rl.overtaking.curriculum import BUDGETS
from vision_rl.overtaking.demos import OBS_DIM, OBSERVATION, Demos, load_demos_for, race_config
from vision_rl.overtaking.dreamer import DreamerAgent, DreamerRecipe, SequenceReplay
from vision_rl.sim.track_library import load_track
from vision_rl.training.artifact import (
    BUFFER_NAME,
    MODEL_NAME,
    SIDECAR_NAME,
    LoadedPolicy,
    PolicyDriver,
    PolicyError,
    PolicySpec,
    check_fingerprint,
    load_policy,
    policy_fingerprint,
    racing_config_to_dict,
    resolve_policy_paths,
    sac_policy,
)
from vision_rl.training.interrupts import learn_between_interrupts
from vision_rl.training.persist import (
    ArtifactError,
    agent_state,
    load_buffer,
    read_agent,
    restore_agent,
    save_buffer,
    write_agent_state,
)
from vision_rl.training.sac import PRESETS, SACPreset, SaveClock, next_multiple, torch_device

ALGOS = ("bc", "gail", "td3", "sac", "dreamer")
ONLINE = ("gail", "td3", "sac", "dreamer")
#: The paper's network for every method (section IV-B): 2 hidden layers of 256 ReLU units.
HIDDEN_UNITS = (256, 256)
RUN_NAME = "baseline.json"
METRICS_NAME = "metrics.jsonl"
RUN_FORMAT = "vision_rl.baseline_run"
#: The discriminator's logit (the learner's reward) is clipped to this, so one confident pair cannot dominate.
REWARD_CLIP = 10.0
#: bc's default cap on gradient updates (it normally stops earlier, at convergence).
BC_DEFAULT_STEPS = 200_000


class BaselineError(ValueError):
    """A baseline run or policy that cannot be used as asked; the message says why."""


@dataclass(frozen=True)
class TrainBaselineConfig:
    """A Table III baseline (bc, gail, td3, sac or dreamer) on the single-car race, MLP 2 x 256, the 96-D
    observation."""

    algo: str = "bc"
    """bc, gail, td3, sac or dreamer (the PlaNet row)."""
    steps: int = 0
    """bc: cap on gradient updates (0: 200k; it stops at convergence); online: environment steps over all cars
    (0: our SAC stage 1's budget, 1M)."""
    seed: int = 0
    """Seed of the networks, exploration, start points and the bc split."""
    demos: str = "runs/demos/ai.npz"
    """Demonstrations (record-demos) for bc and gail."""
    track: str = "expressway"
    """Track: built-in name, random:SEED or CSV path (the demonstrations' own)."""
    car: str = "tt_cup"
    """Car preset (the paper's Audi TT Cup: tt_cup)."""
    cars: int = 20
    """Online algorithms: cars sampled at once in one world (the paper's 20)."""
    out: str = ""
    """Run folder (default runs/baselines/<algo>-<track>-<car>-s<seed>)."""
    force: bool = False
    """Delete the run folder and start over."""
    preset: str = "cpu"
    """Online recipe: cpu (our SAC stage 1's) or paper (Table II)."""
    episode_s: float = 100.0
    """Training episode length, s (1,000 steps at 10 Hz)."""
    learning_rate: float = 0.0
    """Override the preset's (online) or bc's 1e-3 learning rate (0: keep)."""
    batch_size: int = 0
    """Override the preset's (online) or bc's 256 batch size (0: keep)."""
    buffer_size: int = 0
    """Override the preset's replay buffer size (0: keep)."""
    learning_starts: int = -1
    """Override the preset's random start steps (-1: keep)."""
    eval_every_steps: int = 100_000
    """Online: evaluate on the lap-time protocol every N steps (0: off)."""
    eval_seeds: int = 1
    """Start seeds of each periodic evaluation."""
    eval_laps: int = 2
    """Laps of each periodic evaluation (the last is scored)."""
    eval_time_limit_s: float = 0.0
    """Time limit of each periodic evaluation, s (0: the protocol's)."""
    checkpoint_every_steps: int = 200_000
    """Online: save weights and replay buffer every N steps (0: off)."""
    checkpoint_every_min: float = 10.0
    """Online: save weights, optimisers and counters every N minutes (0: off)."""
    bc_patience: int = 10
    """bc: stop after this many epochs without a better held-out error."""
    bc_min_improvement: float = 0.01
    """bc: an epoch is better when its held-out error is below (1 - this) x the best so far."""
    bc_max_epochs: int = 500
    """bc: cap on epochs."""
    gail_disc_every_steps: int = 1_000
    """gail: discriminator updates every N transitions."""
    gail_disc_updates: int = 10
    """gail: discriminator gradient steps each time."""
    gail_disc_batch: int = 256
    """gail: expert and learner pairs per discriminator step (each)."""
    gail_disc_lr: float = 3e-4
    """gail: discriminator learning rate."""
    td3_noise: float = 0.1
    """td3: std of the Gaussian exploration noise, as a share of each action's half range."""
    dreamer_train_every_steps: int = 100
    """dreamer: transitions (over all cars) per update of the world model, actor and value."""
    dreamer_sequence_steps: int = 32
    """dreamer: control steps per training sequence."""
    device: str = "auto"
    """Torch device: auto, cpu or cuda."""


def default_out(cfg: TrainBaselineConfig) -> Path:
    track = cfg.track.replace("random:", "random-")
    if track.endswith(".csv") or os.sep in track:
        track = Path(track).stem
    return Path("runs") / "baselines" / f"{cfg.algo}-{track}-{cfg.car}-s{cfg.seed}"


def check_config(cfg: TrainBaselineConfig) -> None:
    """One clear line for a bad option, before anything is built or written."""
    if cfg.algo not in ALGOS:
        hint = "; PlaNet's row is trained as its successor, --algo dreamer" if cfg.algo.lower() == "planet" else ""
        raise ValueError(f"--algo must be one of {', '.join(ALGOS)}, got {cfg.algo!r}{hint}")
    if cfg.preset not in PRESETS:
        raise ValueError(f"--preset must be one of {sorted(PRESETS)}, got {cfg.preset!r}")
    checks = {
        "steps": cfg.steps >= 0,
        "cars": 1 <= cfg.cars <= 1000,
        "episode_s": cfg.episode_s >= 0.1,
        "learning_rate": cfg.learning_rate >= 0,
        "batch_size": cfg.batch_size >= 0,
        "buffer_size": cfg.buffer_size >= 0,
        "eval_every_steps": cfg.eval_every_steps >= 0,
        "eval_seeds": cfg.eval_seeds >= 1,
        "eval_laps": cfg.eval_laps >= 1,
        "eval_time_limit_s": cfg.eval_time_limit_s >= 0,
        "checkpoint_every_steps": cfg.checkpoint_every_steps >= 0,
        "checkpoint_every_min": cfg.checkpoint_every_min >= 0,
        "bc_patience": cfg.bc_patience >= 1,
        "bc_min_improvement": 0 <= cfg.bc_min_improvement < 1,
        "bc_max_epochs": cfg.bc_max_epochs >= 1,
        "gail_disc_every_steps": cfg.gail_disc_every_steps >= 1,
        "gail_disc_updates": cfg.gail_disc_updates >= 0,
        "gail_disc_batch": cfg.gail_disc_batch >= 1,
        "gail_disc_lr": cfg.gail_disc_lr > 0,
        "td3_noise": cfg.td3_noise >= 0,
        "dreamer_train_every_steps": cfg.dreamer_train_every_steps >= 1,
        "dreamer_sequence_steps": cfg.dreamer_sequence_steps >= 2,
    }
    bad = [name for name, ok in checks.items() if not ok]
    if bad:
        raise ValueError(f"--{bad[0].replace('_', '-')} {getattr(cfg, bad[0])} is out of range")
    if cfg.algo in ONLINE:
        preset = resolve_recipe(cfg)
        if total_steps(cfg) <= preset.learning_starts:
            raise ValueError(
                f"--steps {total_steps(cfg)} is not above the {preset.learning_starts} random start "
                "steps (--learning-starts): it would make no update"
            )
        if preset.buffer_size < cfg.cars:
            raise ValueError(f"--buffer-size {preset.buffer_size} holds less than one step of {cfg.cars} cars")


def resolve_recipe(cfg: TrainBaselineConfig) -> SACPreset:
    """The online recipe: the preset with the options' overrides, always the paper's 2 x 256 network."""
    base = PRESETS[cfg.preset]
    return dataclasses.replace(
        base,
        hidden_units=HIDDEN_UNITS,
        learning_rate=cfg.learning_rate or base.learning_rate,
        batch_size=cfg.batch_size or base.batch_size,
        buffer_size=cfg.buffer_size or base.buffer_size,
        learning_starts=base.learning_starts if cfg.learning_starts < 0 else cfg.learning_starts,
    )


def dreamer_recipe(cfg: TrainBaselineConfig) -> DreamerRecipe:
    """Dreamer's recipe with the options' overrides (sequences per update, the world model's step size)."""
    base = DreamerRecipe(hidden_units=HIDDEN_UNITS)
    return dataclasses.replace(
        base,
        batch_sequences=cfg.batch_size or base.batch_sequences,
        sequence_steps=cfg.dreamer_sequence_steps,
        model_lr=cfg.learning_rate or base.model_lr,
    )


def total_steps(cfg: TrainBaselineConfig) -> int:
    if cfg.steps:
        return cfg.steps
    return BC_DEFAULT_STEPS if cfg.algo == "bc" else BUDGETS[cfg.preset].stage1_max_steps


def baseline_fingerprint(config: RacingConfig, algo: str) -> dict[str, Any]:
    """The policy fingerprint of :func:`~.artifact.policy_fingerprint` plus the algorithm."""
    return {**policy_fingerprint(config, OBSERVATION, OBS_DIM, None), "algo": algo}


def settings_of(cfg: TrainBaselineConfig, demos: Demos | None) -> dict[str, Any]:
    """What a run folder must keep when it is continued (``steps`` may grow)."""
    keep = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in ("steps", "out", "force", "device")}
    if cfg.algo in ONLINE:
        keep["recipe"] = json.loads(json.dumps(dataclasses.asdict(resolve_recipe(cfg))))
    if cfg.algo == "dreamer":
        keep["dreamer"] = json.loads(json.dumps(dataclasses.asdict(dreamer_recipe(cfg))))
    if demos is not None:
        keep["demos_sha256"] = demos.sha256
    return keep


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise BaselineError(f"{path}: unreadable ({exc}); start over with --force") from None
    if not isinstance(data, dict) or data.get("format") != RUN_FORMAT:
        raise BaselineError(f"{path}: not a train-baseline record; start over with --force")
    return data


def _eval_figures(summary: dict[str, Any]) -> dict[str, Any]:
    """A periodic evaluation's protocol figures in metrics.jsonl: the best lap, the starts finished and why each
    start did not (None where it finished)."""
    return {
        "lap_time_s": summary["best_lap_time_s"],
        "finished": summary["n_finished"],
        "dnf_reasons": [seed["dnf_reason"] for seed in summary["seeds"]],
    }


def _append_metrics(folder: Path, record: dict[str, Any]) -> None:
    with open(folder / METRICS_NAME, "a") as f:
        f.write(json.dumps(record) + "\n")


#: ``progress(phase, done, total, figures)``: bc reports epochs, the online algorithms environment steps.
Progress = Callable[[str, int, int, "dict[str, Any] | None"], None]


# ------------------------------------------------------------------------------------------------- the run folder


class _RunFolder:
    """``baseline.json`` of a run: created fresh, or continued with the same settings."""

    def __init__(self, cfg: TrainBaselineConfig, demos: Demos | None) -> None:
        self.cfg = cfg
        self.out = Path(cfg.out) if cfg.out else default_out(cfg)
        self.settings = settings_of(cfg, demos)
        path = self.out / RUN_NAME
        if cfg.force and self.out.exists():
            shutil.rmtree(self.out)
        if path.is_file():
            record = _read_json(path)
            recorded = record.get("settings") or {}
            for key, want in self.settings.items():
                if recorded.get(key) != want:
                    raise BaselineError(
                        f"{path} was started with {key} = {recorded.get(key)!r}, not {want!r}: use "
                        "its settings, another --out, or --force to start over"
                    )
            self.record = record
        else:
            if self.out.exists() and any(self.out.iterdir()):
                raise BaselineError(f"{self.out} is not empty and holds no {RUN_NAME}: give another --out")
            self.record = {"format": RUN_FORMAT, "algo": cfg.algo, "settings": self.settings, "status": "new"}
            write_json(path, self.record)

    def update(self, **fields: Any) -> None:
        self.record.update(fields)
        write_json(self.out / RUN_NAME, self.record)


def _spec(
    cfg: TrainBaselineConfig,
    racing: RacingConfig,
    normalizer,
    fingerprint: dict[str, Any],
    sha256: str,
    recipe: dict[str, Any],
    num_timesteps: int,
    train_time_s: float,
    settings: dict[str, Any],
) -> PolicySpec:
    return PolicySpec(
        observation=OBSERVATION,
        racing_config=racing_config_to_dict(racing),
        obs_normalizer=normalizer.to_dict(),
        fingerprint=fingerprint,
        weights_sha256=sha256,
        model=MODEL_NAME,
        preset=cfg.preset,
        sac={**recipe, "hidden_units": list(HIDDEN_UNITS)},
        seed=cfg.seed,
        num_timesteps=int(num_timesteps),
        train_time_s=round(train_time_s, 2),
        train_config={**settings, "algo": cfg.algo},
    )


# ------------------------------------------------------------------------------------------------- bc


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
    racing = race_config(cfg.track, cfg.car)
    demos = load_demos_for(cfg.demos, cfg.track, cfg.car)
    run = _RunFolder(cfg, demos)
    if run.record.get("status") == "done" and run.record.get("steps") == total_steps(cfg):
        return {**run.record, "out": str(run.out), "trained_now": False}
    (run.out / METRICS_NAME).unlink(missing_ok=True)  # bc starts over: its epochs are its own
    torch.set_num_threads(1)
    device = torch_device(cfg.device)
    policy = sac_policy(OBS_DIM, list(HIDDEN_UNITS), device)
    train_idx, val_idx = split_episodes(demos, cfg.seed)
    scaled = policy.scale_action(demos.expert_actions.astype(np.float64)).astype(np.float32)
    max_epochs = cfg.bc_max_epochs
    t0 = time.perf_counter()

    def on_epoch(record: dict[str, Any]) -> None:
        record["train_time_s"] = round(time.perf_counter() - t0, 2)
        _append_metrics(run.out, record)
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
            learning_rate=cfg.learning_rate or 1e-3,
            batch_size=cfg.batch_size or 256,
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
    recipe = {
        "learning_rate": cfg.learning_rate or 1e-3,
        "batch_size": cfg.batch_size or 256,
        "loss": "mse of tanh actions in [-1, 1]",
    }
    _spec(cfg, racing, normalizer, fingerprint, sha, recipe, 0, train_time_s, run.settings).write(
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


def _demo_normalizer(demos: Demos):
    from vision_rl.envs.observations import ObsNormalizer

    return ObsNormalizer.from_dict(demos.meta["normalizer"])


# ------------------------------------------------------------------------------------------------- gail


class Discriminator(nn.Module):
    """``D(o, a)``: a logit that the (observation, scaled action) pair is the expert's; MLP 2 x 256 ReLU."""

    def __init__(self, obs_dim: int = OBS_DIM, action_dim: int = 2, hidden_units: tuple[int, ...] = HIDDEN_UNITS):
        super().__init__()
        layers: list[nn.Module] = []
        width = obs_dim + action_dim
        for units in hidden_units:
            layers += [nn.Linear(width, units), nn.ReLU()]
            width = units
        layers.append(nn.Linear(width, 1))
        self.net = nn.Sequential(*layers)

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([obs, action], dim=-1)).squeeze(-1)

    def reward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """The learner's reward: the log-odds ``log D - log(1 - D)`` (the logit), clipped to +-REWARD_CLIP."""
        with torch.no_grad():
            return self(obs, action).clamp(-REWARD_CLIP, REWARD_CLIP)


def discriminator_step(
    disc: Discriminator,
    optimizer: torch.optim.Optimizer,
    expert_obs: torch.Tensor,
    expert_act: torch.Tensor,
    learner_obs: torch.Tensor,
    learner_act: torch.Tensor,
) -> dict[str, float]:
    """One logistic-regression step: expert pairs labelled 1, learner pairs 0; returns loss and accuracies."""
    logits_e, logits_l = disc(expert_obs, expert_act), disc(learner_obs, learner_act)
    loss = nn.functional.binary_cross_entropy_with_logits(logits_e, torch.ones_like(logits_e)) + (
        nn.functional.binary_cross_entropy_with_logits(logits_l, torch.zeros_like(logits_l))
    )
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    return {
        "disc_loss": float(loss.detach()),
        "disc_acc_expert": float((logits_e > 0).float().mean()),
        "disc_acc_learner": float((logits_l < 0).float().mean()),
    }


class GAILReplayBuffer(ReplayBuffer):
    """A replay buffer whose sampled rewards are the discriminator's current log-odds of (observation, action)
    (``discriminator`` set after construction; without one, the stored rewards)."""

    discriminator: Discriminator | None = None

    def _get_samples(self, batch_inds, env=None):
        samples = super()._get_samples(batch_inds, env)
        if self.discriminator is None:
            return samples
        reward = self.discriminator.reward(samples.observations, samples.actions).reshape(-1, 1)
        return samples._replace(rewards=reward.to(samples.rewards.dtype))


class GAILUpdater:
    """The discriminator, its optimiser and its updates: expert pairs against pairs drawn from the learner's
    replay buffer (both with actions in the policy's [-1, 1] units, as SB3 stores them).

    Args:
        expert_obs, expert_actions_scaled: (N, obs_dim) and (N, action_dim) demonstration pairs.
        batch, updates, learning_rate: pairs of each kind per step, steps per :meth:`update`, Adam step size.
        seed: of the discriminator's weights and of the pairs drawn.
        hidden_units: the discriminator's MLP.
    """

    def __init__(
        self,
        expert_obs: np.ndarray,
        expert_actions_scaled: np.ndarray,
        *,
        batch: int,
        updates: int,
        learning_rate: float,
        seed: int,
        device: str = "cpu",
        hidden_units: tuple[int, ...] = HIDDEN_UNITS,
    ) -> None:
        self.batch, self.updates, self.device = batch, updates, device
        torch.manual_seed(seed)
        self.disc = Discriminator(expert_obs.shape[1], expert_actions_scaled.shape[1], hidden_units).to(device)
        self.optimizer = torch.optim.Adam(self.disc.parameters(), lr=learning_rate)
        self.expert_obs = torch.as_tensor(expert_obs, dtype=torch.float32, device=device)
        self.expert_act = torch.as_tensor(expert_actions_scaled, dtype=torch.float32, device=device)
        self.rng = np.random.default_rng(seed + 7)
        self.last: dict[str, float] = {}

    def update(self, buffer: ReplayBuffer) -> dict[str, float]:
        rows = buffer.buffer_size if buffer.full else buffer.pos
        if rows == 0:
            return {}
        batch = self.batch
        for _ in range(self.updates):
            e = torch.as_tensor(self.rng.integers(0, len(self.expert_obs), batch), device=self.device)
            r, k = self.rng.integers(0, rows, batch), self.rng.integers(0, buffer.n_envs, batch)
            lo = torch.as_tensor(buffer.observations[r, k], dtype=torch.float32, device=self.device)
            la = torch.as_tensor(buffer.actions[r, k], dtype=torch.float32, device=self.device)
            self.last = discriminator_step(self.disc, self.optimizer, self.expert_obs[e], self.expert_act[e], lo, la)
        return self.last

    def state(self) -> dict[str, Any]:
        return {"discriminator": self.disc.state_dict(), "discriminator_optimizer": self.optimizer.state_dict()}

    def restore(self, state: dict[str, Any], source: str) -> None:
        try:
            self.disc.load_state_dict(state["discriminator"])
            self.optimizer.load_state_dict(state["discriminator_optimizer"])
        except (KeyError, RuntimeError, ValueError) as exc:
            raise BaselineError(
                f"{source}: no discriminator that fits this gail run: {str(exc).splitlines()[0]}"
            ) from None


# ------------------------------------------------------------------------------------------------- online


class _OnlineLoop(BaseCallback):
    """Discriminator updates (gail), periodic evaluations, checkpoints and progress."""

    def __init__(self, session: _OnlineSession, progress: Progress | None) -> None:
        super().__init__()
        self.session, self.progress = session, progress
        cfg, start = session.cfg, session.start_steps
        self.next_eval = next_multiple(start, cfg.eval_every_steps)
        self.saves = SaveClock(start, cfg.checkpoint_every_steps, cfg.checkpoint_every_min)
        self.next_disc = next_multiple(start, cfg.gail_disc_every_steps) if session.gail is not None else None

    def _on_step(self) -> bool:
        n, session = self.num_timesteps, self.session
        if self.next_disc is not None and n >= self.next_disc:
            session.gail.update(self.model.replay_buffer)
            self.next_disc = next_multiple(n, session.cfg.gail_disc_every_steps)
        # As train-policy's loop: the evaluation at the last step waits for SB3's last update (evaluate_held_back).
        if self._eval_due() and n < session.end_steps:
            session.evaluate(self.model)
            self.next_eval = next_multiple(n, session.cfg.eval_every_steps)
        if self.progress is not None:
            self.progress("step", n, session.end_steps, session.last_eval)
        kind = self.saves.due(n)
        if kind is not None:
            session.save(self.model, buffer=kind == "full")
        return True

    def _eval_due(self) -> bool:
        return self.next_eval is not None and self.num_timesteps >= self.next_eval

    def evaluate_held_back(self) -> None:
        """After training: the evaluation due at the last step, of the weights that are saved, and its progress."""
        if self._eval_due():
            self.session.evaluate(self.model)
            if self.progress is not None:
                self.progress("step", self.num_timesteps, self.session.end_steps, self.session.last_eval)


class _OnlineSession:
    """One training session of td3, sac or gail in a run folder: fresh or continued."""

    def __init__(self, cfg: TrainBaselineConfig) -> None:
        self.cfg = cfg
        self.demos = load_demos_for(cfg.demos, cfg.track, cfg.car) if cfg.algo == "gail" else None
        self.run = _RunFolder(cfg, self.demos)
        self.recipe = resolve_recipe(cfg)
        self.device = torch_device(cfg.device)
        self.racing = race_config(cfg.track, cfg.car, cfg.cars, cfg.episode_s)
        self.fingerprint = baseline_fingerprint(self.racing, cfg.algo)
        self.end_steps = total_steps(cfg)
        self.last_eval: dict[str, Any] | None = None
        self.eval_driver: PolicyDriver | None = None
        self.gail: GAILUpdater | None = None
        self.frozen_train_time_s: float | None = None

    def build(self):
        cfg, recipe, out = self.cfg, self.recipe, self.run.out
        if recipe.torch_threads > 0:
            torch.set_num_threads(recipe.torch_threads)
        resumed = (out / SIDECAR_NAME).is_file() and (out / MODEL_NAME).is_file()
        spec = PolicySpec.read(out / SIDECAR_NAME) if resumed else None
        steps_before = spec.num_timesteps if spec is not None else 0
        self.venv = make_sb3_vec_env(self.racing, seed=cfg.seed + steps_before)
        if spec is not None:  # the numbers the policy was trained with
            self.venv.core.observer.normalizer = spec.normalizer
        self.normalizer = self.venv.core.observer.normalizer
        self.env = VecMonitor(self.venv)
        common = dict(
            learning_rate=recipe.learning_rate,
            buffer_size=recipe.buffer_size,
            learning_starts=recipe.learning_starts,
            batch_size=recipe.batch_size,
            tau=recipe.tau,
            gamma=recipe.gamma,
            train_freq=(recipe.train_freq_steps, "step"),
            gradient_steps=recipe.gradient_steps,
            policy_kwargs={"net_arch": list(HIDDEN_UNITS)},
            seed=cfg.seed + steps_before,
            device=self.device,
            verbose=0,
        )
        if cfg.algo == "td3":
            # SB3 adds the noise to the action in the policy's [-1, 1] units: a share of each half range.
            noise = NormalActionNoise(np.zeros(2), cfg.td3_noise * np.ones(2))
            model = TD3("MlpPolicy", self.env, action_noise=noise, **common)
        elif cfg.algo == "gail":
            model = SAC("MlpPolicy", self.env, replay_buffer_class=GAILReplayBuffer, **common)
        else:
            model = SAC("MlpPolicy", self.env, **common)
        # SB3's default logger makes an empty SB3-<date> folder in the temporary directory on every learn().
        model.set_logger(Logger(folder=None, output_formats=[]))
        if cfg.algo == "gail":
            assert self.demos is not None
            scaled = model.policy.scale_action(self.demos.expert_actions.astype(np.float64))
            self.gail = GAILUpdater(
                self.demos.observations,
                scaled,
                batch=cfg.gail_disc_batch,
                updates=cfg.gail_disc_updates,
                learning_rate=cfg.gail_disc_lr,
                seed=cfg.seed,
                device=self.device,
            )
            model.replay_buffer.discriminator = self.gail.disc
        self.train_time_before_s = spec.train_time_s if spec is not None else 0.0
        self.buffer_restored = 0
        if spec is not None:
            try:
                check_fingerprint(spec.fingerprint, self.fingerprint, str(out / SIDECAR_NAME))
                state = read_agent(out / spec.model, self.fingerprint, spec.weights_sha256)
                restore_agent(model, state, str(out / spec.model))
                if self.gail is not None:
                    self.gail.restore(state, str(out / spec.model))
                if (out / BUFFER_NAME).is_file():
                    self.buffer_restored = load_buffer(model.replay_buffer, out / BUFFER_NAME, self.fingerprint)
            except ArtifactError as exc:
                raise BaselineError(f"cannot continue {out}: {exc}") from None
            if self.buffer_restored == 0:  # never update on an empty buffer: refill it first
                model.learning_starts = model.num_timesteps + recipe.learning_starts
        self.start_steps = int(model.num_timesteps)
        self.session_start = time.perf_counter()
        return model

    @property
    def train_time_s(self) -> float:
        if self.frozen_train_time_s is not None:
            return self.frozen_train_time_s
        return self.train_time_before_s + time.perf_counter() - self.session_start

    def evaluate(self, model) -> dict[str, Any]:
        cfg = self.cfg
        t0 = time.perf_counter()
        if self.eval_driver is None:
            self.eval_driver = PolicyDriver.for_config(
                lambda obs: model.predict(obs, deterministic=True)[0], OBSERVATION, self.normalizer, None, self.racing
            )
        summary = time_laps(
            self.eval_driver, cfg.track, cfg.car, range(cfg.eval_seeds), cfg.eval_laps, cfg.eval_time_limit_s
        ).summary()
        eval_time_s = time.perf_counter() - t0
        self.session_start += eval_time_s  # evaluation time is not training time
        episodes = list(model.ep_info_buffer or [])
        record = {
            "num_timesteps": int(model.num_timesteps),
            "train_time_s": round(self.train_time_s, 2),
            "n_updates": int(getattr(model, "_n_updates", 0)),
            **_eval_figures(summary),
            "ep_rew_mean": float(np.mean([e["r"] for e in episodes])) if episodes else None,
            "eval_time_s": round(eval_time_s, 2),
        }
        if self.gail is not None:
            record.update(self.gail.last)
        _append_metrics(self.run.out, record)
        self.last_eval = record
        return record

    def save(self, model, buffer: bool) -> None:
        out = self.run.out
        state = agent_state(model)
        if self.gail is not None:
            state.update(self.gail.state())
        sha = write_agent_state(state, out / MODEL_NAME, self.fingerprint)
        recipe = json.loads(json.dumps(dataclasses.asdict(self.recipe)))
        if self.cfg.algo == "td3":
            recipe["action_noise_std_share"] = self.cfg.td3_noise
        _spec(
            self.cfg,
            self.racing,
            self.normalizer,
            self.fingerprint,
            sha,
            recipe,
            model.num_timesteps,
            self.train_time_s,
            self.run.settings,
        ).write(out / SIDECAR_NAME)
        if buffer and model.replay_buffer is not None:
            save_buffer(model.replay_buffer, out / BUFFER_NAME, self.fingerprint)
        self.run.update(
            status="running", num_timesteps=int(model.num_timesteps), train_time_s=round(self.train_time_s, 2)
        )

    def close(self) -> None:
        self.env.close()
        if self.eval_driver is not None:
            self.eval_driver.close()


def train_online(cfg: TrainBaselineConfig, progress: Progress | None = None) -> dict[str, Any]:
    """td3, sac or gail (see the module's docstring) up to ``steps``, continuing a run folder's saved state."""
    session = _OnlineSession(cfg)
    model = session.build()
    remaining = session.end_steps - int(model.num_timesteps)
    interrupted = False
    t0, steps0, updates0 = time.perf_counter(), int(model.num_timesteps), int(getattr(model, "_n_updates", 0))
    if remaining <= 0:  # already done up to these steps
        session.close()
        return {
            **session.run.record,
            "out": str(session.run.out),
            "policy": str(session.run.out),
            "interrupted": False,
            "trained_now": False,
        }
    try:
        if remaining > 0:
            if session.start_steps == 0:
                session.save(model, buffer=False)  # the run folder holds a loadable policy from the start
            loop = _OnlineLoop(session, progress)
            learn_between_interrupts(
                model, loop, total_timesteps=remaining, reset_num_timesteps=False, log_interval=None
            )
            loop.evaluate_held_back()
    except KeyboardInterrupt:
        interrupted = True
    wall_s = time.perf_counter() - t0
    session.frozen_train_time_s = round(session.train_time_s, 2)
    session.save(model, buffer=True)
    steps_now = int(model.num_timesteps) - steps0
    updates_now = int(getattr(model, "_n_updates", 0)) - updates0
    status = "interrupted" if interrupted else "done"
    session.run.update(status=status, steps=session.end_steps, num_timesteps=int(model.num_timesteps))
    session.close()
    return {
        **session.run.record,
        "out": str(session.run.out),
        "policy": str(session.run.out),
        "interrupted": interrupted,
        "trained_now": steps_now > 0,
        "buffer_restored": int(session.buffer_restored) * cfg.cars,
        "session": {
            "steps": steps_now,
            "updates": updates_now,
            "wall_s": round(wall_s, 2),
            "transitions_per_s": round(steps_now / wall_s, 1) if wall_s > 0 else None,
            "updates_per_s": round(updates_now / wall_s, 2) if wall_s > 0 else None,
        },
    }


# ------------------------------------------------------------------------------------------------- dreamer

SEQUENCE_BUFFER_FORMAT = "vision_rl.sequence_replay"


def save_sequence_replay(replay: SequenceReplay, path: Path, fingerprint: dict[str, Any]) -> str:
    """The replay's filled rows (oldest first per car) as ``.npz`` without pickle; returns the file's SHA-256."""
    meta = {"format": SEQUENCE_BUFFER_FORMAT, "format_version": 1, "fingerprint": fingerprint, "n_cars": replay.n_cars}
    arrays = replay.arrays()

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            np.savez(f, meta=np.array(json.dumps(meta)), **arrays)

    return atomic_write(path, write)


def load_sequence_replay(replay: SequenceReplay, path: Path, fingerprint: dict[str, Any]) -> int:
    """Fill a fresh replay from :func:`save_sequence_replay`'s file; returns the rows restored. Refuses a damaged
    file, another fingerprint or another shape in one line (:class:`ArtifactError`)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            if meta.get("format") != SEQUENCE_BUFFER_FORMAT or meta.get("format_version") != 1:
                raise ArtifactError(f"{path}: not a vision_rl sequence-replay file of format 1")
            check_fingerprint(meta["fingerprint"], fingerprint, str(path))
            arrays = {name: data[name] for name in (*SequenceReplay.ARRAYS, "written")}
        return replay.restore(arrays)
    except ArtifactError:
        raise
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ArtifactError(f"{path}: damaged or mismatched sequence-replay file: {first}") from None


def _to_env_units(actions: np.ndarray) -> np.ndarray:
    """Actions in [-1, 1] to the environment's ``[steer rad, omega]``."""
    space = action_space()
    return space.low + 0.5 * (np.clip(actions, -1.0, 1.0) + 1.0) * (space.high - space.low)


class DreamerDriver(PolicyDriver):
    """A Dreamer agent as a protocol driver: its recurrent state restarts with every protocol run."""

    def __init__(self, agent: DreamerAgent, config: RacingConfig, normalizer, identity: dict[str, Any]) -> None:
        super().__init__(
            self._predict,
            OBSERVATION,
            normalizer,
            None,
            config.image_hw_px,
            config.control_dt_s,
            identity,
            config.frame_delay_s,
            config.steer_action,
            config.pedal_full_at,
            config.steer_change_share_of_range,
        )
        self.agent = agent

    def reset(self, world, car_ids: np.ndarray) -> None:
        super().reset(world, car_ids)
        self.carry = self.agent.initial(len(car_ids))
        self.first = np.ones(len(car_ids))

    def _predict(self, obs: np.ndarray) -> np.ndarray:
        action, self.carry = self.agent.act(self.carry, obs, self.first, explore=False)
        self.first = np.zeros(len(obs))
        return _to_env_units(action)


@dataclass
class LoadedDreamer:
    """A trained Dreamer agent ready to drive (as :class:`~.artifact.LoadedPolicy` for the protocol)."""

    agent: DreamerAgent
    spec: PolicySpec
    weights_path: Path
    spec_path: Path

    @property
    def config(self) -> RacingConfig:
        return self.spec.config

    def driver(self) -> DreamerDriver:
        spec = self.spec
        identity = {
            "driver": "policy",
            "observation": spec.observation,
            "policy": str(self.weights_path),
            "policy_sha256": spec.weights_sha256,
            "num_timesteps": spec.num_timesteps,
            "train_time_s": spec.train_time_s,
            "seed": spec.seed,
            "algo": "dreamer",
        }
        return DreamerDriver(self.agent, self.config, spec.normalizer, identity)


def _dreamer_from_spec(spec: PolicySpec, device: str = "cpu") -> DreamerAgent:
    recipe = DreamerRecipe(
        **{k: tuple(v) if isinstance(v, list) else v for k, v in spec.train_config["dreamer"].items()}
    )
    return DreamerAgent(OBS_DIM, 2, recipe, seed=spec.seed, device=device)


def train_dreamer(cfg: TrainBaselineConfig, progress: Progress | None = None) -> dict[str, Any]:
    """The Dreamer agent (see :mod:`.dreamer`) up to ``steps``, continuing a run folder's saved state."""
    run = _RunFolder(cfg, None)
    out, preset, recipe = run.out, resolve_recipe(cfg), dreamer_recipe(cfg)
    torch.set_num_threads(max(preset.torch_threads, 1))
    device = torch_device(cfg.device)
    racing = race_config(cfg.track, cfg.car, cfg.cars, cfg.episode_s)
    fingerprint = baseline_fingerprint(racing, "dreamer")
    end_steps, n_cars = total_steps(cfg), cfg.cars
    agent = DreamerAgent(OBS_DIM, 2, recipe, seed=cfg.seed, device=device)
    replay = SequenceReplay(max(preset.buffer_size // n_cars, recipe.sequence_steps), n_cars, OBS_DIM, 2)
    spec = PolicySpec.read(out / SIDECAR_NAME) if (out / SIDECAR_NAME).is_file() else None
    steps, train_time_before_s, rows_restored = 0, 0.0, 0
    if spec is not None:
        try:
            check_fingerprint(spec.fingerprint, fingerprint, str(out / SIDECAR_NAME))
            state = read_agent(out / spec.model, fingerprint, spec.weights_sha256)
            agent.load_state_dict(state)
            if (out / BUFFER_NAME).is_file():
                rows_restored = load_sequence_replay(replay, out / BUFFER_NAME, fingerprint)
        except ArtifactError as exc:
            raise BaselineError(f"cannot continue {out}: {exc}") from None
        except (KeyError, RuntimeError, ValueError) as exc:
            raise BaselineError(
                f"cannot continue {out}: its weights do not fit this recipe's networks: {str(exc).splitlines()[0]}"
            ) from None
        steps, agent.n_updates = int(state["counters"]["num_timesteps"]), int(state["counters"]["n_updates"])
        train_time_before_s = spec.train_time_s
    if steps >= end_steps:
        return {**run.record, "out": str(out), "policy": str(out), "interrupted": False, "trained_now": False}
    # Without its buffer a continued run first collects again what it would have learned from.
    learning_starts = preset.learning_starts if rows_restored or steps == 0 else steps + preset.learning_starts
    venv = make_sb3_vec_env(racing, seed=cfg.seed + steps)
    if spec is not None:  # the numbers the policy was trained with
        venv.core.observer.normalizer = spec.normalizer
    normalizer = venv.core.observer.normalizer
    rng = np.random.default_rng(cfg.seed + steps)
    updates_at_start, steps_at_start = agent.n_updates, steps
    session_start = time.perf_counter()
    eval_time_s = 0.0
    episode_returns: list[float] = []
    running_return = np.zeros(n_cars)
    last_eval: dict[str, Any] | None = None
    last_terms: dict[str, float] = {}

    def train_time_s() -> float:
        return train_time_before_s + time.perf_counter() - session_start - eval_time_s

    def save(buffer: bool) -> None:
        counters = {"num_timesteps": steps, "n_updates": agent.n_updates, "episode_num": 0}
        sha = write_agent_state({**agent.state_dict(), "counters": counters}, out / MODEL_NAME, fingerprint)
        recipe_record = {
            **json.loads(json.dumps(dataclasses.asdict(preset))),
            "hidden_units": list(HIDDEN_UNITS),
            "dreamer": json.loads(json.dumps(dataclasses.asdict(recipe))),
            "train_every_steps": cfg.dreamer_train_every_steps,
        }
        _spec(cfg, racing, normalizer, fingerprint, sha, recipe_record, steps, train_time_s(), run.settings).write(
            out / SIDECAR_NAME
        )
        if buffer:
            save_sequence_replay(replay, out / BUFFER_NAME, fingerprint)
        run.update(status="running", num_timesteps=steps, train_time_s=round(train_time_s(), 2))

    def evaluate() -> None:
        nonlocal eval_time_s, last_eval
        t0 = time.perf_counter()
        driver = DreamerDriver(agent, racing, normalizer, {"driver": "policy", "algo": "dreamer"})
        try:
            summary = time_laps(
                driver, cfg.track, cfg.car, range(cfg.eval_seeds), cfg.eval_laps, cfg.eval_time_limit_s
            ).summary()
        finally:
            driver.close()
        eval_time_s += time.perf_counter() - t0
        last_eval = {
            "num_timesteps": steps,
            "train_time_s": round(train_time_s(), 2),
            "n_updates": agent.n_updates,
            **_eval_figures(summary),
            "ep_rew_mean": float(np.mean(episode_returns[-100:])) if episode_returns else None,
            "eval_time_s": round(time.perf_counter() - t0, 2),
            **last_terms,
        }
        _append_metrics(out, last_eval)

    next_eval = next_multiple(steps, cfg.eval_every_steps)
    saves = SaveClock(steps, cfg.checkpoint_every_steps, cfg.checkpoint_every_min)
    all_cars = np.arange(n_cars)
    obs = venv.reset()
    carry = agent.initial(n_cars)
    first = np.ones(n_cars)
    replay.add(all_cars, obs, np.zeros((n_cars, 2)), np.zeros(n_cars), np.ones(n_cars), first)
    interrupted = False
    if steps == 0:
        save(buffer=False)  # the run folder holds a loadable policy from the start
    try:
        while steps < end_steps:
            action, carry = agent.act(carry, obs, first, explore=True)
            if steps < learning_starts:  # uniform random actions fill the replay first
                action = rng.uniform(-1.0, 1.0, (n_cars, 2))
                carry = (carry[0], torch.as_tensor(action, dtype=torch.float32, device=agent.device))
            next_obs, rewards, dones, infos = venv.step(_to_env_units(action))
            rows, continues = next_obs.copy(), np.ones(n_cars)
            done_cars = np.flatnonzero(dones)
            for i in done_cars:  # the last observation of an ended episode, and whether it ended by a crash
                rows[i] = infos[i]["terminal_observation"]
                continues[i] = float(infos[i].get("TimeLimit.truncated", False))
            replay.add(all_cars, rows, action, rewards, continues, np.zeros(n_cars))
            running_return += rewards
            if len(done_cars):
                replay.add(
                    done_cars,
                    next_obs[done_cars],
                    np.zeros((len(done_cars), 2)),
                    np.zeros(len(done_cars)),
                    np.ones(len(done_cars)),
                    np.ones(len(done_cars)),
                )
                episode_returns.extend(running_return[done_cars].tolist())
                running_return[done_cars] = 0.0
            first, obs = dones.astype(np.float64), next_obs
            steps += n_cars
            trained_steps = steps - max(learning_starts, steps_at_start)
            due = updates_at_start + max(trained_steps, 0) // cfg.dreamer_train_every_steps
            while agent.n_updates < due and replay.can_sample(recipe.sequence_steps):
                batch = replay.sample(rng, recipe.batch_sequences, recipe.sequence_steps, agent.device)
                last_terms = agent.update(batch)
            if next_eval is not None and steps >= next_eval:
                evaluate()
                next_eval = next_multiple(steps, cfg.eval_every_steps)
            if progress is not None:
                progress("step", steps, end_steps, last_eval)
            kind = saves.due(steps)
            if kind is not None:
                save(buffer=kind == "full")
    except KeyboardInterrupt:
        interrupted = True
    wall_s = time.perf_counter() - session_start
    save(buffer=True)
    venv.close()
    run.update(status="interrupted" if interrupted else "done", steps=end_steps, num_timesteps=steps)
    steps_now, updates_now = steps - steps_at_start, agent.n_updates - updates_at_start
    return {
        **run.record,
        "out": str(out),
        "policy": str(out),
        "interrupted": interrupted,
        "trained_now": steps_now > 0,
        "buffer_restored": rows_restored,
        "session": {
            "steps": steps_now,
            "updates": updates_now,
            "wall_s": round(wall_s, 2),
            "transitions_per_s": round(steps_now / wall_s, 1) if wall_s > 0 else None,
            "updates_per_s": round(updates_now / wall_s, 2) if wall_s > 0 else None,
        },
    }


def train_baseline(cfg: TrainBaselineConfig, progress: Progress | None = None) -> dict[str, Any]:
    """Train (or continue) one Table III baseline; returns its run record, the policy folder and the figures."""
    check_config(cfg)
    if cfg.algo == "bc":
        return train_bc(cfg, progress)
    if cfg.algo == "dreamer":
        return train_dreamer(cfg, progress)
    return train_online(cfg, progress)


# ------------------------------------------------------------------------------------------------- loading


def baseline_algo(spec: PolicySpec) -> str:
    """The algorithm of a policy sidecar: its fingerprint's ``algo``; a policy without one is SAC (train-policy
    and train-overtaking write SAC policies)."""
    return str(spec.fingerprint.get("algo", "sac"))


def load_baseline(
    path: str | os.PathLike[str], algo: str | None = None, device: str = "cpu"
) -> LoadedPolicy | LoadedDreamer:
    """A Table III policy (a train-baseline folder, or a train-overtaking stage-1 folder as SAC) ready to drive,
    refusing, in one line, a policy of another observation, network size or algorithm (``algo``), and every
    check of :func:`~.artifact.load_policy` (checksum, fingerprint against the track as it loads today)."""
    weights, sidecar = resolve_policy_paths(path)
    spec = PolicySpec.read(sidecar)
    if spec.observation != OBSERVATION:
        raise BaselineError(
            f"{sidecar}: the policy observes {spec.observation!r}, not the {OBS_DIM}-D {OBSERVATION!r} "
            "observation of the single-car race; give a train-baseline run"
        )
    recorded = baseline_algo(spec)
    if recorded not in ALGOS:
        raise BaselineError(f"{sidecar}: algorithm {recorded!r} is not one of {', '.join(ALGOS)}")
    if algo is not None and recorded != algo:
        raise BaselineError(f"{sidecar}: a {recorded} policy, not a {algo} one")
    units = spec.sac.get("hidden_units")
    if [int(u) for u in units or []] != list(HIDDEN_UNITS):
        raise BaselineError(f"{sidecar}: hidden units {units}, not the paper's {list(HIDDEN_UNITS)}")
    if recorded == "dreamer":
        expected = baseline_fingerprint(spec.config, "dreamer")
        try:
            check_fingerprint(spec.fingerprint, expected, str(sidecar))
            agent = _dreamer_from_spec(spec, device)
            agent.load_state_dict(read_agent(weights, expected, spec.weights_sha256), optimizers=False)
        except ArtifactError as exc:
            raise PolicyError(str(exc)) from None
        except (RuntimeError, KeyError, TypeError) as exc:
            raise PolicyError(
                f"{weights}: the weights do not fit the recorded Dreamer recipe: {str(exc).splitlines()[0]}"
            ) from None
        return LoadedDreamer(agent, spec, weights, sidecar)
    if recorded != "td3":
        return load_policy(path, device=device)
    from gymnasium import spaces
    from stable_baselines3.td3.policies import TD3Policy

    expected = baseline_fingerprint(spec.config, "td3")
    try:
        check_fingerprint(spec.fingerprint, expected, str(sidecar))
        state = read_agent(weights, expected, spec.weights_sha256)
        space = spaces.Box(-np.inf, np.inf, (OBS_DIM,), dtype=np.float32)
        policy = TD3Policy(space, action_space(), lambda _: 0.0, net_arch=list(HIDDEN_UNITS)).to(device)
        policy.load_state_dict(state["policy"])
    except ArtifactError as exc:
        raise PolicyError(str(exc)) from None
    except (RuntimeError, KeyError) as exc:
        raise PolicyError(
            f"{weights}: the weights do not fit a TD3 {list(HIDDEN_UNITS)} network of {OBS_DIM} inputs: "
            f"{str(exc).splitlines()[0]}"
        ) from None
    policy.set_training_mode(False)
    return LoadedPolicy(policy, spec, weights, sidecar)


def check_table_track(loaded: LoadedPolicy, track: str, car: str) -> None:
    """Refuse a policy trained on another track geometry or car than the table's."""
    fp = loaded.spec.fingerprint
    want = load_track(track).geometry_hash
    if fp.get("track_geometry_hash") != want or fp.get("car") != car:
        raise BaselineError(
            f"{loaded.spec_path}: trained on track {loaded.spec.racing_config.get('track')!r} "
            f"({str(fp.get('track_geometry_hash'))[:12]}...) with car {fp.get('car')!r}, not {track!r} "
            f"({want[:12]}...) with {car!r}"
        )


__all__ = [
    "ALGOS",
    "BaselineError",
    "Discriminator",
    "GAILReplayBuffer",
    "GAILUpdater",
    "LoadedDreamer",
    "TrainBaselineConfig",
    "baseline_algo",
    "check_table_track",
    "discriminator_step",
    "fit_bc",
    "load_baseline",
    "train_baseline",
]
