"""The encoder: fitting to the space2depth block, fused == trained form, shapes, bad input, MobileNet option."""

from __future__ import annotations

import dataclasses
import importlib.util

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from vision_rl.phase1_repr.encoder import EncoderConfig, ReprNet

TINY = EncoderConfig(
    input_height_px=30,
    input_width_px=46,
    stem_channels=8,
    stage_channels=(16, 24),
    stage_blocks=(1, 2),
    stage_strides=(2, 2),
    n_targets=5,
)


def frames(n: int, cfg: EncoderConfig, seed: int = 0) -> torch.Tensor:
    shape = (n, cfg.input_height_px, cfg.input_width_px, 3)
    return torch.from_numpy(np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8))


def with_batchnorm_statistics(net: ReprNet, x: torch.Tensor) -> ReprNet:
    """Run a few training-mode passes so BatchNorm's running statistics are not the identity."""
    net.train()
    with torch.no_grad():
        for _ in range(3):
            net(x)
    return net.eval()


def test_fitted_size_for_the_papers_frame() -> None:
    assert EncoderConfig().fitted_hw_px == (280, 468)  # 470 = 2 x 235: crop 1 px each side for block 4
    assert EncoderConfig(fit="pad").fitted_hw_px == (280, 472)
    assert EncoderConfig(space2depth_block=2).fitted_hw_px == (280, 470)
    assert EncoderConfig(backbone="s2d", space2depth_block=1).fitted_hw_px == (280, 470)


@pytest.mark.parametrize(
    "change",
    [{}, {"fit": "pad"}, {"space2depth_block": 2}, {"space2depth_block": 1}, {"space2depth_block": 3}],
)
def test_fused_network_computes_the_trained_function(change: dict) -> None:
    torch.manual_seed(0)
    cfg = dataclasses.replace(TINY, **change)
    x = frames(4, cfg)
    net = with_batchnorm_statistics(ReprNet(cfg), x)
    with torch.no_grad():
        rep, pred = net(x)
        fused = ReprNet(cfg).eval()
        fused.load_state_dict(net.state_dict())
        fused.fuse_for_inference()
        rep_f, pred_f = fused(x)
    assert rep.shape == (4, 64) and pred.shape == (4, 5)
    torch.testing.assert_close(rep_f, rep, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(pred_f, pred, rtol=1e-4, atol=1e-5)
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in fused.modules())


def test_trained_form_is_pixel_unshuffle_of_the_normalised_crop() -> None:
    # The stem sees pixel_unshuffle(block 4) of the centre crop 28x44 of a 30x46 frame, normalised per channel.
    torch.manual_seed(1)
    net = ReprNet(TINY).eval()
    x = frames(2, TINY)
    unit = x.permute(0, 3, 1, 2).float() / 255.0
    crop = unit[:, :, 1:29, 1:45]
    norm = (crop - torch.tensor(TINY.pixel_mean).view(1, 3, 1, 1)) / torch.tensor(TINY.pixel_std).view(1, 3, 1, 1)
    with torch.no_grad():
        expected = net.phi_rep(net.backbone(F.pixel_unshuffle(norm, 4)))
        torch.testing.assert_close(net.embed(x), expected)


def test_fusing_needs_eval_mode_and_bad_frames_are_named() -> None:
    net = ReprNet(TINY)
    with pytest.raises(RuntimeError, match="eval"):
        net.fuse_for_inference()
    with pytest.raises(ValueError, match=r"\(N, 30, 46, 3\)"):
        net.check_frames(torch.zeros(1, 46, 30, 3, dtype=torch.uint8))
    with pytest.raises(ValueError, match="uint8"):
        net.check_frames(torch.zeros(1, 30, 46, 3))


def test_config_round_trip_and_validation() -> None:
    cfg = EncoderConfig().scaled(1.5)
    assert cfg.stage_channels == (96, 192, 240, 384) and cfg.stem_channels == 48
    assert EncoderConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ValueError):
        EncoderConfig(stage_channels=(8, 16), stage_blocks=(1,), stage_strides=(2, 2))
    with pytest.raises(ValueError):
        EncoderConfig(backbone="resnet")
    with pytest.raises(ValueError, match="unknown"):
        EncoderConfig.from_dict({**cfg.to_dict(), "colour": "red"})


def test_default_encoder_size() -> None:
    net = ReprNet(EncoderConfig())
    n_params = sum(p.numel() for p in net.parameters())
    assert 150_000 < n_params < 400_000  # the measured default (see the config's comment), not a toy
    assert net.embed(frames(1, EncoderConfig())).shape == (1, 64)


@pytest.mark.skipif(importlib.util.find_spec("torchvision") is not None, reason="torchvision is installed")
def test_mobilenet_without_torchvision_says_how_to_install() -> None:
    with pytest.raises(ImportError, match="pip install torchvision"):
        ReprNet(EncoderConfig(backbone="mobilenet_v3_small"))


@pytest.mark.skipif(importlib.util.find_spec("torchvision") is None, reason="torchvision is not installed")
def test_mobilenet_backbone_outputs_64() -> None:  # pragma: no cover - only where torchvision exists
    cfg = dataclasses.replace(TINY, backbone="mobilenet_v3_small", input_height_px=64, input_width_px=96)
    net = ReprNet(cfg).eval()
    x = frames(2, cfg)
    with torch.no_grad():
        rep = net.embed(x)
        net.fuse_for_inference()
        torch.testing.assert_close(net.embed(x), rep, rtol=1e-4, atol=1e-4)
    assert rep.shape == (2, 64)
    norms = [m for m in net.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert norms and all(m.momentum == 0.1 for m in norms)  # torchvision's 0.01 left short runs unusable in eval
