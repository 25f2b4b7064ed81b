"""DDPG with an asymmetric actor-critic (the Project CARS 2 paper): a pixel actor, a critic on motion and the
racing line, Ornstein-Uhlenbeck exploration, a replay buffer that stores every frame once, and files without pickle.

The networks are the paper's (section IV-D; :class:`DDPGHyper` holds its Table 2): the actor (:class:`PixelActor`)
four small convolutions then three dense layers to four key outputs, the critic (:class:`Critic`) three pathways
(motion, goal, action) into one Q. Variants, for the ablations: ``asymmetric`` (the paper), ``symmetric`` (the
critic also on pixels) and ``state-actor`` (the actor on the critic's motion and goal, no pixels). The replay
(:class:`FrameReplay`) holds one row per car and step, the next observation being the car's following row, so
each frame is stored once; the files (:func:`save_agent_file`, :func:`save_replay`) are read without pickle, the
buffer in chunk files of which only the changed ones are rewritten, listed in an index that is replaced last. The
layers in detail, the measurements behind them and why not Stable-Baselines3's DDPG: docs/notes/ddpg.md,
"agent.py".
"""

from __future__ import annotations

import math
import os
import zipfile
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from vision_rl.ddpg.config import DDPGError, DDPGHyper, FrameSizeError
from vision_rl.envs.observer import in_batches_of
from vision_rl.envs.pixel_racing import (
    PixelObserver,
    PixelRacingConfig,
    action_space,
    critic_input_scale,
    keys_to_action,
)
from vision_rl.evaluation.protocol import DRIVER_BATCH_CARS
from vision_rl.files import (
    CONTENT_KEY,
    atomic_write,
    content_damage,
    content_sha256,
    first_line,
    parse_json,
    sealed_record,
    write_json,
)
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import get_preset
from vision_rl.sim.world import World, WorldState
from vision_rl.training.persist import DAMAGED_FILE_ERRORS, ArtifactError, check_fingerprint, file_sha256

AGENT_FORMAT = "vision_rl.ddpg_agent"
REPLAY_FORMAT = "vision_rl.ddpg_replay"
FORMAT_VERSION = 1
#: The replay index and the run sidecar: 2 carries the SHA-256 of its content; 1 (no hash) still reads.
SEALED_FORMAT_VERSION = 2
AGENT_NAME = "ddpg.pt"
SIDECAR_NAME = "ddpg.json"
REPLAY_DIR = "replay"
#: Frames per buffer chunk file (about 64 MB of 89x120 frames).
CHUNK_FRAMES = 2048
_ACTION_LOW = torch.as_tensor(action_space().low)
_ACTION_HIGH = torch.as_tensor(action_space().high)


# ------------------------------------------------------------------------------------------------ networks


def _dense_pathway(n_in: int, batch_norm: bool = True) -> nn.Sequential:
    """Dense 150, 300, 300, each ReLU then batch-norm (without ``batch_norm``: ReLU only)."""
    layers: list[nn.Module] = []
    for n_out in (150, 300, 300):
        layers += [nn.Linear(n_in, n_out), nn.ReLU()]
        if batch_norm:
            layers.append(nn.BatchNorm1d(n_out))
        n_in = n_out
    return nn.Sequential(*layers)


#: Each preset's convolutions, in order: (filters, stride, 2x2 max-pool after it); every kernel is 2x2. ``paper``: the
#: paper's four stride-1 convolutions, each pooled. ``cpu``: the first two strided 2 (a 2x2 stride-2 kernel still reads
#: every pixel once), the last two unpooled, which cuts the trunk's multiply-adds about tenfold (docs/notes/ddpg.md).
TRUNK_LAYERS = {
    "paper": ((64, 1, True), (64, 1, True), (32, 1, True), (32, 1, True)),
    "cpu": ((64, 2, True), (64, 2, True), (32, 1, False), (32, 1, False)),
}


def _side_out_px(side_px: int, preset: str) -> int:
    """A frame side's length after the preset's convolutions and pooling (< 1: the frame is too small)."""
    for _, stride, pool in TRUNK_LAYERS[preset]:
        side_px = (side_px - 2) // stride + 1
        side_px = side_px // 2 if pool else side_px
    return side_px


def min_frame_px(preset: str) -> int:
    """The shortest frame side that the preset's trunk takes (31 for the paper's, 48 for the cpu one)."""
    return next(side for side in range(2, 1024) if _side_out_px(side, preset) >= 1)


class ConvTrunk(nn.Module):
    """Four 2x2 convolutions (64, 64, 32, 32), each ReLU, batch-norm and, where the preset says, 2x2 max-pool
    (:data:`TRUNK_LAYERS`); input uint8 frames (n, H, W, 3) of exactly ``image_hw_px`` (without ``batch_norm``: no
    batch-norm)."""

    def __init__(self, image_hw_px: tuple[int, int], batch_norm: bool = True, preset: str = "paper") -> None:
        super().__init__()
        self.image_hw_px = (int(image_hw_px[0]), int(image_hw_px[1]))
        h, w = (_side_out_px(side, preset) for side in self.image_hw_px)
        if h < 1 or w < 1:
            side = min_frame_px(preset)
            raise FrameSizeError(
                f"frames of {self.image_hw_px[0]}x{self.image_hw_px[1]} px are too small for the {preset} trunk's "
                f"convolutions and pooling: use at least {side}x{side}"
            )
        layers: list[nn.Module] = []
        c_in = 3
        for c_out, stride, pool in TRUNK_LAYERS[preset]:
            layers.append(nn.Conv2d(c_in, c_out, 2, stride))
            if pool:
                # Pooling before the ReLU gives the same values as after it (both are monotone) on a quarter of them.
                layers.append(nn.MaxPool2d(2))
            layers.append(nn.ReLU(inplace=True))
            if batch_norm:
                layers.append(nn.BatchNorm2d(c_out))
            c_in = c_out
        self.net = nn.Sequential(*layers)
        self.out_dim = c_in * h * w
        self.channels_last = True
        """Feed the convolutions the channels-last view of the frames (False: a contiguous NCHW copy)."""

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        if frames.ndim != 4 or tuple(frames.shape[1:]) != (*self.image_hw_px, 3):
            raise FrameSizeError(
                f"frames of shape {tuple(frames.shape[1:])} (height, width, channels), but this network was built "
                f"for {self.image_hw_px[0]}x{self.image_hw_px[1]}x3: render frames at its image_hw_px"
            )
        x = frames.permute(0, 3, 1, 2).float().div_(255.0)  # a channels-last view of the NHWC frames
        if not self.channels_last:
            x = x.contiguous()
        return self.net(x).flatten(1)


def _variance_scaling_(linear: nn.Linear, scale: float) -> None:
    """Keras VarianceScaling(scale, fan_in, truncated_normal): std sqrt(scale / fan_in) / 0.8796, cut at 2 std."""
    std = math.sqrt(scale / linear.in_features) / 0.87962566103423978
    nn.init.trunc_normal_(linear.weight, std=std, a=-2 * std, b=2 * std)
    nn.init.zeros_(linear.bias)


class _KeyHead(nn.Module):
    """Four outputs: accelerate and brake through ``pedal_activation`` (the paper's relu, or sigmoid), left and right
    tanh."""

    def __init__(self, n_in: int, init_scale: float, pedal_activation: str = "relu") -> None:
        super().__init__()
        self.out = nn.Linear(n_in, 4)
        _variance_scaling_(self.out, init_scale)
        self.pedal = torch.relu if pedal_activation == "relu" else torch.sigmoid

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        return self.keys(self.out(h))

    def keys(self, z: torch.Tensor) -> torch.Tensor:
        """The keys of the output layer's pre-activations ``z`` (n, 4)."""
        return torch.stack([self.pedal(z[:, 0]), torch.tanh(z[:, 1]), torch.tanh(z[:, 2]), self.pedal(z[:, 3])], 1)


class _Scaled(nn.Module):
    """Motion and goal (n, 18), or a task's flat state, scaled by fixed offsets and scales (kept in the weights)."""

    def __init__(self, offset: np.ndarray, scale: np.ndarray) -> None:
        super().__init__()
        self.register_buffer("offset", torch.as_tensor(offset, dtype=torch.float32))
        self.register_buffer("scale", torch.as_tensor(scale, dtype=torch.float32))

    def forward(self, *parts: torch.Tensor) -> torch.Tensor:
        return (torch.cat(parts, 1) - self.offset) / self.scale


class PixelActor(nn.Module):
    """Frames (n, H, W, 3) uint8 -> keys (n, 4)."""

    def __init__(
        self,
        image_hw_px: tuple[int, int],
        init_scale: float = 1e-2,
        pedal_activation: str = "relu",
        batch_norm: bool = True,
        trunk: str = "paper",
    ) -> None:
        super().__init__()
        self.trunk = ConvTrunk(image_hw_px, batch_norm, trunk)
        self.dense = _dense_pathway(self.trunk.out_dim, batch_norm)
        self.head = _KeyHead(300, init_scale, pedal_activation)

    def forward(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        return self.head.keys(self.preactivation(obs))

    def preactivation(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The output layer's values before the keys' activations (n, 4)."""
        return self.head.out(self.dense(self.trunk(obs["image"])))


class StateActor(nn.Module):
    """Motion and goal -> keys (n, 4): the state-only actor of the ablation."""

    def __init__(
        self,
        offset: np.ndarray,
        scale: np.ndarray,
        init_scale: float = 1e-2,
        pedal_activation: str = "relu",
        batch_norm: bool = True,
    ) -> None:
        super().__init__()
        self.scaled = _Scaled(offset, scale)
        self.dense = _dense_pathway(18, batch_norm)
        self.head = _KeyHead(300, init_scale, pedal_activation)

    def forward(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        return self.head.keys(self.preactivation(obs))

    def preactivation(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The output layer's values before the keys' activations (n, 4)."""
        return self.head.out(self.dense(self.scaled(obs["motion"], obs["goal"])))


class Critic(nn.Module):
    """Q(motion, goal, action): three pathways merged into Dense 600 and Q."""

    def __init__(self, offset: np.ndarray, scale: np.ndarray, batch_norm: bool = True) -> None:
        super().__init__()
        self.scaled = _Scaled(offset, scale)
        self.motion = _dense_pathway(15, batch_norm)
        self.goal = _dense_pathway(3, batch_norm)
        self.action = _dense_pathway(4, batch_norm)
        self.merge = nn.Sequential(nn.Linear(900, 600), nn.ReLU(), nn.Linear(600, 1))

    def forward(self, obs: Mapping[str, torch.Tensor], action: torch.Tensor) -> torch.Tensor:
        x = self.scaled(obs["motion"], obs["goal"])
        h = torch.cat([self.motion(x[:, :15]), self.goal(x[:, 15:]), self.action(action)], 1)
        return self.merge(h).squeeze(1)


class PixelCritic(nn.Module):
    """Q(frame, action) of the symmetric ablation: a CNN pathway like the actor's in place of motion and goal."""

    def __init__(self, image_hw_px: tuple[int, int], batch_norm: bool = True, trunk: str = "paper") -> None:
        super().__init__()
        self.trunk = ConvTrunk(image_hw_px, batch_norm, trunk)
        self.image = _dense_pathway(self.trunk.out_dim, batch_norm)
        self.action = _dense_pathway(4, batch_norm)
        self.merge = nn.Sequential(nn.Linear(600, 600), nn.ReLU(), nn.Linear(600, 1))

    def forward(self, obs: Mapping[str, torch.Tensor], action: torch.Tensor) -> torch.Tensor:
        h = torch.cat([self.image(self.trunk(obs["image"])), self.action(action)], 1)
        return self.merge(h).squeeze(1)


@dataclass(frozen=True)
class VectorTask:
    """A task other than racing: a flat observation vector (key ``state``), scaled by fixed offsets and scales like
    motion and goal, and ``action_dim`` actions in [-1, 1] (the caller maps them onto its task's bounds). With it the
    ``state-actor`` agent's layers, update, noise and replay learn a standard Gymnasium task
    (:mod:`vision_rl.ddpg.reference`)."""

    obs_offset: tuple[float, ...]
    """Subtracted from each observation component."""
    obs_scale: tuple[float, ...]
    """Each observation component is divided by this after the offset."""
    action_dim: int
    """Actions per step, each in [-1, 1]."""

    def __post_init__(self) -> None:
        if len(self.obs_offset) != len(self.obs_scale) or not self.obs_scale or self.action_dim < 1:
            raise DDPGError(
                f"a vector task needs as many offsets as scales (got {len(self.obs_offset)} and "
                f"{len(self.obs_scale)}) and action_dim >= 1 (got {self.action_dim})"
            )

    @property
    def obs_dim(self) -> int:
        return len(self.obs_scale)


class VectorActor(nn.Module):
    """A flat state (n, d) -> actions (n, k) in [-1, 1]: the state actor's layers (scaled input, Dense 150, 300,
    300, an output layer initialised by variance scaling) with tanh on every output."""

    def __init__(self, task: VectorTask, init_scale: float = 1e-2, batch_norm: bool = True) -> None:
        super().__init__()
        self.scaled = _Scaled(np.asarray(task.obs_offset), np.asarray(task.obs_scale))
        self.dense = _dense_pathway(task.obs_dim, batch_norm)
        self.out = nn.Linear(300, task.action_dim)
        _variance_scaling_(self.out, init_scale)

    def forward(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        return torch.tanh(self.out(self.dense(self.scaled(obs["state"]))))


class VectorCritic(nn.Module):
    """Q(state, action) of a vector task: the critic's layers with one state pathway in place of motion and goal
    (as :class:`PixelCritic`'s image pathway), merged with the action pathway into Dense 600 and Q."""

    def __init__(self, task: VectorTask, batch_norm: bool = True) -> None:
        super().__init__()
        self.scaled = _Scaled(np.asarray(task.obs_offset), np.asarray(task.obs_scale))
        self.state = _dense_pathway(task.obs_dim, batch_norm)
        self.action = _dense_pathway(task.action_dim, batch_norm)
        self.merge = nn.Sequential(nn.Linear(600, 600), nn.ReLU(), nn.Linear(600, 1))

    def forward(self, obs: Mapping[str, torch.Tensor], action: torch.Tensor) -> torch.Tensor:
        h = torch.cat([self.state(self.scaled(obs["state"])), self.action(action)], 1)
        return self.merge(h).squeeze(1)


# ------------------------------------------------------------------------------------------------ noise


class OUNoise:
    """Ornstein-Uhlenbeck noise per car and output: ``x <- x + theta (mu - x) dt + sigma sqrt(dt) N(0, 1)``."""

    def __init__(
        self, n: int, dim: int, theta: float, sigma: float, mu: float = 0.0, dt: float = 1.0, seed: int | None = None
    ) -> None:
        self.theta, self.sigma, self.mu, self.dt = theta, sigma, mu, dt
        self.rng = np.random.default_rng(seed)
        self.x = np.full((n, dim), mu, dtype=np.float64)

    def reset(self, rows: np.ndarray | None = None) -> None:
        """Back to the mean (all rows, or ``rows``: cars starting a new episode)."""
        if rows is None:
            self.x[:] = self.mu
        else:
            self.x[rows] = self.mu

    def __call__(self) -> np.ndarray:
        shock = self.rng.standard_normal(self.x.shape)
        self.x += self.theta * (self.mu - self.x) * self.dt + self.sigma * math.sqrt(self.dt) * shock
        return self.x.copy()


# ------------------------------------------------------------------------------------------------ replay


class FrameReplay:
    """Per-car streams of observation rows; a row with an action is a transition whose next observation is the
    car's following row. ``capacity`` rows in all (``capacity // n_cars`` per car, at least 4). ``state_dims``: the
    observation's vector keys and widths (racing's motion 15 and goal 3 by default; a vector task's state), beside
    the frames of ``image_hw_px``; ``action_dim`` actions per row."""

    #: What a racing row holds, in the order of the files (:attr:`arrays`: this buffer's).
    ARRAYS = ("image", "motion", "goal", "action", "reward", "terminated", "valid")

    def __init__(
        self,
        capacity: int,
        n_cars: int,
        image_hw_px: tuple[int, int] | None,
        state_dims: Mapping[str, int] | None = None,
        action_dim: int = 4,
    ) -> None:
        self.n_cars = int(n_cars)
        self.rows = int(capacity) // self.n_cars
        if self.rows < 4:
            raise DDPGError(
                f"a replay buffer of {capacity} rows leaves {self.rows} per car for {n_cars} cars; "
                "give at least 4 per car"
            )
        self.image_hw_px = None if image_hw_px is None else (int(image_hw_px[0]), int(image_hw_px[1]))
        shape = (self.n_cars, self.rows)
        # np.zeros maps untouched pages lazily: an unfilled 3.2 GB buffer costs only what has been written.
        self.image = None if image_hw_px is None else np.zeros((*shape, *self.image_hw_px, 3), dtype=np.uint8)
        self.state_keys = tuple(state_dims or {"motion": 15, "goal": 3})
        for key, width in (state_dims or {"motion": 15, "goal": 3}).items():
            setattr(self, key, np.zeros((*shape, width), dtype=np.float32))
        self.arrays = ("image", *self.state_keys, "action", "reward", "terminated", "valid")
        """What a row holds, in the order of the files."""
        self.action = np.zeros((*shape, action_dim), dtype=np.float32)
        self.reward = np.zeros(shape, dtype=np.float32)
        self.terminated = np.zeros(shape, dtype=bool)
        self.valid = np.zeros(shape, dtype=bool)
        self.pos = np.zeros(self.n_cars, dtype=np.int64)
        per_chunk = max(1, CHUNK_FRAMES // self.n_cars)
        self.chunk_rows = min(per_chunk, self.rows)
        self.dirty = np.ones(-(-self.rows // self.chunk_rows), dtype=bool)
        self._cars = np.arange(self.n_cars)

    @property
    def size(self) -> int:
        """Transitions that can be sampled."""
        return int(self.valid.sum())

    def _write_obs(self, cars: np.ndarray, rows: np.ndarray, obs: Mapping[str, np.ndarray]) -> None:
        if self.image is not None:
            self.image[cars, rows] = obs["image"]
        for key in self.state_keys:
            getattr(self, key)[cars, rows] = obs[key]
        self.valid[cars, rows] = False
        self.dirty[rows // self.chunk_rows] = True

    def start(self, obs: Mapping[str, np.ndarray], cars: np.ndarray | None = None) -> None:
        """The first observation of every car, or of ``cars`` (after a reset of those cars)."""
        cars = self._cars if cars is None else np.asarray(cars)
        self._write_obs(cars, self.pos[cars], obs)

    def add(
        self,
        action: np.ndarray,
        reward: np.ndarray,
        terminated: np.ndarray,
        next_obs: Mapping[str, np.ndarray],
        done: np.ndarray,
        reset_obs: Mapping[str, np.ndarray] | None = None,
        cars: np.ndarray | None = None,
    ) -> None:
        """One step of every car (or of ``cars``, the columns of one sampler's world, in its order): its action,
        reward and termination on its pending row, then ``next_obs`` (the final observation where ``done``) in the
        next row and, where ``done``, ``reset_obs`` (the new episode's first observation, rows of the done cars in
        order) in the row after."""
        cars = self._cars if cars is None else np.asarray(cars)
        rows = self.pos[cars]
        self.action[cars, rows] = action
        self.reward[cars, rows] = reward
        self.terminated[cars, rows] = terminated
        self.valid[cars, rows] = True
        self.pos[cars] = (rows + 1) % self.rows
        self._write_obs(cars, self.pos[cars], next_obs)
        done_cars = cars[np.flatnonzero(done)]
        if len(done_cars):
            assert reset_obs is not None, "finished cars need their new episode's first observation"
            self.pos[done_cars] = (self.pos[done_cars] + 1) % self.rows
            self._write_obs(done_cars, self.pos[done_cars], reset_obs)

    def sample(self, batch: int, rng: np.random.Generator) -> dict[str, Any]:
        """``batch`` transitions drawn uniformly: {obs, action, reward, terminated, next_obs}."""
        flat = np.flatnonzero(self.valid.reshape(-1))
        if len(flat) == 0:
            raise DDPGError("the replay buffer holds no transition yet")
        pick = flat[rng.integers(0, len(flat), batch)]
        cars, rows = np.divmod(pick, self.rows)
        nxt = (rows + 1) % self.rows

        def obs(r: np.ndarray) -> dict[str, np.ndarray]:
            out = {key: getattr(self, key)[cars, r] for key in self.state_keys}
            if self.image is not None:
                out["image"] = self.image[cars, r]
            return out

        return {
            "obs": obs(rows),
            "action": self.action[cars, rows],
            "reward": self.reward[cars, rows],
            "terminated": self.terminated[cars, rows],
            "next_obs": obs(nxt),
        }


def save_replay(buffer: FrameReplay, folder: str | os.PathLike[str], fingerprint: Mapping[str, Any]) -> int:
    """Write the chunks changed since the last save (new files, named by generation), then the index that lists
    every chunk with its SHA-256, then remove the files it no longer lists. Returns the chunks written."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    index_path = folder / "index.json"
    old = _read_index(index_path) if index_path.is_file() else None
    chunks = dict(old["chunks"]) if old is not None and old.get("fingerprint") == dict(fingerprint) else {}
    generation = int(old["generation"]) + 1 if old is not None else 1
    written = 0
    for j in range(len(buffer.dirty)):
        if not buffer.dirty[j] and str(j) in chunks:
            continue
        a, b = j * buffer.chunk_rows, min((j + 1) * buffer.chunk_rows, buffer.rows)
        arrays = {name: getattr(buffer, name)[:, a:b] for name in buffer.arrays if getattr(buffer, name) is not None}
        name = f"chunk_{j:05d}_g{generation}.npz"

        def write(tmp: Path, arrays=arrays) -> None:
            with open(tmp, "wb") as f:
                np.savez(f, **arrays)

        chunks[str(j)] = {"file": name, "sha256": atomic_write(folder / name, write)}
        written += 1
    index = {
        "format": REPLAY_FORMAT,
        "format_version": SEALED_FORMAT_VERSION,
        "fingerprint": dict(fingerprint),
        "generation": generation,
        "n_cars": buffer.n_cars,
        "rows": buffer.rows,
        "chunk_rows": buffer.chunk_rows,
        "image_hw_px": None if buffer.image_hw_px is None else list(buffer.image_hw_px),
        "pos": buffer.pos.tolist(),
        "chunks": chunks,
    }
    write_json(index_path, sealed_record(index), indent=None)
    buffer.dirty[:] = False
    keep = {c["file"] for c in chunks.values()}
    for stale in folder.glob("chunk_*.npz"):
        if stale.name not in keep:
            stale.unlink(missing_ok=True)
    return written


def _read_index(path: Path) -> dict[str, Any]:
    try:
        index = parse_json(path.read_text())
    except (OSError, ValueError) as exc:
        raise ArtifactError(f"{path}: unreadable replay index: {exc}") from None
    versions = (FORMAT_VERSION, SEALED_FORMAT_VERSION)
    if (
        not isinstance(index, dict)
        or index.get("format") != REPLAY_FORMAT
        or index.get("format_version") not in versions
    ):
        raise ArtifactError(f"{path}: not a DDPG replay index of format {versions}")
    if (damage := seal_damage(index)) is not None:
        raise ArtifactError(f"{path} {damage}; delete {path.parent} to resume without the buffer")
    return index


def seal_damage(data: Mapping[str, Any]) -> str | None:
    """What is wrong with a sealed file's content hash, or None; a file of format 1 (before the hash) that carries
    none passes. A hash present is always checked, so one flipped bit of the version cannot turn the check off."""
    if data.get("format_version") == FORMAT_VERSION and CONTENT_KEY not in data:
        return None
    return content_damage(data)


def read_run_sidecar(path: Path) -> dict[str, Any]:
    """A train-ddpg run's sidecar (``ddpg.json``), its content hash checked (:func:`seal_damage`)."""
    try:
        data = parse_json(path.read_text())
    except (OSError, ValueError) as exc:
        raise DDPGError(f"{path}: cannot read the run's sidecar: {exc}") from None
    if not isinstance(data, dict):
        raise DDPGError(f"{path}: not a train-ddpg sidecar (not a JSON object)")
    if (damage := seal_damage({"format_version": FORMAT_VERSION, **data})) is not None:
        raise DDPGError(f"{path} {damage}")
    return data


def load_replay(buffer: FrameReplay, folder: str | os.PathLike[str], fingerprint: Mapping[str, Any]) -> int:
    """Fill a fresh ``buffer`` from :func:`save_replay`'s folder, checking the fingerprint, the layout and every
    chunk's SHA-256; returns the transitions restored."""
    folder = Path(folder)
    index = _read_index(folder / "index.json")
    check_fingerprint(index["fingerprint"], fingerprint, str(folder / "index.json"))
    layout = (index["n_cars"], index["rows"], index["chunk_rows"])
    if layout != (buffer.n_cars, buffer.rows, buffer.chunk_rows):
        raise ArtifactError(
            f"{folder}: the buffer was saved as {layout[0]} cars x {layout[1]} rows, this one is {buffer.n_cars} x "
            f"{buffer.rows}: resume with the same --cars and --buffer-size"
        )
    for j, entry in index["chunks"].items():
        path = folder / entry["file"]
        if not path.is_file() or file_sha256(path) != entry["sha256"]:
            raise ArtifactError(
                f"{path}: replay chunk missing or changed after it was written (SHA-256); delete "
                f"{folder} to resume without the buffer"
            )
        a = int(j) * buffer.chunk_rows
        try:
            with np.load(path, allow_pickle=False) as data:
                for name in buffer.arrays:
                    target = getattr(buffer, name)
                    if target is not None:
                        target[:, a : a + data[name].shape[1]] = data[name]
        except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
            raise ArtifactError(f"{path}: damaged replay chunk: {exc}") from None
    buffer.pos[:] = np.asarray(index["pos"], dtype=np.int64)
    buffer.dirty[:] = False
    return buffer.size


# ------------------------------------------------------------------------------------------------ the agent


def to_torch(obs: Mapping[str, np.ndarray], device: torch.device) -> dict[str, torch.Tensor]:
    return {k: torch.as_tensor(np.ascontiguousarray(v), device=device) for k, v in obs.items()}


def _batch_arrays(batch: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """A sampled batch flat: ``obs.<key>`` and ``next.<key>`` (frames stay uint8), action, reward and ``alive``
    (1 - terminated) as float32."""
    flat = {f"obs.{k}": v for k, v in batch["obs"].items()} | {f"next.{k}": v for k, v in batch["next_obs"].items()}
    flat |= {"action": batch["action"], "reward": batch["reward"]}
    out = {k: v if k.endswith(".image") else np.asarray(v, dtype=np.float32) for k, v in flat.items()}
    out["alive"] = 1.0 - np.asarray(batch["terminated"], dtype=np.float32)
    return out


def _upload(
    arrays: Mapping[str, np.ndarray], device: torch.device, pack: bool | None = None
) -> dict[str, torch.Tensor]:
    """``arrays`` as tensors on ``device``. On a CPU (``pack`` False) they are views of the arrays; elsewhere the
    arrays of each dtype travel in one buffer (pinned for a GPU) and one asynchronous copy: a batch's nine arrays
    were nine copies, each a launch and a wait for the host (docs/notes/ddpg.md, "the host side of an update")."""
    if not (device.type != "cpu" if pack is None else pack):
        return {k: torch.as_tensor(np.ascontiguousarray(v)) for k, v in arrays.items()}
    out: dict[str, torch.Tensor] = {}
    for dtype in {np.asarray(v).dtype for v in arrays.values()}:
        keys = [k for k, v in arrays.items() if np.asarray(v).dtype == dtype]
        host = torch.from_numpy(np.concatenate([np.asarray(arrays[k]).reshape(-1) for k in keys]))
        sent = (host.pin_memory() if device.type == "cuda" else host).to(device, non_blocking=True)
        start = 0
        for k in keys:
            shape = np.shape(arrays[k])
            out[k] = sent[start : start + math.prod(shape)].view(shape)
            start += math.prod(shape)
    return out


def _networks(hyper: DDPGHyper, env: PixelRacingConfig | VectorTask) -> tuple[nn.Module, nn.Module]:
    """The actor and the critic of ``hyper``'s variant for ``env``, built in this order (torch's seed decides both)."""
    init, pedal, bn = hyper.output_init_scale, hyper.pedal_activation, hyper.batch_norm
    if isinstance(env, VectorTask):
        if hyper.variant != "state-actor":
            raise DDPGError(f"a vector task has no frames: only the state-actor variant learns it, not {hyper.variant}")
        return VectorActor(env, init, bn), VectorCritic(env, bn)
    if (hyper.pixel_actor or hyper.pixel_critic) and not env.frames:
        raise DDPGError(f"the {hyper.variant} agent reads frames: the environment must render them (frames=True)")
    offset, scale = critic_input_scale(load_track(env.track), get_preset(env.car), env.goal_frame)
    hw = env.image_hw_px
    if hyper.pixel_actor:
        actor: nn.Module = PixelActor(hw, init, pedal, bn, hyper.trunk)
    else:
        actor = StateActor(offset, scale, init, pedal, bn)
    critic = PixelCritic(hw, bn, hyper.trunk) if hyper.pixel_critic else Critic(offset, scale, bn)
    return actor, critic


class DDPGAgent:
    """Actor, critic, their targets and optimisers, and the exploration noise, for ``env``'s track, car and frames.

    Args:
        hyper: the hyper-parameters and variant.
        env: the environment the agent acts in (its frame size, goal frame, track and car), or a
            :class:`VectorTask` (the state-actor variant only: its flat state drives actor and critic).
        n_cars: exploration processes (one per car).
        seed: torch's and the noise's seed.
    """

    def __init__(
        self,
        hyper: DDPGHyper,
        env: PixelRacingConfig | VectorTask,
        n_cars: int = 1,
        seed: int = 0,
        device: str = "cpu",
    ) -> None:
        self.hyper, self.env = hyper, env
        self.device = torch.device(device)
        torch.manual_seed(seed)
        self.actor, self.critic = _networks(hyper, env)
        if isinstance(env, VectorTask):
            self.action_low, self.action_high = -np.ones(env.action_dim), np.ones(env.action_dim)
        else:
            self.action_low, self.action_high = action_space().low, action_space().high
        self.actor_target = self._copy(self.actor)
        self.critic_target = self._copy(self.critic)
        for net in (self.actor, self.critic, self.actor_target, self.critic_target):
            net.to(self.device)
            if hyper.channels_last:
                net.to(memory_format=torch.channels_last)
            for trunk in net.modules():
                if isinstance(trunk, ConvTrunk):
                    trunk.channels_last = hyper.channels_last
        self.actor_target.eval()
        self.critic_target.eval()
        # On a GPU the fused Adam steps all of a network's parameters in one kernel (one per tensor otherwise).
        fused = self.device.type == "cuda"
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=hyper.actor_lr, fused=fused)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=hyper.critic_lr, fused=fused)
        self.noise = OUNoise(
            n_cars, len(self.action_low), hyper.ou_theta, hyper.ou_sigma, hyper.ou_mu, hyper.ou_dt, seed=seed
        )
        self.n_updates = 0
        self.last_update: dict[str, torch.Tensor] = {}
        """The latest update's losses and mean target Q (0-d tensors; empty before the first update)."""
        # The targets' tensors and their online twins, floats (lerped) apart from counters (copied), for one
        # foreach call each per update in place of one call per tensor.
        pairs = [
            pair
            for target, online in ((self.actor_target, self.actor), (self.critic_target, self.critic))
            for pair in zip(target.state_dict().values(), online.state_dict().values(), strict=True)
        ]
        self._lerped = ([t for t, _ in pairs if t.is_floating_point()], [o for t, o in pairs if t.is_floating_point()])
        self._copied = (
            [t for t, _ in pairs if not t.is_floating_point()],
            [o for t, o in pairs if not t.is_floating_point()],
        )

    @staticmethod
    def _copy(net: nn.Module) -> nn.Module:
        import copy

        clone = copy.deepcopy(net)
        for p in clone.parameters():
            p.requires_grad_(False)
        return clone

    def actor_inputs(self, obs: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The keys of an observation that the actor reads."""
        if isinstance(self.env, VectorTask):
            return {"state": obs["state"]}
        return {"image": obs["image"]} if self.hyper.pixel_actor else {"motion": obs["motion"], "goal": obs["goal"]}

    @torch.no_grad()
    def act(self, obs: Mapping[str, np.ndarray], explore: bool = False) -> np.ndarray:
        """Keys (n, 4) for observations of n cars (eval-mode batch-norm); ``explore`` adds the OU noise (one
        process per car: n must be the agent's n_cars) and clips to the action space."""
        self.actor.eval()
        keys = self.actor(to_torch(self.actor_inputs(obs), self.device)).cpu().numpy().astype(np.float64)
        if explore:
            keys = keys + self.noise()
        return np.clip(keys, self.action_low, self.action_high)

    def update(self, batch: Mapping[str, Any]) -> dict[str, torch.Tensor]:
        """One critic and one actor step on a sampled batch, then the soft target update. Returns the losses and the
        mean target Q as 0-d tensors on the agent's device: reading them (``float``) waits for the device, so a
        caller that does not log them costs no synchronisation."""
        h = self.hyper
        sent = _upload(_batch_arrays(batch), self.device)
        obs = {k[4:]: v for k, v in sent.items() if k.startswith("obs.")}
        nxt = {k[5:]: v for k, v in sent.items() if k.startswith("next.")}
        action, alive, reward = sent["action"], sent["alive"], sent["reward"] * h.reward_scale
        with torch.no_grad():
            target_q = reward + h.gamma * alive * self.critic_target(nxt, self.actor_target(nxt))
        self.critic.train()
        critic_loss = torch.nn.functional.mse_loss(self.critic(obs, action), target_q)
        self.critic_opt.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic_opt.step()

        self.actor.train()
        # The actor climbs the critic's Q of each state and action (eval-mode batch-norm): in train mode the critic's
        # batch-norm normalised the actor's actions over the batch, so a change common to all of them cancelled and
        # ours-bn never learned Pendulum-v1 (docs/results/ddpg-reference); its running statistics also took in the
        # actor's actions besides the buffer's.
        self.critic.eval()
        for p in self.critic.parameters():
            p.requires_grad_(False)
        try:
            actor_loss = -self.critic(obs, self.actor(obs)).mean()
            self.actor_opt.zero_grad(set_to_none=True)
            actor_loss.backward()
            self.actor_opt.step()
        finally:
            for p in self.critic.parameters():
                p.requires_grad_(True)
        self.soft_update(h.tau)
        self.n_updates += 1
        self.last_update = {
            "critic_loss": critic_loss.detach(),
            "actor_loss": actor_loss.detach(),
            "q_mean": target_q.mean(),
        }
        return self.last_update

    @torch.no_grad()
    def soft_update(self, tau: float) -> None:
        """Targets <- tau online + (1 - tau) targets; batch-norm running statistics too, counters copied."""
        torch._foreach_lerp_(*self._lerped, tau)
        if self._copied[0]:
            torch._foreach_copy_(*self._copied)

    # ------------------------------------------------------------------ state
    def state(self) -> dict[str, Any]:
        """Everything needed to go on: weights, targets, optimisers, noise state, counters (tensors, plain values)."""
        return {
            "networks": {
                name: getattr(self, name).state_dict() for name in ("actor", "critic", "actor_target", "critic_target")
            },
            "optimizers": {"actor": self.actor_opt.state_dict(), "critic": self.critic_opt.state_dict()},
            "noise": torch.as_tensor(self.noise.x),
            "n_updates": int(self.n_updates),
        }

    def load_state(self, state: Mapping[str, Any], source: str = "agent") -> None:
        try:
            for name, weights in state["networks"].items():
                getattr(self, name).load_state_dict(weights)
            self.actor_opt.load_state_dict(state["optimizers"]["actor"])
            self.critic_opt.load_state_dict(state["optimizers"]["critic"])
        except (RuntimeError, KeyError, ValueError, AttributeError) as exc:
            first = first_line(exc)
            raise DDPGError(f"{source}: its weights do not fit this agent's networks: {first}") from None
        noise = np.asarray(state["noise"], dtype=np.float64)
        if noise.shape == self.noise.x.shape:
            self.noise.x[:] = noise
        self.n_updates = int(state["n_updates"])


def ddpg_fingerprint(hyper: DDPGHyper, env: PixelRacingConfig) -> dict[str, Any]:
    """What an agent's weights belong to: checked on every load and resume."""
    return {
        "variant": hyper.variant,
        "track_geometry_hash": load_track(env.track).geometry_hash,
        "car": env.car,
        "image_hw_px": list(env.image_hw_px) if (hyper.pixel_actor or hyper.pixel_critic) else None,
        "mask_rows": env.mask_rows,
        "goal_frame": env.goal_frame,
        "racing_line": env.racing_line,
    }


def save_agent_file(
    agent: DDPGAgent, path: str | os.PathLike[str], fingerprint: Mapping[str, Any], counters: Mapping[str, Any]
) -> str:
    """Write the agent (no pickled objects) with its fingerprint; returns the file's SHA-256."""
    payload = {
        "format": AGENT_FORMAT,
        "format_version": FORMAT_VERSION,
        "fingerprint": dict(fingerprint),
        "hyper": asdict(agent.hyper),
        "env": agent.env.to_dict(),
        "counters": dict(counters),
        **agent.state(),
    }
    payload[STATE_KEY] = state_sha256(payload)
    return atomic_write(path, lambda tmp: torch.save(payload, tmp))


#: The key under which an agent file carries :func:`state_sha256` of the rest of it (files from before it have none).
STATE_KEY = "state_sha256"


def state_sha256(state: Mapping[str, Any]) -> str:
    """SHA-256 of an agent file's content but :data:`STATE_KEY`, each tensor by its dtype, shape and bytes: an agent
    file loaded alone, without the run sidecar that records its file's SHA-256, is still checked."""
    from vision_rl.phase1_repr.checkpoint import tensor_sha256

    def plain(value: Any) -> Any:
        if isinstance(value, torch.Tensor):
            return {"tensor_sha256": tensor_sha256(value)}
        if isinstance(value, Mapping):
            return {str(k): plain(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [plain(v) for v in value]
        return value

    return content_sha256(plain(state), leave_out=(STATE_KEY,))


def read_agent_file(path: str | os.PathLike[str], sha256: str | None = None) -> dict[str, Any]:
    """An agent file's contents, refusing a changed file (``sha256``) or one that is not a DDPG agent file."""
    path = Path(path)
    if sha256 is not None and file_sha256(path) != sha256:
        raise ArtifactError(f"{path}: its SHA-256 is not the recorded one: the file changed after it was written")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except DAMAGED_FILE_ERRORS as exc:  # a flipped bit of the pickled index can fail anywhere in the unpickler
        first = first_line(exc)
        raise ArtifactError(
            f"{path}: not a DDPG agent file (it holds more than tensors and plain values, or is damaged): {first}"
        ) from None
    if not isinstance(state, dict) or state.get("format") != AGENT_FORMAT:
        raise ArtifactError(f"{path}: not a DDPG agent file (no format {AGENT_FORMAT!r})")
    if state.get("format_version") != FORMAT_VERSION:
        version = state.get("format_version")
        raise ArtifactError(f"{path}: DDPG agent format {version!r}, this code reads {FORMAT_VERSION}")
    if STATE_KEY in state and state[STATE_KEY] != state_sha256(state):  # absent in files from before it
        raise ArtifactError(
            f"{path}: its content does not have its recorded {STATE_KEY}: the file changed after it was written"
        )
    return state


def resolve_agent_path(path: str | os.PathLike[str]) -> Path:
    """The agent file of a run folder, or the file itself."""
    path = Path(path)
    candidate = path / AGENT_NAME if path.is_dir() else path
    if not candidate.is_file():
        raise DDPGError(f"{path}: no DDPG agent here (expected a train-ddpg run folder or its {AGENT_NAME})")
    return candidate


def load_agent(path: str | os.PathLike[str], variant: str | None = None, device: str = "cpu") -> DDPGAgent:
    """A saved agent, ready to act. ``variant`` (when given) must be the one it was trained as; its fingerprint
    must match its own environment (the track's geometry now, the frame size); a run folder's sidecar checksum is
    checked when there."""
    path = resolve_agent_path(path)
    sidecar = path.with_name(SIDECAR_NAME)
    sha = None
    if sidecar.is_file() and path.name == AGENT_NAME:
        sha = read_run_sidecar(sidecar).get("weights_sha256")
    state = read_agent_file(path, sha)
    try:
        hyper = DDPGHyper(**state["hyper"])
        env = PixelRacingConfig.from_dict(state["env"])
    except (TypeError, KeyError) as exc:
        raise ArtifactError(f"{path}: bad hyper-parameters or environment in the agent file: {exc}") from None
    if variant is not None and variant != hyper.variant:
        raise DDPGError(
            f"{path} holds an agent of variant {hyper.variant!r}, not {variant!r}: load it as --variant "
            f"{hyper.variant} or train a {variant} one"
        )
    check_fingerprint(state["fingerprint"], ddpg_fingerprint(hyper, env), str(path))
    agent = DDPGAgent(hyper, env, n_cars=1, device=device)
    agent.load_state(state, str(path))
    agent.counters = dict(state.get("counters", {}))
    return agent


# ------------------------------------------------------------------------------------------------ protocol driver


class DDPGDriver:
    """A DDPG actor as a driver of the lap-time protocol: each car observed by a
    :class:`~vision_rl.envs.pixel_racing.PixelObserver` built like its training environment's, deterministic keys
    (no noise) mapped to ``[steer rad, omega]``."""

    def __init__(self, agent: DDPGAgent, identity: dict[str, Any] | None = None) -> None:
        self.agent = agent
        self.control_dt_s = agent.env.control_dt_s
        self.identity = identity or {"driver": "ddpg", "variant": agent.hyper.variant}
        self.observer: PixelObserver | None = None
        self._key: tuple | None = None

    def reset(self, world: World, car_ids: np.ndarray) -> None:
        env = self.agent.env
        # The pixel observer draws only what the actor reads: the state actor needs no renderer.
        config = PixelRacingConfig(
            **{**env.to_dict(), "image_hw_px": env.image_hw_px, "frames": self.agent.hyper.pixel_actor}
        )
        key = (id(world.track), world.car.name, tuple(world.model.groups.tolist()))
        if self.observer is None or key != self._key:
            if self.observer is not None:
                self.observer.close()
            self.observer = PixelObserver(config, world.track, world.car, world.model.groups, DRIVER_BATCH_CARS)
            self._key = key
        self.car_ids = np.asarray(car_ids)

    def act(self, state: WorldState) -> np.ndarray:
        assert self.observer is not None, "reset() first"
        obs = self.observer(state, self.car_ids)

        def act(rows: np.ndarray) -> np.ndarray:
            return self.agent.act({k: v[rows] for k, v in obs.items()}, explore=False)

        return keys_to_action(in_batches_of(DRIVER_BATCH_CARS, act, np.arange(len(self.car_ids))))

    def close(self) -> None:
        if self.observer is not None:
            self.observer.close()
            self.observer = None
