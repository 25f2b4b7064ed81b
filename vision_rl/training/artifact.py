"""The policy artifact, ``policy.pt`` (weights, no pickle) plus ``policy.json`` (what rebuilds the policy's inputs
as in training: observation, racing config, normaliser, encoder, fingerprint), and the protocol driver a loaded
policy becomes. Loading refuses changed weights, a sidecar that no longer matches the weights or the track, and
another encoder than the recorded one.

The sidecar's fields, one by one: docs/notes/training.md.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from vision_rl.envs.core import RacingConfig, pedal_command, steering_command
from vision_rl.envs.observations import ObservationKind, ObsNormalizer
from vision_rl.envs.observer import Observer, in_batches_of
from vision_rl.envs.racing_env import action_space
from vision_rl.evaluation.protocol import DRIVER_BATCH_CARS
from vision_rl.files import atomic_write, content_damage, first_line, json_text, parse_json, sealed_record
from vision_rl.sim.track_library import load_track
from vision_rl.sim.world import World, WorldState
from vision_rl.training.persist import (
    ArtifactError,
    check_fingerprint,
    read_agent,
    read_sb3_zip,
    seal_buffer_file,
    write_agent_state,
)

if TYPE_CHECKING:
    from vision_rl.phase1_repr.checkpoint import FrozenEncoder

POLICY_FORMAT = "vision_rl.policy"
#: 4: the sidecar carries the SHA-256 of its own content (``content_sha256``), so that an edited normaliser,
#: control step or steering action is refused. Formats 3 (no content hash) and 2 (an SB3 zip) are converted by
#: ``vision-rl convert-policy``; format 1 (observations this code no longer makes) is refused.
POLICY_FORMAT_VERSION = 4
#: The format before the sidecar's content hash: converted in place by ``vision-rl convert-policy``.
UNSEALED_FORMAT_VERSION = 3
SIDECAR_NAME = "policy.json"
MODEL_NAME = "policy.pt"
BUFFER_NAME = "replay_buffer.npz"
#: Sub-folder of a run that holds the weights chosen by held-out starts (train-policy ``--select-starts``).
BEST_DIR = "best"
#: What format 2 stored the weights in.
SB3_ZIP_NAME = "policy.zip"


class PolicyError(ValueError):
    """A policy that cannot be used as asked (missing files, another encoder, a bad sidecar); the message says why."""


def racing_config_to_dict(config: RacingConfig) -> dict[str, Any]:
    """A JSON-ready dict of ``config`` (tuples become lists)."""
    return json.loads(json.dumps(dataclasses.asdict(config)))


def racing_config_from_dict(data: Mapping[str, Any]) -> RacingConfig:
    """The inverse of :func:`racing_config_to_dict`; unknown keys (a newer writer), values of another type than
    the field's default and values the config refuses are refused in one line."""
    if not isinstance(data, Mapping):
        raise PolicyError(f"racing_config is {type(data).__name__}, not an object of the environment's settings")
    fields = {f.name: f for f in dataclasses.fields(RacingConfig)}
    unknown = set(data) - set(fields)
    if unknown:
        raise PolicyError(f"racing_config has unknown fields {sorted(unknown)}")
    defaults = racing_config_to_dict(RacingConfig())
    for key, value in data.items():
        if not _same_json_type(value, defaults[key]):
            raise PolicyError(f"racing_config.{key} is {value!r}, not a value like {defaults[key]!r}")
    kwargs = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
    try:
        return RacingConfig(**kwargs)
    except (TypeError, ValueError) as exc:
        raise PolicyError(f"racing_config: {exc}") from None


def _same_json_type(value: Any, like: Any) -> bool:
    """Whether a JSON ``value`` has the type of ``like`` (an int where a float is due; a list of the same length
    and element types; any object where an object is)."""
    if isinstance(like, bool) or isinstance(value, bool):
        return isinstance(value, bool) and isinstance(like, bool)
    if isinstance(like, float):
        return isinstance(value, (int, float)) and math.isfinite(value)
    if isinstance(like, list):
        return (
            isinstance(value, list)
            and len(value) == len(like)
            and all(_same_json_type(v, w) for v, w in zip(value, like, strict=True))
        )
    return isinstance(value, type(like))


def obs_dim(kind: str, rep_dim: int = 64, critic_state: bool = False) -> int:
    """Length of a policy's input vector: 38 (state), 96 (overtaking) or rep_dim + 11 (vision; + 38 with
    ``critic_state``, the critic's columns)."""
    try:
        return ObservationKind.of(kind).vector_dim(rep_dim, critic_state)
    except ValueError as exc:
        raise PolicyError(str(exc)) from None


def policy_fingerprint(config: RacingConfig, observation: str, obs_dim: int, encoder_sha256: str | None) -> dict:
    """What a policy's weights belong to: checked against its sidecar and the track on every load."""
    return {
        "track_geometry_hash": load_track(config.track).geometry_hash,
        "car": config.car,
        "observation": ObservationKind.of(observation).value,
        "obs_dim": int(obs_dim),
        "encoder_sha256": encoder_sha256,
    }


@dataclass(frozen=True)
class PolicySpec:
    """The contents of ``policy.json``."""

    observation: str
    racing_config: dict[str, Any]
    obs_normalizer: dict[str, list[float]]
    fingerprint: dict[str, Any]
    """See :func:`policy_fingerprint`."""
    weights_sha256: str
    """SHA-256 of the agent file ``model``."""
    encoder: dict[str, Any] | None = None
    model: str = MODEL_NAME
    preset: str = ""
    sac: dict[str, Any] = dataclasses.field(default_factory=dict)
    seed: int = 0
    num_timesteps: int = 0
    """Environment steps (transitions over all cars) the weights were trained on."""
    train_time_s: float = 0.0
    """Wall-clock training time over all sessions of the run, s."""
    train_config: dict[str, Any] = dataclasses.field(default_factory=dict)
    selection: dict[str, Any] | None = None
    """For weights kept by ``--select-starts``: the held-out start seeds, laps, and the mean scored lap (s) that
    chose them; None for a run's last weights."""

    def __post_init__(self) -> None:
        try:
            ObservationKind.of(self.observation)
        except ValueError as exc:
            raise PolicyError(str(exc)) from None
        if self.kind.sees_frames and not self.encoder:
            raise PolicyError("a vision policy must record its encoder checkpoint")

    @property
    def kind(self) -> ObservationKind:
        return ObservationKind(self.observation)

    @property
    def config(self) -> RacingConfig:
        return racing_config_from_dict(self.racing_config)

    @property
    def normalizer(self) -> ObsNormalizer:
        return ObsNormalizer.from_dict(self.obs_normalizer)

    @property
    def encoder_sha256(self) -> str | None:
        return self.encoder["sha256"] if self.encoder else None

    @property
    def hidden_units(self) -> list[int]:
        return [int(n) for n in self.sac["hidden_units"]]

    def driver_identity(self, weights_path: Path) -> dict[str, Any]:
        """Who drives, for a protocol record: the weights at ``weights_path`` that this spec describes."""
        return {
            "driver": "policy",
            "observation": self.observation,
            "policy": str(weights_path),
            "policy_sha256": self.weights_sha256,
            "encoder_sha256": self.encoder_sha256,
            "num_timesteps": self.num_timesteps,
            "train_time_s": self.train_time_s,
            "seed": self.seed,
        }

    def to_dict(self) -> dict[str, Any]:
        from vision_rl.files import package_version

        return {
            "format": POLICY_FORMAT,
            "format_version": POLICY_FORMAT_VERSION,
            "package_version": package_version(),
            **dataclasses.asdict(self),
        }

    @classmethod
    def from_dict(cls, data: Any, source: str = "policy.json") -> PolicySpec:
        """A sidecar as read: refused in one line unless it is of this format, its content hash matches its content
        and every field has its type."""
        version = sidecar_version(data, source)
        if version == 2:
            raise PolicyError(
                f"{source}: policy format 2 keeps its weights in a Stable-Baselines3 zip, whose pickled parts can "
                f"run code when loaded, so it is not loaded; convert its tensors (nothing pickled is read) with "
                f"`vision-rl convert-policy --run {_run_of(source)}`"
            )
        if version == UNSEALED_FORMAT_VERSION:
            raise PolicyError(
                f"{source}: policy format 3 has no content hash, so an edit of its settings would go unseen; check "
                f"its weights and seal it with `vision-rl convert-policy --run {_run_of(source)}`"
            )
        if version < POLICY_FORMAT_VERSION:
            raise PolicyError(
                f"{source}: policy format {version} was trained on observations this version no longer makes "
                f"(format {POLICY_FORMAT_VERSION}); train it again with train-policy"
            )
        damage = content_damage(data)
        if damage is not None:
            raise PolicyError(f"{source}: the policy sidecar {damage}")
        return cls.from_fields(data, source)

    @classmethod
    def from_fields(cls, data: Mapping[str, Any], source: str = "policy.json") -> PolicySpec:
        """The spec of ``data``'s fields, each checked for its type (no format or content check: a converter's)."""
        check_spec_fields(data, source)
        names = {f.name for f in dataclasses.fields(cls)}
        try:
            return cls(**{k: v for k, v in data.items() if k in names})
        except (TypeError, ValueError) as exc:
            raise PolicyError(f"{source}: bad policy sidecar: {exc}") from None

    def write(self, path: str | os.PathLike[str]) -> Path:
        """Write the sidecar with the SHA-256 of its content (:func:`vision_rl.files.content_sha256`)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        data = sealed_record(self.to_dict())
        atomic_write(path, lambda tmp: tmp.write_text(json_text(data, indent=2)))
        return path

    @classmethod
    def read(cls, path: str | os.PathLike[str]) -> PolicySpec:
        return cls.from_dict(read_sidecar(path), str(path))


def read_sidecar(path: str | os.PathLike[str]) -> Any:
    """The parsed JSON of a sidecar, or a one-line PolicyError naming it."""
    try:
        return parse_json(Path(path).read_text())
    except OSError as exc:
        raise PolicyError(f"{path}: cannot read the policy sidecar: {exc.strerror or exc}") from None
    except ValueError as exc:
        raise PolicyError(f"{path}: the policy sidecar is not valid JSON: {exc}") from None


def sidecar_version(data: Any, source: str) -> int:
    """The format version of a parsed sidecar, refusing what is not one of this package or is newer."""
    if not isinstance(data, dict) or data.get("format") != POLICY_FORMAT:
        raise PolicyError(f"{source}: not a vision_rl policy sidecar (no format {POLICY_FORMAT!r})")
    version = data.get("format_version", 0)
    if not isinstance(version, int) or isinstance(version, bool):
        raise PolicyError(f"{source}: format_version is {version!r}, not a whole number")
    if version > POLICY_FORMAT_VERSION:
        raise PolicyError(f"{source}: policy format {version} is newer than this code's")
    return version


def _run_of(sidecar: str) -> Path:
    """The run folder a sidecar belongs to (a snapshot's or the chosen weights' sidecar lies one folder down)."""
    folder = Path(sidecar).parent
    return folder.parent if folder.name in ("checkpoints", BEST_DIR) else folder


#: The type of each sidecar field (None: may be null).
_FIELD_TYPES: dict[str, tuple[type, ...]] = {
    "observation": (str,),
    "racing_config": (dict,),
    "obs_normalizer": (dict,),
    "fingerprint": (dict,),
    "weights_sha256": (str,),
    "encoder": (dict, type(None)),
    "model": (str,),
    "preset": (str,),
    "sac": (dict,),
    "seed": (int,),
    "num_timesteps": (int,),
    "train_time_s": (int, float),
    "train_config": (dict,),
    "selection": (dict, type(None)),
}


def check_spec_fields(data: Mapping[str, Any], source: str) -> None:
    """Refuse, in one line naming the field, a sidecar field of the wrong type or a value that cannot be used: a
    config the environment refuses, a normaliser that is not two equal lists of finite numbers (scale not 0), a
    weights file outside the sidecar's folder, hidden layers that are not positive whole numbers."""
    for key, types in _FIELD_TYPES.items():
        if key in data and (not isinstance(data[key], types) or isinstance(data[key], bool)):
            raise PolicyError(f"{source}: {key} is {_short(data[key])}, not of type {types[0].__name__}")
    try:
        racing_config_from_dict(data.get("racing_config", {}))
    except PolicyError as exc:
        raise PolicyError(f"{source}: {exc}") from None
    normalizer = data.get("obs_normalizer", {})
    columns = [normalizer.get(k) for k in ("offset", "scale")]
    numbers = all(isinstance(c, list) and all(_finite(v) for v in c) for c in columns)
    if not numbers or len(columns[0]) != len(columns[1]):
        raise PolicyError(f"{source}: obs_normalizer needs offset and scale as lists of finite numbers, equally long")
    if 0 in columns[1]:
        raise PolicyError(f"{source}: obs_normalizer.scale holds a 0 (a division by zero)")
    model = data.get("model", MODEL_NAME)
    if Path(model).name != model or model in ("", ".", ".."):
        raise PolicyError(f"{source}: model {model!r} is not a file name beside the sidecar")
    hidden = (data.get("sac") or {}).get("hidden_units", [])
    if not isinstance(hidden, list) or not all(_finite(n) and n == int(n) and n > 0 for n in hidden):
        raise PolicyError(f"{source}: sac.hidden_units is {_short(hidden)}, not a list of positive whole numbers")
    encoder = data.get("encoder")
    if encoder is not None and not all(isinstance(encoder.get(k), str) for k in ("path", "sha256")):
        raise PolicyError(f"{source}: encoder needs its checkpoint's path and sha256 as text")


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _short(value: Any, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def chosen_weights(run: str | os.PathLike[str]) -> Path | None:
    """The folder of the weights a run's held-out starts chose (``run/best``), or None when it kept none."""
    best = Path(run) / BEST_DIR
    return best if (best / SIDECAR_NAME).is_file() else None


def snapshot_sidecar(weights: Path) -> Path:
    """The sidecar of a snapshot ``checkpoints/policy_<steps>.pt``: ``policy_<steps>.json`` beside it."""
    return weights.with_suffix(".json")


def resolve_policy_paths(path: str | os.PathLike[str]) -> tuple[Path, Path]:
    """(weights, sidecar) of a policy given as a run folder, its ``policy.pt``, or a snapshot
    ``checkpoints/policy_<steps>.pt`` (whose sidecar is ``policy_<steps>.json`` beside it)."""
    path = Path(path)
    if path.is_dir():
        spec_path = path / SIDECAR_NAME
        weights = path / MODEL_NAME
    elif path.suffix == ".json":
        spec_path, weights = path, path.with_suffix(".pt")
    else:
        weights = path
        spec_path = path.parent / SIDECAR_NAME if path.name == MODEL_NAME else snapshot_sidecar(path)
    if not spec_path.is_file():
        if not path.exists():
            raise PolicyError(
                f"{path}: no such policy (give a run folder of the command that trained it, or its {MODEL_NAME})"
            )
        raise PolicyError(f"{path}: the policy has no sidecar ({spec_path.name}) beside it")
    weights = spec_path.parent / PolicySpec.read(spec_path).model
    if not weights.is_file():
        raise PolicyError(f"{path}: no policy weights here (missing {weights})")
    return weights, spec_path


def load_checked_encoder(
    spec: PolicySpec,
    encoder: str | os.PathLike[str] = "",
    source: str = "policy",
    device: str = "cpu",
    runtime: str = "torch",
) -> FrozenEncoder:
    """The frozen encoder a vision policy was trained with, read once; refused when the SHA-256 of what was read is
    not the recorded one. ``encoder`` empty: the recorded path (which must still hold the same bytes)."""
    from vision_rl.phase1_repr.checkpoint import load_encoder

    if not spec.kind.sees_frames:
        raise PolicyError(f"{source} observes {spec.observation!r}, not frames: it takes no encoder")
    assert spec.encoder is not None
    recorded = spec.encoder["sha256"]
    path = Path(encoder) if encoder else Path(spec.encoder["path"])
    if not path.is_file():
        hint = "" if encoder else "; pass the encoder it was trained with (--encoder)"
        raise PolicyError(f"{source}: encoder checkpoint {path} not found{hint}")
    module = load_encoder(path, device=device, runtime=runtime)
    if module.sha256 != recorded:
        raise PolicyError(
            f"{source} was trained with encoder sha256 {recorded[:12]}... ({spec.encoder['path']}), but {path} "
            f"has sha256 {module.sha256[:12]}...: a policy only works with the frozen encoder it was trained on"
        )
    return module


class PolicyDriver:
    """A policy as a driver of the lap-time protocol: observations of its cars by an
    :class:`~vision_rl.envs.observer.Observer` built like the one it was trained with, deterministic actions.

    Args:
        predict: observations (n, obs_dim) -> actions (n, 2) ``[steer rad, omega]``.
        kind, normalizer, encoder: the observation it reads (as in training).
        config: its training environment's, whose frame size, control step, frame delay, steering and pedal actions
            it observes and acts with (see :func:`vision_rl.envs.core.steering_command` and
            :func:`~vision_rl.envs.core.pedal_command`); the default environment's when None.
        identity: who it is, for the record (policy path, hashes, training steps).
    """

    def __init__(
        self,
        predict,
        kind: str,
        normalizer: ObsNormalizer | None,
        encoder=None,
        config: RacingConfig | None = None,
        identity: dict[str, Any] | None = None,
    ) -> None:
        self.predict = predict
        self.kind, self.normalizer, self.encoder = kind, normalizer, encoder
        self.config = config or RacingConfig()
        self.identity = identity or {"driver": "policy", "observation": kind}
        self.observer: Observer | None = None

    @property
    def control_dt_s(self) -> float:
        """How often it acts, s (every driver of the protocol tells)."""
        return self.config.control_dt_s

    @classmethod
    def for_config(
        cls,
        predict,
        kind: str,
        normalizer: ObsNormalizer | None,
        encoder,
        config: RacingConfig,
        identity: dict[str, Any] | None = None,
    ) -> PolicyDriver:
        """A driver that observes and acts as the environment ``config`` did in training. A policy with a
        state-reading critic observes as a vision policy (:func:`vision_rl.training.critic_state.actor_only`)."""
        if config.critic_state:
            from vision_rl.training.critic_state import actor_only

            normalizer, predict = actor_only(normalizer, predict)
        return cls(predict, kind, normalizer, encoder, config, identity)

    def reset(self, world: World, car_ids: np.ndarray) -> None:
        if self.observer is not None:
            self.observer.close()
        self.observer = Observer(
            self.kind,
            world.track,
            world.car,
            world.model.groups,
            self.normalizer,
            self.encoder,
            self.config.image_hw_px,
            batch_cars=DRIVER_BATCH_CARS,
        )
        self.observer.delay_frames(self.config.frame_delay_s, self.control_dt_s)
        self.car_ids = np.asarray(car_ids)
        # As the environment: a run starts from the wheel angle the car was placed with.
        self.steer_command_rad = world.state.vehicle.steer_rad[self.car_ids].copy()
        self.max_steer_change_rad = world.car.max_steer_rate_radps * self.control_dt_s
        self.wheelbase_m = world.car.wheelbase_m

    def act(self, state: WorldState) -> np.ndarray:
        assert self.observer is not None, "reset() first"
        self.observer.remember(state)  # called once per control step, as the environment does after each step
        obs = self.observer(state, self.car_ids)
        action = in_batches_of(DRIVER_BATCH_CARS, self.predict, obs).astype(np.float64).reshape(len(self.car_ids), 2)
        speed = np.hypot(state.vehicle.vx_mps[self.car_ids], state.vehicle.vy_mps[self.car_ids])
        action[:, 0] = self.steer_command_rad = steering_command(
            action[:, 0],
            self.steer_command_rad,
            self.config.steer_action,
            self.max_steer_change_rad,
            speed,
            self.wheelbase_m,
            self.config.steer_change_share_of_range,
        )
        action[:, 1] = pedal_command(action[:, 1], self.config.pedal_full_at)
        return action

    def close(self) -> None:
        if self.observer is not None:
            self.observer.close()
            self.observer = None


@dataclass
class LoadedPolicy:
    """A trained policy ready to drive: the SB3 actor-critic in evaluation mode, its sidecar and, for vision, its
    frozen encoder."""

    policy: Any
    spec: PolicySpec
    weights_path: Path
    spec_path: Path
    encoder: Any = None
    encoder_path: Path | None = None

    @property
    def config(self) -> RacingConfig:
        return self.spec.config

    @property
    def obs_dim(self) -> int:
        rep_dim = self.encoder.rep_dim if self.encoder is not None else 64
        return obs_dim(self.spec.observation, rep_dim, self.config.critic_state)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions (n, 2) ``[steer rad, omega]`` for observations (n, obs_dim)."""
        action, _ = self.policy.predict(obs, deterministic=True)
        return np.asarray(action, dtype=np.float64).reshape(len(obs), 2)

    def driver(self) -> PolicyDriver:
        """This policy as a protocol driver, reading what it was trained on."""
        spec, identity = self.spec, self.spec.driver_identity(self.weights_path)
        return PolicyDriver.for_config(self.act, spec.observation, spec.normalizer, self.encoder, spec.config, identity)


def sac_policy(obs_dim: int, hidden_units: list[int], device: str = "cpu", critic_state: bool = False):
    """An SB3 SAC actor-critic for ``obs_dim`` inputs and the racing action space, untrained; with ``critic_state``
    its actor reads all but the critic's last columns (:mod:`vision_rl.training.critic_state`)."""
    from gymnasium import spaces

    from vision_rl.training.critic_state import sac_policy_class

    space = spaces.Box(-np.inf, np.inf, (obs_dim,), dtype=np.float32)
    policy_class, kwargs = sac_policy_class(obs_dim, critic_state)
    return policy_class(space, action_space(), lambda _: 0.0, net_arch=list(hidden_units), **kwargs).to(device)


def load_policy(
    path: str | os.PathLike[str],
    encoder: str | os.PathLike[str] = "",
    device: str = "cpu",
    encoder_runtime: str = "auto",
) -> LoadedPolicy:
    """Load a policy (run folder, ``policy.pt`` or a snapshot) with, for vision, its frozen encoder.

    The weights must have the recorded SHA-256 and the fingerprint the sidecar and the track's geometry give.
    ``encoder``: optional checkpoint path for a vision policy; refused when its hash is not the recorded one.
    ``encoder_runtime``: see :func:`~vision_rl.phase1_repr.checkpoint.load_encoder`.
    """
    from vision_rl.phase1_repr.onnx_runtime import resolve_runtime

    resolve_runtime(encoder_runtime, device)  # refused for a state policy too, which would never use it
    weights_path, spec_path = resolve_policy_paths(path)
    spec = PolicySpec.read(spec_path)
    encoder_path = None
    module = None
    if spec.kind.sees_frames:
        module = load_checked_encoder(spec, encoder, f"policy {weights_path}", device, encoder_runtime)
        encoder_path = module.path
    elif encoder:
        load_checked_encoder(spec, encoder, source=f"policy {weights_path}")  # raises: a state policy takes none
    critic_state = spec.config.critic_state
    dim = obs_dim(spec.observation, module.rep_dim if module is not None else 64, critic_state)
    expected = policy_fingerprint(spec.config, spec.observation, dim, spec.encoder_sha256)
    try:
        # The sidecar's claim against the track as it loads today, then the weights' own record against both.
        check_fingerprint(spec.fingerprint, expected, str(spec_path))
        state = read_agent(weights_path, expected, spec.weights_sha256)
        policy = sac_policy(dim, spec.hidden_units, device, critic_state)
        policy.load_state_dict(state["policy"])
    except ArtifactError as exc:
        raise PolicyError(str(exc)) from None
    except RuntimeError as exc:
        raise PolicyError(
            f"{weights_path}: the weights do not fit a {spec.hidden_units} network of {dim} inputs: {first_line(exc)}"
        ) from None
    policy.set_training_mode(False)
    return LoadedPolicy(policy, spec, weights_path, spec_path, module, encoder_path)


def convert_run(run: str | os.PathLike[str]) -> list[Path]:
    """Bring a run folder to this version in place; returns the files written. Format 2 (an SB3 zip):
    :func:`convert_sb3_run`. Format 3: each sidecar (the run's, ``best/``'s and the snapshots') whose weights still
    have the recorded SHA-256 and fingerprint is sealed with its content hash, and a replay buffer of format 1 with
    its arrays' hashes. What a format-3 sidecar says cannot be checked: sealing it vouches for it as it is now."""
    run = Path(run)
    spec_path = run / SIDECAR_NAME
    if not spec_path.is_file():
        raise PolicyError(f"{run}: not a run folder (no {SIDECAR_NAME})")
    if sidecar_version(read_sidecar(spec_path), str(spec_path)) == 2:
        return convert_sb3_run(run)
    sidecars = [spec_path, run / BEST_DIR / SIDECAR_NAME, *sorted((run / "checkpoints").glob("policy_*.json"))]
    written = []
    for sidecar in (p for p in sidecars if p.is_file()):
        data = read_sidecar(sidecar)
        if sidecar_version(data, str(sidecar)) == UNSEALED_FORMAT_VERSION:
            spec = PolicySpec.from_fields({**data, "format_version": POLICY_FORMAT_VERSION}, str(sidecar))
            expected = {**spec.fingerprint, "track_geometry_hash": load_track(spec.config.track).geometry_hash}
            try:
                check_fingerprint(spec.fingerprint, expected, str(sidecar))
                read_agent(sidecar.parent / spec.model, expected, spec.weights_sha256)
            except ArtifactError as exc:
                raise PolicyError(f"{exc}; not sealed") from None
            written.append(spec.write(sidecar))
        else:
            PolicySpec.read(sidecar)  # this version's: it must be whole
    for buffer in (run / BUFFER_NAME, run / BEST_DIR / BUFFER_NAME):
        try:
            if buffer.is_file() and seal_buffer_file(buffer):
                written.append(buffer)
        except ArtifactError as exc:
            raise PolicyError(str(exc)) from None
    return written


def convert_sb3_run(run: str | os.PathLike[str]) -> list[Path]:
    """Convert a format-2 run folder (``policy.zip`` and ``checkpoints/policy_<steps>.zip``) to this format in
    place; returns the files written. Only the zips' tensors and plain JSON counters are read
    (:func:`~vision_rl.training.persist.read_sb3_zip`), so nothing in them can run. The pickled replay buffer is
    not read: a resumed run collects a new one."""
    run = Path(run)
    spec_path = run / SIDECAR_NAME
    data = read_sidecar(spec_path)
    if sidecar_version(data, str(spec_path)) != 2:
        raise PolicyError(f"{spec_path}: not a format-2 policy sidecar (nothing to convert)")
    try:
        config = racing_config_from_dict(data["racing_config"])
    except (PolicyError, KeyError) as exc:
        raise PolicyError(f"{spec_path}: {exc}") from None
    encoder_sha = data["encoder"]["sha256"] if data.get("encoder") else None
    states = {}  # every zip is read before anything is written: a damaged one leaves the run as it was
    for zip_path in [run / data.get("model", SB3_ZIP_NAME), *sorted((run / "checkpoints").glob("policy_*.zip"))]:
        try:
            states[zip_path] = state = read_sb3_zip(zip_path)
            state["input_dim"] = int(state["policy"]["actor.latent_pi.0.weight"].shape[1])  # the actor's inputs
        except ArtifactError as exc:
            raise PolicyError(str(exc)) from None
        except KeyError:
            raise PolicyError(f"{zip_path}: not the zip of an SB3 SAC MLP policy (no actor.latent_pi.0)") from None
    written = []
    for zip_path, state in states.items():
        fingerprint = policy_fingerprint(config, data["observation"], state.pop("input_dim"), encoder_sha)
        weights = zip_path.with_suffix(".pt")
        sha = write_agent_state(state, weights, fingerprint)
        entry = {
            **data,
            "format_version": POLICY_FORMAT_VERSION,
            "model": weights.name,
            "weights_sha256": sha,
            "fingerprint": fingerprint,
            "num_timesteps": state["counters"]["num_timesteps"],
        }
        sidecar = spec_path if zip_path.parent == run else snapshot_sidecar(weights)
        PolicySpec.from_fields(entry, str(sidecar)).write(sidecar)
        written += [weights, sidecar]
    return written
