"""Observation vectors of the environments, their names, and their normalisation.

- ``state`` (38-D, the privileged baseline of Fuchs et al.): the 27 Phase-1 targets with the curvature sampled
  1.0-2.8 s ahead at the current speed instead of 40-120 m ahead, then the 11 dedicated features.
- ``overtaking`` (96-D, overtaking paper Table I): body velocity (3), body acceleration (3), heading angle to the
  centre line (1), 72 lidar beams (72), previous steering (1), wall flag (1), car flag (1), curvature 0.2-3.0 s
  ahead (14).
- ``vision``: a Dict of the rendered frame and the 11 dedicated features (Phase 2 embeds the frame).

Normalisation follows the overtaking paper (section III-B): z-score for every feature except the lidar, which is
min-max scaled to [0, 1]. The z-score statistics come from states sampled once by the disrupted built-in AI and
are cached on disk per (track geometry, car, observation kind), so every run of one configuration uses the same
numbers.
"""

from __future__ import annotations

import enum
import hashlib
import json
from dataclasses import dataclass

import numpy as np

from vision_rl.files import write_json
from vision_rl.sim import sensors
from vision_rl.sim.driving import cache_dir
from vision_rl.sim.track import Track
from vision_rl.sim.vehicle import ACTION_STEER_LIMIT_RAD
from vision_rl.sim.world import WorldState

STATE_OBS_NAMES: tuple[str, ...] = (
    sensors.TARGET_NAMES[:17]
    + tuple(f"curvature_{t:.1f}s_ahead" for t in sensors.STATE_CURVATURE_TIMES_S)
    + sensors.DEDICATED_NAMES
)
OVERTAKING_OBS_NAMES: tuple[str, ...] = (
    *sensors.DEDICATED_NAMES[:6],
    "heading_angle_to_centre_line",
    *tuple(f"lidar_{np.rad2deg(a):+.1f}deg" for a in sensors.LIDAR_ANGLES_RAD),
    "previous_steering",
    "wall_contact",
    "car_contact",
    *tuple(f"curvature_{t:.1f}s_ahead" for t in sensors.OVERTAKING_CURVATURE_TIMES_S),
)
#: Slice of the lidar beams inside the overtaking vector: min-max scaled, not z-scored.
OVERTAKING_LIDAR = slice(7, 79)


class ObservationKind(str, enum.Enum):
    """What a policy observes. A str, so its value is the name configs, sidecars and records hold."""

    STATE = "state"
    """The 38-D privileged vector."""
    OVERTAKING = "overtaking"
    """The overtaking paper's 96-D vector (lidar among it)."""
    VISION = "vision"
    """The rendered frame (embedded by a frozen encoder) and the 11 dedicated features."""

    def __str__(self) -> str:  # its name in file names, keys and messages, on every Python version
        return self.value

    @classmethod
    def of(cls, name: str) -> ObservationKind:
        """The kind named ``name``; another name is refused in one line that lists the kinds."""
        try:
            return cls(name)
        except ValueError:
            raise ValueError(f"observation must be one of {[k.value for k in cls]}, got {name!r}") from None

    @property
    def sees_frames(self) -> bool:
        return self is ObservationKind.VISION

    @property
    def names(self) -> tuple[str, ...]:
        """The names of a fixed vector's entries (vision's depend on the encoder: none)."""
        return {ObservationKind.STATE: STATE_OBS_NAMES, ObservationKind.OVERTAKING: OVERTAKING_OBS_NAMES}.get(self, ())

    def vector_dim(self, rep_dim: int = 64, critic_state: bool = False) -> int:
        """Length of the vector: 38 (state), 96 (overtaking) or, for vision with an encoder of ``rep_dim``,
        ``rep_dim`` + 11, + 38 with ``critic_state`` (the state observation after them)."""
        if self.sees_frames:
            return rep_dim + len(sensors.DEDICATED_NAMES) + (len(STATE_OBS_NAMES) if critic_state else 0)
        return len(self.names)

    @property
    def min_max_columns(self) -> slice | None:
        """Columns scaled min-max to [0, 1] instead of z-scored: the overtaking vector's lidar."""
        return OVERTAKING_LIDAR if self is ObservationKind.OVERTAKING else None


OBS_NAMES = {kind.value: kind.names for kind in ObservationKind if kind.names}


def feature_bounds(names: tuple[str, ...], track: Track) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) float64 of the raw features ``names`` on ``track`` that hold by their definitions, -inf/inf where
    none does: edge rays within [0, 200] m (their range), wall distances >= 0 m, the heading angle to the centre line
    within [-pi, pi] rad, curvature ahead within the track's least and greatest, lidar beams within [0, 20] m,
    contact flags 0 or 1, the previous steering command within +-pi/6 rad (every command is clipped to it). Speeds,
    accelerations, rates and the centre-line offset have no such bound."""
    curvature = (float(track.curvature_1pm.min()), float(track.curvature_1pm.max()))
    by_prefix = {
        "edge_distance_": (0.0, sensors.EDGE_RAY_RANGE_M),
        "min_distance_": (0.0, np.inf),
        "heading_angle_to_centre_line": (-np.pi, np.pi),
        "curvature_": curvature,
        "lidar_": (0.0, sensors.LIDAR_RANGE_M),
        "wall_contact": (0.0, 1.0),
        "car_contact": (0.0, 1.0),
        "previous_steering": (-ACTION_STEER_LIMIT_RAD, ACTION_STEER_LIMIT_RAD),
    }
    bounds = [next((b for p, b in by_prefix.items() if name.startswith(p)), (-np.inf, np.inf)) for name in names]
    low, high = np.array(bounds, dtype=np.float64).reshape(-1, 2).T
    return low, high


#: Bump when an observation's definition or its statistics' sampling changes: cached statistics of older versions
#: are then ignored. 3: statistics always come from a 20-group world, whatever the environment that asks.
OBS_VERSION = 3


def _speed(state: WorldState, ids: np.ndarray) -> np.ndarray:
    return np.hypot(state.vehicle.vx_mps[ids], state.vehicle.vy_mps[ids])


def state_observation(track: Track, caster: sensors.WallRayCaster, state: WorldState, ids: np.ndarray) -> np.ndarray:
    """The 38-D ``state`` observation (len(ids), 38) of the cars ``ids``, raw physical units."""
    v = state.vehicle
    targets = sensors.environment_targets(
        track, caster, v.x_m[ids], v.y_m[ids], v.yaw_rad[ids], state.s_m[ids], state.lateral_m[ids]
    )
    curvature = sensors.state_curvature_ahead(track, state.s_m[ids], _speed(state, ids))
    vehicle_ids = type(v)(*(a[ids] for a in v))
    dedicated = sensors.dedicated_features(vehicle_ids, state.wall_contact[ids], state.prev_steer_cmd_rad[ids])
    return np.hstack([targets[:, :17], curvature, dedicated])


def overtaking_observation(
    track: Track,
    caster: sensors.WallRayCaster,
    state: WorldState,
    ids: np.ndarray,
    car_length_m: float,
    car_width_m: float,
    groups: np.ndarray,
) -> np.ndarray:
    """The 96-D ``overtaking`` observation (len(ids), 96) of the cars ``ids``; the lidar sees same-group cars."""
    v = state.vehicle
    corners = sensors.car_corners(v.x_m, v.y_m, v.yaw_rad, car_length_m, car_width_m)
    beams = sensors.lidar(caster, v.x_m[ids], v.y_m[ids], v.yaw_rad[ids], corners, groups, car_index=ids)
    heading = sensors.wrap_angle(v.yaw_rad[ids] - track.heading_at(state.s_m[ids]))
    curvature = sensors.curvature_ahead_time(
        track, state.s_m[ids], _speed(state, ids), sensors.OVERTAKING_CURVATURE_TIMES_S
    )
    out = np.empty((len(ids), 96))
    out[:, 0] = v.vx_mps[ids]
    out[:, 1] = v.vy_mps[ids]
    out[:, 2] = 0.0
    out[:, 3] = v.ax_mps2[ids]
    out[:, 4] = v.ay_mps2[ids]
    out[:, 5] = 0.0
    out[:, 6] = heading
    out[:, OVERTAKING_LIDAR] = beams
    out[:, 79] = state.prev_steer_cmd_rad[ids]
    out[:, 80] = state.wall_contact[ids]
    out[:, 81] = state.car_contact[ids]
    out[:, 82:] = curvature
    return out


@dataclass(frozen=True)
class ObsNormalizer:
    """``(obs - offset) / scale`` per feature; features that never vary keep scale 1."""

    offset: np.ndarray
    scale: np.ndarray

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return ((obs - self.offset) / self.scale).astype(np.float32)

    def to_dict(self) -> dict:
        return {"offset": self.offset.tolist(), "scale": self.scale.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> ObsNormalizer:
        return cls(offset=np.asarray(d["offset"], dtype=np.float64), scale=np.asarray(d["scale"], dtype=np.float64))

    @classmethod
    def from_samples(cls, kind: str, samples: np.ndarray) -> ObsNormalizer:
        """z-score statistics of ``samples`` (n, dim); for ``overtaking`` the lidar is min-max over [0, range]."""
        offset = samples.mean(axis=0)
        scale = samples.std(axis=0)
        scale = np.where(scale > 1e-6, scale, 1.0)
        lidar = ObservationKind.of(kind).min_max_columns
        if lidar is not None:
            offset[lidar] = 0.0
            scale[lidar] = sensors.LIDAR_RANGE_M
        return cls(offset=offset, scale=scale)


def stats_key(track: Track, car_name: str, kind: str) -> str:
    raw = f"{track.geometry_hash}|{car_name}|{kind}|{OBS_VERSION}"
    return hashlib.sha256(raw.encode()).hexdigest()[:16]


def load_or_compute_normalizer(track: Track, car_name: str, kind: str, sample) -> ObsNormalizer:
    """The cached normaliser of (track, car, kind), or ``sample()`` -> (n, dim) raw observations, cached.

    A corrupt or unreadable cache file is recomputed and rewritten.
    """
    path = cache_dir() / "obs_stats" / f"{kind}-{stats_key(track, car_name, kind)}.json"
    try:
        normalizer = ObsNormalizer.from_dict(json.loads(path.read_text()))
        if normalizer.offset.shape == (ObservationKind.of(kind).vector_dim(),):
            return normalizer
    except (OSError, ValueError, KeyError, TypeError):
        pass
    normalizer = ObsNormalizer.from_samples(kind, sample())
    write_json(path, {**normalizer.to_dict(), "track": track.name, "car": car_name, "kind": kind}, indent=None)
    return normalizer
