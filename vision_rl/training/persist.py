"""Off-policy agents (Stable-Baselines3 SAC, TD3, DDPG) on disk without pickle.

- An *agent file* (``.pt``) holds the networks, the optimisers, the entropy coefficient and the counters as tensors
  and plain values, written with ``torch.save`` and read with ``torch.load(weights_only=True)``: loading it cannot
  run code. Its ``fingerprint`` (track geometry hash, car, observation, ...) is stored inside, so a sidecar edited
  to claim another track no longer matches the weights.
- A *buffer file* (``.npz``) holds the filled part of a replay buffer (not its preallocated capacity), read with
  ``numpy.load(allow_pickle=False)``; every array is CRC-32-checked by the zip container on read, its ``meta``
  records each array's SHA-256 (dtype, shape and bytes) and the SHA-256 of the meta itself, so a buffer re-saved
  with other rewards is refused; non-finite rewards, actions or observations are refused naming the array.

Writes go to a temporary file in the same folder that is then renamed, so a kill leaves the previous file whole; a
failed write (a full disk) raises :class:`ArtifactWriteError` naming the file and removes the temporary file.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import pickle
import shutil
import struct
import tokenize
import zipfile
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from vision_rl.files import atomic_write, content_damage, file_sha256, first_line, json_text, parse_json, sealed_record

AGENT_FORMAT = "vision_rl.agent"
BUFFER_FORMAT = "vision_rl.replay_buffer"
FORMAT_VERSION = 1
#: 2: the meta records each array's SHA-256 and its own (``content_sha256``). Format 1 is sealed in place by
#: ``vision-rl convert-policy`` (:func:`seal_buffer_file`).
BUFFER_FORMAT_VERSION = 2
#: Arrays of a buffer that must hold finite numbers (``ai_labels`` is NaN where a transition has no label).
FINITE_BUFFER_ARRAYS = ("observations", "next_observations", "actions", "rewards")
#: What a damaged zip container, ``.npy`` header or weights-only pickle raises while numpy or torch reads it.
DAMAGED_FILE_ERRORS = (
    OSError,
    ValueError,
    KeyError,
    IndexError,
    TypeError,
    AttributeError,
    EOFError,
    zipfile.BadZipFile,
    pickle.UnpicklingError,
    NotImplementedError,
    struct.error,
    zlib.error,
    OverflowError,
    MemoryError,
    RuntimeError,
    SyntaxError,  # a .npy header is a Python literal: numpy tokenizes and evaluates it
    tokenize.TokenError,
)
#: The arrays of an SB3 ReplayBuffer that a buffer file keeps, each (capacity, n_envs, ...).
BUFFER_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")
#: Arrays a buffer carries only in some runs: the built-in AI's labels of each transition (``--guide-label-weight``,
#: :func:`vision_rl.phase2_rl.guide.start_labels`). Saved when the buffer has them; a file without them leaves
#: them NaN (no label).
OPTIONAL_BUFFER_ARRAYS = ("ai_labels",)


class ArtifactError(ValueError):
    """A file that is not what it should be (corrupt, foreign, or made for something else); the message says how."""


def check_fingerprint(recorded: Mapping[str, Any], expected: Mapping[str, Any], source: str) -> None:
    """Refuse, naming the first field that differs, a file made for something other than ``expected``."""
    for key, want in expected.items():
        have = recorded.get(key)
        if have != want:
            raise ArtifactError(f"{source} was made for {key} = {have!r}, not {want!r}")


# ------------------------------------------------------------------------------------------------- agents


def agent_state(model: OffPolicyAlgorithm) -> dict[str, Any]:
    """Everything an off-policy learner needs to go on: weights, optimiser states, counters."""
    optimizers = {}
    for name in ("actor", "critic"):
        module = getattr(model, name, None)
        if module is not None and getattr(module, "optimizer", None) is not None:
            optimizers[name] = module.optimizer.state_dict()
    state: dict[str, Any] = {
        "policy": model.policy.state_dict(),
        "optimizers": optimizers,
        "counters": {
            "num_timesteps": int(model.num_timesteps),
            "n_updates": int(getattr(model, "_n_updates", 0)),
            "episode_num": int(model._episode_num),
        },
    }
    if getattr(model, "ent_coef_optimizer", None) is not None:  # SAC with a learned entropy coefficient
        optimizers["ent_coef"] = model.ent_coef_optimizer.state_dict()
        state["log_ent_coef"] = model.log_ent_coef.detach().cpu().clone()
    return state


def save_agent(model: OffPolicyAlgorithm, path: str | os.PathLike[str], fingerprint: Mapping[str, Any]) -> str:
    """Write ``model``'s :func:`agent_state` with ``fingerprint``; returns the file's SHA-256."""
    return write_agent_state(agent_state(model), path, fingerprint)


def previous_weights_path(path: str | os.PathLike[str]) -> Path:
    """Where :func:`write_agent_state` keeps the file it replaces: ``<name>.prev``."""
    path = Path(path)
    return path.with_name(path.name + ".prev")


def write_agent_state(state: Mapping[str, Any], path: str | os.PathLike[str], fingerprint: Mapping[str, Any]) -> str:
    """Write an :func:`agent_state` dict with ``fingerprint``; returns the file's SHA-256. The file it replaces stays
    beside it (:func:`previous_weights_path`, a hard link) until the next write: callers write the sidecar that
    records the new checksum after this, and a kill in between leaves a sidecar that names the previous file, which
    :func:`read_agent` then reads, so that such a kill loses the last interval only."""
    path = Path(path)
    payload = {"format": AGENT_FORMAT, "format_version": FORMAT_VERSION, "fingerprint": dict(fingerprint), **state}
    if path.is_file():
        previous = previous_weights_path(path)
        previous.unlink(missing_ok=True)
        try:
            os.link(path, previous)
        except OSError:  # a filesystem without hard links
            shutil.copyfile(path, previous)
    return atomic_write(path, lambda tmp: torch.save(payload, tmp))


def read_sb3_zip(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The :func:`agent_state` of a Stable-Baselines3 SAC zip, read without unpickling anything: its tensors with
    ``torch.load(weights_only=True)`` and its counters from the plain JSON fields of its ``data`` member (the
    pickled members, such as the spaces and schedules, are never read)."""
    path = Path(path)

    def tensors(archive: zipfile.ZipFile, name: str) -> Any:
        with archive.open(name) as member:
            return torch.load(io.BytesIO(member.read()), map_location="cpu", weights_only=True)

    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
            state: dict[str, Any] = {
                "policy": tensors(archive, "policy.pth"),
                "optimizers": {
                    "actor": tensors(archive, "actor.optimizer.pth"),
                    "critic": tensors(archive, "critic.optimizer.pth"),
                },
            }
            if "ent_coef_optimizer.pth" in names:
                state["optimizers"]["ent_coef"] = tensors(archive, "ent_coef_optimizer.pth")
                state["log_ent_coef"] = tensors(archive, "pytorch_variables.pth")["log_ent_coef"]
            data = json.loads(archive.read("data"))
    except DAMAGED_FILE_ERRORS as exc:
        raise ArtifactError(
            f"{path}: not a Stable-Baselines3 SAC zip whose tensors load safely: {first_line(exc)}"
        ) from None
    state["counters"] = {
        "num_timesteps": int(data.get("num_timesteps", 0)),
        "n_updates": int(data.get("_n_updates", 0)),
        "episode_num": int(data.get("_episode_num", 0)),
    }
    return state


def read_agent(
    path: str | os.PathLike[str], fingerprint: Mapping[str, Any] | None = None, sha256: str | None = None
) -> dict[str, Any]:
    """An agent file's contents, refusing a changed file (``sha256``), a foreign one, or one whose stored
    fingerprint differs from ``fingerprint``."""
    path = Path(path)
    if sha256 is not None:
        actual = file_sha256(path)
        previous = previous_weights_path(path)
        if actual != sha256 and previous.is_file() and file_sha256(previous) == sha256:
            # Killed after the weights were replaced and before their sidecar was: the last complete pair.
            path, actual = previous, sha256
        if actual != sha256:
            raise ArtifactError(
                f"{path}: its SHA-256 is {actual[:12]}..., not the recorded {sha256[:12]}...: the "
                "file changed after it was written"
            )
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except DAMAGED_FILE_ERRORS as exc:
        raise ArtifactError(
            f"{path}: not a vision_rl agent file (it holds more than tensors and plain values, or is damaged): "
            f"{first_line(exc)}"
        ) from None
    if not isinstance(state, dict) or state.get("format") != AGENT_FORMAT:
        raise ArtifactError(f"{path}: not a vision_rl agent file (no format {AGENT_FORMAT!r})")
    if state.get("format_version") != FORMAT_VERSION:
        raise ArtifactError(f"{path}: agent format {state.get('format_version')!r}, this code reads {FORMAT_VERSION}")
    if fingerprint is not None:
        recorded = state.get("fingerprint")
        check_fingerprint(recorded if isinstance(recorded, dict) else {}, fingerprint, str(path))
    return state


def restore_agent(model: OffPolicyAlgorithm, state: Mapping[str, Any], source: str = "agent") -> None:
    """Load :func:`read_agent`'s ``state`` into a freshly built ``model`` of the same architecture."""
    try:
        model.policy.load_state_dict(state["policy"])
        for name, optimizer_state in state["optimizers"].items():
            optimizer = model.ent_coef_optimizer if name == "ent_coef" else getattr(model, name).optimizer
            optimizer.load_state_dict(optimizer_state)
    except (RuntimeError, KeyError, ValueError, AttributeError) as exc:
        first = first_line(exc)
        raise ArtifactError(f"{source}: its weights do not fit this agent's networks: {first}") from None
    if "log_ent_coef" in state:
        with torch.no_grad():
            model.log_ent_coef.copy_(state["log_ent_coef"].to(model.log_ent_coef.device))
    counters = state["counters"]
    model.num_timesteps = int(counters["num_timesteps"])
    model._n_updates = int(counters["n_updates"])
    model._episode_num = int(counters["episode_num"])


# ------------------------------------------------------------------------------------------------- buffers


def save_buffer(buffer: ReplayBuffer, path: str | os.PathLike[str], fingerprint: Mapping[str, Any]) -> str:
    """Write the filled part of ``buffer`` (all of it once it wrapped round) with ``fingerprint``; returns the
    file's SHA-256."""
    n = buffer.buffer_size if buffer.full else buffer.pos
    meta = {
        "format": BUFFER_FORMAT,
        "format_version": BUFFER_FORMAT_VERSION,
        "fingerprint": dict(fingerprint),
        "pos": int(buffer.pos),
        "full": bool(buffer.full),
        "capacity": int(buffer.buffer_size),
        "n_envs": int(buffer.n_envs),
    }
    return write_sealed_arrays(path, meta, {name: getattr(buffer, name)[:n] for name in _buffer_arrays(buffer)})


def write_sealed_arrays(path: str | os.PathLike[str], meta: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> str:
    """``arrays`` and ``meta`` sealed with the arrays' and the meta's SHA-256 as ``.npz`` (no pickle), written
    atomically; returns the file's SHA-256. :func:`check_sealed_arrays` checks them when read."""
    meta = sealed_record({**meta, "arrays_sha256": {k: array_sha256(v) for k, v in arrays.items()}})

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            np.savez(f, meta=np.array(json_text(meta)), **arrays)

    return atomic_write(path, write)


def array_sha256(values: np.ndarray) -> str:
    """SHA-256 of an array's dtype, shape and bytes (C order)."""
    digest = hashlib.sha256(f"{values.dtype.str}{values.shape}".encode())
    digest.update(np.ascontiguousarray(values).view(np.uint8).reshape(-1).data)
    return digest.hexdigest()


def _buffer_arrays(buffer: ReplayBuffer) -> tuple[str, ...]:
    return BUFFER_ARRAYS + tuple(name for name in OPTIONAL_BUFFER_ARRAYS if getattr(buffer, name, None) is not None)


def read_buffer_file(path: str | os.PathLike[str]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """(meta, arrays) of a buffer file of format 2, refused in one line naming the file unless its meta and each
    array carry the SHA-256 they were written with and the arrays that must be finite are."""
    path = Path(path)
    meta, arrays = _read_npz(path)
    if meta.get("format_version") == FORMAT_VERSION:
        raise ArtifactError(
            f"{path}: replay-buffer format 1 has no content hash, so a re-saved buffer would go unseen; seal it "
            f"with `vision-rl convert-policy --run {path.parent}`"
        )
    if meta.get("format_version") != BUFFER_FORMAT_VERSION:
        raise ArtifactError(f"{path}: replay-buffer format {meta.get('format_version')!r}, this code reads 2")
    check_sealed_arrays(path, meta, arrays)
    for name, values in arrays.items():
        if name in FINITE_BUFFER_ARRAYS and values.dtype.kind == "f" and not np.isfinite(values).all():
            raise ArtifactError(f"{path}: the array {name} holds non-finite numbers (NaN or infinity)")
    return meta, arrays


def check_sealed_arrays(path: Path, meta: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> None:
    """Refuse, naming ``path``, arrays or a meta that are not what :func:`write_sealed_arrays` wrote."""
    damage = content_damage(meta)
    if damage is not None:
        raise ArtifactError(f"{path}: the replay buffer's meta {damage}")
    recorded = meta.get("arrays_sha256")
    if not isinstance(recorded, dict) or set(recorded) != set(arrays):
        raise ArtifactError(f"{path}: holds the arrays {sorted(arrays)}, its meta lists {sorted(recorded or {})}")
    for name, values in arrays.items():
        if array_sha256(values) != recorded[name]:
            raise ArtifactError(f"{path}: the array {name} is not the one written (its SHA-256 differs)")


def _read_npz(path: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The meta and arrays of a buffer file, without checks beyond its being one; one-line ArtifactError."""
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = parse_json(str(data["meta"]))
            if not isinstance(meta, dict) or meta.get("format") != BUFFER_FORMAT:
                raise ArtifactError(f"{path}: not a vision_rl replay-buffer file (no format {BUFFER_FORMAT!r})")
            arrays = {name: data[name] for name in data.files if name != "meta"}
    except ArtifactError:
        raise
    except DAMAGED_FILE_ERRORS as exc:
        raise ArtifactError(f"{path}: damaged replay-buffer file: {first_line(exc)}") from None
    return meta, arrays


def seal_buffer_file(path: str | os.PathLike[str]) -> bool:
    """Seal a buffer file of format 1 in place as format 2 (its arrays as they are); False when it is sealed
    already. Its content cannot be checked: format 1 recorded no hash beyond the zip's CRC-32, which is read."""
    path = Path(path)
    meta, arrays = _read_npz(path)
    if meta.get("format_version") == BUFFER_FORMAT_VERSION:
        read_buffer_file(path)
        return False
    if meta.get("format_version") != FORMAT_VERSION:
        raise ArtifactError(f"{path}: replay-buffer format {meta.get('format_version')!r}, not 1 or 2")
    write_sealed_arrays(path, {**meta, "format_version": BUFFER_FORMAT_VERSION}, arrays)
    return True


def load_buffer(buffer: ReplayBuffer, path: str | os.PathLike[str], fingerprint: Mapping[str, Any]) -> int:
    """Fill a fresh ``buffer`` from a buffer file; returns the transitions (per env) restored. Refuses a damaged
    or changed file (:func:`read_buffer_file`), another fingerprint, or arrays that do not fit ``buffer``."""
    path = Path(path)
    meta, stored = read_buffer_file(path)
    check_fingerprint(meta.get("fingerprint") or {}, fingerprint, str(path))
    missing = [name for name in BUFFER_ARRAYS if name not in stored]
    if missing:
        raise ArtifactError(f"{path}: a replay buffer without the arrays {missing}")
    arrays = {name: stored[name] for name in _buffer_arrays(buffer) if name in stored}
    n = len(arrays["observations"])
    if n > buffer.buffer_size:
        raise ArtifactError(
            f"{path} holds {n} transitions per env, more than this buffer's capacity {buffer.buffer_size}"
        )
    for name, values in arrays.items():
        target = getattr(buffer, name)
        if values.shape[1:] != target.shape[1:] or len(values) != n:
            raise ArtifactError(
                f"{path}: {name} has shape {values.shape[1:]} per transition, this buffer {target.shape[1:]}"
            )
        target[:n] = values
    if n == buffer.buffer_size:  # the writing position of a wrapped buffer is kept: the oldest goes first
        buffer.full, buffer.pos = True, int(meta["pos"]) % n
    else:
        buffer.full, buffer.pos = False, n
    return n
