"""`train-ddpg`: DDPG with an asymmetric actor-critic on ``vision_rl/PixelRacing-v0`` (the Project CARS 2 paper), and
its ablations (``--variant symmetric``, ``state-actor``).

A run folder holds ``ddpg.pt`` (weights, targets, optimisers, noise, counters; no pickle), ``ddpg.json`` (its
sidecar: variant, environment, hyper-parameters, fingerprint, the weights' SHA-256, counters), ``replay/`` (the
buffer in chunk files, only changed chunks rewritten), ``metrics.jsonl`` (one line per periodic evaluation through
the lap-time protocol, with the critic's latest mean Q and loss) and ``episodes.jsonl`` (one line per finished
training episode: return, steps, distance, laps, why it ended). What survives a kill: the agent is saved every
``checkpoint_every_min`` minutes (light: no buffer) and, with the buffer, every ``checkpoint_every_steps``; Ctrl-C
(and SIGTERM, which the command maps to it) saves everything and returns. ``--resume`` continues with the stored
agent and buffer (without a saved buffer it collects ``learning_starts`` transitions before updating again) and cuts
``episodes.jsonl`` back to the checkpoint's episodes. ``--train-minutes`` bounds the run's training time over all
its sessions, for comparisons at equal wall-clock."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vision_rl.config import flat_fields, flat_values, resume_conflicts
from vision_rl.ddpg.agent import (
    AGENT_NAME,
    REPLAY_DIR,
    SEALED_FORMAT_VERSION,
    SIDECAR_NAME,
    DDPGAgent,
    DDPGDriver,
    DDPGError,
    DDPGHyper,
    FrameReplay,
    ddpg_fingerprint,
    load_replay,
    read_agent_file,
    read_run_sidecar,
    save_agent_file,
    save_replay,
)
from vision_rl.ddpg.config import TrainDDPGConfig, check_bounds
from vision_rl.ddpg.sampling import episode_record
from vision_rl.envs.pixel_racing import PixelRacingConfig, PixelRacingCore
from vision_rl.evaluation.leaderboard import evaluation_record
from vision_rl.evaluation.protocol import time_laps
from vision_rl.files import atomic_write, clear_folder, json_text, lock_run_folder, sealed_record, write_json
from vision_rl.signals import HeldSignal
from vision_rl.training.persist import ArtifactError, check_fingerprint
from vision_rl.training.sac import next_multiple, torch_device

METRICS_NAME = "metrics.jsonl"
EPISODES_NAME = "episodes.jsonl"
SIDECAR_FORMAT = "vision_rl.ddpg_run"
Progress = Callable[[int, int, dict[str, Any] | None], None]


def _read_sidecar(path: Path) -> dict[str, Any]:
    data = read_run_sidecar(path)
    if data.get("format") != SIDECAR_FORMAT:
        raise DDPGError(f"{path}: not a train-ddpg sidecar (no format {SIDECAR_FORMAT!r})")
    return data


def _drop_lost_episodes(path: Path, num_steps: int) -> None:
    """Keep the lines of episodes.jsonl that end before ``num_steps``, the resumed checkpoint's step count: those
    after it were lost with the kill and are driven again, and a line torn by the kill is no record."""
    if not path.is_file():
        return
    lines = path.read_text().splitlines()
    kept = []
    for line in lines:
        try:
            if json.loads(line)["num_steps"] < num_steps:
                kept.append(line)
        except (ValueError, KeyError, TypeError):
            continue
    if len(kept) != len(lines):
        atomic_write(path, lambda tmp: tmp.write_text("".join(line + "\n" for line in kept)))


#: The options a resumed run takes from its own start: the agent's hyper-parameters and its environment.
RESUME_KEEPS = tuple(flat.name for flat in flat_fields(TrainDDPGConfig) if flat.path[0] in ("hyper", "env"))


class _Run:
    def __init__(self, cfg: TrainDDPGConfig) -> None:
        check_bounds(flat_values(cfg))
        self.cfg = cfg
        # A track given as a CSV path must not add folders to the name: only its separators are replaced.
        track = cfg.env.track.replace(os.sep, "_")
        default = f"runs/ddpg/{cfg.variant}-{track}-{cfg.env.car}-s{cfg.seed}"
        self.out = Path(cfg.out or default)
        self.previous: dict[str, Any] | None = None
        if cfg.resume:
            if not (self.out / SIDECAR_NAME).is_file():
                raise DDPGError(f"{self.out}: no train-ddpg run to resume (no {SIDECAR_NAME})")
            self.previous = _read_sidecar(self.out / SIDECAR_NAME)
            if self.previous["hyper"]["variant"] != cfg.variant:
                raise DDPGError(
                    f"{self.out} holds a run of variant {self.previous['hyper']['variant']!r}, not {cfg.variant!r}: "
                    f"resume it with --variant {self.previous['hyper']['variant']} or start a new run in another --out"
                )
            conflicts = resume_conflicts(cfg, self.previous.get("train_config", {}), RESUME_KEEPS)
            if conflicts:
                raise DDPGError(
                    f"{self.out}: a resumed run keeps its own settings, and these options differ from them: "
                    f"{', '.join(conflicts)}; leave them out or start a new run in another --out"
                )
            self.hyper = DDPGHyper(**self.previous["hyper"])
            self.env = PixelRacingConfig.from_dict(self.previous["env"])
        else:
            self.hyper, self.env = cfg.agent_configs()
        # Locked before anything in it changes: a second writer of a running run is refused with its files intact.
        self._lock_fd: int | None = lock_run_folder(self.out, "a running train-ddpg")
        if not cfg.resume and ((self.out / SIDECAR_NAME).exists() or (self.out / AGENT_NAME).exists()):
            if not cfg.force:
                self.release_folder()
                raise FileExistsError(f"{self.out} holds a run: pass --resume to continue it or --force to start over")
            clear_folder(self.out)
        self.fingerprint = ddpg_fingerprint(self.hyper, self.env)
        counters = (self.previous or {}).get("counters", {})
        self.num_steps = int(counters.get("num_steps", 0))
        self.episodes = int(counters.get("episodes", 0))
        self.train_time_before_s = float(counters.get("train_time_s", 0.0))
        # CPU time tells what a shared core really gave a run of an equal-compute comparison (older runs: 0).
        self.train_cpu_before_s = float(counters.get("train_cpu_s", 0.0))
        if cfg.resume:
            _drop_lost_episodes(self.out / EPISODES_NAME, self.num_steps)
        self.start_clocks()
        self.last_eval: dict[str, Any] | None = None
        self.driver: DDPGDriver | None = None

    def start_clocks(self) -> None:
        """Training time (wall-clock and this process's CPU) counts from here on."""
        self.session_start, self.cpu_session_start = time.perf_counter(), time.process_time()

    @property
    def train_time_s(self) -> float:
        return self.train_time_before_s + time.perf_counter() - self.session_start

    @property
    def train_cpu_s(self) -> float:
        """CPU seconds of this process's training (all its threads; evaluations and Ray samplers excluded)."""
        return self.train_cpu_before_s + time.process_time() - self.cpu_session_start

    @property
    def out_of_time(self) -> bool:
        """The run has had its --train-minutes."""
        return self.cfg.train_minutes > 0 and self.train_time_s >= 60.0 * self.cfg.train_minutes

    def counters(self, agent: DDPGAgent) -> dict[str, Any]:
        return {
            "num_steps": self.num_steps,
            "n_updates": agent.n_updates,
            "episodes": self.episodes,
            "train_time_s": round(self.train_time_s, 2),
            "train_cpu_s": round(self.train_cpu_s, 2),
        }

    def save(self, agent: DDPGAgent, buffer: FrameReplay | None) -> None:
        """The agent, then its sidecar (which names the agent's SHA-256), then the buffer's changed chunks."""
        counters = self.counters(agent)
        train_config = json.loads(json.dumps(flat_values(self.cfg)))  # the options, flat
        sha = save_agent_file(agent, self.out / AGENT_NAME, self.fingerprint, counters)
        sidecar = {
            "format": SIDECAR_FORMAT,
            "format_version": SEALED_FORMAT_VERSION,
            "weights": AGENT_NAME,
            "weights_sha256": sha,
            "fingerprint": self.fingerprint,
            "hyper": dataclasses.asdict(self.hyper),
            "env": self.env.to_dict(),
            "counters": counters,
            "seed": (self.previous or {}).get("seed", self.cfg.seed),
            "train_config": (self.previous or {}).get("train_config", train_config),
        }
        write_json(self.out / SIDECAR_NAME, sealed_record(sidecar))
        if buffer is not None:
            save_replay(buffer, self.out / REPLAY_DIR, self.fingerprint)

    def evaluate(self, agent: DDPGAgent) -> dict[str, Any]:
        cfg = self.cfg
        t0, cpu0 = time.perf_counter(), time.process_time()
        if self.driver is None:
            self.driver = DDPGDriver(agent)
        timing = time_laps(
            self.driver,
            self.env.track,
            self.env.car,
            range(max(cfg.evaluation.seeds, 1)),
            cfg.evaluation.laps,
            time_limit_s=cfg.eval_time_limit_s,
        )
        summary = timing.summary()
        eval_time = time.perf_counter() - t0
        self.session_start += eval_time  # evaluation time is not training time
        self.cpu_session_start += time.process_time() - cpu0
        record = {
            "num_steps": self.num_steps,
            "n_updates": agent.n_updates,
            "episodes": self.episodes,
            "train_time_s": round(self.train_time_s, 2),
            "lap_time_s": summary["best_lap_time_s"],
            "finished": summary["n_finished"],
            "dnf_reasons": [s["dnf_reason"] for s in summary["seeds"]],
            "distance_m": float(np.mean([s["distance_m"] for s in summary["seeds"]])),
            "wall_contact_s": None if summary["best_lap"] is None else summary["best_lap"]["wall_contact_s"],
            "limit_lap_time_s": summary["limit_lap_time_s"],
            "eval_time_s": round(eval_time, 2),
            # The critic at this point (its latest update's batch): a mean Q far above the largest reward over
            # (1 - gamma) is a critic that has diverged (docs/notes/ddpg.md).
            **{key: float(agent.last_update[key]) if agent.last_update else None for key in ("q_mean", "critic_loss")},
        }
        with open(self.out / METRICS_NAME, "a") as f:
            f.write(json_text(record) + "\n")
        self.last_eval = record
        return record

    def close(self) -> None:
        if self.driver is not None:
            self.driver.close()

    def release_folder(self) -> None:
        """Let another writer have the run folder (once this session saved or failed)."""
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None


def train_ddpg(cfg: TrainDDPGConfig, progress: Progress | None = None) -> dict[str, Any]:
    """Train (or resume) as configured; returns where things went and the last evaluation. A KeyboardInterrupt
    (Ctrl-C, or SIGTERM where the caller maps it) saves everything and returns with ``interrupted``."""
    from vision_rl.training.distributed import cluster_for

    # The options, Ray's cluster and the worker count are checked before the run folder is touched.
    check_bounds(flat_values(cfg))
    with cluster_for(cfg.samplers.workers, cfg.samplers.address) as cluster:
        return _train(cfg, cluster, progress)


def _train(cfg: TrainDDPGConfig, cluster: Any, progress: Progress | None) -> dict[str, Any]:
    run = _Run(cfg)
    try:
        return _train_run(run, cfg, cluster, progress)
    finally:
        run.release_folder()


def _train_run(run: _Run, cfg: TrainDDPGConfig, cluster: Any, progress: Progress | None) -> dict[str, Any]:
    if cfg.torch_threads > 0:
        torch.set_num_threads(cfg.torch_threads)
    hyper, env = run.hyper, run.env
    workers = cfg.samplers.workers or 0
    trained_with = (run.previous or {}).get("train_config", {}).get("workers") or 0
    if run.previous is not None and trained_with != workers:
        raise DDPGError(
            f"{run.out} was trained with --workers {trained_with or 'left out'}: its replay buffer has "
            f"a column per car of every sampler; resume it with the same --workers"
        )
    # A resumed session draws new start points and noise: reusing the first session's would replay its episodes.
    session_seed = cfg.seed + run.num_steps
    agent = DDPGAgent(hyper, env, n_cars=env.n_cars, seed=session_seed, device=torch_device(cfg.device))
    buffer = FrameReplay(hyper.buffer_size, env.n_cars * max(workers, 1), env.image_hw_px if env.frames else None)
    restored, learning_starts = _restore(run, agent, buffer)
    rng = np.random.default_rng(session_seed + 1)
    hooks = _StepHooks(run, agent, buffer, progress)
    interrupted = False
    sampling = None
    try:
        with hooks.held.installed():
            if workers:
                sampling = _learn_with_samplers(
                    run, agent, buffer, rng, restored > 0, learning_starts, cluster, hooks.log_episode, hooks.after_step
                )
            else:
                _learn_here(
                    run,
                    agent,
                    buffer,
                    rng,
                    restored > 0,
                    learning_starts,
                    session_seed,
                    hooks.log_episode,
                    hooks.after_step,
                )
        if cfg.evaluation.seeds > 0 and (run.last_eval is None or run.last_eval["num_steps"] != run.num_steps):
            run.evaluate(agent)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        hooks.close()
    run.save(agent, buffer)
    run.close()
    return {
        "out": str(run.out),
        "agent": str(run.out / AGENT_NAME),
        "variant": hyper.variant,
        "track": env.track,
        "car": env.car,
        "num_steps": run.num_steps,
        "n_updates": agent.n_updates,
        "episodes": run.episodes,
        "train_time_s": round(run.train_time_s, 2),
        "train_cpu_s": round(run.train_cpu_s, 2),
        "stopped_by": "interrupt" if interrupted else "steps" if run.num_steps >= cfg.steps else "train_minutes",
        "interrupted": interrupted,
        "resumed": cfg.resume,
        "buffer_restored": restored if cfg.resume else None,
        "last_eval": run.last_eval,
        "metrics_jsonl": str(run.out / METRICS_NAME),
        "episodes_jsonl": str(run.out / EPISODES_NAME),
        "sampling": sampling,
    }


def _restore(run: _Run, agent: DDPGAgent, buffer: FrameReplay) -> tuple[int, int]:
    """A resumed run's agent and buffer; returns (rows restored, transitions to collect before updating)."""
    cfg = run.cfg
    if run.previous is None:
        return 0, cfg.learning_starts
    restored = 0
    try:
        state = read_agent_file(run.out / AGENT_NAME, run.previous["weights_sha256"])
        check_fingerprint(state["fingerprint"], run.fingerprint, str(run.out / AGENT_NAME))
        agent.load_state(state, str(run.out / AGENT_NAME))
        if (run.out / REPLAY_DIR / "index.json").is_file():
            restored = load_replay(buffer, run.out / REPLAY_DIR, run.fingerprint)
    except ArtifactError as exc:
        raise DDPGError(f"cannot resume: {exc}") from None
    # Never update on an empty buffer: refill it first.
    return restored, cfg.learning_starts if restored == 0 else 0


class _StepHooks:
    """What follows every step of all cars, here or from a sampler (evaluation, checkpoints, progress), and the
    line of each finished episode in episodes.jsonl; it holds the schedules' state and the open episodes file."""

    def __init__(self, run: _Run, agent: DDPGAgent, buffer: FrameReplay, progress: Progress | None) -> None:
        cfg = run.cfg
        self.run, self.agent, self.buffer, self.progress = run, agent, buffer, progress
        self.next_eval = next_multiple(run.num_steps, cfg.evaluation.every_steps)
        self.next_checkpoint = next_multiple(run.num_steps, cfg.checkpoints.every_steps)
        self.last_light_s = time.perf_counter()
        self.episodes_file = open(run.out / EPISODES_NAME, "a")  # closed by close()
        self.held = HeldSignal()

    def after_step(self) -> None:
        run, cfg = self.run, self.run.cfg
        self.held.release()  # the step is counted and stored: an interrupt held since acts here
        if self.next_eval is not None and run.num_steps >= self.next_eval and cfg.evaluation.seeds > 0:
            run.evaluate(self.agent)
            self.next_eval += cfg.evaluation.every_steps
        if self.next_checkpoint is not None and run.num_steps >= self.next_checkpoint:
            run.save(self.agent, self.buffer)
            self.next_checkpoint += cfg.checkpoints.every_steps
            self.last_light_s = time.perf_counter()
        elif cfg.checkpoints.every_min and time.perf_counter() - self.last_light_s >= 60.0 * cfg.checkpoints.every_min:
            run.save(self.agent, None)
            self.last_light_s = time.perf_counter()
        if self.progress is not None:
            self.progress(run.num_steps, cfg.steps, run.last_eval)

    def log_episode(self, record: dict[str, Any]) -> None:
        run = self.run
        line = {
            "episode": run.episodes,
            "num_steps": run.num_steps,
            **record,
            "train_time_s": round(run.train_time_s, 2),
        }
        self.episodes_file.write(json_text(line) + "\n")
        self.episodes_file.flush()
        run.episodes += 1

    def close(self) -> None:
        self.episodes_file.close()


def _learn_here(
    run: _Run,
    agent: DDPGAgent,
    buffer: FrameReplay,
    rng: np.random.Generator,
    restored: bool,
    learning_starts: int,
    session_seed: int,
    log_episode: Callable[[dict[str, Any]], None],
    after_vector_step: Callable[[], None],
) -> None:
    """The session's steps in this process: the world, then an update, one step of all cars at a time."""
    cfg, env, hyper = run.cfg, run.env, run.hyper
    n = env.n_cars
    core = PixelRacingCore(env, seed=session_seed)
    try:
        core.reset_cars(core.ids)
        obs = core.observation()
        if restored:
            # The restored rows end with each car's pending observation; this session starts new episodes after.
            buffer.pos = (buffer.pos + 1) % buffer.rows
        buffer.start(obs)
        agent.noise.reset()
        collected = 0
        run.start_clocks()  # training time starts with the first step, after the set-up
        while run.num_steps < cfg.steps and not run.out_of_time:
            keys = agent.act(obs, explore=True)
            next_obs, reward, terminated, truncated, info = core.step(keys)
            done = terminated | truncated
            reset_obs = None
            if done.any():
                ids = np.flatnonzero(done)
                for i in ids:  # one line per finished episode (episode ends, not steps)
                    log_episode(episode_record(info, i, bool(terminated[i]), env))
                core.reset_cars(ids)
                reset_obs = core.observation(ids)
                agent.noise.reset(ids)
            buffer.add(keys, reward, terminated, next_obs, done, reset_obs)
            if reset_obs is not None:
                for key in next_obs:
                    next_obs[key][ids] = reset_obs[key]
            obs = next_obs
            run.num_steps += n
            collected += n
            if collected >= learning_starts and buffer.size >= hyper.batch_size:
                for _ in range(cfg.updates_per_step):
                    agent.update(buffer.sample(hyper.batch_size, rng))
            after_vector_step()
    finally:
        core.close()


def _learn_with_samplers(
    run: _Run,
    agent: DDPGAgent,
    buffer: FrameReplay,
    rng: np.random.Generator,
    restored: bool,
    learning_starts: int,
    cluster: Any,
    log_episode: Callable[[dict[str, Any]], None],
    after_vector_step: Callable[[], None],
) -> dict[str, Any]:
    """The session's steps from ``cfg.samplers.workers`` sampler actors (:mod:`vision_rl.ddpg.sampling`), the same
    updates per step, evaluations and checkpoints as :func:`_learn_here`. A lost sampler is a line of
    metrics.jsonl; when none is left, the run is saved and the error raised."""
    from vision_rl.ddpg.sampling import DDPGLearner, sampler_setup
    from vision_rl.training.distributed import Pacing, SamplersLostError, learn_with_samplers

    cfg, env = run.cfg, run.env
    n = env.n_cars

    def on_vector_step(worker: int, episodes: list[dict[str, Any]]) -> bool:
        for record in episodes:
            log_episode({k: v for k, v in record.items() if k != "step"})
        run.num_steps += n
        after_vector_step()
        return not run.out_of_time

    def log_event(record: dict[str, Any]) -> None:
        record = {**record, "num_steps": run.num_steps, "train_time_s": round(run.train_time_s, 2)}
        with open(run.out / METRICS_NAME, "a") as f:
            f.write(json_text(record) + "\n")

    pacing = Pacing(
        workers=int(cfg.samplers.workers or 0),
        n_cars=n,
        gradient_steps=cfg.updates_per_step,
        learning_starts=learning_starts if restored else max(learning_starts, run.hyper.batch_size),
        start_timesteps=0,
        total_timesteps=max(0, cfg.steps - run.num_steps),
        version_every_updates=cfg.samplers.version_every_updates,
        max_staleness=cfg.samplers.max_staleness,
    )
    setup = sampler_setup(run.hyper, env, run.fingerprint, cfg.seed + run.num_steps)
    learner = DDPGLearner(agent, buffer, n, rng, restored, on_vector_step)
    run.start_clocks()  # training time starts with the samplers, after the set-up
    try:
        return learn_with_samplers(learner, setup, pacing, cluster, log_event=log_event)
    except SamplersLostError as exc:
        run.save(agent, buffer)
        run.close()
        raise SamplersLostError(f"{exc}; the run in {run.out} was saved: continue it with --resume") from None


def evaluate_ddpg(
    path: str | os.PathLike[str],
    seeds: int = 3,
    laps: int = 2,
    variant: str | None = None,
    time_limit_s: float = 0.0,
    write: bool = True,
    video: str = "",
    plot: str = "",
) -> dict[str, Any]:
    """Time a saved agent (a run folder or its ddpg.pt) with the lap-time protocol on its own track and car; with
    ``write``, the record goes to ``evaluation.json`` beside it, where the leaderboard finds it. ``video`` / ``plot``:
    an MP4 of the best start's driver view (at the game screen's size, not the actor's 89x120) / a PNG of its
    trajectory."""
    from vision_rl.ddpg.agent import load_agent, resolve_agent_path
    from vision_rl.evaluation.outputs import check_video_dependencies, plot_trajectory, write_video

    if video:
        check_video_dependencies()
    agent = load_agent(path, variant=variant)
    driver = DDPGDriver(agent)
    try:
        timing = time_laps(
            driver,
            agent.env.track,
            agent.env.car,
            range(seeds),
            laps,
            time_limit_s=time_limit_s,
            record=bool(video or plot),
        )
    finally:
        driver.close()
    variant = agent.hyper.variant
    identity = {
        "driver": "ddpg",
        "variant": variant,
        "observation": f"ddpg {variant}",
        "agent": str(path),
        "counters": getattr(agent, "counters", {}),
    }
    record = evaluation_record(timing, identity, f"ddpg {variant}")
    best = timing.best_index()
    record["video"] = str(write_video(timing, best, video)) if video else None
    record["plot"] = str(plot_trajectory(timing, best, plot, f"ddpg {variant}")) if plot else None
    if write:
        out = resolve_agent_path(path).with_name("evaluation.json")
        write_json(out, record)
        record["evaluation_json"] = str(out)
    return record
