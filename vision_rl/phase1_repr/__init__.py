"""Phase 1: the space2depth + depthwise-separable encoder (phi_rep, 64-D) and its regressor (phi_reg, 27 targets),
its training and latency bench, and :func:`load_encoder` for Phase 2.

Training is :func:`.train.train_repr` (``TrainReprConfig``), the latency bench :func:`.bench.bench_latency`
(``BenchLatencyConfig``, in :mod:`.config`); import those modules directly (train pulls in Lightning). The names
below load their module (and torch) when first used, so that :mod:`.config` imports without torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from vision_rl.files import file_sha256
    from vision_rl.phase1_repr.checkpoint import (
        EncoderCheckpointError,
        FrozenEncoder,
        load_encoder,
        read_checkpoint,
        save_checkpoint,
    )
    from vision_rl.phase1_repr.encoder import EncoderConfig, ReprNet

_HOMES = {
    "EncoderCheckpointError": "vision_rl.phase1_repr.checkpoint",
    "EncoderConfig": "vision_rl.phase1_repr.encoder",
    "FrozenEncoder": "vision_rl.phase1_repr.checkpoint",
    "ReprNet": "vision_rl.phase1_repr.encoder",
    "file_sha256": "vision_rl.files",
    "load_encoder": "vision_rl.phase1_repr.checkpoint",
    "read_checkpoint": "vision_rl.phase1_repr.checkpoint",
    "save_checkpoint": "vision_rl.phase1_repr.checkpoint",
}


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_HOMES[name]), name)


__all__ = [
    "EncoderCheckpointError",
    "EncoderConfig",
    "FrozenEncoder",
    "ReprNet",
    "file_sha256",
    "load_encoder",
    "read_checkpoint",
    "save_checkpoint",
]
