"""Demonstrations of the single-car race for the imitation baselines of the overtaking paper's Table III (BC, GAIL).

The demonstrator, :class:`HeldAIDriver`, is the built-in AI expressed in the environments' 10 Hz action space: the
AI is tuned at 50 Hz and does not complete a lap when its command is simply held for a 0.1 s step, so at each
control step it drives a copy of the world for five of its 0.02 s steps and the mean of those commands is held.
The file is an ``.npz`` read without pickle: the observations, the applied and the demonstrator's actions, the
rewards, the episode starts, and a ``meta`` record with the :func:`demo_fingerprint` and a SHA-256 over the arrays;
:func:`load_demos` refuses, in one line each, a file that is damaged, edited, of another format, or recorded for
another track, car or observation. A recording is written once at its end, atomically. The demonstrator's lap time
and the file's fields in full: docs/notes/overtaking.md, "demos.py".
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import os
import time
import zipfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from vision_rl.config import Bounds, above, at_least, check_option_bounds, flat_values
from vision_rl.envs.core import RacingCore
from vision_rl.envs.observations import OBS_NAMES, OBS_VERSION, ObsNormalizer
from vision_rl.envs.racing_env import action_space
from vision_rl.files import atomic_write, first_line, json_text
from vision_rl.overtaking.config import OBSERVATION, SCENARIO, RecordDemosConfig, race_config
from vision_rl.sim.ai_driver import DEFAULT_SKILL, AIDriver
from vision_rl.sim.driving import line_and_profile
from vision_rl.sim.fleet import AI_CONTROL_DT_S
from vision_rl.sim.track_library import load_track
from vision_rl.sim.world import World, WorldModel, WorldState, world_step
from vision_rl.training.persist import ArtifactError, check_fingerprint

DEMO_FORMAT = "vision_rl.demos"
#: 2: ``expert_actions`` (the demonstrator's label) beside ``actions`` (what was applied).
DEMO_FORMAT_VERSION = 2
OBS_DIM = len(OBS_NAMES[OBSERVATION])
ARRAYS = ("observations", "actions", "expert_actions", "rewards", "episode_starts")
DRIVERS = ("ai",)


class DemoError(ArtifactError):
    """A demonstrations file that cannot be used as asked (damaged, edited, another track or car); says why."""


# ------------------------------------------------------------------------------------------------- the demonstrator


class HeldAIDriver:
    """The built-in AI as a driver acting every 0.1 s: the mean of the five 50 Hz commands it would give over the
    step (found on a copy of the world), held (see the module's docstring). A protocol driver too."""

    control_dt_s = 0.1

    def __init__(self, skill: float = DEFAULT_SKILL) -> None:
        if not 0.0 < skill <= 1.0:
            raise ValueError(f"skill must be in (0, 1], got {skill}")
        self.skill = float(skill)
        self._ai: AIDriver | None = None

    @property
    def identity(self) -> dict[str, Any]:
        rule = "mean of its five 0.02 s commands over the 0.1 s step, found on a copy of the world"
        return {"driver": "built-in AI held at 10 Hz", "skill": self.skill, "rule": rule}

    def reset(self, world: World, car_ids: np.ndarray) -> None:
        line, profile = line_and_profile(world.track, world.car)
        self._ids = np.asarray(car_ids)
        self._ai = AIDriver(world.car, line, profile, world.n_cars, skill=self.skill, groups=world.model.groups)
        config = dataclasses.replace(world.model.config, control_dt_s=AI_CONTROL_DT_S)
        self._model = WorldModel(track=world.track, car=world.car, groups=world.model.groups, config=config)
        self._substeps = round(self.control_dt_s / AI_CONTROL_DT_S)

    def act(self, state: WorldState) -> np.ndarray:
        assert self._ai is not None, "reset() first"
        steer_sum, omega_sum = 0.0, 0.0
        for k in range(self._substeps):
            steer, omega = self._ai.act(state)
            steer_sum, omega_sum = steer_sum + steer, omega_sum + omega
            if k + 1 < self._substeps:
                state, _ = world_step(self._model, state, steer, omega)
        action = np.stack([steer_sum, omega_sum], axis=1) / self._substeps
        return action[self._ids]


# ------------------------------------------------------------------------------------------------- the file


def normalizer_sha256(normalizer: ObsNormalizer) -> str:
    """SHA-256 of a normaliser's numbers (float64 offset then scale)."""
    data = np.ascontiguousarray(normalizer.offset, dtype=np.float64).tobytes()
    data += np.ascontiguousarray(normalizer.scale, dtype=np.float64).tobytes()
    return hashlib.sha256(data).hexdigest()


def environment_normalizer(track: str, car: str) -> ObsNormalizer:
    """The normaliser the single-car race's environment applies today (cached per track, car and version)."""
    core = RacingCore(race_config(track, car, n_groups=1))
    try:
        return core.observer.normalizer
    finally:
        core.observer.close()


def demo_fingerprint(track: str, car: str, normalizer: ObsNormalizer | None = None) -> dict[str, Any]:
    """What a demonstrations file belongs to; ``normalizer`` None: the environment's today."""
    normalizer = normalizer if normalizer is not None else environment_normalizer(track, car)
    return {**_setting_fingerprint(track, car), "normalizer_sha256": normalizer_sha256(normalizer)}


def _setting_fingerprint(track: str, car: str) -> dict[str, Any]:
    return {
        "track_geometry_hash": load_track(track).geometry_hash,
        "car": car,
        "observation": OBSERVATION,
        "obs_dim": OBS_DIM,
        "obs_version": OBS_VERSION,
        "control_dt_s": 0.1,
        "scenario": SCENARIO,
    }


def arrays_sha256(arrays: Mapping[str, np.ndarray]) -> str:
    """SHA-256 over the arrays of :data:`ARRAYS` (name, dtype, shape and bytes, in that order)."""
    digest = hashlib.sha256()
    for name in ARRAYS:
        values = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}|{values.dtype.str}|{values.shape}|".encode())
        digest.update(values.tobytes())
    return digest.hexdigest()


@dataclass(frozen=True)
class Demos:
    """A loaded demonstrations file."""

    observations: np.ndarray
    """(N, 96) float32, normalised as the environment returns them."""
    actions: np.ndarray
    """(N, 2) float32 ``[steer rad, omega]`` applied at that step (the demonstrator's, plus ``noise``)."""
    expert_actions: np.ndarray
    """(N, 2) float32: the demonstrator's own action at that step, the label the imitation baselines learn."""
    rewards: np.ndarray
    """(N,) float32, Eq. 1."""
    episode_starts: np.ndarray
    """(N,) bool, True at an episode's first step."""
    meta: dict[str, Any]
    """The file's ``meta`` record (fingerprint, demonstrator, settings, figures)."""
    path: Path
    sha256: str
    """SHA-256 of the file."""

    @property
    def n_transitions(self) -> int:
        return len(self.actions)

    @property
    def fingerprint(self) -> dict[str, Any]:
        return dict(self.meta["fingerprint"])

    def episode_slices(self) -> list[slice]:
        """One slice per episode, in file order."""
        starts = [*np.flatnonzero(self.episode_starts).tolist(), self.n_transitions]
        return [slice(a, b) for a, b in itertools.pairwise(starts)]


def write_demos(path: str | os.PathLike[str], arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> str:
    """Write a demonstrations file (``meta`` gains ``format``, ``format_version`` and ``arrays_sha256``); returns
    the file's SHA-256."""
    path = Path(path)
    checked = {name: np.asarray(arrays[name]) for name in ARRAYS}
    record = {
        **meta,
        "format": DEMO_FORMAT,
        "format_version": DEMO_FORMAT_VERSION,
        "arrays_sha256": arrays_sha256(checked),
    }

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            np.savez(f, meta=np.array(json_text(record)), **checked)

    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write(path, write)


def load_demos(path: str | os.PathLike[str], fingerprint: Mapping[str, Any] | None = None) -> Demos:
    """A demonstrations file, refusing (:class:`DemoError`, one line) a missing, damaged or edited file, another
    format, arrays of the wrong shape, or a fingerprint other than ``fingerprint`` (e.g. :func:`demo_fingerprint`
    of the track and car it is to be used on)."""
    from vision_rl.files import file_sha256

    path = Path(path)
    if not path.is_file():
        raise DemoError(f"{path}: no such demonstrations file (make one with `vision-rl record-demos`)")
    try:
        with np.load(path, allow_pickle=False) as data:
            if "meta" not in data.files:
                raise DemoError(f"{path}: not a vision_rl demonstrations file (no meta record)")
            meta = json.loads(str(data["meta"]))
            if not isinstance(meta, dict) or meta.get("format") != DEMO_FORMAT:
                raise DemoError(f"{path}: not a vision_rl demonstrations file (no format {DEMO_FORMAT!r})")
            if int(meta.get("format_version", 0)) != DEMO_FORMAT_VERSION:
                raise DemoError(
                    f"{path}: demonstrations format {meta.get('format_version')}, this code reads "
                    f"{DEMO_FORMAT_VERSION}; record them again with `vision-rl record-demos`"
                )
            missing = [name for name in ARRAYS if name not in data.files]
            if missing:
                raise DemoError(f"{path}: the demonstrations lack the array {missing[0]!r}")
            arrays = {name: data[name] for name in ARRAYS}
    except DemoError:
        raise
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
        first = first_line(exc)
        raise DemoError(f"{path}: damaged demonstrations file ({first}); record them again") from None
    n = len(arrays["actions"])
    shapes = {
        "observations": (n, OBS_DIM),
        "actions": (n, 2),
        "expert_actions": (n, 2),
        "rewards": (n,),
        "episode_starts": (n,),
    }
    for name, shape in shapes.items():
        if arrays[name].shape != shape:
            raise DemoError(
                f"{path}: {name} has shape {arrays[name].shape}, not {shape}: not demonstrations of the "
                f"{OBS_DIM}-D {OBSERVATION} observation"
            )
    if n == 0 or not bool(arrays["episode_starts"][0]):
        raise DemoError(f"{path}: holds no transitions, or does not start with an episode start")
    if arrays_sha256(arrays) != meta.get("arrays_sha256"):
        raise DemoError(
            f"{path}: its arrays do not match their recorded SHA-256: the file was edited or damaged "
            "after it was recorded; record them again"
        )
    if not all(np.isfinite(arrays[name]).all() for name in ("observations", "actions", "expert_actions", "rewards")):
        raise DemoError(f"{path}: holds values that are not finite")
    if fingerprint is not None:
        _check(meta.get("fingerprint", {}), fingerprint, path)
    return Demos(
        observations=arrays["observations"].astype(np.float32, copy=False),
        actions=arrays["actions"].astype(np.float32, copy=False),
        expert_actions=arrays["expert_actions"].astype(np.float32, copy=False),
        rewards=arrays["rewards"].astype(np.float32),
        episode_starts=arrays["episode_starts"].astype(bool),
        meta=meta,
        path=path,
        sha256=file_sha256(path),
    )


def load_demos_for(path: str | os.PathLike[str], track: str, car: str) -> Demos:
    """:func:`load_demos` checked against ``track`` and ``car``: first the track, car and observation (cheap), then
    the normaliser the environment applies today (which may have to be sampled once)."""
    demos = load_demos(path, _setting_fingerprint(track, car))
    _check(demos.meta["fingerprint"], demo_fingerprint(track, car), demos.path)
    return demos


def _check(recorded: Mapping[str, Any], expected: Mapping[str, Any], path: Path) -> None:
    try:
        check_fingerprint(recorded, expected, f"{path} (demonstrations)")
    except ArtifactError as exc:
        raise DemoError(f"{exc}: record demonstrations on this track and car with `vision-rl record-demos`") from None


# ------------------------------------------------------------------------------------------------- recording


#: ``progress(laps_driven, laps_wanted)``.
DemoProgress = Callable[[float, float], None]
#: A learner that drives while the AI labels (DAgger): normalised observations (n, 96) -> actions (n, 2).
Learner = Callable[[np.ndarray], np.ndarray]


def check_record_config(cfg: RecordDemosConfig) -> None:
    """One clear line for a bad option, before anything is built."""
    if cfg.driver not in DRIVERS:
        raise ValueError(
            f"--driver must be one of {', '.join(DRIVERS)} (human demonstrations need a human driver, "
            f"which does not exist yet), got {cfg.driver!r}"
        )
    check_option_bounds(
        flat_values(cfg),
        {
            "laps": above(0),
            "cars": Bounds(1, 1000),
            "episode_s": at_least(0.1),
            "skill": Bounds(0, 1, low_open=True),
            "noise": Bounds(0, 1),
        },
    )
    if not cfg.out:
        raise ValueError("--out must name the demonstrations file")


def record_demos(
    cfg: RecordDemosConfig, progress: DemoProgress | None = None, learner: Learner | None = None
) -> dict[str, Any]:
    """Drive ``cfg.cars`` cars with :class:`HeldAIDriver` (or ``learner``, the AI labelling: DAgger) through the
    single-car race's episodes (random start points, ``cfg.episode_s`` long, same-step reset) until they have driven
    ``cfg.laps`` laps together, and write the transitions episode by episode after those of ``cfg.include``;
    returns the file's figures."""
    check_record_config(cfg)
    if bool(cfg.learner) != (learner is not None):
        raise ValueError("--learner names the run that drives; the caller loads it and passes it as learner")
    included = load_demos_for(cfg.include, cfg.track, cfg.car) if cfg.include else None
    t0 = time.perf_counter()
    recording = _drive_demos(cfg, progress, learner)
    arrays = _episode_major(recording.steps, recording.episode_ids, cfg.cars)
    n_new = len(arrays["actions"])
    if included is not None:
        arrays = {name: np.concatenate([getattr(included, name), arrays[name]]) for name in ARRAYS}
    record_s = time.perf_counter() - t0
    from vision_rl.files import package_version

    meta = {
        "fingerprint": demo_fingerprint(cfg.track, cfg.car, recording.normalizer),
        "track": cfg.track,
        "track_name": load_track(cfg.track).name,
        "demonstrator": recording.demonstrator,
        "settings": dataclasses.asdict(cfg),
        "normalizer": recording.normalizer.to_dict(),
        # DAgger's rounds: what drove, and the file this one extends (its own record keeps the rounds before).
        "driven_by": {"learner": cfg.learner} if cfg.learner else {"driver": cfg.driver},
        "included": None
        if included is None
        else {"path": str(included.path), "sha256": included.sha256, "n_transitions": included.n_transitions},
        "n_recorded_now": n_new,
        "n_transitions": len(arrays["actions"]),
        "n_episodes": int(arrays["episode_starts"].sum()),
        "laps_driven": round(recording.laps_driven, 3),
        "wall_contact_s_in_finished_episodes": round(recording.wall_s, 2),
        "mean_reward": float(arrays["rewards"].mean()),
        "record_time_s": round(record_s, 2),
        "package_version": package_version(),
    }
    sha = write_demos(cfg.out, arrays, meta)
    shown = (
        "n_transitions",
        "driven_by",
        "n_episodes",
        "laps_driven",
        "mean_reward",
        "record_time_s",
        "demonstrator",
        "fingerprint",
    )
    return {
        "out": str(cfg.out),
        "sha256": sha,
        "transitions_per_s": round(n_new / record_s, 1),
        "n_recorded_now": n_new,
        **{k: meta[k] for k in shown},
    }


class _Recording(NamedTuple):
    """What :func:`_drive_demos` drove: per step (T, cars, ...) arrays of :data:`ARRAYS` and each group's episode
    counter, with the laps driven, the wall contact of the finished episodes, the normaliser and the driver."""

    steps: dict[str, list[np.ndarray]]
    episode_ids: list[np.ndarray]
    laps_driven: float
    wall_s: float
    normalizer: ObsNormalizer
    demonstrator: dict[str, Any]


def _drive_demos(cfg: RecordDemosConfig, progress: DemoProgress | None, learner: Learner | None) -> _Recording:
    """The demonstrator's steps (or the learner's, labelled by the demonstrator) until the cars together have
    driven ``cfg.laps`` laps."""
    core = RacingCore(race_config(cfg.track, cfg.car, cfg.cars, cfg.episode_s), seed=cfg.seed)
    try:
        expert = HeldAIDriver(cfg.skill)
        rng = np.random.default_rng([cfg.seed, 1])
        half_range = action_space().high.astype(np.float32)
        expert.reset(core.world, core.ego_ids)
        core.reset_groups(np.arange(cfg.cars))
        lap_m = core.track.length_m
        steps: dict[str, list[np.ndarray]] = {name: [] for name in ARRAYS}
        starts = np.ones(cfg.cars, dtype=bool)
        episode = np.zeros(cfg.cars, dtype=np.int64)  # per group: its episode counter
        episode_ids: list[np.ndarray] = []
        done_progress_m, laps_driven, wall_s = 0.0, 0.0, 0.0
        while laps_driven < cfg.laps:
            obs = core.observation()
            # Actions are stored as float32: the environment is driven by exactly what is recorded.
            label = expert.act(core.world.state).astype(np.float32)
            action = label if learner is None else np.asarray(learner(obs), dtype=np.float32).reshape(label.shape)
            if cfg.noise > 0:
                jitter = rng.normal(0.0, cfg.noise, size=label.shape) * half_range
                action = np.clip(action + jitter, -half_range, half_range).astype(np.float32)
            _, reward, terminated, truncated, infos = core.step(action, autoreset=True)
            steps["observations"].append(obs)
            steps["actions"].append(action)
            steps["expert_actions"].append(label)
            steps["rewards"].append(reward)
            steps["episode_starts"].append(starts.copy())
            episode_ids.append(episode.copy())
            done = terminated | truncated
            current_m = 0.0
            for info in infos:
                if "final_info" in info:
                    done_progress_m += info["final_info"]["progress_m"]
                    wall_s += info["final_info"]["wall_contact_s"]
                else:
                    current_m += info["progress_m"]
            laps_driven = (done_progress_m + current_m) / lap_m
            episode += done
            starts = done
            if progress is not None:
                progress(laps_driven, cfg.laps)
        return _Recording(steps, episode_ids, laps_driven, wall_s, core.observer.normalizer, expert.identity)
    finally:
        core.observer.close()


def _episode_major(steps: dict[str, list[np.ndarray]], episode_ids: list[np.ndarray], cars: int) -> dict[str, Any]:
    """(T, cars, ...) -> episode by episode: group-major, then each group's episodes in time order."""
    n_steps = len(steps["actions"])
    group = np.repeat(np.arange(cars)[None, :], n_steps, axis=0).ravel()
    ep = np.stack(episode_ids).ravel()
    t = np.repeat(np.arange(n_steps), cars)
    order = np.lexsort((t, ep, group))
    arrays = {
        name: np.stack(values).reshape(n_steps * cars, *np.shape(values[0])[1:])[order]
        for name, values in steps.items()
    }
    arrays["observations"] = arrays["observations"].astype(np.float32)
    arrays["episode_starts"] = arrays["episode_starts"].astype(bool)
    return arrays


__all__ = [
    "DemoError",
    "Demos",
    "HeldAIDriver",
    "RecordDemosConfig",
    "demo_fingerprint",
    "load_demos",
    "load_demos_for",
    "race_config",
    "record_demos",
    "write_demos",
]
