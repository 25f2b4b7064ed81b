"""ONNX Runtime computes the encoder's phi_rep as torch does, for any batch size and through load_encoder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from tests.helpers.checkpoints import trained_net, write_checkpoint
from vision_rl.phase1_repr import load_encoder
from vision_rl.phase1_repr.onnx_runtime import OnnxEmbedding, onnxruntime_installed, resolve_runtime

needs_onnxruntime = pytest.mark.skipif(not onnxruntime_installed(), reason="the onnx extra is not installed")


@needs_onnxruntime
def test_onnx_embedding_equals_torch_for_any_batch_size() -> None:
    net = trained_net().fuse_for_inference()
    run = OnnxEmbedding(net, threads=1)
    frames = np.random.default_rng(0).integers(0, 256, (3, 32, 48, 3), dtype=np.uint8)
    for batch in (frames[:1], frames[1:], frames):
        expected = net.embed(torch.from_numpy(batch)).detach().numpy()
        np.testing.assert_allclose(run(batch), expected, rtol=1e-4, atol=1e-5)


@needs_onnxruntime
def test_load_encoder_on_onnxruntime_matches_torch(tmp_path: Path) -> None:
    path = tmp_path / "ckpt.pt"
    write_checkpoint(path)
    on_torch = load_encoder(path, runtime="torch")
    on_onnx = load_encoder(path, runtime="onnxruntime")
    assert (on_torch.runtime, on_onnx.runtime, load_encoder(path, runtime="auto").runtime) == (
        "torch",
        "onnxruntime",
        "onnxruntime",
    )
    frames = np.random.default_rng(1).integers(0, 256, (4, 32, 48, 3), dtype=np.uint8)
    rep = on_onnx(frames)
    assert rep.shape == (4, 64) and rep.dtype == torch.float32
    torch.testing.assert_close(rep, on_torch(frames), rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(on_onnx(torch.from_numpy(frames)), rep)
    with pytest.raises(ValueError, match="expected uint8 frames"):
        on_onnx(frames[:, :16])  # the frame check still guards this path


def test_runtime_choice() -> None:
    assert resolve_runtime("torch", "cpu") == "torch"
    assert resolve_runtime("auto", "cuda") == "torch"  # ONNX Runtime runs on the CPU here
    assert resolve_runtime("auto", "cpu") == ("onnxruntime" if onnxruntime_installed() else "torch")
    with pytest.raises(ValueError, match="CPU"):
        resolve_runtime("onnxruntime", "cuda")
    with pytest.raises(ValueError, match="one of"):
        resolve_runtime("tensorrt", "cpu")


@needs_onnxruntime
def test_auto_falls_back_to_torch_when_the_export_fails(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "ckpt.pt"
    write_checkpoint(path)

    def fail(net):
        raise RuntimeError("exporter broke")

    monkeypatch.setattr("vision_rl.phase1_repr.checkpoint.export_embedding", fail)
    with pytest.warns(RuntimeWarning, match="exporter broke"):
        assert load_encoder(path, runtime="auto").runtime == "torch"
    with pytest.raises(RuntimeError, match="exporter broke"):
        load_encoder(path, runtime="onnxruntime")
