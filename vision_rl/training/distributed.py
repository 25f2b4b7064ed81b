"""Sampling in Ray actors while this process learns: ``train-policy``, ``train-overtaking`` and (through
:class:`Learner`) ``train-ddpg`` with ``--workers N``. Transitions travel as numpy arrays and the actor as a numpy
``state_dict``: nothing of ours is pickled. :class:`Pacer` keeps the single-process loop's update-to-data ratio
and bounds how many weight versions a sampler may lag (``max_staleness``).

The pacing rules, what is deterministic and how a lost sampler is handled: docs/notes/training.md.
"""

from __future__ import annotations

import math
import os
import signal
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vision_rl.files import first_line
from vision_rl.training.schedules import SamplerOptions

RAY_MISSING = "--workers needs Ray: pip install 'vision_rl[ray]'"
#: Seconds the learner blocks at most on samplers before it looks again (Ctrl-C and SIGTERM are handled between).
WAIT_SLICE_S = 0.25
#: Prefix of the sampler actors' names (listed by ``ray.util.list_named_actors()``).
ACTOR_PREFIX = "vision_rl_sampler"
#: Seconds between TensorBoard's rollout figures (the episodes' return and length, steps/s) of a session.
LOG_EVERY_S = 30.0
#: Arrays of a chunk of transitions, each (steps, cars, ...), as the replay buffer stores them.
CHUNK_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


class DistributedError(ValueError):
    """A run with samplers that cannot start or go on (no Ray, too many workers, no sampler left); one line."""


class SamplersLostError(DistributedError):
    """Every sampler actor died; the message names the last reason."""


# ------------------------------------------------------------------------------------------------- the cluster


class Cluster:
    """A connection to a Ray cluster (started here, or joined); :meth:`close` shuts down only what it started."""

    def __init__(self, ray: Any, started: bool, cpus: float, address: str) -> None:
        self.ray = ray
        self.started = started
        self.cpus = cpus
        self.address = address

    def close(self) -> None:
        if self.started and self.ray.is_initialized():
            self.ray.shutdown()
        self.started = False


def import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise DistributedError(RAY_MISSING) from None
    return ray


def check_workers(workers: int | None, max_staleness: int, version_every_updates: int) -> None:
    """One clear line for sampling options out of range (before Ray is started)."""
    if workers is not None and workers < 1:
        raise DistributedError(
            f"--workers {workers}: give at least 1 sampler actor, or leave --workers out to sample in this process"
        )
    if max_staleness < 0:
        raise DistributedError(f"--max-staleness {max_staleness} is out of range: 0 (synchronous) or more versions")
    if version_every_updates < 1:
        raise DistributedError(f"--version-every-updates {version_every_updates} is out of range: 1 or more")


def connect(address: str, workers: int) -> Cluster:
    """Join the Ray cluster at ``address`` (``auto``, ``host:port``, ``ray://host:port``), or use the one this
    process already joined, or start a local one of this machine's CPUs (empty address); refuse more sampler
    actors than the cluster has CPUs (each takes one)."""
    check_workers(workers, 0, 1)
    ray = import_ray()
    started = False
    if not ray.is_initialized():
        # ray.init installs its own SIGTERM handler (exit without saving): keep the caller's (save like Ctrl-C).
        main = threading.current_thread() is threading.main_thread()
        previous = signal.getsignal(signal.SIGTERM) if main else None
        os.environ.setdefault("RAY_AUTH_MODE", "disabled")
        kwargs: dict[str, Any] = dict(include_dashboard=False, log_to_driver=False, configure_logging=False)
        try:
            if address:
                ray.init(address=address, **kwargs)
            else:
                # Ray starts its workers at nice 15, where anything else on the machine takes a sampler's core
                # first (the pipeline's state policy beside a vision run left its sampler half a core, the learner
                # waiting); the samplers are this run's own work, at the learner's priority unless the caller says.
                os.environ.setdefault("RAY_worker_niceness", "0")
                ray.init(num_cpus=os.cpu_count() or 1, **kwargs)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            first = first_line(exc)
            raise DistributedError(f"cannot join the Ray cluster at {address or 'a new local one'}: {first}") from None
        finally:
            if main and previous is not None:
                signal.signal(signal.SIGTERM, previous)
        started = True
    cpus = float(ray.cluster_resources().get("CPU", 0.0))
    where = f"at {address}" if address else "of this process"
    if workers > cpus:
        if started:
            ray.shutdown()
        raise DistributedError(
            f"--workers {workers} is more than the {cpus:g} CPUs of the Ray cluster {where}: each sampler actor "
            f"takes one; use --workers {max(1, int(cpus))} or a larger cluster"
        )
    return Cluster(ray, started, cpus, address)


@contextmanager
def cluster_for(workers: int | None, address: str) -> Iterator[Cluster | None]:
    """The Ray cluster of a trainer's session with ``workers`` sampler actors, closed when it ends; None without
    ``--workers`` (Ray is then not imported)."""
    if workers is None:
        yield None
        return
    cluster = connect(address, workers)
    try:
        yield cluster
    finally:
        cluster.close()


# ------------------------------------------------------------------------------------------------- pacing


@dataclass(frozen=True)
class Pacing:
    """How the learner and the samplers keep step (see the module docstring)."""

    workers: int
    """Sampler actors."""
    n_cars: int
    """Cars of each sampler's world (transitions per vector step)."""
    gradient_steps: int
    """Updates earned by every ``train_freq_steps`` vector steps after the random start steps (the run's ratio)."""
    learning_starts: int
    """Transitions (the model's step count) before which actions are random and no step earns updates."""
    start_timesteps: int
    """The model's step count when this session starts."""
    total_timesteps: int | None
    """Stop once the step count reaches this (None: run until ``deadline_s``)."""
    version_every_updates: int
    """Updates per weight version (V)."""
    max_staleness: int
    """Versions a sampler's weights may lag the learner's (K; 0: synchronous)."""
    train_freq_steps: int = 1
    """Vector steps per ``gradient_steps`` updates."""

    @property
    def chunk_steps(self) -> int:
        """Vector steps per chunk: the N samplers together collect about one version's data at a time."""
        updates_per_step = self.gradient_steps / self.train_freq_steps
        return max(1, math.ceil(self.version_every_updates / (updates_per_step * self.workers)))


class Pacer:
    """The bookkeeping of :class:`Pacing`: when the learner may update, when a sampler may get a chunk. Counts are
    this session's: vector steps launched, received, updates made, and the version of every chunk in flight."""

    def __init__(self, pacing: Pacing) -> None:
        p = self.pacing = pacing
        before = p.learning_starts - p.start_timesteps
        # Step j (0-based in this session) starts at t = start + j * n: random while t < learning_starts, and
        # earns updates when it ends past learning_starts (Stable-Baselines3's rules).
        self.random_steps = max(0, math.ceil(before / p.n_cars))
        self.first_learning_step = max(0, math.floor(before / p.n_cars))
        self.total_steps = (
            None if p.total_timesteps is None else max(0, math.ceil((p.total_timesteps - p.start_timesteps) / p.n_cars))
        )
        self.launched = 0
        self.received = 0
        self.updates = 0
        self.inflight: dict[int, int] = {}  # chunk id -> the version it acts with
        self.max_staleness_seen = 0

    @property
    def version(self) -> int:
        return self.updates // self.pacing.version_every_updates

    def earned(self, steps: int) -> int:
        """Updates earned by the first ``steps`` vector steps of the session."""
        p = self.pacing
        return p.gradient_steps * (max(0, steps - self.first_learning_step) // p.train_freq_steps)

    def can_update(self) -> bool:
        """The data received has earned another update, and it publishes no version past a sampler's bound."""
        if self.updates >= self.earned(self.received):
            return False
        following = self.updates + 1
        if following % self.pacing.version_every_updates == 0 and self.inflight:
            if following // self.pacing.version_every_updates - min(self.inflight.values()) > self.pacing.max_staleness:
                return False
        return True

    def next_chunk(self) -> tuple[int, int] | None:
        """(vector steps, of which random) of the next chunk, or None when a sampler should wait."""
        steps = self.pacing.chunk_steps
        if self.total_steps is not None:
            steps = min(steps, self.total_steps - self.launched)
            if steps <= 0:
                return None
        ahead = self.earned(self.launched) - self.updates
        budget = (self.pacing.max_staleness + 1) * self.pacing.version_every_updates
        if ahead > 0 and ahead + self.earned(self.launched + steps) - self.earned(self.launched) > budget:
            return None
        return steps, int(np.clip(self.random_steps - self.launched, 0, steps))

    def launch(self, chunk_id: int, steps: int) -> None:
        self.launched += steps
        self.inflight[chunk_id] = self.version

    def receive(self, chunk_id: int, steps: int) -> None:
        self.max_staleness_seen = max(self.max_staleness_seen, self.version - self.inflight.pop(chunk_id))
        self.received += steps

    def lose(self, chunk_id: int, steps: int) -> None:
        """A chunk that will never come (its sampler died): its steps are collected again."""
        self.inflight.pop(chunk_id)
        self.launched -= steps

    def updated(self) -> bool:
        """Count one update; True when it publishes a new version."""
        self.updates += 1
        published = self.updates % self.pacing.version_every_updates == 0
        if published and self.inflight:
            self.max_staleness_seen = max(self.max_staleness_seen, self.version - min(self.inflight.values()))
        return published

    @property
    def done(self) -> bool:
        return (
            self.total_steps is not None
            and self.received == self.total_steps
            and self.updates >= self.earned(self.total_steps)
        )


# ------------------------------------------------------------------------------------------------- the sampler


@dataclass(frozen=True)
class SamplerSetup:
    """What a sampler actor builds its world and policy from: plain values only."""

    racing_config: Mapping[str, Any]
    """The run's environment (``racing_config_to_dict``), with the run's number of cars."""
    observation: str
    """``state`` or ``vision``."""
    obs_normalizer: Mapping[str, Any]
    """The run's observation normalisation (``ObsNormalizer.to_dict``)."""
    fingerprint: Mapping[str, Any]
    """The run's policy fingerprint; a sampler whose world or encoder differs refuses to start."""
    hidden_units: tuple[int, ...]
    """Hidden layers of the SAC actor."""
    seed: int
    """Base seed; sampler w uses a child of (seed, w)."""
    encoder_path: str = ""
    """Vision: the encoder checkpoint (an absolute path every node can read)."""
    encoder_runtime: str = "auto"
    """Vision: the encoder's runtime on the sampler's CPU."""
    label_skill: float | None = None
    """The built-in AI's skill that labels every state the sampler's cars visit (``--guide-label-weight``); None:
    no labels."""

    def body(self) -> type:
        """The class of the sampler actors built from this setup."""
        return Sampler


def worker_seed(seed: int, worker: int) -> int:
    """Sampler ``worker``'s seed: independent streams for every (seed, worker)."""
    return int(np.random.SeedSequence([seed, worker]).generate_state(1)[0])


def actor_weights(model: Any) -> dict[str, np.ndarray]:
    """``model.actor``'s ``state_dict`` (batch-norm statistics included) as numpy arrays: what the samplers load."""
    return {name: t.detach().cpu().numpy() for name, t in model.actor.state_dict().items()}


def load_actor_weights(actor: Any, weights: list[Any]) -> None:
    """Load the version that ``weights`` (a one-element list holding a Ray object reference) names into ``actor``."""
    import ray
    import torch

    actor.load_state_dict({k: torch.tensor(np.array(v)) for k, v in ray.get(weights[0]).items()})


def check_sampler_fingerprint(worker: int, mine: Mapping[str, Any], run: Mapping[str, Any]) -> None:
    """Refuse to build sampler ``worker`` when its world or networks differ from the run's."""
    for key, want in run.items():
        if mine.get(key) != want:
            raise ValueError(f"sampler {worker} was built for {key} = {mine.get(key)!r}, the run has {want!r}")


def portable_track(track: str) -> str:
    """A CSV track by its absolute path (the samplers may run in another folder); a built-in name as it is."""
    path = Path(track)
    return str(path.resolve()) if path.suffix == ".csv" and path.is_file() else track


class Sampler:
    """The body of a sampler actor: one world of the run's cars and a copy of the SAC actor.

    ``sample(weights, version, steps, random_steps)`` steps the world ``steps`` times and returns the transitions as
    numpy arrays (the observations before and after, with the last observation of an episode in place of the
    next one where it ended, the actions scaled to [-1, 1] as SAC stores them, rewards, dones, time-limit flags;
    with ``setup.label_skill`` also ``ai_labels``, the built-in AI's action at each state an action was chosen in,
    scaled as the actions), the episodes that ended, and the version it acted with. The first ``random_steps`` act
    uniformly at random (the run's start steps); the rest sample the policy's stochastic action. ``weights`` is a
    one-element list holding a Ray object reference, fetched only when ``version`` changes.
    """

    def __init__(self, setup: SamplerSetup, worker: int) -> None:
        import torch

        from vision_rl.envs.observations import ObservationKind, ObsNormalizer
        from vision_rl.envs.vector import make_sb3_vec_env
        from vision_rl.training.artifact import policy_fingerprint, racing_config_from_dict
        from vision_rl.training.critic_state import sac_policy_class

        torch.set_num_threads(1)  # the learner and the other samplers share the cores
        self.torch = torch
        self.worker = worker
        self.seed = worker_seed(setup.seed, worker)
        torch.manual_seed(self.seed)
        self.rng = np.random.default_rng(self.seed)
        config = racing_config_from_dict(dict(setup.racing_config))
        self.env = make_sb3_vec_env(config, seed=self.seed)
        core = self.env.core
        normalizer = ObsNormalizer.from_dict(dict(setup.obs_normalizer))
        encoder_sha = None
        if ObservationKind.of(setup.observation).sees_frames:
            from vision_rl.phase1_repr.checkpoint import load_encoder

            encoder = load_encoder(setup.encoder_path, device="cpu", runtime=setup.encoder_runtime)
            encoder_sha = encoder.sha256
            core.observer.close()
            core.observer = core.vision_observer(encoder, normalizer)
            self.env.observation_space = core.observer.space
        else:
            core.observer.normalizer = normalizer
        mine = policy_fingerprint(config, setup.observation, self.env.observation_space.shape[0], encoder_sha)
        check_sampler_fingerprint(worker, mine, setup.fingerprint)
        if setup.label_skill is not None:
            core.label_with_ai(setup.label_skill)
        dim = self.env.observation_space.shape[0]
        policy_class, policy_kwargs = sac_policy_class(dim, config.critic_state)
        self.policy = policy_class(
            self.env.observation_space,
            self.env.action_space,
            lambda _: 0.0,
            net_arch=list(setup.hidden_units),
            **policy_kwargs,
        )
        self.policy.set_training_mode(False)
        space = self.env.action_space
        self.low, self.high = space.low.astype(np.float64), space.high.astype(np.float64)
        self.version = -1
        self.obs = self.env.reset()
        n = self.env.num_envs
        self.episode_return = np.zeros(n)
        self.episode_length = np.zeros(n, dtype=np.int64)

    def ready(self) -> int:
        return self.worker

    def pid(self) -> int:
        return os.getpid()

    def sample(self, weights: list[Any], version: int, steps: int, random_steps: int) -> dict[str, np.ndarray]:
        torch = self.torch
        t0 = time.perf_counter()
        if steps > random_steps and version != self.version:
            load_actor_weights(self.policy.actor, weights)
            self.version = version
        n, dim = self.env.num_envs, self.env.observation_space.shape[0]
        out = {
            "observations": np.empty((steps, n, dim), np.float32),
            "next_observations": np.empty((steps, n, dim), np.float32),
            "actions": np.empty((steps, n, 2), np.float32),
            "rewards": np.empty((steps, n), np.float32),
            "dones": np.empty((steps, n), np.float32),
            "timeouts": np.empty((steps, n), np.float32),
            "episode_return": np.full((steps, n), np.nan),
            "episode_length": np.zeros((steps, n), np.int64),
        }
        labelled = self.env.core.labeller is not None
        if labelled:
            out["ai_labels"] = np.empty((steps, n, 2), np.float32)
        for k in range(steps):
            if k < random_steps:
                unscaled = self.rng.uniform(self.low, self.high, (n, 2))
                scaled = 2.0 * (unscaled - self.low) / (self.high - self.low) - 1.0
            else:
                with torch.no_grad():
                    scaled = self.policy.actor(torch.as_tensor(self.obs), deterministic=False).numpy()
            scaled = np.asarray(scaled, dtype=np.float32)  # the stored action is exactly the one applied
            action = self.low + 0.5 * (scaled.astype(np.float64) + 1.0) * (self.high - self.low)
            new_obs, rewards, dones, infos = self.env.step(action)
            next_obs = np.array(new_obs, dtype=np.float32)
            ended = np.flatnonzero(dones)
            for i in ended:  # the cars whose episode ended (a few per chunk)
                next_obs[i] = infos[i]["terminal_observation"]
            out["observations"][k] = self.obs
            out["next_observations"][k] = next_obs
            out["actions"][k] = scaled
            out["rewards"][k] = rewards
            out["dones"][k] = dones
            out["timeouts"][k] = [info.get("TimeLimit.truncated", False) for info in infos]
            if labelled:
                # Scaled as the in-process path scales them (GuidedSAC._store_transition).
                out["ai_labels"][k] = self.policy.scale_action(np.stack([info["ai_action"] for info in infos]))
            self.episode_return += rewards
            self.episode_length += 1
            out["episode_return"][k, ended] = self.episode_return[ended]
            out["episode_length"][k, ended] = self.episode_length[ended]
            self.episode_return[ended] = 0.0
            self.episode_length[ended] = 0
            self.obs = new_obs
        out["version"] = np.int64(version)
        out["busy_s"] = np.float64(time.perf_counter() - t0)
        return out


def start_samplers(cluster: Cluster, setup: Any, workers: int) -> list[Any]:
    """``workers`` sampler actors of class ``setup.body()`` (one CPU each), named ``vision_rl_sampler_<run>_<w>``."""
    ray = cluster.ray
    remote = ray.remote(num_cpus=1, max_restarts=0)(setup.body())
    token = uuid.uuid4().hex[:8]
    return [remote.options(name=f"{ACTOR_PREFIX}_{token}_{w}").remote(setup, w) for w in range(workers)]


def add_vector_step(buffer: Any, chunk: Mapping[str, np.ndarray], k: int) -> None:
    """Vector step ``k`` of a chunk into an SB3 ``ReplayBuffer`` (what ``ReplayBuffer.add`` stores, and the AI's
    labels where the buffer has them: see :func:`vision_rl.phase2_rl.guide.start_labels`)."""
    pos = buffer.pos
    for name in CHUNK_ARRAYS:
        getattr(buffer, name)[pos] = chunk[name][k]
    if getattr(buffer, "ai_labels", None) is not None:
        buffer.ai_labels[pos] = chunk["ai_labels"][k]
    buffer.pos = pos + 1
    if buffer.pos == buffer.buffer_size:
        buffer.full, buffer.pos = True, 0


# ------------------------------------------------------------------------------------------------- the learner


class Learner:
    """What a :class:`SamplingLearner` trains: the algorithm's side of a session (SAC's :class:`SB3Learner`, the
    DDPG learner of :mod:`vision_rl.ddpg.sampling`)."""

    def num_steps(self) -> int:
        """Transitions trained on so far (the run's step count)."""
        raise NotImplementedError

    def weights(self) -> dict[str, np.ndarray]:
        """The actor's weights as numpy arrays, what the samplers load."""
        raise NotImplementedError

    def started(self, worker: int, ready: Any) -> None:
        """Sampler ``worker`` is built; ``ready`` is what its ``ready()`` returned."""

    def take(self, chunk: Mapping[str, Any], worker: int, steps: int, elapsed_s: float) -> bool:
        """Add the ``steps`` vector steps of ``worker``'s chunk in order; False ends the session after the step that
        asked it (the rest of the chunk is dropped)."""
        raise NotImplementedError

    def update(self) -> None:
        """One gradient update."""
        raise NotImplementedError


class SB3Learner(Learner):
    """An SB3 off-policy model (SAC) whose replay buffer holds ``n_cars`` envs; ``on_vector_step()`` is called after
    each vector step is added (the model's step count updated), and its False ends the session as an SB3 callback
    stops ``learn``."""

    def __init__(self, model: Any, on_vector_step: Callable[[], Any] | None = None) -> None:
        if getattr(model.replay_buffer, "optimize_memory_usage", False):
            raise DistributedError("sampling with --workers needs a replay buffer without optimize_memory_usage")
        if model.ep_info_buffer is None:  # set by SB3's learn(), which this loop replaces
            from collections import deque

            model.ep_info_buffer = deque(maxlen=model._stats_window_size)
            model.ep_success_buffer = deque(maxlen=model._stats_window_size)
        self.model, self.on_vector_step = model, on_vector_step

    def num_steps(self) -> int:
        return int(self.model.num_timesteps)

    def weights(self) -> dict[str, np.ndarray]:
        return actor_weights(self.model)

    def take(self, chunk: Mapping[str, Any], worker: int, steps: int, elapsed_s: float) -> bool:
        model = self.model
        n = model.n_envs
        for k in range(steps):
            add_vector_step(model.replay_buffer, chunk, k)
            model.num_timesteps += n
            ended = np.flatnonzero(chunk["dones"][k])
            for i in ended:
                episode = {"r": float(chunk["episode_return"][k, i]), "l": int(chunk["episode_length"][k, i])}
                model.ep_info_buffer.append({**episode, "t": round(elapsed_s, 6)})
            model._episode_num += len(ended)
            if self.on_vector_step is not None and self.on_vector_step() is False:
                return False
        return True

    def update(self) -> None:
        self.model.train(gradient_steps=1, batch_size=self.model.batch_size)


class SamplingLearner:
    """The learner's side of a session with sampler actors (built from ``setup``, of class ``setup.body()``):
    :meth:`run` trains ``learner`` on their transitions until ``pacing.total_timesteps`` or a deadline;
    :meth:`close` stops the actors. ``log_event(record)`` is called when a sampler is lost. Raises
    :class:`SamplersLostError` when no sampler is left (the learner keeps what it learned). The constructor returns
    once every sampler is built."""

    def __init__(
        self,
        learner: Learner,
        setup: Any,
        pacing: Pacing,
        cluster: Cluster,
        log_event: Callable[[dict[str, Any]], None] | None = None,
    ) -> None:
        from ray.exceptions import RayError

        self.ray, self.ray_error = cluster.ray, RayError
        self.learner, self.pacing = learner, pacing
        self.log_event = log_event
        self.pacer = Pacer(pacing)
        self.handles = start_samplers(cluster, setup, pacing.workers)
        self.alive = dict(enumerate(self.handles))
        self.busy = {w: False for w in self.alive}
        self.lost: list[dict[str, Any]] = []
        self.stopped = False
        self.inflight: dict[Any, tuple[int, int, int]] = {}  # object ref -> (worker, chunk id, steps)
        self.next_chunk_id = 0
        self.counts = {"chunks": 0, "transitions": 0, "sampler_busy_s": 0.0, "learner_wait_s": 0.0, "duration_s": 0.0}
        self.t_session = time.perf_counter()
        self.weights = [self.ray.put(learner.weights())]
        try:
            # Every sampler is built (world, encoder, policy) before anything is timed.
            pending = {h.ready.remote(): w for w, h in self.alive.items()}
            while pending:
                ready, _ = self.ray.wait(list(pending), num_returns=1, timeout=WAIT_SLICE_S)
                for ref in ready:
                    worker = pending.pop(ref)
                    try:
                        value = self.ray.get(ref)
                    except RayError as exc:
                        self._lose(worker, _ray_error_line(exc))
                    else:
                        learner.started(worker, value)
        except BaseException:
            self.close()
            raise

    def _lose(self, worker: int, reason: str) -> None:
        self.alive.pop(worker, None)
        self.busy.pop(worker, None)
        self.ray.kill(self.handles[worker], no_restart=True)
        record = {
            "event": "sampler_lost",
            "worker": worker,
            "num_timesteps": self.learner.num_steps(),
            "reason": reason,
            "samplers_alive": len(self.alive),
        }
        self.lost.append(record)
        if self.log_event is not None:
            self.log_event(record)
        if not self.alive:
            raise SamplersLostError(
                f"all {self.pacing.workers} sampler actors died (the last: {reason}); training stopped at "
                f"{self.learner.num_steps()} steps"
            )

    def _take(self, ref: Any) -> None:
        worker, chunk_id, steps = self.inflight.pop(ref)
        try:
            chunk = self.ray.get(ref)
        except self.ray_error as exc:
            self.pacer.lose(chunk_id, steps)
            self._lose(worker, _ray_error_line(exc))
            return
        self.busy[worker] = False
        self.pacer.receive(chunk_id, steps)
        if not self.learner.take(chunk, worker, steps, time.perf_counter() - self.t_session):
            self.stopped = True
        self.counts["chunks"] += 1
        self.counts["transitions"] += steps * self.pacing.n_cars
        self.counts["sampler_busy_s"] += float(chunk["busy_s"])

    def _launch(self) -> None:
        for worker in sorted(w for w, b in self.busy.items() if not b):
            planned = self.pacer.next_chunk()
            if planned is None:
                return
            steps, random_steps = planned
            ref = self.alive[worker].sample.remote(self.weights, self.pacer.version, steps, random_steps)
            self.inflight[ref] = (worker, self.next_chunk_id, steps)
            self.pacer.launch(self.next_chunk_id, steps)
            self.busy[worker] = True
            self.next_chunk_id += 1

    def run(self, deadline_s: float | None = None) -> None:
        """Train until the session's steps are done, or for ``deadline_s`` seconds (chunks in flight stay so)."""
        ray, pacer, counts = self.ray, self.pacer, self.counts
        start = time.perf_counter()
        try:
            while True:
                self._launch()
                if pacer.done or self.stopped or (deadline_s is not None and time.perf_counter() - start >= deadline_s):
                    return
                can_update = pacer.can_update()
                if self.inflight:
                    refs = list(self.inflight)
                    t_wait = time.perf_counter()
                    ready, _ = ray.wait(
                        refs, num_returns=len(refs) if can_update else 1, timeout=0 if can_update else WAIT_SLICE_S
                    )
                    if not can_update:
                        counts["learner_wait_s"] += time.perf_counter() - t_wait
                    if ready:
                        for ref in sorted(ready, key=lambda r: self.inflight[r][1]):  # in the order launched
                            self._take(ref)
                        continue
                elif not can_update:
                    raise RuntimeError(f"sampling stalled: {pacer.__dict__}")  # the pacing rules exclude this
                if can_update:
                    self.learner.update()
                    if pacer.updated():
                        self.weights = [ray.put(self.learner.weights())]
        finally:
            counts["duration_s"] += time.perf_counter() - start

    def stats(self) -> dict[str, Any]:
        """The session's sampling figures so far."""
        c, p = self.counts, self.pacing
        return {
            "workers": p.workers,
            "samplers_alive": len(self.alive),
            "samplers_lost": list(self.lost),
            "chunks": c["chunks"],
            "chunk_steps": p.chunk_steps,
            "transitions": c["transitions"],
            "updates": self.pacer.updates,
            "duration_s": round(c["duration_s"], 3),
            "learner_wait_s": round(c["learner_wait_s"], 3),
            "sampler_busy_s": round(c["sampler_busy_s"], 3),
            "max_staleness": p.max_staleness,
            "max_staleness_seen": self.pacer.max_staleness_seen,
            "version_every_updates": p.version_every_updates,
            "weight_versions": self.pacer.version,
        }

    def close(self) -> None:
        for handle in self.handles:
            self.ray.kill(handle, no_restart=True)


def learn_with_samplers(
    learner: Learner,
    setup: Any,
    pacing: Pacing,
    cluster: Cluster,
    log_event: Callable[[dict[str, Any]], None] | None = None,
    deadline_s: float | None = None,
) -> dict[str, Any]:
    """A :class:`SamplingLearner` session from start to end (or ``deadline_s`` seconds); its :meth:`stats`."""
    session = SamplingLearner(learner, setup, pacing, cluster, log_event)
    try:
        session.run(deadline_s)
    finally:
        session.close()
    return session.stats()


def learn_like_sb3(
    model: Any,
    setup: SamplerSetup,
    cluster: Cluster,
    *,
    samplers: SamplerOptions,
    total_timesteps: int,
    callback: Any,
    log_event: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """``model.learn(total_timesteps - model.num_timesteps, callback)`` with ``samplers.workers`` actors: the model's
    own update ratio, batch size and random start steps; ``callback`` (an SB3 ``BaseCallback``) after every vector
    step, on the same step counts (its False ends the session); TensorBoard's rollout figures every
    :data:`LOG_EVERY_S`. Returns the session's :meth:`SamplingLearner.stats`."""
    pacing = Pacing(
        workers=int(samplers.workers or 0),
        n_cars=model.n_envs,
        gradient_steps=model.gradient_steps,
        train_freq_steps=model.train_freq.frequency,
        learning_starts=int(model.learning_starts),
        start_timesteps=int(model.num_timesteps),
        total_timesteps=total_timesteps,
        version_every_updates=samplers.version_every_updates,
        max_staleness=samplers.max_staleness,
    )
    callback.init_callback(model)
    last_dump = [time.perf_counter(), model.num_timesteps]

    def on_vector_step() -> bool:
        go_on = callback.on_step()
        # TensorBoard's rollout figures, which SB3's own loop writes every few episodes.
        if time.perf_counter() - last_dump[0] >= LOG_EVERY_S and model.ep_info_buffer:
            steps = model.num_timesteps - last_dump[1]
            model.logger.record("rollout/ep_rew_mean", float(np.mean([e["r"] for e in model.ep_info_buffer])))
            model.logger.record("rollout/ep_len_mean", float(np.mean([e["l"] for e in model.ep_info_buffer])))
            model.logger.record("time/fps", int(steps / (time.perf_counter() - last_dump[0])))
            model.logger.dump(step=model.num_timesteps)
            last_dump[:] = [time.perf_counter(), model.num_timesteps]
        return go_on

    return learn_with_samplers(SB3Learner(model, on_vector_step), setup, pacing, cluster, log_event=log_event)


def _ray_error_line(exc: BaseException) -> str:
    """The cause of a Ray error in one line (a task's own exception, not Ray's traceback)."""
    cause = getattr(exc, "cause", None)
    if isinstance(cause, BaseException) and str(cause).strip():
        return f"{type(cause).__name__}: {first_line(cause)}"
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    # An actor whose constructor raised: Ray's text ends with that exception's own last line.
    raised = [line for line in lines if line.split(":")[0].endswith(("Error", "Exception")) and ": " in line]
    if raised and "creation task" in str(exc):
        return raised[-1]
    return f"{type(exc).__name__}: {lines[0] if lines else ''}".rstrip(": ")
