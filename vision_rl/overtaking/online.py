"""`train-baseline --algo td3 / sac` (and gail's learner): Stable-Baselines3's off-policy learners, online on the
single-car race with the paper's 2 x 256 network and our SAC stage 1's recipe and budget (train-overtaking's ``cpu``
preset: batch, buffer, random start steps, learning rate, gamma, tau, one update per vector step, 20 cars, 1M steps).

- **td3**: SB3's TD3 with Gaussian exploration noise (``td3_noise`` of each action's half range).
- **sac**: SB3's SAC as train-overtaking's stage 1, for a fixed number of steps (no stopping criterion).
- **gail**: SB3's SAC with gail's companion (:class:`.gail.GAILCompanion`) riding along: its replay buffer, its
  discriminator's updates and state.

A run saves light checkpoints (weights, optimisers, counters) every ``checkpoint_every_min`` minutes, full ones
(with the buffer) every ``checkpoint_every_steps`` and on Ctrl-C (SIGTERM where the command maps it); the same
command continues it from what it saved.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.vec_env import VecMonitor

from vision_rl.envs.racing_env import action_space
from vision_rl.envs.vector import make_sb3_vec_env
from vision_rl.evaluation.protocol import time_laps
from vision_rl.files import first_line
from vision_rl.overtaking.baseline_run import (
    HIDDEN_UNITS,
    BaselineError,
    Progress,
    RunFolder,
    TrainBaselineConfig,
    append_metrics,
    baseline_fingerprint,
    eval_figures,
    policy_spec,
    resolve_recipe,
    total_steps,
)
from vision_rl.overtaking.config import OBSERVATION
from vision_rl.overtaking.demos import OBS_DIM, Demos
from vision_rl.training.artifact import (
    BUFFER_NAME,
    MODEL_NAME,
    SIDECAR_NAME,
    LoadedPolicy,
    PolicyDriver,
    PolicyError,
    PolicySpec,
    check_fingerprint,
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
from vision_rl.training.sac import SaveClock, next_multiple, torch_device


class Companion(Protocol):
    """What rides along an online learner (gail's discriminator, :class:`.gail.GAILCompanion`)."""

    demos: Demos
    replay_buffer_class: type[ReplayBuffer]

    def attach(self, model, device: str) -> None: ...
    def begin(self, start_steps: int) -> None: ...
    def on_step(self, num_timesteps: int, model) -> None: ...
    def figures(self) -> dict[str, float]: ...
    def state(self) -> dict[str, Any]: ...
    def restore(self, state: dict[str, Any], source: str) -> None: ...


class _OnlineLoop(BaseCallback):
    """The companion's updates (gail), periodic evaluations, checkpoints and progress."""

    def __init__(self, session: _OnlineSession, progress: Progress | None) -> None:
        super().__init__()
        self.session, self.progress = session, progress
        cfg, start = session.cfg, session.start_steps
        self.next_eval = next_multiple(start, cfg.evaluation.every_steps)
        self.saves = SaveClock(start, cfg.checkpoints.every_steps, cfg.checkpoints.every_min)
        if session.companion is not None:
            session.companion.begin(start)

    def _on_step(self) -> bool:
        n, session = self.num_timesteps, self.session
        if session.companion is not None:
            session.companion.on_step(n, self.model)
        # As train-policy's loop: the evaluation at the last step waits for SB3's last update (evaluate_held_back).
        if self._eval_due() and n < session.end_steps:
            session.evaluate(self.model)
            self.next_eval = next_multiple(n, session.cfg.evaluation.every_steps)
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

    def __init__(self, cfg: TrainBaselineConfig, companion: Companion | None = None) -> None:
        self.cfg = cfg
        self.companion = companion
        self.run = RunFolder(cfg, companion.demos if companion is not None else None)
        self.recipe = resolve_recipe(cfg)
        self.device = torch_device(cfg.device)
        self.racing = cfg.racing
        self.fingerprint = baseline_fingerprint(self.racing, cfg.algo)
        self.end_steps = total_steps(cfg)
        self.last_eval: dict[str, Any] | None = None
        self.eval_driver: PolicyDriver | None = None
        self.frozen_train_time_s: float | None = None

    def build(self):
        """The learner, fresh or restored from the run folder's weights, optimisers and buffer."""
        out = self.run.out
        if self.recipe.torch_threads > 0:
            torch.set_num_threads(self.recipe.torch_threads)
        resumed = (out / SIDECAR_NAME).is_file() and (out / MODEL_NAME).is_file()
        spec = PolicySpec.read(out / SIDECAR_NAME) if resumed else None
        model = self._make_model(spec.num_timesteps if spec is not None else 0, spec)
        self.train_time_before_s = spec.train_time_s if spec is not None else 0.0
        self.buffer_restored = 0
        if spec is not None:
            self._restore(model, spec)
        self.start_steps = int(model.num_timesteps)
        self.session_start = time.perf_counter()
        return model

    def _make_model(self, steps_before: int, spec: PolicySpec | None):
        cfg, recipe = self.cfg, self.recipe
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
        elif self.companion is not None:
            model = SAC("MlpPolicy", self.env, replay_buffer_class=self.companion.replay_buffer_class, **common)
        else:
            model = SAC("MlpPolicy", self.env, **common)
        # SB3's default logger makes an empty SB3-<date> folder in the temporary directory on every learn().
        model.set_logger(Logger(folder=None, output_formats=[]))
        if self.companion is not None:
            self.companion.attach(model, self.device)
        return model

    def _restore(self, model, spec: PolicySpec) -> None:
        out = self.run.out
        try:
            check_fingerprint(spec.fingerprint, self.fingerprint, str(out / SIDECAR_NAME))
            state = read_agent(out / spec.model, self.fingerprint, spec.weights_sha256)
            restore_agent(model, state, str(out / spec.model))
            if self.companion is not None:
                self.companion.restore(state, str(out / spec.model))
            if (out / BUFFER_NAME).is_file():
                self.buffer_restored = load_buffer(model.replay_buffer, out / BUFFER_NAME, self.fingerprint)
        except ArtifactError as exc:
            raise BaselineError(f"cannot continue {out}: {exc}") from None
        if self.buffer_restored == 0:  # never update on an empty buffer: refill it first
            model.learning_starts = model.num_timesteps + self.recipe.learning_starts

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
            self.eval_driver,
            cfg.racing.track,
            cfg.racing.car,
            range(cfg.evaluation.seeds),
            cfg.evaluation.laps,
            cfg.eval_time_limit_s,
        ).summary()
        eval_time_s = time.perf_counter() - t0
        self.session_start += eval_time_s  # evaluation time is not training time
        episodes = list(model.ep_info_buffer or [])
        record = {
            "num_timesteps": int(model.num_timesteps),
            "train_time_s": round(self.train_time_s, 2),
            "n_updates": int(getattr(model, "_n_updates", 0)),
            **eval_figures(summary),
            "ep_rew_mean": float(np.mean([e["r"] for e in episodes])) if episodes else None,
            "eval_time_s": round(eval_time_s, 2),
        }
        if self.companion is not None:
            record.update(self.companion.figures())
        append_metrics(self.run.out, record)
        self.last_eval = record
        return record

    def save(self, model, buffer: bool) -> None:
        out = self.run.out
        state = agent_state(model)
        if self.companion is not None:
            state.update(self.companion.state())
        sha = write_agent_state(state, out / MODEL_NAME, self.fingerprint)
        recipe = json.loads(json.dumps(dataclasses.asdict(self.recipe)))
        if self.cfg.algo == "td3":
            recipe["action_noise_std_share"] = self.cfg.td3_noise
        policy_spec(
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


def train_online(
    cfg: TrainBaselineConfig, progress: Progress | None = None, companion: Companion | None = None
) -> dict[str, Any]:
    """td3, sac or, with gail's ``companion``, gail (see the module's docstring) up to ``steps``, continuing a run
    folder's saved state."""
    session = _OnlineSession(cfg, companion)
    model = session.build()
    remaining = session.end_steps - int(model.num_timesteps)
    if remaining <= 0:  # already done up to these steps
        session.close()
        return _record(session, interrupted=False, trained_now=False)
    t0, steps0, updates0 = time.perf_counter(), int(model.num_timesteps), int(getattr(model, "_n_updates", 0))
    interrupted = False
    try:
        if session.start_steps == 0:
            session.save(model, buffer=False)  # the run folder holds a loadable policy from the start
        loop = _OnlineLoop(session, progress)
        learn_between_interrupts(model, loop, total_timesteps=remaining, reset_num_timesteps=False, log_interval=None)
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
        **_record(session, interrupted=interrupted, trained_now=steps_now > 0),
        "buffer_restored": int(session.buffer_restored) * cfg.racing.n_groups,
        "session": {
            "steps": steps_now,
            "updates": updates_now,
            "wall_s": round(wall_s, 2),
            "transitions_per_s": round(steps_now / wall_s, 1) if wall_s > 0 else None,
            "updates_per_s": round(updates_now / wall_s, 2) if wall_s > 0 else None,
        },
    }


def _record(session: _OnlineSession, interrupted: bool, trained_now: bool) -> dict[str, Any]:
    out = str(session.run.out)
    return {**session.run.record, "out": out, "policy": out, "interrupted": interrupted, "trained_now": trained_now}


def load_td3(weights: Path, spec: PolicySpec, sidecar: Path, device: str = "cpu") -> LoadedPolicy:
    """A td3 policy ready to drive (:func:`.baselines.load_baseline` checked its observation and network size)."""
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
            f"{first_line(exc)}"
        ) from None
    policy.set_training_mode(False)
    return LoadedPolicy(policy, spec, weights, sidecar)


__all__ = ["Companion", "load_td3", "train_online"]
