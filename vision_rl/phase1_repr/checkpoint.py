"""The encoder checkpoint ``ckpt.pt``, the hand-over from Phase 1 to Phase 2, and :func:`load_encoder`.

``ckpt.pt`` is a plain dict that ``torch.load(path, weights_only=True)`` reads, with checksums of every tensor and
field that :func:`read_checkpoint` verifies; checkpoints without them (format version 1) are refused. The fields
one by one: docs/notes/phase1_repr.md.
"""

from __future__ import annotations

import functools
import hashlib
import io
import json
import os
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from vision_rl.phase1_repr.encoder import EncoderConfig, ReprNet
from vision_rl.phase1_repr.onnx_runtime import OnnxEmbedding, export_embedding, resolve_runtime

CKPT_FORMAT = "vision_rl.encoder"
CKPT_FORMAT_VERSION = 2
_REQUIRED_KEYS = (
    "format",
    "format_version",
    "encoder_config",
    "state_dict",
    "target_names",
    "target_units",
    "target_mean",
    "target_std",
    "dataset",
    "tensor_sha256",
    "field_sha256",
    "content_sha256",
)
#: Entries covered by ``tensor_sha256`` (besides the state dict's tensors) and those that are checksums themselves.
_TENSOR_KEYS = ("target_mean", "target_std")
_CHECKSUM_KEYS = ("tensor_sha256", "field_sha256", "content_sha256")


class EncoderCheckpointError(ValueError):
    """A checkpoint that cannot serve as requested: the message names the file and the problem."""


def tensor_sha256(tensor: torch.Tensor) -> str:
    """Hex SHA-256 of a tensor's dtype, shape and bytes."""
    t = tensor.detach().cpu().contiguous()
    digest = hashlib.sha256(f"{t.dtype}{tuple(t.shape)}".encode())
    digest.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()


def _json_sha256(value: Any) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).hexdigest()


def checkpoint_checksums(payload: Mapping[str, Any]) -> dict[str, Any]:
    """``tensor_sha256``, ``field_sha256`` and ``content_sha256`` of a checkpoint dict (docs/notes/phase1_repr.md)."""
    tensors = {f"state_dict.{k}": tensor_sha256(v) for k, v in payload["state_dict"].items()}
    tensors.update({k: tensor_sha256(payload[k]) for k in _TENSOR_KEYS})
    fields = {k: _json_sha256(v) for k, v in payload.items() if k not in ("state_dict", *_TENSOR_KEYS, *_CHECKSUM_KEYS)}
    return {
        "tensor_sha256": tensors,
        "field_sha256": fields,
        "content_sha256": _json_sha256({"tensors": tensors, "fields": fields}),
    }


def save_checkpoint(
    path: str | os.PathLike[str],
    net: ReprNet,
    *,
    target_names: Sequence[str],
    target_units: Sequence[str],
    target_mean: np.ndarray | torch.Tensor,
    target_std: np.ndarray | torch.Tensor,
    metrics: Mapping[str, Any] | None = None,
    dataset: Mapping[str, Any] | None = None,
) -> Path:
    """Write ``ckpt.pt`` for ``net`` (trained form, not fused) with its checksums; returns the path. ``dataset``
    describes the training data (docs/notes/phase1_repr.md); plain JSON types only. A failed write (a full disk) raises
    an ``OSError`` naming the file and leaves neither a partial checkpoint nor a temporary file."""
    from vision_rl.files import atomic_write, package_version

    if net.fused:
        raise ValueError("save the trained network, not the fused inference copy")
    n = net.config.n_targets
    mean = torch.as_tensor(np.asarray(target_mean, dtype=np.float32)).reshape(-1)
    std = torch.as_tensor(np.asarray(target_std, dtype=np.float32)).reshape(-1)
    if not len(target_names) == len(target_units) == mean.numel() == std.numel() == n:
        raise ValueError(f"the network predicts {n} targets: names, units, mean and std must all have {n}")
    payload = {
        "format": CKPT_FORMAT,
        "format_version": CKPT_FORMAT_VERSION,
        "encoder_config": net.config.to_dict(),
        "state_dict": {k: v.detach().cpu().clone() for k, v in net.state_dict().items()},
        "target_names": list(target_names),
        "target_units": list(target_units),
        "target_mean": mean,
        "target_std": std,
        "package_version": package_version(),
        "metrics": dict(metrics or {}),
        "dataset": json.loads(json.dumps(dict(dataset or {}))),
    }
    payload.update(checkpoint_checksums(payload))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda tmp: torch.save(payload, tmp))  # a kill never leaves half a checkpoint
    return path


def _verifycheckpoint_checksums(path: Path, ckpt: Mapping[str, Any]) -> None:
    """Refuse a checkpoint whose content differs from its recorded checksums, naming the field or tensor."""
    recorded_tensors, recorded_fields = ckpt["tensor_sha256"], ckpt["field_sha256"]
    if not isinstance(recorded_tensors, dict) or not isinstance(recorded_fields, dict):
        raise EncoderCheckpointError(f"{path}: malformed checksums (tensor_sha256 / field_sha256 must be dicts)")
    if _json_sha256({"tensors": recorded_tensors, "fields": recorded_fields}) != ckpt["content_sha256"]:
        raise EncoderCheckpointError(f"{path}: content_sha256 does not match the recorded checksums (edited file)")
    actual = checkpoint_checksums(ckpt)
    for kind, recorded, now in (
        ("tensor", recorded_tensors, actual["tensor_sha256"]),
        ("field", recorded_fields, actual["field_sha256"]),
    ):
        for name in sorted(set(recorded) | set(now)):
            if name not in now:
                raise EncoderCheckpointError(f"{path}: {kind} {name!r} is recorded in the checksums but missing")
            if name not in recorded:
                raise EncoderCheckpointError(f"{path}: {kind} {name!r} is not covered by the recorded checksums")
            if recorded[name] != now[name]:
                raise EncoderCheckpointError(
                    f"{path}: {kind} {name!r} does not match its recorded SHA-256 (damaged or edited checkpoint): "
                    "restore it or train again"
                )


def read_checkpoint(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The checkpoint dict, checked for its keys and internal consistency (tensors on the CPU)."""
    return _read_checked(Path(path))[0]


def _read_checked(path: Path) -> tuple[dict[str, Any], str]:
    """(:func:`read_checkpoint`'s dict, the file's SHA-256), from one read of the file."""
    if not path.is_file():
        raise EncoderCheckpointError(f"{path}: no such checkpoint file")
    try:
        data = path.read_bytes()
        sha256 = hashlib.sha256(data).hexdigest()
        ckpt = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types (RuntimeError, UnpicklingError, EOFError) for a bad file
        raise EncoderCheckpointError(
            f"{path}: not a readable encoder checkpoint (corrupt or truncated?): {exc}"
        ) from exc
    if not isinstance(ckpt, dict) or ckpt.get("format") != CKPT_FORMAT:
        raise EncoderCheckpointError(f"{path}: not a vision_rl encoder checkpoint (no format {CKPT_FORMAT!r})")
    version = int(ckpt.get("format_version", 0))
    if version < CKPT_FORMAT_VERSION and "content_sha256" not in ckpt:
        raise EncoderCheckpointError(
            f"{path}: checkpoint format {version} carries no checksums, so damaged or edited weights would go "
            "unnoticed: train it again with train-repr"
        )
    missing = [k for k in _REQUIRED_KEYS if k not in ckpt]
    if missing:
        raise EncoderCheckpointError(f"{path}: checkpoint lacks {missing}")
    if not isinstance(ckpt["state_dict"], dict) or not all(isinstance(ckpt[k], torch.Tensor) for k in _TENSOR_KEYS):
        raise EncoderCheckpointError(f"{path}: state_dict must be a dict and target_mean/target_std tensors")
    _verifycheckpoint_checksums(path, ckpt)
    if int(ckpt["format_version"]) > CKPT_FORMAT_VERSION:
        raise EncoderCheckpointError(f"{path}: checkpoint format {ckpt['format_version']} is newer than this code's")
    try:
        cfg = EncoderConfig.from_dict(ckpt["encoder_config"])
    except (TypeError, ValueError) as exc:
        raise EncoderCheckpointError(f"{path}: bad encoder_config: {exc}") from exc
    n = cfg.n_targets
    sizes = (
        len(ckpt["target_names"]),
        len(ckpt["target_units"]),
        ckpt["target_mean"].numel(),
        ckpt["target_std"].numel(),
    )
    if set(sizes) != {n}:
        raise EncoderCheckpointError(
            f"{path}: the network predicts {n} targets but names/units/mean/std have {sizes} entries"
        )
    return ckpt, sha256


def build_network(ckpt: Mapping[str, Any], path: str | os.PathLike[str] = "<checkpoint>") -> ReprNet:
    """The trained :class:`ReprNet` of a checkpoint dict (eval mode, unfused)."""
    net = ReprNet(EncoderConfig.from_dict(ckpt["encoder_config"]))
    try:
        net.load_state_dict(ckpt["state_dict"], strict=True)
    except RuntimeError as exc:
        raise EncoderCheckpointError(f"{path}: the weights do not fit the stored architecture: {exc}") from exc
    return net.eval()


class FrozenEncoder(nn.Module):
    """uint8 frames (N, H, W, 3), numpy or torch, on any device -> phi_rep (N, rep_dim) float32, no gradients.

    :meth:`predict_targets` gives phi_reg's 27 targets in physical units (m, rad, 1/m) for diagnostics. With an
    ``onnx`` embedding (CPU only), phi_rep is computed by ONNX Runtime; ``predict_targets`` stays on torch.
    """

    def __init__(
        self, net: ReprNet, ckpt: Mapping[str, Any], path: Path, sha256: str, onnx: OnnxEmbedding | None = None
    ) -> None:
        super().__init__()
        self.net = net
        self.onnx = onnx
        self.path = path
        self.sha256 = sha256
        """SHA-256 of the checkpoint file's bytes, as read once at load: what a policy records and checks."""
        self.config: EncoderConfig = net.config
        self.target_names: list[str] = list(ckpt["target_names"])
        self.target_units: list[str] = list(ckpt["target_units"])
        self.metrics: dict[str, Any] = dict(ckpt.get("metrics", {}))
        self.register_buffer("target_mean", ckpt["target_mean"].float().clone())
        self.register_buffer("target_std", ckpt["target_std"].float().clone())
        self.requires_grad_(False)
        self.eval()

    @property
    def input_hw_px(self) -> tuple[int, int]:
        return self.config.input_height_px, self.config.input_width_px

    @property
    def runtime(self) -> str:
        return "torch" if self.onnx is None else "onnxruntime"

    @property
    def rep_dim(self) -> int:
        return self.config.rep_dim

    @property
    def device(self) -> torch.device:
        return self.target_mean.device

    def train(self, mode: bool = True) -> FrozenEncoder:
        # Frozen: BatchNorm statistics and the fused layers must never switch back to training behaviour.
        return super().train(False)

    def _frames(self, frames: np.ndarray | torch.Tensor) -> torch.Tensor:
        x = torch.from_numpy(np.ascontiguousarray(frames)) if isinstance(frames, np.ndarray) else frames
        self.net.check_frames(x)
        return x.to(self.device, non_blocking=True)

    def forward(self, frames: np.ndarray | torch.Tensor) -> torch.Tensor:
        if self.onnx is not None:
            x = self._frames(frames)
            return torch.from_numpy(self.onnx(x.numpy()))
        with torch.no_grad():
            return self.net.embed(self._frames(frames))

    def predict_targets(self, frames: np.ndarray | torch.Tensor) -> torch.Tensor:
        """phi_reg(phi_rep(frames)) in physical units, (N, n_targets)."""
        with torch.no_grad():
            _, standardised = self.net(self._frames(frames))
            return standardised * self.target_std + self.target_mean


def load_encoder(
    path: str | os.PathLike[str],
    device: str | torch.device = "cpu",
    *,
    expected_input_hw_px: tuple[int, int] | None = None,
    expected_target_names: Sequence[str] | None = None,
    expected_dataset: Mapping[str, Any] | None = None,
    fuse: bool = True,
    runtime: str = "torch",
) -> FrozenEncoder:
    """Load ``ckpt.pt`` as a frozen module from uint8 frames (N, H, W, 3) to (N, 64).

    Args:
        path: the checkpoint.
        device: where the module runs (``"cpu"``, ``"cuda"``...); numpy frames are moved there.
        expected_input_hw_px: refuse a checkpoint built for another frame size (height, width) in pixels.
        expected_target_names: refuse a checkpoint trained on other targets (count or names).
        expected_dataset: refuse a checkpoint trained on other data than this ``dataset`` record (see the module
            doc), naming the first differing field.
        fuse: fold BatchNorm, normalisation and space2depth into the convolutions (same outputs, faster).
        runtime: ``"torch"``, ``"onnxruntime"`` (CPU; phi_rep by ONNX Runtime with torch's current thread count, the
            same outputs to float rounding, 3-6x faster on the project's CPUs) or ``"auto"`` (ONNX Runtime on the CPU
            when installed).
    """
    requested_runtime, runtime = runtime, resolve_runtime(runtime, device)
    path = Path(path)
    ckpt, sha256 = _read_checked(path)
    cfg = EncoderConfig.from_dict(ckpt["encoder_config"])
    if expected_input_hw_px is not None:
        want = (int(expected_input_hw_px[0]), int(expected_input_hw_px[1]))
        have = (cfg.input_height_px, cfg.input_width_px)
        if want != have:
            raise EncoderCheckpointError(
                f"{path}: checkpoint was trained on {have[0]}x{have[1]} (HxW) frames, expected {want[0]}x{want[1]}"
            )
    if expected_target_names is not None:
        want_names, have_names = list(expected_target_names), list(ckpt["target_names"])
        if want_names != have_names:
            if len(want_names) != len(have_names):
                detail = f"{len(have_names)} targets, expected {len(want_names)}"
            else:
                first = next(a for a, b in zip(have_names, want_names, strict=True) if a != b)
                detail = f"other targets than expected (first difference: {first!r})"
            raise EncoderCheckpointError(f"{path}: checkpoint predicts {detail}")
    if expected_dataset is not None:
        from vision_rl.capture.h5format import first_difference

        diff = first_difference(ckpt["dataset"], dict(expected_dataset), "dataset")
        if diff is not None:
            field, have, want = diff
            raise EncoderCheckpointError(
                f"{path}: checkpoint was trained on other data: {field} is {have!r}, expected {want!r}"
            )
    net = build_network(ckpt, path)
    if fuse or runtime == "onnxruntime":
        net.fuse_for_inference()
    onnx = None
    if runtime == "onnxruntime":
        try:
            model = _exported_embedding(str(path.resolve()), sha256)
            onnx = OnnxEmbedding(model, threads=torch.get_num_threads())
        except Exception as exc:  # the exporter's and ONNX Runtime's errors have many types
            if requested_runtime != "auto":
                raise
            warnings.warn(
                f"{path}: ONNX Runtime cannot run this encoder, torch will ({exc})", RuntimeWarning, stacklevel=2
            )
    return FrozenEncoder(net, ckpt, path, sha256, onnx).to(device)


@functools.lru_cache(maxsize=4)
def _exported_embedding(path: str, sha256: str) -> bytes:
    """The ONNX export of a checkpoint's embedding, kept per process and file content: an export takes seconds, and
    the pipeline loads the encoder it has just trained with again to evaluate."""
    return export_embedding(build_network(read_checkpoint(path), path).fuse_for_inference())
