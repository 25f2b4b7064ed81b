"""The Phase-1 network: uint8 frames -> 64-D representation phi_rep -> 27 standardised targets (phi_reg).

The vision paper (section 3) keeps a 60 fps budget (8 ms on a GPU) with a space2depth stem, which folds each b x b
pixel block into channels so the convolutions run at 1/b of the resolution without discarding pixels, followed by
depthwise-separable convolutions only. This module builds that family with configurable width and depth, plus a
torchvision MobileNetV3-small backbone for comparison (torchvision is imported only when that option is chosen).

Frames enter as uint8 (N, H, W, 3) RGB, the layout of the capture file and the renderer; the conversion to float,
the pixel normalisation and the crop or pad to a multiple of the space2depth block are part of the module, so the
latency benchmark and Phase 2 pay for them and cannot forget them.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import partial
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval

BACKBONES = ("s2d", "mobilenet_v3_small")


@dataclass(frozen=True)
class EncoderConfig:
    """Architecture of the representation network (stored in ``ckpt.pt``; every field is a plain value)."""

    backbone: str = "s2d"
    """``"s2d"`` (space2depth + depthwise-separable, the paper's design) or ``"mobilenet_v3_small"`` (torchvision)."""
    input_height_px: int = 280
    """Frame height the network is built and trained for (the paper: 470 x 280, section 4)."""
    input_width_px: int = 470
    """Frame width, pixels."""
    space2depth_block: int = 4
    """Side of the pixel block folded into channels; the frame is cropped (or padded) to a multiple of it."""
    fit: str = "crop"
    """How a frame whose size is not a multiple of the block is fitted: ``"crop"`` (centre) or ``"pad"`` (zeros)."""
    stem_channels: int = 32
    """Channels of the 1x1 convolution right after space2depth (it mixes the pixels of each block; a 3x3 one there
    cost 5 ms of the budget on these CPUs for little gain, the depthwise stages see the neighbourhood)."""
    # Defaults chosen by measurement: batch-1 p50 about 5.4 ms on 1 thread, 3.1 ms on 2, of these
    # 2-core CPUs with preprocessing, 242k parameters; 1.5x wider and deeper cost 6.9 ms / 4.4 ms.
    stage_channels: tuple[int, ...] = (64, 128, 160, 256)
    """Output channels of each stage of depthwise-separable blocks."""
    stage_blocks: tuple[int, ...] = (2, 2, 3, 2)
    """Blocks per stage; the first block of a stage has the stride, the others add a residual connection."""
    stage_strides: tuple[int, ...] = (2, 2, 2, 2)
    """Stride of each stage's first block."""
    rep_dim: int = 64
    """Size of phi_rep, the representation Phase 2 consumes (the paper's D_rep = 64, section 4)."""
    n_targets: int = 27
    """Outputs of phi_reg (the paper's D_env = 27)."""
    pixel_mean: tuple[float, float, float] = (0.5, 0.5, 0.5)
    """Per-channel mean subtracted from pixels scaled to [0, 1] (RGB)."""
    pixel_std: tuple[float, float, float] = (0.25, 0.25, 0.25)
    """Per-channel divisor applied after the mean (RGB)."""

    def __post_init__(self) -> None:
        if self.backbone not in BACKBONES:
            raise ValueError(f"backbone must be one of {BACKBONES}, got {self.backbone!r}")
        if self.fit not in ("crop", "pad"):
            raise ValueError(f"fit must be 'crop' or 'pad', got {self.fit!r}")
        if not len(self.stage_channels) == len(self.stage_blocks) == len(self.stage_strides) > 0:
            raise ValueError("stage_channels, stage_blocks and stage_strides need the same, non-zero length")
        if min(self.stage_blocks) < 1 or min(self.stage_channels) < 1 or self.space2depth_block < 1:
            raise ValueError("stage blocks, channels and the space2depth block must be >= 1")
        if min(self.input_height_px, self.input_width_px) < self.space2depth_block:
            raise ValueError("the input is smaller than one space2depth block")

    @property
    def fitted_hw_px(self) -> tuple[int, int]:
        """Frame size after the crop or pad to a multiple of the space2depth block."""
        b = self.space2depth_block if self.backbone == "s2d" else 1
        round_ = math.floor if self.fit == "crop" else math.ceil
        return b * round_(self.input_height_px / b), b * round_(self.input_width_px / b)

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in out.items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EncoderConfig:
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise ValueError(f"unknown encoder config fields {sorted(unknown)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})

    def scaled(self, width_mult: float = 1.0) -> EncoderConfig:
        """The same design with every channel count multiplied by ``width_mult`` (rounded to a multiple of 8)."""

        def r(c: int) -> int:
            return max(8, round(c * width_mult / 8) * 8)

        return dataclasses.replace(
            self, stem_channels=r(self.stem_channels), stage_channels=tuple(r(c) for c in self.stage_channels)
        )


class _ConvBNAct(nn.Sequential):
    def __init__(self, c_in: int, c_out: int, kernel: int, stride: int = 1, groups: int = 1, act: bool = True):
        super().__init__(
            nn.Conv2d(c_in, c_out, kernel, stride, kernel // 2, groups=groups, bias=False),
            nn.BatchNorm2d(c_out),
            nn.ReLU(inplace=True) if act else nn.Identity(),
        )


class DepthwiseSeparable(nn.Module):
    """3x3 depthwise then 1x1 pointwise convolution (MobileNet, Howard et al. 2017), residual when shapes allow."""

    def __init__(self, c_in: int, c_out: int, stride: int) -> None:
        super().__init__()
        self.residual = stride == 1 and c_in == c_out
        self.depthwise = _ConvBNAct(c_in, c_in, 3, stride, groups=c_in)
        # No activation before the sum in a residual block (MobileNetV2's linear bottleneck), so the skip is clean.
        self.pointwise = _ConvBNAct(c_in, c_out, 1, act=not self.residual)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.pointwise(self.depthwise(x))
        return F.relu(x + y) if self.residual else y


class SpaceToDepthBackbone(nn.Module):
    """Stem and depthwise-separable stages over space2depth input (N, 3 b^2, H/b, W/b) -> global average pool."""

    def __init__(self, cfg: EncoderConfig) -> None:
        super().__init__()
        layers: list[nn.Module] = [_ConvBNAct(3 * cfg.space2depth_block**2, cfg.stem_channels, 1)]
        c = cfg.stem_channels
        for c_out, n, stride in zip(cfg.stage_channels, cfg.stage_blocks, cfg.stage_strides, strict=True):
            layers.append(DepthwiseSeparable(c, c_out, stride))
            layers.extend(DepthwiseSeparable(c_out, c_out, 1) for _ in range(n - 1))
            c = c_out
        self.features = nn.Sequential(*layers)
        self.out_channels = c

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.features(x).mean(dim=(2, 3))


class MobileNetV3SmallBackbone(nn.Module):
    """torchvision's MobileNetV3-small feature extractor, randomly initialised (no weights are downloaded)."""

    def __init__(self, cfg: EncoderConfig) -> None:
        super().__init__()
        try:
            from torchvision.models import mobilenet_v3_small
        except ImportError as exc:
            raise ImportError(
                "the mobilenet_v3_small backbone needs torchvision, which is not installed: `pip install torchvision` "
                "(a build matching the installed torch)"
            ) from exc
        # torchvision's BatchNorm momentum, 0.01, suits ImageNet's long schedules; after the few hundred steps of a
        # short run the running statistics still lagged the weights and the eval-mode network predicted nothing
        # (R^2 about 0 after 4 epochs, with a training loss below the s2d encoder's; measured): torch's default 0.1.
        net = mobilenet_v3_small(weights=None, norm_layer=partial(nn.BatchNorm2d, eps=0.001, momentum=0.1))
        self.features = net.features
        self.out_channels = int(net.classifier[0].in_features)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.features(x).mean(dim=(2, 3))


class ReprNet(nn.Module):
    """Backbone -> phi_rep (Linear to ``rep_dim``) -> phi_reg (Linear to ``n_targets``, standardised units).

    ``forward`` takes uint8 frames (N, H, W, 3) and returns ``(rep (N, rep_dim), targets (N, n_targets))``.
    Training code that augments pixels calls :meth:`frames_to_unit` and :meth:`embed_unit`.

    The trained form runs ``F.pixel_unshuffle`` then a 1x1 stem convolution. :meth:`fuse_for_inference` rewrites
    that pair as the one convolution it equals (kernel b, stride b, on the 3 colour channels), folds the pixel
    normalisation and every BatchNorm into the convolutions, and then takes the uint8 frame's float copy as it is
    (NHWC memory is the channels-last layout): on these CPUs the permute of pixel_unshuffle alone took 1.5-2.5 ms.
    """

    def __init__(self, cfg: EncoderConfig) -> None:
        super().__init__()
        self.config = cfg
        self.backbone = SpaceToDepthBackbone(cfg) if cfg.backbone == "s2d" else MobileNetV3SmallBackbone(cfg)
        self.phi_rep = nn.Linear(self.backbone.out_channels, cfg.rep_dim)
        self.phi_reg = nn.Linear(cfg.rep_dim, cfg.n_targets)
        mean = torch.tensor(cfg.pixel_mean, dtype=torch.float32)
        std = torch.tensor(cfg.pixel_std, dtype=torch.float32)
        self.register_buffer("_unit_mean", mean.view(1, 3, 1, 1), persistent=False)
        self.register_buffer("_unit_scale", (1.0 / std).view(1, 3, 1, 1), persistent=False)
        self.fused = False

    def check_frames(self, frames: torch.Tensor) -> None:
        h, w = self.config.input_height_px, self.config.input_width_px
        if frames.ndim != 4 or tuple(frames.shape[1:]) != (h, w, 3):
            raise ValueError(f"expected uint8 frames (N, {h}, {w}, 3), got shape {tuple(frames.shape)}")
        if frames.dtype != torch.uint8:
            raise ValueError(f"expected uint8 frames, got {frames.dtype}")

    def _fit(self, x: torch.Tensor, h_dim: int) -> torch.Tensor:
        """Centre-crop or zero-pad dims ``h_dim`` and ``h_dim + 1`` to the configured fitted size."""
        fh, fw = self.config.fitted_hw_px
        h, w = x.shape[h_dim], x.shape[h_dim + 1]
        if (fh, fw) == (h, w):
            return x
        if fh <= h and fw <= w:
            return x.narrow(h_dim, (h - fh) // 2, fh).narrow(h_dim + 1, (w - fw) // 2, fw)
        ph, pw = fh - h, fw - w
        pad = (pw // 2, pw - pw // 2, ph // 2, ph - ph // 2)
        return F.pad(x, pad if h_dim == 2 else (0, 0, *pad))

    @staticmethod
    def frames_to_unit(frames: torch.Tensor) -> torch.Tensor:
        """uint8 (N, H, W, 3) -> float (N, 3, H, W) in [0, 1], the space the augmentations work in."""
        return frames.permute(0, 3, 1, 2).float().div_(255.0)

    def embed_unit(self, x_unit: torch.Tensor) -> torch.Tensor:
        """Float frames in [0, 1] (N, 3, H, W) -> phi_rep (N, rep_dim): the trained form of the network."""
        if self.fused:
            raise RuntimeError("embed_unit needs the unfused network (fuse_for_inference folded the normalisation)")
        # Fit before normalising so that padding is black in this path and in the fused one alike.
        x = (self._fit(x_unit, 2) - self._unit_mean) * self._unit_scale
        if self.config.backbone == "s2d" and self.config.space2depth_block > 1:
            x = F.pixel_unshuffle(x, self.config.space2depth_block)
        return self.phi_rep(self.backbone(x))

    def embed(self, frames: torch.Tensor) -> torch.Tensor:
        """uint8 frames (N, H, W, 3) -> phi_rep (N, rep_dim)."""
        if not self.fused:
            return self.embed_unit(self.frames_to_unit(frames))
        x = self._fit(frames, 1).float().permute(0, 3, 1, 2)
        if self.config.backbone != "s2d":
            x = (x - 255.0 * self._unit_mean) * (self._unit_scale / 255.0)
        return self.phi_rep(self.backbone(x))

    def forward(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        rep = self.embed(frames)
        return rep, self.phi_reg(rep)

    @torch.no_grad()
    def fuse_for_inference(self) -> ReprNet:
        """Fold every BatchNorm into its convolution and, for the space2depth backbone, pixel_unshuffle, the pixel
        normalisation and the 1x1 stem into one strided convolution (exact: the stem has no padding). In place,
        eval mode only; the result computes the same function (to float rounding) and can no longer be trained."""
        if self.training:
            raise RuntimeError("fuse_for_inference needs eval mode: BatchNorm must use its running statistics")
        if self.fused:
            return self
        for module in self.modules():
            if isinstance(module, _ConvBNAct) and isinstance(module[1], nn.BatchNorm2d):
                module[0] = fuse_conv_bn_eval(module[0], module[1])
                module[1] = nn.Identity()
        if self.config.backbone == "s2d":
            b = self.config.space2depth_block
            stem = self.backbone.features[0][0]
            # Input channel c * b^2 + i * b + j of pixel_unshuffle is pixel (i, j) of colour c in its block.
            scale = (self._unit_scale / 255.0).view(3).repeat_interleave(b * b)
            offset = (-self._unit_mean * self._unit_scale).view(3).repeat_interleave(b * b)
            weight = stem.weight[:, :, 0, 0]
            bias = stem.bias + weight @ offset
            conv = nn.Conv2d(3, stem.out_channels, b, stride=b, bias=True).to(weight.device)
            conv.weight.copy_((weight * scale).view(stem.out_channels, 3, b, b))
            conv.bias.copy_(bias)
            self.backbone.features[0][0] = conv
        self.fused = True
        return self


def count_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())
