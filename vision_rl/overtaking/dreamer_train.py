"""`train-baseline --algo dreamer`: the Dreamer agent of :mod:`.dreamer` (the Table III PlaNet row) trained online on
the single-car race.

One update of the world model, actor and value every ``dreamer_train_every_steps`` transitions after the preset's
random start steps; the preset's buffer size is spread over the cars' sequences; ``batch_size`` and
``learning_rate`` override its sequences per update and its world model's step size. A run saves light checkpoints
every ``checkpoint_every_min`` minutes, full ones (with the sequence replay) every ``checkpoint_every_steps`` and on
Ctrl-C; the same command continues it from what it saved.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vision_rl.envs.vector import make_sb3_vec_env
from vision_rl.evaluation.protocol import time_laps
from vision_rl.files import CONTENT_KEY, first_line, parse_json
from vision_rl.overtaking.baseline_run import (
    HIDDEN_UNITS,
    BaselineError,
    Progress,
    RunFolder,
    TrainBaselineConfig,
    append_metrics,
    baseline_fingerprint,
    dreamer_recipe,
    eval_figures,
    policy_spec,
    resolve_recipe,
    total_steps,
)
from vision_rl.overtaking.demos import OBS_DIM
from vision_rl.overtaking.dreamer import (
    DreamerAgent,
    DreamerDriver,
    DreamerRecipe,
    LoadedDreamer,
    SequenceReplay,
    to_env_units,
)
from vision_rl.training.artifact import BUFFER_NAME, MODEL_NAME, SIDECAR_NAME, PolicyError, PolicySpec
from vision_rl.training.persist import (
    DAMAGED_FILE_ERRORS,
    ArtifactError,
    check_fingerprint,
    check_sealed_arrays,
    read_agent,
    write_agent_state,
    write_sealed_arrays,
)
from vision_rl.training.sac import SaveClock, next_multiple, torch_device

SEQUENCE_BUFFER_FORMAT = "vision_rl.sequence_replay"


def save_sequence_replay(replay: SequenceReplay, path: Path, fingerprint: dict[str, Any]) -> str:
    """The replay's filled rows (oldest first per car) as ``.npz`` without pickle, sealed with the SHA-256 of each
    array and of the meta (format 2); returns the file's SHA-256."""
    meta = {"format": SEQUENCE_BUFFER_FORMAT, "format_version": 2, "fingerprint": fingerprint, "n_cars": replay.n_cars}
    return write_sealed_arrays(path, meta, replay.arrays())


def load_sequence_replay(replay: SequenceReplay, path: Path, fingerprint: dict[str, Any]) -> int:
    """Fill a fresh replay from :func:`save_sequence_replay`'s file; returns the rows restored. Refuses a damaged or
    edited file, another fingerprint or another shape in one line (:class:`ArtifactError`); format 1 (before the
    hashes) reads as it was."""
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = parse_json(str(data["meta"]))
            if not isinstance(meta, dict) or meta.get("format") != SEQUENCE_BUFFER_FORMAT:
                raise ArtifactError(f"{path}: not a vision_rl sequence-replay file")
            if meta.get("format_version") not in (1, 2):
                raise ArtifactError(f"{path}: sequence-replay format {meta.get('format_version')!r}, this code reads 2")
            arrays = {name: data[name] for name in data.files if name != "meta"}
        if meta["format_version"] == 2 or CONTENT_KEY in meta:
            check_sealed_arrays(path, meta, arrays)
        check_fingerprint(meta["fingerprint"], fingerprint, str(path))
        return replay.restore({name: arrays[name] for name in (*SequenceReplay.ARRAYS, "written")})
    except ArtifactError:
        raise
    except (*DAMAGED_FILE_ERRORS, KeyError) as exc:
        first = first_line(exc)
        raise ArtifactError(f"{path}: damaged or mismatched sequence-replay file: {first}") from None


def _dreamer_from_spec(spec: PolicySpec, device: str = "cpu") -> DreamerAgent:
    recipe = DreamerRecipe(
        **{k: tuple(v) if isinstance(v, list) else v for k, v in spec.train_config["dreamer"].items()}
    )
    return DreamerAgent(OBS_DIM, 2, recipe, seed=spec.seed, device=device)


def load_dreamer(weights: Path, spec: PolicySpec, sidecar: Path, device: str = "cpu") -> LoadedDreamer:
    """A dreamer policy ready to drive (:func:`.baselines.load_baseline` checked its observation and network
    size)."""
    expected = baseline_fingerprint(spec.config, "dreamer")
    try:
        check_fingerprint(spec.fingerprint, expected, str(sidecar))
        agent = _dreamer_from_spec(spec, device)
        agent.load_state_dict(read_agent(weights, expected, spec.weights_sha256), optimizers=False)
    except ArtifactError as exc:
        raise PolicyError(str(exc)) from None
    except (RuntimeError, KeyError, TypeError) as exc:
        raise PolicyError(f"{weights}: the weights do not fit the recorded Dreamer recipe: {first_line(exc)}") from None
    return LoadedDreamer(agent, spec, weights, sidecar)


class _DreamerSession:
    """One training session of the Dreamer agent in its run folder, fresh or continued: the agent, its replay and
    the environments, stepped by :meth:`step`, with the evaluations, checkpoints and figures of the session."""

    def __init__(self, cfg: TrainBaselineConfig) -> None:
        self.cfg = cfg
        self.run = RunFolder(cfg, None)
        self.out, self.preset, self.recipe = self.run.out, resolve_recipe(cfg), dreamer_recipe(cfg)
        torch.set_num_threads(max(self.preset.torch_threads, 1))
        device = torch_device(cfg.device)
        self.racing = cfg.racing
        self.fingerprint = baseline_fingerprint(self.racing, "dreamer")
        self.end_steps, self.n_cars = total_steps(cfg), cfg.racing.n_groups
        self.agent = DreamerAgent(OBS_DIM, 2, self.recipe, seed=cfg.seed, device=device)
        self.replay = SequenceReplay(
            max(self.preset.buffer_size // self.n_cars, self.recipe.sequence_steps), self.n_cars, OBS_DIM, 2
        )
        sidecar = self.out / SIDECAR_NAME
        self.spec = PolicySpec.read(sidecar) if sidecar.is_file() else None
        self.steps, self.train_time_before_s, self.rows_restored = 0, 0.0, 0
        if self.spec is not None:
            self._restore(self.spec)

    def _restore(self, spec: PolicySpec) -> None:
        out = self.out
        try:
            check_fingerprint(spec.fingerprint, self.fingerprint, str(out / SIDECAR_NAME))
            state = read_agent(out / spec.model, self.fingerprint, spec.weights_sha256)
            self.agent.load_state_dict(state)
            if (out / BUFFER_NAME).is_file():
                self.rows_restored = load_sequence_replay(self.replay, out / BUFFER_NAME, self.fingerprint)
        except ArtifactError as exc:
            raise BaselineError(f"cannot continue {out}: {exc}") from None
        except (KeyError, RuntimeError, ValueError) as exc:
            raise BaselineError(
                f"cannot continue {out}: its weights do not fit this recipe's networks: {first_line(exc)}"
            ) from None
        self.steps, self.agent.n_updates = int(state["counters"]["num_timesteps"]), int(state["counters"]["n_updates"])
        self.train_time_before_s = spec.train_time_s

    def start(self) -> None:
        """The environments and the session's counters; the first observations go to the replay."""
        cfg, n_cars, steps = self.cfg, self.n_cars, self.steps
        # Without its buffer a continued run first collects again what it would have learned from.
        starts = self.preset.learning_starts
        self.learning_starts = starts if self.rows_restored or steps == 0 else steps + starts
        self.venv = make_sb3_vec_env(self.racing, seed=cfg.seed + steps)
        if self.spec is not None:  # the numbers the policy was trained with
            self.venv.core.observer.normalizer = self.spec.normalizer
        self.normalizer = self.venv.core.observer.normalizer
        self.rng = np.random.default_rng(cfg.seed + steps)
        self.updates_at_start, self.steps_at_start = self.agent.n_updates, steps
        self.session_start = time.perf_counter()
        self.eval_time_s = 0.0
        self.episode_returns: list[float] = []
        self.running_return = np.zeros(n_cars)
        self.last_eval: dict[str, Any] | None = None
        self.last_terms: dict[str, float] = {}
        self.next_eval = next_multiple(steps, cfg.evaluation.every_steps)
        self.saves = SaveClock(steps, cfg.checkpoints.every_steps, cfg.checkpoints.every_min)
        self.all_cars = np.arange(n_cars)
        self.obs = self.venv.reset()
        self.carry = self.agent.initial(n_cars)
        self.first = np.ones(n_cars)
        self.replay.add(self.all_cars, self.obs, np.zeros((n_cars, 2)), np.zeros(n_cars), np.ones(n_cars), self.first)
        if steps == 0:
            self.save(buffer=False)  # the run folder holds a loadable policy from the start

    def train_time_s(self) -> float:
        return self.train_time_before_s + time.perf_counter() - self.session_start - self.eval_time_s

    def step(self) -> None:
        """One step of all cars into the replay, then the updates that are due."""
        self._collect()
        trained_steps = self.steps - max(self.learning_starts, self.steps_at_start)
        due = self.updates_at_start + max(trained_steps, 0) // self.cfg.dreamer_train_every_steps
        recipe = self.recipe
        while self.agent.n_updates < due and self.replay.can_sample(recipe.sequence_steps):
            batch = self.replay.sample(self.rng, recipe.batch_sequences, recipe.sequence_steps, self.agent.device)
            self.last_terms = self.agent.update(batch)

    def _collect(self) -> None:
        agent, n_cars = self.agent, self.n_cars
        action, self.carry = agent.act(self.carry, self.obs, self.first, explore=True)
        if self.steps < self.learning_starts:  # uniform random actions fill the replay first
            action = self.rng.uniform(-1.0, 1.0, (n_cars, 2))
            self.carry = (self.carry[0], torch.as_tensor(action, dtype=torch.float32, device=agent.device))
        next_obs, rewards, dones, infos = self.venv.step(to_env_units(action))
        rows, continues = next_obs.copy(), np.ones(n_cars)
        done_cars = np.flatnonzero(dones)
        for i in done_cars:  # the last observation of an ended episode, and whether it ended by a crash
            rows[i] = infos[i]["terminal_observation"]
            continues[i] = float(infos[i].get("TimeLimit.truncated", False))
        self.replay.add(self.all_cars, rows, action, rewards, continues, np.zeros(n_cars))
        self.running_return += rewards
        if len(done_cars):
            n_done = len(done_cars)
            self.replay.add(
                done_cars,
                next_obs[done_cars],
                np.zeros((n_done, 2)),
                np.zeros(n_done),
                np.ones(n_done),
                np.ones(n_done),
            )
            self.episode_returns.extend(self.running_return[done_cars].tolist())
            self.running_return[done_cars] = 0.0
        self.first, self.obs = dones.astype(np.float64), next_obs
        self.steps += n_cars

    def periodic(self, progress: Progress | None) -> None:
        """After a step: the evaluation, the progress and the checkpoint that are due."""
        if self.next_eval is not None and self.steps >= self.next_eval:
            self.evaluate()
            self.next_eval = next_multiple(self.steps, self.cfg.evaluation.every_steps)
        if progress is not None:
            progress("step", self.steps, self.end_steps, self.last_eval)
        kind = self.saves.due(self.steps)
        if kind is not None:
            self.save(buffer=kind == "full")

    def evaluate(self) -> None:
        """The protocol lap of the deterministic agent, appended to metrics.jsonl (its time is not training)."""
        cfg = self.cfg
        t0 = time.perf_counter()
        driver = DreamerDriver(self.agent, self.racing, self.normalizer, {"driver": "policy", "algo": "dreamer"})
        try:
            summary = time_laps(
                driver,
                cfg.racing.track,
                cfg.racing.car,
                range(cfg.evaluation.seeds),
                cfg.evaluation.laps,
                cfg.eval_time_limit_s,
            ).summary()
        finally:
            driver.close()
        self.eval_time_s += time.perf_counter() - t0
        returns = self.episode_returns
        self.last_eval = {
            "num_timesteps": self.steps,
            "train_time_s": round(self.train_time_s(), 2),
            "n_updates": self.agent.n_updates,
            **eval_figures(summary),
            "ep_rew_mean": float(np.mean(returns[-100:])) if returns else None,
            "eval_time_s": round(time.perf_counter() - t0, 2),
            **self.last_terms,
        }
        append_metrics(self.out, self.last_eval)

    def save(self, buffer: bool) -> None:
        cfg, out = self.cfg, self.out
        counters = {"num_timesteps": self.steps, "n_updates": self.agent.n_updates, "episode_num": 0}
        sha = write_agent_state({**self.agent.state_dict(), "counters": counters}, out / MODEL_NAME, self.fingerprint)
        recipe_record = {
            **json.loads(json.dumps(dataclasses.asdict(self.preset))),
            "hidden_units": list(HIDDEN_UNITS),
            "dreamer": json.loads(json.dumps(dataclasses.asdict(self.recipe))),
            "train_every_steps": cfg.dreamer_train_every_steps,
        }
        train_time_s = self.train_time_s()
        spec = policy_spec(
            cfg,
            self.racing,
            self.normalizer,
            self.fingerprint,
            sha,
            recipe_record,
            self.steps,
            train_time_s,
            self.run.settings,
        )
        spec.write(out / SIDECAR_NAME)
        if buffer:
            save_sequence_replay(self.replay, out / BUFFER_NAME, self.fingerprint)
        self.run.update(status="running", num_timesteps=self.steps, train_time_s=round(self.train_time_s(), 2))

    def finish(self, interrupted: bool) -> dict[str, Any]:
        """Everything saved, the environments closed; the run's record with this session's figures."""
        wall_s = time.perf_counter() - self.session_start
        self.save(buffer=True)
        self.venv.close()
        self.run.update(status="interrupted" if interrupted else "done", steps=self.end_steps, num_timesteps=self.steps)
        steps_now, updates_now = self.steps - self.steps_at_start, self.agent.n_updates - self.updates_at_start
        return {
            **self.run.record,
            "out": str(self.out),
            "policy": str(self.out),
            "interrupted": interrupted,
            "trained_now": steps_now > 0,
            "buffer_restored": self.rows_restored,
            "session": {
                "steps": steps_now,
                "updates": updates_now,
                "wall_s": round(wall_s, 2),
                "transitions_per_s": round(steps_now / wall_s, 1) if wall_s > 0 else None,
                "updates_per_s": round(updates_now / wall_s, 2) if wall_s > 0 else None,
            },
        }


def train_dreamer(cfg: TrainBaselineConfig, progress: Progress | None = None) -> dict[str, Any]:
    """The Dreamer agent (see :mod:`.dreamer`) up to ``steps``, continuing a run folder's saved state."""
    session = _DreamerSession(cfg)
    if session.steps >= session.end_steps:
        out = str(session.out)
        return {**session.run.record, "out": out, "policy": out, "interrupted": False, "trained_now": False}
    session.start()
    interrupted = False
    try:
        while session.steps < session.end_steps:
            session.step()
            session.periodic(progress)
    except KeyboardInterrupt:
        interrupted = True
    return session.finish(interrupted)


__all__ = ["load_dreamer", "load_sequence_replay", "save_sequence_replay", "train_dreamer"]
