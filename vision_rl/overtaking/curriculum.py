"""`train-overtaking`: the overtaking paper's curriculum SAC (section III-C) and standard SAC, on the 96-D
``overtaking`` observation (72-beam lidar) with Stable-Baselines3.

The curriculum, one run folder per training seed (``--out``): stage 1 races alone until its protocol lap time is
within ``stage1_margin`` of the built-in AI's (or ``stage1_max_steps``); stage 2 goes on with the kept buffer, the
exploration re-initialised and one AI car ahead (Agent 1); stage 3 goes on with a FIFO buffer that forgets stage 1
(Agent 2 with stage 2's collision weights, Agent 3 with them doubled); standard SAC learns the stage-2 setting from
the first step for the curriculum's budget. Agents 1-3 share one stage-1/2 run. A stage folder holds the policy,
its replay buffer, ``stage.json`` and ``metrics.jsonl``; a stage saves its starting point, checkpoints and on
Ctrl-C, and the same command continues it. Every periodic evaluation measures the protocol lap and the overtaking
return of the stage-2 setting, so curriculum and standard SAC share one scale (the paper's Fig. 3). In full:
docs/notes/overtaking.md, "curriculum.py".
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import VecMonitor

from vision_rl.config import flat_values
from vision_rl.envs.core import RacingConfig, RacingCore
from vision_rl.envs.observations import OBS_NAMES, ObsNormalizer
from vision_rl.envs.vector import make_sb3_vec_env
from vision_rl.evaluation.protocol import BuiltinAI, time_laps
from vision_rl.files import (
    CONTENT_KEY,
    clear_folder,
    content_damage,
    json_text,
    parse_json,
    run_folder_locked,
    sealed_record,
    write_json,
)
from vision_rl.overtaking.config import (
    BUDGETS,
    OBSERVATION,
    CurriculumBudget,
    TrainOvertakingConfig,
    check_overtaking_ranges,
)
from vision_rl.training.artifact import (
    BUFFER_NAME,
    MODEL_NAME,
    SIDECAR_NAME,
    LoadedPolicy,
    PolicyDriver,
    PolicyError,
    PolicySpec,
    convert_run,
    load_policy,
    policy_fingerprint,
    racing_config_to_dict,
    read_sidecar,
    resolve_policy_paths,
)
from vision_rl.training.interrupts import learn_between_interrupts
from vision_rl.training.persist import ArtifactError, load_buffer, read_agent, restore_agent, save_agent, save_buffer
from vision_rl.training.presets import resolve_preset
from vision_rl.training.sac import SaveClock, next_multiple, sampler_setup, torch_device
from vision_rl.training.sac import read_metrics as read_train_metrics

OBS_DIM = len(OBS_NAMES[OBSERVATION])
RUN_NAME = "run.json"
STAGE_NAME = "stage.json"
METRICS_NAME = "metrics.jsonl"
RUN_FORMAT = "vision_rl.overtaking_run"
#: Version of run.json, stage.json and agentN.json / standard.json. 1 (no ``format_version``): no content hash;
#: 2: sealed with the SHA-256 of their content (``vision-rl convert-policy --run RUN`` checks and seals a 1).
RUN_FORMAT_VERSION = 2
#: The paper's collision weights: stages 1-2 and Agent 2's stage 3 (0.005), Agent 3's stage 3 (0.01).
PENALTY_STAGE2 = 0.005
PENALTY_AGENT3 = 0.01
#: Seed of the overtaking-return evaluation episodes: the same episodes for every run and every evaluation.
EVAL_EPISODE_SEED = 20_000


#: Shared settings that stage 1 (racing alone) does not depend on: a run may start from another's stage 1 across them.
STAGE1_FREE_SETTINGS = ("overtake_gain_c_r", "detection_range_c_d_m")


class OvertakingRunError(ValueError):
    """A run folder that cannot be continued as asked (other settings, missing stages); the message says why."""


# ------------------------------------------------------------------------------------------------- the sidecar


@dataclass(frozen=True)
class OvertakingPolicySpec(PolicySpec):
    """``policy.json`` of an overtaking policy: the fields of :class:`PolicySpec`, observation ``overtaking``."""

    def __post_init__(self) -> None:
        if self.observation != OBSERVATION:
            raise PolicyError(
                f"this policy observes {self.observation!r}, not the 96-D {OBSERVATION!r} observation: an overtaking "
                "policy comes from train-overtaking"
            )


def read_overtaking_spec(path: str | os.PathLike[str]) -> OvertakingPolicySpec:
    """Read a sidecar, refusing one of another observation with one line that says so."""
    path = Path(path)
    data = read_sidecar(path)
    if isinstance(data, dict) and data.get("observation") not in (None, OBSERVATION):
        raise PolicyError(
            f"{path}: the policy observes {data.get('observation')!r}, not the 96-D {OBSERVATION!r} observation; "
            "give a policy of train-overtaking"
        )
    if not isinstance(data, dict):
        raise PolicyError(f"{path}: not a vision_rl policy sidecar")
    return OvertakingPolicySpec.from_dict(data, str(path))


def load_overtaking_policy(path: str | os.PathLike[str], device: str = "cpu") -> LoadedPolicy:
    """Load a policy of train-overtaking (a stage folder, its ``policy.pt`` or ``policy.json``) with
    :func:`~vision_rl.training.artifact.load_policy`'s checks, refusing one of another observation."""
    _, sidecar = resolve_policy_paths(path)
    read_overtaking_spec(sidecar)
    return load_policy(path, device=device)


# ------------------------------------------------------------------------------------------------- stages


@dataclass(frozen=True)
class Stage:
    """One training stage: what it trains on, how long, and how it starts from the stage before it."""

    name: str
    """Its folder in the run."""
    scenario: str
    """``stage1`` (alone) or ``stage2`` (one AI car 200 m ahead)."""
    penalty_c: float
    """c_w = c_c of its reward."""
    steps: int
    """Steps it adds (stage 1: at most)."""
    buffer_size: int
    """Replay buffer capacity, transitions."""
    previous: str | None
    """The stage it continues from (None: a fresh policy)."""
    reinit_exploration: bool = False
    """Reset the entropy coefficient and the log-std layer at its start (stage 2)."""
    fifo_from_previous: bool = False
    """Start with the newest transitions of the previous buffer in a buffer of ``buffer_size`` (stage 3)."""
    until_criterion: bool = False
    """End at the lap-time criterion (stage 1)."""

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def resolve_budget(cfg: TrainOvertakingConfig) -> CurriculumBudget:
    base = BUDGETS[cfg.sac.preset]
    return CurriculumBudget(
        cfg.stage1_max_steps or base.stage1_max_steps,
        cfg.stage2_steps or base.stage2_steps,
        cfg.stage3_steps or base.stage3_steps,
    )


def stages_of(cfg: TrainOvertakingConfig) -> list[Stage]:
    """The chain of stages that makes ``cfg.agent``."""
    sac, budget = resolve_preset(cfg.sac), resolve_budget(cfg)
    if cfg.agent == "standard":
        steps = cfg.standard_steps or budget.stage1_max_steps + budget.stage2_steps + budget.stage3_steps
        return [Stage("standard", "stage2", PENALTY_STAGE2, steps, sac.buffer_size, None)]
    stage1 = Stage(
        "stage1", "stage1", PENALTY_STAGE2, budget.stage1_max_steps, sac.buffer_size, None, until_criterion=True
    )
    stage2 = Stage(
        "stage2", "stage2", PENALTY_STAGE2, budget.stage2_steps, sac.buffer_size, "stage1", reinit_exploration=True
    )
    if cfg.agent == "1":
        return [stage1, stage2]
    penalty = PENALTY_STAGE2 if cfg.agent == "2" else PENALTY_AGENT3
    fifo = cfg.stage3_buffer_size or max(budget.stage3_steps // 2, cfg.racing.n_groups)
    stage3 = Stage(
        f"agent{cfg.agent}-stage3", "stage2", penalty, budget.stage3_steps, fifo, "stage2", fifo_from_previous=True
    )
    return [stage1, stage2, stage3]


def shared_settings(cfg: TrainOvertakingConfig) -> dict[str, Any]:
    """What every agent of one run folder must agree on (``run.json``)."""
    budget = resolve_budget(cfg)
    return {
        "track": cfg.racing.track,
        "car": cfg.racing.car,
        "cars": cfg.racing.n_groups,
        "seed": cfg.seed,
        "preset": cfg.sac.preset,
        "sac": json.loads(json.dumps(dataclasses.asdict(resolve_preset(cfg.sac)))),
        "stage1_max_steps": budget.stage1_max_steps,
        "stage1_margin": cfg.stage1_margin,
        "stage2_steps": budget.stage2_steps,
        "episode_s": cfg.racing.episode_s,
        "overtake_gain_c_r": cfg.racing.overtake_gain_c_r,
        "detection_range_c_d_m": cfg.racing.detection_range_c_d_m,
        "eval_every_steps": cfg.evaluation.every_steps,
        "eval_seeds": cfg.evaluation.seeds,
        "eval_laps": cfg.evaluation.laps,
        "eval_time_limit_s": cfg.eval_time_limit_s,
    }


def check_config(cfg: TrainOvertakingConfig) -> None:
    """One clear line for a bad option, before anything is built or written."""
    check_overtaking_ranges(flat_values(cfg))
    if cfg.samplers.workers is not None or cfg.samplers.address:
        from vision_rl.training.distributed import check_workers

        if cfg.samplers.workers is None:
            raise ValueError(
                f"--address {cfg.samplers.address} needs --workers: the samplers are what runs on the cluster"
            )
        check_workers(cfg.samplers.workers, cfg.samplers.max_staleness, cfg.samplers.version_every_updates)
    sac = resolve_preset(cfg.sac)
    for stage in stages_of(cfg):
        if stage.buffer_size < cfg.racing.n_groups:
            raise ValueError(
                f"{stage.name}: a buffer of {stage.buffer_size} transitions holds less than one step of "
                f"{cfg.racing.n_groups} cars"
            )
        if stage.previous is None and stage.steps <= sac.learning_starts:
            raise ValueError(
                f"{stage.name}: {stage.steps} steps are not above the {sac.learning_starts} random "
                "start steps (--learning-starts): it would make no update"
            )


def default_out(cfg: TrainOvertakingConfig) -> Path:
    track = cfg.racing.track.replace("random:", "random-")
    if track.endswith(".csv") or os.sep in track:
        track = Path(track).stem
    return Path("runs") / "overtaking" / f"{track}-{cfg.racing.car}-s{cfg.seed}"


def _run_folder(path: Path) -> Path:
    """The run folder of one of its records (``stage.json`` lies in a stage's folder)."""
    return path.parent.parent if path.name == STAGE_NAME else path.parent


def _parse_record(path: Path) -> dict[str, Any]:
    """A run record's JSON of format :data:`RUN_FORMAT`, its seal not checked (the converter's read); an agent's
    summary of format 1 names no format."""
    try:
        data = parse_json(path.read_text())
    except (OSError, ValueError) as exc:
        raise OvertakingRunError(f"{path}: unreadable ({exc}); start over with --force") from None
    unsealed_summary = isinstance(data, dict) and "format" not in data and CONTENT_KEY not in data and "agent" in data
    if not isinstance(data, dict) or (data.get("format") != RUN_FORMAT and not unsealed_summary):
        raise OvertakingRunError(f"{path}: not a train-overtaking record (no format {RUN_FORMAT!r})")
    return data


def _record_to_convert(path: Path) -> dict[str, Any]:
    """A run record as the converter reads it: any of format 1, or a sealed one that is whole."""
    data = _parse_record(path)
    return _read_json(path) if CONTENT_KEY in data else data


def _read_json(path: Path) -> dict[str, Any]:
    """A sealed run record, or one line naming it: the steps, settings and stage boundaries it holds decide what a
    resume trains and where Fig. 3 puts a stage switch, so an edit must not go unseen."""
    data = _parse_record(path)
    if CONTENT_KEY not in data:
        raise OvertakingRunError(
            f"{path}: a run record of format 1 has no content hash, so an edit of it would go unseen; check and seal "
            f"the run with `vision-rl convert-policy --run {_run_folder(path)}`"
        )
    damage = content_damage(data)
    if damage is not None:
        raise OvertakingRunError(f"{path}: the run record {damage}; start over with --force")
    if data.get("format_version") != RUN_FORMAT_VERSION:
        raise OvertakingRunError(f"{path}: run record format {data.get('format_version')!r}, not {RUN_FORMAT_VERSION}")
    return data


def write_run_record(path: str | os.PathLike[str], record: dict[str, Any]) -> None:
    """``record`` as a sealed run record (run.json, stage.json, agentN.json), written atomically."""
    write_json(path, sealed_record({**record, "format": RUN_FORMAT, "format_version": RUN_FORMAT_VERSION}))


def reinit_exploration(model: SAC) -> None:
    """Stage 2's reset of the exploration term: entropy coefficient 1 (SB3's ``auto`` start) with a new optimiser,
    and the actor's log-std layer drawn anew with its Adam moments cleared."""
    if model.log_ent_coef is not None:
        with torch.no_grad():
            model.log_ent_coef.zero_()
        model.ent_coef_optimizer = torch.optim.Adam([model.log_ent_coef], lr=model.lr_schedule(1))
    layer = model.actor.log_std
    layer.reset_parameters()
    for parameter in layer.parameters():
        model.actor.optimizer.state.pop(parameter, None)


def chronological_rows(buffer: ReplayBuffer) -> np.ndarray:
    """Indices (per env) of the filled rows of ``buffer``, oldest first."""
    if buffer.full:
        return np.roll(np.arange(buffer.buffer_size), -buffer.pos)
    return np.arange(buffer.pos)


def copy_newest(source: ReplayBuffer, target: ReplayBuffer) -> int:
    """Fill an empty FIFO ``target`` with the newest transitions of ``source`` (as many as fit), oldest first, so
    that they are the first to be overwritten; returns the rows (per env) copied."""
    rows = chronological_rows(source)[-target.buffer_size :]
    n = len(rows)
    for name in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts"):
        getattr(target, name)[:n] = getattr(source, name)[rows]
    target.pos = n % target.buffer_size
    target.full = n == target.buffer_size
    return n


#: ``progress(stage_name, num_timesteps, stage_end_steps, last_evaluation_or_None)``.
Progress = Callable[[str, int, int, "dict[str, Any] | None"], None]


class _StageLoop(BaseCallback):
    """Evaluations, the stage-1 criterion, checkpoints and progress, on cumulative environment steps."""

    def __init__(self, session: _StageSession, progress: Progress | None) -> None:
        super().__init__()
        self.session = session
        self.progress = progress
        cfg = session.cfg
        start = session.start_steps_now
        self.next_eval = next_multiple(start, cfg.evaluation.every_steps)
        self.saves = SaveClock(start, cfg.checkpoints.every_steps, cfg.checkpoints.every_min)

    def _on_step(self) -> bool:
        n = self.num_timesteps
        session = self.session
        go_on = True
        if self.next_eval is not None and n >= self.next_eval:
            record = session.evaluate(self.model)
            self.next_eval = next_multiple(n, session.cfg.evaluation.every_steps)
            if session.stage.until_criterion and record["criterion_met"]:
                session.criterion_met_at = n
                go_on = False
        if self.progress is not None:
            self.progress(session.stage.name, n, session.end_steps, session.last_eval)
        kind = self.saves.due(n)
        if kind is not None:
            session.save(self.model, buffer=kind == "full")
        return go_on


class _StageSession:
    """Training one stage in its folder: start (fresh, from the previous stage, or resumed), learn, save."""

    def __init__(self, run: OvertakingRun, stage: Stage) -> None:
        self.run, self.cfg, self.stage = run, run.cfg, stage
        self.folder = run.out / stage.name
        self.last_eval: dict[str, Any] | None = None
        self.criterion_met_at: int | None = None
        self.eval_driver: PolicyDriver | None = None
        self.frozen_train_time_s: float | None = None
        """The stage's training time once it ended: the sidecar and stage.json then record the same figure."""

    def racing(self) -> RacingConfig:
        cfg, stage = self.cfg, self.stage
        return dataclasses.replace(
            cfg.racing, scenario=stage.scenario, wall_penalty_c_w=stage.penalty_c, car_penalty_c_c=stage.penalty_c
        )

    # ------------------------------------------------------------------ set-up
    def build(self) -> SAC:
        """The stage's model: fresh, from the previous stage's folder (weights, optimisers, buffer), or resumed."""
        self.racing_config = self.racing()
        self.fingerprint = policy_fingerprint(self.racing_config, OBSERVATION, OBS_DIM, None)
        record_path = self.folder / STAGE_NAME
        record, source = self._source(record_path)
        resumed = record is not None
        spec = read_overtaking_spec(source / SIDECAR_NAME) if source is not None else None
        model = self._make_model(spec)
        self.buffer_restored = 0
        if spec is not None:
            assert source is not None
            self._restore(model, spec, source, resumed)
        self.train_time_before_s = spec.train_time_s if spec is not None else 0.0
        self.session_start = time.perf_counter()
        self.start_steps_now = int(model.num_timesteps)
        self.record = record if record is not None else self._start_fresh(model)
        self.end_steps = int(self.record["start_steps"]) + self.stage.steps
        (self.folder / "tensorboard").mkdir(parents=True, exist_ok=True)
        model.set_logger(configure(str(self.folder / "tensorboard"), ["tensorboard"]))
        if not resumed:
            # The starting point (the kept buffer included) is on disk before any training: a kill at any moment
            # resumes this stage with a buffer, never from the previous stage again.
            self.save(model, buffer=True)
            write_run_record(record_path, self.record)
        return model

    def _source(self, record_path: Path) -> tuple[dict[str, Any] | None, Path | None]:
        """(the stage's own record when it is resumed, else None; the folder whose policy it starts from)."""
        stage = self.stage
        if record_path.is_file() and (self.folder / SIDECAR_NAME).is_file():
            record = _read_json(record_path)
            if record.get("stage") != stage.to_dict():
                raise OvertakingRunError(_differs(record_path, record.get("stage") or {}, stage.to_dict()))
            return record, self.folder
        return None, (self.run.out / stage.previous if stage.previous is not None else None)

    def _make_model(self, spec: OvertakingPolicySpec | None) -> SAC:
        sac = self.run.sac
        steps_before = spec.num_timesteps if spec is not None else 0
        self.venv = make_sb3_vec_env(self.racing_config, seed=self.cfg.seed + steps_before)
        if spec is not None:  # the numbers the policy was trained with, not whatever the cache holds today
            self.venv.core.observer.normalizer = spec.normalizer
        self.normalizer: ObsNormalizer = self.venv.core.observer.normalizer
        self.env = VecMonitor(self.venv)
        return SAC(
            "MlpPolicy",
            self.env,
            learning_rate=sac.learning_rate,
            buffer_size=self.stage.buffer_size,
            learning_starts=sac.learning_starts,
            batch_size=sac.batch_size,
            tau=sac.tau,
            gamma=sac.gamma,
            train_freq=(sac.train_freq_steps, "step"),
            gradient_steps=sac.gradient_steps,
            policy_kwargs={"net_arch": list(sac.hidden_units)},
            seed=self.cfg.seed + steps_before,
            device=self.run.device,
            verbose=0,
        )

    def _restore(self, model: SAC, spec: OvertakingPolicySpec, source: Path, resumed: bool) -> None:
        """Weights and optimisers from ``source``; the buffer: the stage's own (resumed), the newest rows of the
        previous stage's (a FIFO stage) or all of it."""
        try:
            state = read_agent(source / spec.model, self.fingerprint, spec.weights_sha256)
            restore_agent(model, state, str(source / spec.model))
            if resumed:
                if (self.folder / BUFFER_NAME).is_file():
                    self.buffer_restored = load_buffer(model.replay_buffer, self.folder / BUFFER_NAME, self.fingerprint)
            elif self.stage.fifo_from_previous:
                kept = ReplayBuffer(
                    int(spec.sac["buffer_size"]),
                    model.observation_space,
                    model.action_space,
                    device="cpu",
                    n_envs=self.cfg.racing.n_groups,
                )
                load_buffer(kept, source / BUFFER_NAME, self.fingerprint)
                self.buffer_restored = copy_newest(kept, model.replay_buffer)
                del kept
            else:
                self.buffer_restored = load_buffer(model.replay_buffer, source / BUFFER_NAME, self.fingerprint)
        except ArtifactError as exc:
            raise OvertakingRunError(f"cannot continue {self.folder}: {exc}") from None
        if self.buffer_restored == 0:  # never update on an empty buffer: refill it first
            model.learning_starts = model.num_timesteps + self.run.sac.learning_starts

    def _start_fresh(self, model: SAC) -> dict[str, Any]:
        """A stage that starts now: its exploration re-initialised where it asks so, and its new stage.json record."""
        if self.stage.reinit_exploration:
            reinit_exploration(model)
        return {
            "format": RUN_FORMAT,
            "stage": self.stage.to_dict(),
            "status": "running",
            "start_steps": int(model.num_timesteps),
            "start_train_time_s": round(self.train_time_before_s, 2),
            "buffer_at_start": int(self.buffer_restored) * self.cfg.racing.n_groups,
            "racing_config": racing_config_to_dict(self.racing_config),
        }

    # ------------------------------------------------------------------ periodic work
    @property
    def train_time_s(self) -> float:
        if self.frozen_train_time_s is not None:
            return self.frozen_train_time_s
        return self.train_time_before_s + time.perf_counter() - self.session_start

    def evaluate(self, model: SAC) -> dict[str, Any]:
        """The protocol lap racing alone and the overtaking return, appended to the stage's metrics.jsonl."""
        cfg, run = self.cfg, self.run
        t0 = time.perf_counter()
        if self.eval_driver is None:
            self.eval_driver = PolicyDriver.for_config(
                lambda obs: model.predict(obs, deterministic=True)[0],
                OBSERVATION,
                self.normalizer,
                None,
                self.racing_config,
            )
        timing = time_laps(
            self.eval_driver,
            cfg.racing.track,
            cfg.racing.car,
            range(cfg.evaluation.seeds),
            cfg.evaluation.laps,
            cfg.eval_time_limit_s,
        )
        summary = timing.summary()
        lap = summary["best_lap_time_s"]
        ai_lap = run.ai_lap_time_s()
        overtaking = overtaking_return(model, self.normalizer, cfg) if cfg.eval_episodes > 0 else {}
        eval_time_s = time.perf_counter() - t0
        self.session_start += eval_time_s  # evaluation time is not training time
        episodes = list(model.ep_info_buffer or [])
        record = {
            "stage": self.stage.name,
            "num_timesteps": int(model.num_timesteps),
            "train_time_s": round(self.train_time_s, 2),
            "n_updates": int(getattr(model, "_n_updates", 0)),
            "overtaking_return": overtaking.get("return"),
            "overtaken": overtaking.get("overtaken"),
            "lap_time_s": lap,
            "ai_lap_time_s": ai_lap,
            "finished": summary["n_finished"],
            "criterion_met": lap is not None and ai_lap is not None and lap <= (1.0 + cfg.stage1_margin) * ai_lap,
            "ep_rew_mean": float(np.mean([e["r"] for e in episodes])) if episodes else None,
            "eval_time_s": round(eval_time_s, 2),
        }
        with open(self.folder / METRICS_NAME, "a") as f:
            f.write(json_text(record) + "\n")
        if record["overtaking_return"] is not None:
            model.logger.record("eval/overtaking_return", record["overtaking_return"])
        if lap is not None:
            model.logger.record("eval/lap_time_s", lap)
        model.logger.dump(step=model.num_timesteps)
        self.last_eval = record
        return record

    def spec(self, model: SAC, sha256: str) -> OvertakingPolicySpec:
        return OvertakingPolicySpec(
            observation=OBSERVATION,
            racing_config=racing_config_to_dict(self.racing_config),
            obs_normalizer=self.normalizer.to_dict(),
            fingerprint=self.fingerprint,
            weights_sha256=sha256,
            model=MODEL_NAME,
            preset=self.cfg.sac.preset,
            sac=self.run.settings["sac"],
            seed=self.cfg.seed,
            num_timesteps=int(model.num_timesteps),
            train_time_s=round(self.train_time_s, 2),
            train_config={**self.run.settings, "agent_stage": self.stage.name},
        )

    def save(self, model: SAC, buffer: bool) -> None:
        """Weights then sidecar (a kill between leaves the sidecar naming the previous weights, kept beside the new
        ones as ``policy.pt.prev``), and the replay buffer when ``buffer``."""
        self.folder.mkdir(parents=True, exist_ok=True)
        sha = save_agent(model, self.folder / MODEL_NAME, self.fingerprint)
        self.spec(model, sha).write(self.folder / SIDECAR_NAME)
        if buffer and model.replay_buffer is not None:
            save_buffer(model.replay_buffer, self.folder / BUFFER_NAME, self.fingerprint)

    def finish(self, model: SAC) -> dict[str, Any]:
        self.frozen_train_time_s = round(self.train_time_s, 2)
        self.save(model, buffer=True)
        self.record.update(
            status="done",
            end_steps=int(model.num_timesteps),
            end_train_time_s=round(self.train_time_s, 2),
        )
        if self.stage.until_criterion:
            ai = self.run.ai_lap_time_s()
            self.record["criterion"] = {
                "rule": f"protocol lap time <= (1 + {self.cfg.stage1_margin}) x the built-in AI's "
                f"(evaluated every {self.cfg.evaluation.every_steps} steps)",
                "met": self.criterion_met_at is not None,
                "met_at_steps": self.criterion_met_at,
                "ai_lap_time_s": ai,
                "last_lap_time_s": self.last_eval["lap_time_s"] if self.last_eval else None,
            }
        write_run_record(self.folder / STAGE_NAME, self.record)
        return self.record

    def learn_with_samplers(self, model: SAC, loop: _StageLoop, cluster: Any) -> None:
        """The stage's steps from ``cfg.samplers.workers`` sampler actors, each a world of this stage's scenario; a lost
        sampler is a line of the stage's metrics.jsonl; when none is left, the stage is saved and the error raised."""
        from vision_rl.training.distributed import SamplersLostError, learn_like_sb3

        cfg = self.cfg
        setup = sampler_setup(
            self.racing_config,
            OBSERVATION,
            self.normalizer,
            self.fingerprint,
            self.run.sac.hidden_units,
            cfg.seed + int(model.num_timesteps),
        )

        def log_event(record: dict[str, Any]) -> None:
            with open(self.folder / METRICS_NAME, "a") as f:
                f.write(
                    json_text({**record, "stage": self.stage.name, "train_time_s": round(self.train_time_s, 2)}) + "\n"
                )

        try:
            learn_like_sb3(
                model,
                setup,
                cluster,
                samplers=cfg.samplers,
                total_timesteps=self.end_steps,
                callback=loop,
                log_event=log_event,
            )
        except SamplersLostError as exc:
            self.save(model, buffer=True)
            self.close()
            raise SamplersLostError(f"{exc}; {self.folder} was saved: run the same command to continue") from None

    def close(self) -> None:
        self.env.close()
        if self.eval_driver is not None:
            self.eval_driver.close()


def _differs(path: Path, recorded: dict[str, Any], wanted: dict[str, Any]) -> str:
    for key, want in wanted.items():
        if recorded.get(key) != want:
            return (
                f"{path} was started with {key} = {recorded.get(key)!r}, not {want!r}: use its settings, "
                "another --out, or --force to start over"
            )
    return f"{path} holds other settings: use another --out or --force"


def overtaking_return(model: SAC, normalizer: ObsNormalizer, cfg: TrainOvertakingConfig) -> dict[str, float]:
    """Mean summed Eq. 2 reward (``c_w = c_c = 0.005``) and mean opponents passed over ``cfg.eval_episodes``
    fixed-seed stage-2 episodes of the deterministic policy (all episodes at once, one world)."""
    episode_s = cfg.eval_episode_s or cfg.racing.episode_s
    config = dataclasses.replace(
        cfg.racing,
        scenario="stage2",
        n_groups=cfg.eval_episodes,
        episode_s=episode_s,
        wall_penalty_c_w=PENALTY_STAGE2,
        car_penalty_c_c=PENALTY_STAGE2,
    )
    core = RacingCore(config, seed=EVAL_EPISODE_SEED)
    core.observer.normalizer = normalizer
    try:
        core.reset_groups(np.arange(cfg.eval_episodes))
        total = np.zeros(cfg.eval_episodes)
        infos: list[dict] = []
        for _ in range(config.max_episode_steps):
            action, _ = model.predict(core.observation(), deterministic=True)
            _, reward, _, _, infos = core.step(action, autoreset=False)
            total += reward
        return {"return": float(total.mean()), "overtaken": float(np.mean([i["overtaken"] for i in infos]))}
    finally:
        core.observer.close()


class OvertakingRun:
    """A run folder: shared settings, the built-in AI's reference lap, and its stages."""

    def __init__(self, cfg: TrainOvertakingConfig) -> None:
        check_config(cfg)
        self.cfg = cfg
        self.out = Path(cfg.out) if cfg.out else default_out(cfg)
        self.device = torch_device(cfg.device)
        self.sac = resolve_preset(cfg.sac)
        self.settings = shared_settings(cfg)
        self.stages = stages_of(cfg)
        run_path = self.out / RUN_NAME
        if run_path.is_file() and not cfg.force:
            recorded = _read_json(run_path)
            if recorded.get("settings") != self.settings:
                raise OvertakingRunError(_differs(run_path, recorded.get("settings") or {}, self.settings))
            self.record = recorded
        else:
            if cfg.force and self.out.exists():
                clear_folder(self.out)  # the folder itself holds train_overtaking's lock
            elif self.out.exists() and any(self.out.iterdir()):
                raise OvertakingRunError(f"{self.out} is not empty and holds no {RUN_NAME}: give another --out")
            self.record = {"format": RUN_FORMAT, "settings": self.settings, "ai_lap_time_s": None}
            write_run_record(run_path, self.record)
        if cfg.stage1_from and not (self.out / "stage1").exists():
            self.adopt_stage1(Path(cfg.stage1_from))
        if self.sac.torch_threads > 0:
            torch.set_num_threads(self.sac.torch_threads)

    def adopt_stage1(self, source: Path) -> None:
        """Link ``source``'s finished stage 1 into this run folder, refusing a source of other settings (c_r and c_d
        aside) or an unfinished stage 1; the built-in AI's lap, timed on the same protocol, comes along."""
        theirs = _read_json(source / RUN_NAME) if (source / RUN_NAME).is_file() else None
        if theirs is None:
            raise OvertakingRunError(f"--stage1-from {source}: no {RUN_NAME} there: give a train-overtaking run folder")
        other = theirs.get("settings") or {}
        mine = {k: v for k, v in self.settings.items() if k not in STAGE1_FREE_SETTINGS}
        for key, want in mine.items():
            if other.get(key) != want:
                raise OvertakingRunError(f"--stage1-from {source}: its {key} is {other.get(key)!r}, not {want!r}")
        record = source / "stage1" / STAGE_NAME
        if not record.is_file() or _read_json(record).get("status") != "done":
            raise OvertakingRunError(f"--stage1-from {source}: its stage1 is not done")

        def link(src: str, dst: str) -> None:
            try:
                os.link(src, dst)
            except OSError:  # another filesystem
                shutil.copy2(src, dst)

        shutil.copytree(source / "stage1", self.out / "stage1", copy_function=link)
        self.record.update(
            {k: theirs[k] for k in ("ai_lap_time_s", "ai_timing") if k in theirs}, stage1_from=str(source)
        )
        write_run_record(self.out / RUN_NAME, self.record)

    def ai_lap_time_s(self) -> float | None:
        """The built-in AI's lap time on the evaluation's protocol (computed once per run folder)."""
        if "ai_timing" not in self.record:
            cfg = self.cfg
            timing = time_laps(
                BuiltinAI(),
                cfg.racing.track,
                cfg.racing.car,
                range(cfg.evaluation.seeds),
                cfg.evaluation.laps,
                cfg.eval_time_limit_s,
            ).summary()
            self.record.update(ai_lap_time_s=timing["best_lap_time_s"], ai_timing={"n_finished": timing["n_finished"]})
            write_run_record(self.out / RUN_NAME, self.record)
        return self.record["ai_lap_time_s"]

    def stage_record(self, stage: Stage) -> dict[str, Any] | None:
        path = self.out / stage.name / STAGE_NAME
        return _read_json(path) if path.is_file() else None


def train_overtaking(cfg: TrainOvertakingConfig, progress: Progress | None = None) -> dict[str, Any]:
    """Train the stages of ``cfg.agent`` that are not done yet (continuing an interrupted one); returns the stage
    boundaries and the agent's policy folder. Ctrl-C (or SIGTERM where the caller maps it) saves the stage and
    returns with ``interrupted``."""
    from vision_rl.training.distributed import cluster_for

    if (
        cfg.samplers.workers is not None
    ):  # Ray's cluster and the worker count are checked before the run folder is touched
        check_config(cfg)
    out = Path(cfg.out) if cfg.out else default_out(cfg)
    # Two runs in one folder (a --force of a running one) deleted each other's files: the second is refused.
    with (
        cluster_for(cfg.samplers.workers, cfg.samplers.address) as cluster,
        run_folder_locked(out, "a running train-overtaking"),
    ):
        return _train_stages(cfg, cluster, progress)


def _train_stages(cfg: TrainOvertakingConfig, cluster: Any, progress: Progress | None) -> dict[str, Any]:
    run = OvertakingRun(cfg)
    interrupted = False
    trained: list[str] = []
    for stage in run.stages:
        record = run.stage_record(stage)
        if record is not None and record.get("stage") != stage.to_dict():
            raise OvertakingRunError(
                _differs(run.out / stage.name / STAGE_NAME, record.get("stage") or {}, stage.to_dict())
            )
        if record is not None and record.get("status") == "done":
            continue
        if stage.previous is not None:
            previous = run.stage_record(next(s for s in run.stages if s.name == stage.previous))
            if previous is None or previous.get("status") != "done":
                raise OvertakingRunError(f"{run.out}: {stage.previous} is not done before {stage.name}")
        session = _StageSession(run, stage)
        model = session.build()
        loop = _StageLoop(session, progress)
        remaining = session.end_steps - int(model.num_timesteps)
        try:
            if remaining > 0 and cluster is not None:
                session.learn_with_samplers(model, loop, cluster)
            elif remaining > 0:
                learn_between_interrupts(
                    model, loop, total_timesteps=remaining, reset_num_timesteps=False, log_interval=4
                )
        except KeyboardInterrupt:
            interrupted = True
        if interrupted:
            session.save(model, buffer=True)
            session.close()
            break
        session.finish(model)
        session.close()
        trained.append(stage.name)
    boundaries = []
    for stage in run.stages:
        record = run.stage_record(stage) or {}
        boundaries.append(
            {
                "stage": stage.name,
                "status": record.get("status", "not started"),
                "start_steps": record.get("start_steps"),
                "end_steps": record.get("end_steps"),
                "start_train_time_s": record.get("start_train_time_s"),
                "end_train_time_s": record.get("end_train_time_s"),
                "penalty_c": stage.penalty_c,
                "buffer_size": stage.buffer_size,
                "criterion": record.get("criterion"),
            }
        )
    policy = run.out / run.stages[-1].name
    result = {
        "out": str(run.out),
        "agent": cfg.agent,
        "policy": str(policy),
        "stages": boundaries,
        "trained_now": trained,
        "interrupted": interrupted,
        "ai_lap_time_s": run.record.get("ai_lap_time_s"),
        "done": all(b["status"] == "done" for b in boundaries),
    }
    if result["done"]:
        write_run_record(
            agent_record_path(run.out, cfg.agent),
            {"agent": cfg.agent, "policy": str(policy), "stages": boundaries},
        )
    return result


def agent_record_path(out: Path, agent: str) -> Path:
    """Where a finished agent's summary goes: ``agentN.json``, or ``standard.json`` for standard SAC."""
    return out / ("standard.json" if agent == "standard" else f"agent{agent}.json")


def convert_overtaking_run(run: str | os.PathLike[str]) -> list[Path]:
    """Seal a run folder written before its records were sealed, in place; returns the files written. Each stage's
    policy and replay buffer go through :func:`~vision_rl.training.artifact.convert_run` first (their weights'
    SHA-256 checked), then each record is checked against them (:func:`_stage_problem`, :func:`_agent_problem`) and
    sealed: nothing is sealed that disagrees with the checked weights. Records sealed already must be intact."""
    run = Path(run)
    records = {run / RUN_NAME: _record_to_convert(run / RUN_NAME)}
    if not isinstance(records[run / RUN_NAME].get("settings"), dict):
        raise OvertakingRunError(f"{run / RUN_NAME}: holds no settings")
    written: list[Path] = []
    stages: dict[str, dict[str, Any]] = {}
    for path in sorted(run.glob(f"*/{STAGE_NAME}")):
        try:
            written += convert_run(path.parent)
        except PolicyError as exc:
            raise OvertakingRunError(str(exc)) from None
        stages[path.parent.name] = records[path] = _record_to_convert(path)
    for path, record in records.items():
        problem = _stage_problem(path, record, stages) if path.name == STAGE_NAME else None
        if problem is not None:
            raise OvertakingRunError(f"{path}: {problem}; not sealed")
    for path in sorted([*run.glob("agent*.json"), run / "standard.json"]):
        if path.is_file():
            records[path] = _record_to_convert(path)
            problem = _agent_problem(records[path], stages)
            if problem is not None:
                raise OvertakingRunError(f"{path}: {problem}; not sealed")
    for path, record in records.items():  # every record checked before the first is written
        if CONTENT_KEY not in record:
            write_run_record(path, record)
            written.append(path)
    return written


def _stage_problem(path: Path, record: dict[str, Any], stages: dict[str, dict[str, Any]]) -> str | None:
    """What in a stage record disagrees with its stage's checked policy sidecar or with the stage before it."""
    try:
        stage = Stage(**record["stage"])
    except (KeyError, TypeError) as exc:
        return f"its stage is not one of train-overtaking ({exc})"
    spec = read_overtaking_spec(path.parent / SIDECAR_NAME)
    previous = stages.get(stage.previous or "", {})
    if stage.name != path.parent.name:
        return f"names stage {stage.name!r} in folder {path.parent.name!r}"
    if record.get("status") not in ("running", "done") or not _whole(record.get("start_steps")):
        return f"status {record.get('status')!r} and start_steps {record.get('start_steps')!r} are not a stage's"
    if record.get("racing_config") != spec.racing_config:
        return f"its racing_config differs from {SIDECAR_NAME}'s"
    if previous.get("status") == "done" and record["start_steps"] != previous.get("end_steps"):
        return f"starts at step {record['start_steps']}, not where {stage.previous} ended ({previous.get('end_steps')})"
    done = (record.get("end_steps"), record.get("end_train_time_s"))
    if record["status"] == "done" and done != (spec.num_timesteps, spec.train_time_s):
        return (
            f"ends at step {done[0]} after {done[1]} s, its policy at {spec.num_timesteps} after {spec.train_time_s} s"
        )
    if spec.num_timesteps < record["start_steps"]:
        return f"starts at step {record['start_steps']}, after its policy's {spec.num_timesteps}"
    return None


def _agent_problem(record: dict[str, Any], stages: dict[str, dict[str, Any]]) -> str | None:
    """What in an agent's summary disagrees with its stages' records."""
    listed = record.get("stages")
    if not isinstance(listed, list) or not listed:
        return "lists no stages"
    for entry in listed:
        name = entry.get("stage") if isinstance(entry, dict) else None
        own = stages.get(name) if isinstance(name, str) else None
        if own is None:
            return f"lists stage {name!r}, which has no {STAGE_NAME}"
        for key in ("status", "start_steps", "end_steps", "start_train_time_s", "end_train_time_s"):
            if entry.get(key) != own.get(key):
                return f"its {name} {key} is {entry.get(key)!r}, its {STAGE_NAME}'s {own.get(key)!r}"
    return None


def _whole(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def read_metrics(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """The evaluation records of a stage's metrics.jsonl, as :func:`~vision_rl.phase2_rl.train.read_metrics` reads
    them (a torn last line, event lines and the evaluations a resume from an older checkpoint replaced are left
    out); none when the stage has not started."""
    path = Path(path)
    return read_train_metrics(path) if path.is_file() else []


def learning_curve(out: str | os.PathLike[str], agent: str) -> dict[str, Any]:
    """One agent's evaluations over its stages in order (cumulative steps and training seconds), the steps where
    each stage after the first began, and whether the agent has finished (its record written)."""
    cfg = TrainOvertakingConfig(agent=agent, stage1_max_steps=1, stage2_steps=1, stage3_steps=2)
    names = [s.name for s in stages_of(cfg)]
    out = Path(out)
    records, switches = [], []
    for i, name in enumerate(names):
        stage_path = out / name / STAGE_NAME
        if i > 0 and stage_path.is_file():
            switches.append({"stage": name, "num_timesteps": _read_json(stage_path).get("start_steps")})
        records += read_metrics(out / name / METRICS_NAME)
    finished = agent_record_path(out, agent).is_file()
    return {"agent": agent, "out": str(out), "records": records, "stage_switches": switches, "finished": finished}


__all__ = [
    "OvertakingPolicySpec",
    "OvertakingRunError",
    "agent_record_path",
    "convert_overtaking_run",
    "copy_newest",
    "learning_curve",
    "load_overtaking_policy",
    "reinit_exploration",
    "stages_of",
    "train_overtaking",
    "write_run_record",
]
