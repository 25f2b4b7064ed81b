"""Phase 1: the space2depth + depthwise-separable encoder (phi_rep, 64-D) and its regressor (phi_reg, 27 targets),
its training and latency bench, and :func:`load_encoder` for Phase 2.

Training is :func:`.train.train_repr` (``TrainReprConfig``), the latency bench :func:`.bench.bench_latency`
(``BenchLatencyConfig``); import those modules directly (train pulls in Lightning).
"""

from vision_rl.files import file_sha256
from vision_rl.phase1_repr.checkpoint import (
    EncoderCheckpointError,
    FrozenEncoder,
    load_encoder,
    read_checkpoint,
    save_checkpoint,
)
from vision_rl.phase1_repr.encoder import EncoderConfig, ReprNet

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
