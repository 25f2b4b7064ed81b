"""The encoder's embedding run by ONNX Runtime on the CPU (the ``onnx`` extra).

On the project's 2-core CPUs (measured side by side, one thread), ONNX Runtime computed phi_rep of a 236x140 frame
in 0.18 ms against 0.92 ms for torch eager, and of a batch of 10 in 2.0 ms against 9.7 ms; inside a vision env step
with 10 cars the encoder took 2.4 ms against 5.6 ms and the whole step 12.2 ms against 16.5 ms. Phase 2 embeds every
ego's frame on every control step, so on a CPU it runs the encoder this way when it can.
"""

from __future__ import annotations

import importlib.util
import logging
import warnings

import numpy as np
import torch

from vision_rl.phase1_repr.encoder import ReprNet

RUNTIMES = ("torch", "onnxruntime", "auto")


def onnxruntime_installed() -> bool:
    return importlib.util.find_spec("onnxruntime") is not None and importlib.util.find_spec("onnxscript") is not None


def resolve_runtime(runtime: str, device: str | torch.device) -> str:
    """``"auto"``: ONNX Runtime on the CPU when it is installed, torch otherwise. ONNX Runtime runs on the CPU only."""
    if runtime not in RUNTIMES:
        raise ValueError(f"encoder runtime must be one of {RUNTIMES}, got {runtime!r}")
    on_cpu = torch.device(device).type == "cpu"
    if runtime == "auto":
        return "onnxruntime" if on_cpu and onnxruntime_installed() else "torch"
    if runtime == "onnxruntime":
        if not on_cpu:
            raise ValueError(f"the onnxruntime encoder runtime runs on the CPU, not on {device}")
        if not onnxruntime_installed():
            raise ImportError("the onnxruntime encoder runtime needs `pip install 'vision_rl[onnx]'`")
    return runtime


class _Embed(torch.nn.Module):
    def __init__(self, net: ReprNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        return self.net.embed(frames)


def export_embedding(net: ReprNet) -> bytes:
    """``net.embed`` (uint8 frames (N, H, W, 3) -> phi_rep (N, rep_dim)) as a serialised ONNX model, N free."""
    h, w = net.config.input_height_px, net.config.input_width_px
    example = torch.zeros(2, h, w, 3, dtype=torch.uint8)
    export_logger = logging.getLogger("torch.onnx")
    level = export_logger.level
    export_logger.setLevel(logging.ERROR)  # it warns about torchvision operators it cannot register
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            program = torch.onnx.export(
                _Embed(net).cpu().eval(),
                (example,),
                None,
                input_names=["frames"],
                verbose=False,
                dynamic_shapes=({0: torch.export.Dim("batch", min=1, max=65536)},),
            )
    finally:
        export_logger.setLevel(level)
    return program.model_proto.SerializeToString()


class OnnxEmbedding:
    """phi_rep of uint8 frames (N, H, W, 3) as float32 (N, rep_dim), computed by ONNX Runtime on the CPU with
    ``threads`` intra-op threads (0: its default)."""

    def __init__(self, model: bytes | ReprNet, threads: int = 1) -> None:
        import onnxruntime as ort

        options = ort.SessionOptions()
        if threads > 0:
            options.intra_op_num_threads = threads
            options.inter_op_num_threads = 1
        model_bytes = export_embedding(model) if isinstance(model, ReprNet) else model
        self.session = ort.InferenceSession(model_bytes, options, providers=["CPUExecutionProvider"])

    def __call__(self, frames: np.ndarray) -> np.ndarray:
        return self.session.run(None, {"frames": np.ascontiguousarray(frames)})[0]
