"""`train-policy`: SAC (Stable-Baselines3) on the batched racing env, from the 38-D privileged state or, with
``--encoder``, from the frozen 64-D frame embedding plus the 11 dedicated features (vision paper, section 3
"Phase 2" and section 4). A run folder holds the policy artifact, the replay buffer, snapshots, ``metrics.jsonl``
and TensorBoard logs; it survives a kill (time-based checkpoints, Ctrl-C and SIGTERM save) and ``--resume``
continues it, in this process or with ``--workers`` Ray samplers.

The run folder, ``--select-starts`` and what survives a kill: docs/notes/phase2_rl.md.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import VecMonitor

from vision_rl.config import flat_fields, flat_values, resume_conflicts
from vision_rl.envs.observations import ObservationKind, ObsNormalizer
from vision_rl.envs.vector import make_sb3_vec_env
from vision_rl.evaluation.protocol import CLEAN_WALL_CONTACT_S, time_laps
from vision_rl.files import atomic_write, clear_folder, json_text, lock_run_folder
from vision_rl.phase1_repr.onnx_runtime import resolve_runtime
from vision_rl.phase2_rl.config import SELECT_SEED_BASE, TrainPolicyConfig, check_bounds
from vision_rl.training.artifact import (
    BEST_DIR,
    BUFFER_NAME,
    MODEL_NAME,
    SIDECAR_NAME,
    PolicyDriver,
    PolicyError,
    PolicySpec,
    chosen_weights,
    load_checked_encoder,
    policy_fingerprint,
    racing_config_to_dict,
    snapshot_sidecar,
)
from vision_rl.training.critic_state import sac_policy_class
from vision_rl.training.interrupts import learn_between_interrupts
from vision_rl.training.persist import ArtifactError, load_buffer, read_agent, restore_agent, save_agent, save_buffer
from vision_rl.training.presets import SACPreset, resolve_preset
from vision_rl.training.sac import (
    METRICS_NAME,
    Progress,
    SaveClock,
    gamma_per_step,
    next_multiple,
    sampler_setup,
    torch_device,
)

if TYPE_CHECKING:
    from vision_rl.phase1_repr.checkpoint import FrozenEncoder


def default_out(cfg: TrainPolicyConfig) -> Path:
    kind = cfg.kind.value
    track = cfg.racing.track.replace("random:", "random-")
    if track.endswith(".csv") or os.sep in track:
        track = Path(track).stem
    return Path("runs") / "policy" / f"{kind}-{track}-{cfg.racing.car}-s{cfg.seed}"


class _TrainingLoop(BaseCallback):
    """Progress, periodic evaluation (TensorBoard + metrics.jsonl) and checkpoints, on environment steps."""

    def __init__(self, run: _Run, progress: Progress | None) -> None:
        super().__init__()
        self.run = run
        self.progress = progress
        cfg = run.cfg
        self.next_eval = next_multiple(run.start_steps, cfg.evaluation.every_steps)
        self.saves = SaveClock(run.start_steps, cfg.checkpoints.every_steps, cfg.checkpoints.every_min)

    def _eval_due(self) -> bool:
        return self.next_eval is not None and self.num_timesteps >= self.next_eval

    def _on_step(self) -> bool:
        n = self.num_timesteps
        # SB3 updates once more after the rollout that reaches the last step: that evaluation waits for the end of
        # training, so the curve's last point times the weights that are saved (it timed those of one update
        # before, and a knife-edge corner could finish another start in the final evaluation).
        if self._eval_due() and n < self.run.cfg.steps:
            self.run.evaluate(self.model)
            self.next_eval = next_multiple(n, self.run.cfg.evaluation.every_steps)
        if self.progress is not None:
            self.progress(n, self.run.cfg.steps, self.run.last_eval)
        kind = self.saves.due(n)
        if kind is not None:
            self.run.save(self.model, buffer=kind == "full", snapshot=kind == "full")
        return True

    def evaluate_held_back(self) -> None:
        """After training: the evaluation due at the last step (held back by :meth:`_on_step`), then its progress
        call, as :meth:`_on_step` makes after an evaluation (``vision-rl tune`` reports the evaluations from it)."""
        if self._eval_due():
            self.run.evaluate(self.model)
            if self.progress is not None:
                self.progress(self.num_timesteps, self.run.cfg.steps, self.run.last_eval)


#: The options a resumed run takes from its own start (its environment, SAC settings, seed, guidance, selection).
RESUME_KEEPS = tuple(
    flat.name
    for flat in flat_fields(TrainPolicyConfig)
    if flat.path[0] in ("racing", "sac")
    or flat.name in ("seed", "select_starts", "select_clean")
    or flat.name.startswith("guide_")
)


class _Run:
    """One training session of a run folder: environments, model, artifact and bookkeeping."""

    def __init__(self, cfg: TrainPolicyConfig) -> None:
        self.cfg = cfg
        self.out = Path(cfg.out) if cfg.out else default_out(cfg)
        self.device = torch_device(cfg.device)
        self.previous: PolicySpec | None = None
        check_bounds(flat_values(cfg))
        resolve_runtime(cfg.encoder_runtime, self.device)  # a bad value is refused before the run folder is touched
        if cfg.resume:
            if not (self.out / MODEL_NAME).is_file() or not (self.out / SIDECAR_NAME).is_file():
                raise FileNotFoundError(f"{self.out}: nothing to resume (no {MODEL_NAME} and {SIDECAR_NAME})")
            self.previous = PolicySpec.read(self.out / SIDECAR_NAME)
            check_resumable(self.previous, self.out / SIDECAR_NAME)
            conflicts = resume_conflicts(cfg, self.previous.train_config, RESUME_KEEPS)
            if conflicts:
                raise PolicyError(
                    f"{self.out}: a resumed run keeps its own settings, and these options differ from them: "
                    f"{', '.join(conflicts)}; leave them out or start a new run in another --out"
                )
        self.preset = resolve_preset(cfg.sac) if self.previous is None else _preset_from_spec(self.previous)
        if self.previous is None and cfg.steps <= self.preset.learning_starts:
            raise ValueError(
                f"--steps {cfg.steps} is not above the {self.preset.learning_starts} random start steps "
                f"(--learning-starts, preset {cfg.sac.preset!r}): training would make no update"
            )
        if self.previous is None and cfg.encoder and not Path(cfg.encoder).is_file():
            raise FileNotFoundError(f"{cfg.encoder}: no such encoder checkpoint")
        if self.previous is not None and not self.previous.kind.sees_frames and cfg.encoder:
            raise PolicyError(f"the run in {self.out} observes state; it cannot resume with an --encoder")
        if self.preset.torch_threads > 0:  # before the encoder loads: ONNX Runtime takes torch's thread count
            torch.set_num_threads(self.preset.torch_threads)
        self.encoder = self._load_encoder()  # the one read of the checkpoint: its frame size and hash come from it
        # Checked only now, so that a bad option never deletes the run it would have replaced; the folder is
        # locked first, so that a second writer of a running run is refused with its files intact.
        self._lock_fd: int | None = lock_run_folder(self.out, "a running train-policy")
        if self.previous is None and ((self.out / SIDECAR_NAME).exists() or (self.out / MODEL_NAME).exists()):
            if not cfg.force:
                self.release_folder()
                raise FileExistsError(f"{self.out} holds a run: pass --resume to continue it or --force to start over")
            clear_folder(self.out)
        if self.previous is not None:
            self.kind = self.previous.kind
            self.racing = self.previous.config
            self.start_steps = self.previous.num_timesteps
            self.train_time_before_s = self.previous.train_time_s
        else:
            self.kind = cfg.kind
            image_hw = self.encoder.input_hw_px if self.encoder is not None else cfg.racing.image_hw_px
            self.racing = dataclasses.replace(cfg.racing, observation=self.kind.value, image_hw_px=image_hw)
            self.start_steps = 0
            self.train_time_before_s = 0.0
        self.seed = self.previous.seed if self.previous is not None else cfg.seed  # a resumed run keeps its own
        self.session_start = time.perf_counter()
        self.last_eval: dict[str, Any] | None = None
        # A resumed run goes on from the weights it kept (a kill may have rolled it back before them: they stay).
        best = chosen_weights(self.out) if self.previous is not None else None
        selection = PolicySpec.read(best / SIDECAR_NAME).selection if best else None
        self.best_mean_lap_s: float | None = selection["mean_lap_time_s"] if selection else None

    # ------------------------------------------------------------------ set-up
    def _load_encoder(self) -> FrozenEncoder | None:
        """The frozen encoder of a vision run: --encoder for a new run, the recorded one (or --encoder, checked
        against its hash) for a resumed run; None for a state run."""
        cfg, where = self.cfg, dict(device=self.device, runtime=self.cfg.encoder_runtime)
        if self.previous is not None:
            if not self.previous.kind.sees_frames:
                return None
            return load_checked_encoder(self.previous, cfg.encoder, f"the run in {self.out}", **where)
        if not cfg.encoder:
            return None
        from vision_rl.phase1_repr.checkpoint import load_encoder

        return load_encoder(cfg.encoder, **where)

    def build(self) -> SAC:
        """The environments, the SAC model (restored for a resumed run) and the guided start, as configured."""
        # A resumed session draws new start points: reusing the first session's would replay its episodes.
        venv = make_sb3_vec_env(self.racing, seed=self.seed + self.start_steps)
        self.venv = venv
        self._observe(venv)
        self.env = VecMonitor(venv)
        model = self._model(venv)
        model.set_logger(configure(str(self.out / "tensorboard"), ["tensorboard"]))
        encoder_sha = self.encoder.sha256 if self.encoder is not None else None
        self.fingerprint = policy_fingerprint(self.racing, self.kind, venv.observation_space.shape[0], encoder_sha)
        self._guide(model, venv)
        self.eval_driver: PolicyDriver | None = None
        return model

    def _observe(self, venv: Any) -> None:
        """The environment's observer and its normalisation: the run's own numbers when it resumes."""
        core = venv.core
        if self.encoder is not None:
            # The SAC input is the vision vector (with the critic's state after it): the env's observer embeds the
            # frames with the frozen encoder, so the replay buffer holds vectors, not images.
            observer = core.vision_observer(self.encoder)
            if self.previous is not None:
                observer.normalizer = self.previous.normalizer
            else:
                # Statistics of the embedding are not cached per track: they belong to this encoder, and are stored
                # with the policy and never recomputed for it.
                samples = core.sample_raw_observations(observer, self.cfg.stats_steps)
                observer.normalizer = ObsNormalizer.from_samples(ObservationKind.VISION, samples)
            core.observer.close()
            core.observer = observer
            venv.observation_space = observer.space
        elif self.previous is not None:
            core.observer.normalizer = self.previous.normalizer  # the numbers it was trained with, not the cache's
        self.normalizer = core.observer.normalizer

    @property
    def _cloning(self) -> bool:
        """Whether the actor also clones the built-in AI (its transitions or its labels): a guided SAC."""
        return (
            self._kept("guide_bc_weight") > 0
            or self._kept("guide_label_weight") > 0
            or (self.previous is None and self.cfg.guide_pretrain_steps > 0)
        )

    def _model(self, venv: Any) -> SAC:
        p = self.preset
        if self._cloning:
            from vision_rl.phase2_rl.guide import guided_sac_class
        policy_class, policy_kwargs = sac_policy_class(venv.observation_space.shape[0], self.racing.critic_state)
        return (guided_sac_class() if self._cloning else SAC)(
            policy_class,
            self.env,
            learning_rate=p.learning_rate_schedule(),
            buffer_size=p.buffer_size,
            learning_starts=p.learning_starts,
            batch_size=p.batch_size,
            tau=p.tau,
            gamma=gamma_per_step(p.gamma, self.racing.control_dt_s),
            train_freq=(p.train_freq_steps, "step"),
            gradient_steps=p.gradient_steps,
            policy_kwargs={"net_arch": list(p.hidden_units), **policy_kwargs},
            seed=self.seed + self.start_steps,
            target_entropy=p.target_entropy or "auto",
            device=self.device,
            verbose=0,
            n_steps=self.cfg.n_step,
        )

    def _guide(self, model: SAC, venv: Any) -> None:
        """The AI's labels, the run's restored state (or the AI's transitions in a new run's buffer), and the
        cloning weights of a guided SAC."""
        self.buffer_restored = 0
        self.guided_transitions = 0
        label_weight = self._kept("guide_label_weight")
        if label_weight > 0:  # before a restore, which fills the labels' array too
            from vision_rl.phase2_rl.guide import start_labels

            start_labels(
                model,
                venv,
                label_weight,
                fade_steps=int(self._kept("guide_label_fade_steps")),
                end_steps=self.cfg.steps,
                steer_weight=self._kept("guide_label_steer_weight", 1.0),
            )
        if self.previous is not None:
            self._restore(model)
        elif self.cfg.guide_steps > 0:
            from vision_rl.phase2_rl.guide import add_guided_transitions

            self.guided_transitions = add_guided_transitions(model, venv, self.cfg.guide_steps)
        if self._cloning and (self.previous is None or self.buffer_restored):
            # The guided rows lead the buffer; a resumed run finds them there when its buffer was saved.
            guided = self.guided_transitions or (
                int(self.previous.train_config.get("guide_steps", 0)) if self.previous is not None else 0
            )
            model.demo_rows = -(-guided // self.racing.n_groups)
            model.bc_weight = self._kept("guide_bc_weight")
            if self.previous is None and self.cfg.guide_pretrain_steps > 0:
                model.clone(self.cfg.guide_pretrain_steps, self.preset.batch_size)

    def _kept(self, name: str, default: float = 0.0) -> float:
        """The run's value of a setting a resumed run keeps from its start (``default`` for a run older than it)."""
        config = self.previous.train_config if self.previous is not None else flat_values(self.cfg)
        return float(config.get(name, default))

    def _restore(self, model: SAC) -> None:
        """Weights, optimisers and counters of the run, and its buffer when one was saved."""
        assert self.previous is not None
        try:
            state = read_agent(self.out / self.previous.model, self.fingerprint, self.previous.weights_sha256)
            restore_agent(model, state, str(self.out / self.previous.model))
            if (self.out / BUFFER_NAME).is_file():
                self.buffer_restored = load_buffer(model.replay_buffer, self.out / BUFFER_NAME, self.fingerprint)
        except ArtifactError as exc:
            raise PolicyError(f"cannot resume: {exc}") from None
        if self.buffer_restored == 0:  # never update on an empty buffer: refill it first
            model.learning_starts = model.num_timesteps + self.preset.learning_starts

    # ------------------------------------------------------------------ periodic work
    @property
    def train_time_s(self) -> float:
        return self.train_time_before_s + time.perf_counter() - self.session_start

    def evaluate(self, model: SAC) -> dict[str, Any]:
        """The protocol (cfg.evaluation.laps laps, last scored) with the current deterministic policy, logged."""
        cfg = self.cfg
        train_time_s = self.train_time_s
        t0 = time.perf_counter()
        if self.eval_driver is None:
            self.eval_driver = PolicyDriver.for_config(
                lambda obs: model.predict(obs, deterministic=True)[0],
                self.kind.value,
                self.normalizer,
                self.encoder,
                self.racing,
            )
        timing = time_laps(
            self.eval_driver, self.racing.track, self.racing.car, range(cfg.evaluation.seeds), cfg.evaluation.laps
        )
        summary = timing.summary()
        episodes = list(model.ep_info_buffer or [])
        record = {
            "num_timesteps": int(model.num_timesteps),
            "train_time_s": round(train_time_s, 2),
            "n_updates": int(getattr(model, "_n_updates", 0)),
            "lap_time_s": summary["best_lap_time_s"],
            "lap_times_s": [[lap["lap_time_s"] for lap in s["laps"]] for s in summary["seeds"]],
            "finished": summary["n_finished"],
            "scored_lap_times_s": [s["lap_time_s"] for s in summary["seeds"]],
            "scored_wall_contact_s": [
                s["laps"][-1]["wall_contact_s"] if s["finished"] else 0.0 for s in summary["seeds"]
            ],
            "limit_lap_time_s": summary["limit_lap_time_s"],
            "dnf_reasons": [s["dnf_reason"] for s in summary["seeds"]],
            "distance_m": float(np.mean([s["distance_m"] for s in summary["seeds"]])),
            "wall_contact_s": None if summary["best_lap"] is None else summary["best_lap"]["wall_contact_s"],
            "wall_contact_per_lap_s": float(
                np.mean([lap["wall_contact_s"] for s in summary["seeds"] for lap in s["laps"]] or [np.nan])
            ),
            "ep_rew_mean": float(np.mean([e["r"] for e in episodes])) if episodes else None,
        }
        starts = int(self._kept("select_starts"))
        if starts:
            record["selection"] = self._select(model, starts)
        eval_time = time.perf_counter() - t0
        self.session_start += eval_time  # evaluation time is not training time
        record["eval_time_s"] = round(eval_time, 2)
        with open(self.out / METRICS_NAME, "a") as f:
            f.write(json_text(record) + "\n")
        logger = model.logger
        logger.record("eval/distance_m", record["distance_m"])
        logger.record("eval/laps_finished", record["finished"])
        logger.record("eval/wall_contact_per_lap_s", record["wall_contact_per_lap_s"])
        if record["lap_time_s"] is not None:
            logger.record("eval/lap_time_s", record["lap_time_s"])
        logger.record("time/train_time_s", record["train_time_s"])
        logger.dump(step=model.num_timesteps)
        self.last_eval = record
        return record

    def spec(self, model: SAC, weights_name: str, weights_sha256: str) -> PolicySpec:
        encoder = None
        if self.kind.sees_frames:
            assert self.encoder is not None
            encoder = {
                "path": str(self.encoder.path.resolve()),
                "sha256": self.encoder.sha256,
                "rep_dim": int(self.encoder.rep_dim),
                "input_hw_px": list(self.encoder.input_hw_px),
            }
        sac = dataclasses.asdict(self.preset)
        return PolicySpec(
            observation=self.kind.value,
            racing_config=racing_config_to_dict(self.racing),
            obs_normalizer=self.normalizer.to_dict(),
            fingerprint=self.fingerprint,
            weights_sha256=weights_sha256,
            encoder=encoder,
            model=weights_name,
            preset=self.previous.preset if self.previous is not None else self.cfg.sac.preset,
            sac=json.loads(json.dumps(sac)),
            seed=self.seed,
            num_timesteps=int(model.num_timesteps),
            train_time_s=round(self.train_time_s, 2),
            # A resumed run keeps the options it was started with (its track, car and cars win over the new ones).
            train_config=self.previous.train_config if self.previous is not None else flat_values(self.cfg),
        )

    def _select(self, model: SAC, starts: int) -> dict[str, Any]:
        """Time the held-out starts; keep the weights in best/ when every start finished (clean, unless the run was
        started with --no-select-clean) and their mean scored lap is the fastest so far."""
        seeds = list(range(SELECT_SEED_BASE, SELECT_SEED_BASE + starts))
        assert self.eval_driver is not None
        summary = time_laps(
            self.eval_driver, self.racing.track, self.racing.car, seeds, self.cfg.evaluation.laps
        ).summary()
        clean = all(s["clean"] for s in summary["seeds"])
        need_clean = bool(self._kept("select_clean", True))
        eligible = clean if need_clean else summary["n_finished"] == len(seeds)
        mean_lap_s = float(np.mean([s["lap_time_s"] for s in summary["seeds"]])) if eligible else None
        kept = mean_lap_s is not None and (self.best_mean_lap_s is None or mean_lap_s < self.best_mean_lap_s)
        if kept:
            self.best_mean_lap_s = mean_lap_s
            self._write_policy(
                model,
                self.out / BEST_DIR,
                selection={
                    "start_seeds": seeds,
                    "laps": self.cfg.evaluation.laps,
                    "mean_lap_time_s": mean_lap_s,
                    "clean_wall_contact_s": CLEAN_WALL_CONTACT_S if need_clean else None,
                },
            )
        return {"mean_lap_time_s": mean_lap_s, "finished": summary["n_finished"], "clean": clean, "kept": kept}

    def _write_policy(self, model: SAC, folder: Path, selection: dict[str, Any] | None = None) -> PolicySpec:
        """Weights and then the sidecar that names them: a kill between the two leaves the sidecar naming the
        previous weights, which stay beside the new ones (``policy.pt.prev``) and are what a load then reads."""
        folder.mkdir(exist_ok=True)
        sha = save_agent(model, folder / MODEL_NAME, self.fingerprint)
        spec = dataclasses.replace(self.spec(model, MODEL_NAME, sha), selection=selection)
        spec.write(folder / SIDECAR_NAME)
        return spec

    def save(self, model: SAC, buffer: bool = True, snapshot: bool = False) -> None:
        """Weights (policy.pt) and sidecar (:meth:`_write_policy`); the replay buffer when ``buffer`` (and
        cfg.save_buffer); with ``snapshot`` also checkpoints/policy_<steps>.pt and its sidecar."""
        spec = self._write_policy(model, self.out)
        if buffer and self.cfg.save_buffer and model.replay_buffer is not None:
            save_buffer(model.replay_buffer, self.out / BUFFER_NAME, self.fingerprint)
        if snapshot:
            weights = self.out / "checkpoints" / f"policy_{model.num_timesteps}.pt"
            weights.parent.mkdir(exist_ok=True)
            # Through a temporary file: a full disk left a cut policy_<steps>.pt without its sidecar.
            atomic_write(weights, lambda tmp: shutil.copyfile(self.out / MODEL_NAME, tmp))
            dataclasses.replace(spec, model=weights.name).write(snapshot_sidecar(weights))

    def close(self) -> None:
        self.env.close()
        if self.eval_driver is not None:
            self.eval_driver.close()

    def release_folder(self) -> None:
        """Let another writer have the run folder (once this session saved or failed)."""
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None


def check_resumable(previous: PolicySpec, sidecar: Path) -> None:
    """Refuse a resume of a run that train-policy did not make: a baseline's policy.json holds settings that are no
    SAC preset's (its resume raised a TypeError traceback)."""
    foreign = sorted(set(previous.sac) - {f.name for f in dataclasses.fields(SACPreset)})
    if foreign:
        raise PolicyError(
            f"{sidecar}: not a train-policy run (its settings hold {', '.join(foreign)}): resume it with the "
            "command that made it, or give another --out"
        )


def _preset_from_spec(spec: PolicySpec) -> SACPreset:
    sac = dict(spec.sac)
    sac["hidden_units"] = tuple(sac["hidden_units"])
    return SACPreset(**sac)


def train_policy(cfg: TrainPolicyConfig, progress: Progress | None = None) -> dict[str, Any]:
    """Train (or resume) as configured; returns where things went and the last evaluation. A KeyboardInterrupt
    (Ctrl-C, or SIGTERM where the caller maps it) saves everything and returns with ``interrupted``."""
    from vision_rl.training.distributed import cluster_for

    if cfg.samplers.workers is not None:  # Ray's cluster and the worker count, before the run folder is touched
        check_bounds(flat_values(cfg))
    with cluster_for(cfg.samplers.workers, cfg.samplers.address) as cluster:
        run = _Run(cfg)
        try:
            return _train(run, cfg, cluster, progress)
        finally:
            run.release_folder()


def _train(run: _Run, cfg: TrainPolicyConfig, cluster: Any, progress: Progress | None) -> dict[str, Any]:
    """:func:`train_policy` once its run folder is checked and locked."""
    model = run.build()
    loop = _TrainingLoop(run, progress)
    remaining = cfg.steps - run.start_steps
    interrupted = False
    sampling = None
    try:
        if remaining > 0 and cluster is not None:
            sampling = _learn_with_samplers(run, model, loop, cluster)
        elif remaining > 0:
            learn_between_interrupts(model, loop, total_timesteps=remaining, reset_num_timesteps=False, log_interval=4)
        loop.evaluate_held_back()
    except KeyboardInterrupt:
        interrupted = True
    run.save(model, buffer=True, snapshot=not interrupted and remaining > 0)
    run.close()
    return {
        "out": str(run.out),
        "policy": str(run.out / MODEL_NAME),
        "observation": run.kind.value,
        "num_timesteps": int(model.num_timesteps),
        "n_updates": int(getattr(model, "_n_updates", 0)),
        "train_time_s": round(run.train_time_s, 2),
        "interrupted": interrupted,
        "guided_transitions": run.guided_transitions,
        "resumed_from_steps": run.start_steps if cfg.resume else None,
        "buffer_restored": run.buffer_restored if cfg.resume else None,
        "last_eval": run.last_eval,
        "metrics_jsonl": str(run.out / METRICS_NAME),
        "tensorboard": str(run.out / "tensorboard"),
        "sampling": sampling,
    }


def _learn_with_samplers(run: _Run, model: SAC, loop: _TrainingLoop, cluster: Any) -> dict[str, Any]:
    """The session's steps from ``--workers`` sampler actors (:mod:`vision_rl.training.distributed`); the same
    evaluations, checkpoints and progress as the single-process loop, on the same step counts. A lost sampler is a
    line of metrics.jsonl; when none is left, the run is saved and the error raised."""
    from vision_rl.training.distributed import SamplersLostError, learn_like_sb3

    cfg = run.cfg
    setup = sampler_setup(
        run.racing,
        run.kind.value,
        run.normalizer,
        run.fingerprint,
        run.preset.hidden_units,
        run.seed + run.start_steps,
        run.encoder.path if run.encoder is not None else None,
        cfg.encoder_runtime,
        label_skill=getattr(model, "label_skill", None),
    )

    def log_event(record: dict[str, Any]) -> None:
        record = {**record, "train_time_s": round(run.train_time_s, 2)}
        with open(run.out / METRICS_NAME, "a") as f:
            f.write(json_text(record) + "\n")

    try:
        return learn_like_sb3(
            model,
            setup,
            cluster,
            samplers=cfg.samplers,
            total_timesteps=cfg.steps,
            callback=loop,
            log_event=log_event,
        )
    except SamplersLostError as exc:
        run.save(model, buffer=True)
        run.close()
        raise SamplersLostError(f"{exc}; the run in {run.out} was saved: continue it with --resume") from None
