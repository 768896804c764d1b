"""Attention modules a generator can put after each down-block convolution.

Every module takes ``(B, C, H, W)`` and returns ``(B, out_channels, H, W)`` at any H, W >= 1;
``out_channels`` is an attribute because the paper's module doubles the channels (it returns
the input next to its attended copy) while the usual alternatives keep them.

==============  ============================================================  ============
name            what                                                          out_channels
==============  ============================================================  ============
``multiscale``  the paper's eq. 1: pooled at N scales, shared 1x1 conv,       2C
                bilinear up, sum, sigmoid, product; concat(X, X')
``none``        identity (the "w/o attention" ablation)                       C
``se``          squeeze-and-excitation (Hu et al. 2018)                       C
``cbam``        channel then spatial attention (Woo et al. 2018)              C
==============  ============================================================  ============
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .._config import param
from .._registry import ModelSpec

__all__ = [
    "AttentionModule",
    "MultiScaleAttention",
    "MultiScaleConfig",
    "NoAttention",
    "NoAttentionConfig",
    "SqueezeExcitation",
    "SEConfig",
    "CBAMAttention",
    "CBAMConfig",
    "MULTISCALE",
    "NONE",
    "SE",
    "CBAM",
]


class AttentionModule(nn.Module):
    """Base of the built-in attention modules: records ``in_channels`` and ``out_channels``."""

    def __init__(self, channels: int, out_channels: int):
        super().__init__()
        if channels < 1:
            raise ValueError(f"attention needs at least one input channel, got {channels}")
        self.in_channels = channels
        self.out_channels = out_channels


def _hidden_width(channels: int, reduction: int) -> int:
    # A one- or two-unit bottleneck at small widths is often dead after ReLU; keep a few units.
    return max(min(8, channels), channels // reduction)


# -- multiscale (the paper) -------------------------------------------------------------------


@dataclass(frozen=True)
class MultiScaleConfig:
    scales: tuple[int, ...] = param(
        (1, 2, 4, 8),
        "pooling factors s_i: X is average-pooled to (H/s_i, W/s_i), at least 1x1, before the shared conv",
    )

    def __post_init__(self):
        if not self.scales or any(s < 1 for s in self.scales):
            raise ValueError(f"scales must be a non-empty tuple of integers >= 1, got {self.scales}")


class MultiScaleAttention(AttentionModule):
    """Eq. 1: ``X' = sigmoid(sum_i up_i(W_c * avgpool_i(X))) * X``; returns ``concat(X, X')``.

    Shapes: ``(B, C, H, W)`` -> ``(B, 2C, H, W)``. ``W_c`` is one 1x1 convolution shared by all
    scales; ``up_i`` is bilinear upsampling back to ``(H, W)``. Pooling is adaptive, so maps
    whose size the factor does not divide, and maps smaller than the factor, work.
    """

    def __init__(self, config: MultiScaleConfig, channels: int):
        super().__init__(channels, 2 * channels)
        self.scales = tuple(config.scales)
        self.conv = nn.Conv2d(channels, channels, kernel_size=1)  # W_c

    def forward(self, x: Tensor) -> Tensor:
        h, w = x.shape[-2:]
        logits = None
        for s in self.scales:
            size = (max(1, h // s), max(1, w // s))
            pooled = x if size == (h, w) else F.adaptive_avg_pool2d(x, size)
            y = self.conv(pooled)
            # A 1x1 map upsampled bilinearly is a constant: broadcasting it is the same sum, and
            # spares torch.compile's CPU backend a scatter it fails to compile (torch 2.13).
            if y.shape[-2:] != (h, w) and y.shape[-2:] != (1, 1):
                y = F.interpolate(y, size=(h, w), mode="bilinear", align_corners=False)
            logits = y if logits is None else logits + y
        return torch.cat([x, torch.sigmoid(logits) * x], dim=1)


# -- none ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class NoAttentionConfig:
    pass


class NoAttention(AttentionModule):
    """Identity: ``(B, C, H, W)`` -> the same tensor. The "w/o attention" ablation."""

    def __init__(self, config: NoAttentionConfig, channels: int):
        super().__init__(channels, channels)

    def forward(self, x: Tensor) -> Tensor:
        return x


# -- squeeze-and-excitation -----------------------------------------------------------------


@dataclass(frozen=True)
class SEConfig:
    reduction: int = param(
        16, "hidden width of the excitation MLP: C // reduction, at least min(8, C) (as timm)"
    )

    def __post_init__(self):
        if self.reduction < 1:
            raise ValueError(f"reduction must be >= 1, got {self.reduction}")


class SqueezeExcitation(AttentionModule):
    """Hu et al. 2018: per-channel gates from the spatial mean. ``(B, C, H, W)`` -> same shape."""

    def __init__(self, config: SEConfig, channels: int):
        super().__init__(channels, channels)
        hidden = _hidden_width(channels, config.reduction)
        self.fc1 = nn.Conv2d(channels, hidden, 1)
        self.fc2 = nn.Conv2d(hidden, channels, 1)

    def forward(self, x: Tensor) -> Tensor:
        z = x.mean(dim=(2, 3), keepdim=True)
        return x * torch.sigmoid(self.fc2(F.relu(self.fc1(z))))


# -- CBAM ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class CBAMConfig:
    reduction: int = param(
        16, "hidden width of the channel MLP: C // reduction, at least min(8, C) (as timm)"
    )
    kernel_size: int = param(7, "size of the spatial-attention convolution (odd)")

    def __post_init__(self):
        if self.reduction < 1:
            raise ValueError(f"reduction must be >= 1, got {self.reduction}")
        if self.kernel_size < 1 or self.kernel_size % 2 == 0:
            raise ValueError(f"kernel_size must be odd and positive, got {self.kernel_size}")


class CBAMAttention(AttentionModule):
    """Woo et al. 2018: channel gates from mean- and max-pooled features through a shared MLP,
    then a spatial gate from a conv over the channel-wise mean and max. Keeps the shape."""

    def __init__(self, config: CBAMConfig, channels: int):
        super().__init__(channels, channels)
        hidden = _hidden_width(channels, config.reduction)
        self.mlp = nn.Sequential(nn.Conv2d(channels, hidden, 1), nn.ReLU(), nn.Conv2d(hidden, channels, 1))
        self.spatial = nn.Conv2d(2, 1, config.kernel_size, padding=config.kernel_size // 2)

    def forward(self, x: Tensor) -> Tensor:
        avg = x.mean(dim=(2, 3), keepdim=True)
        peak = x.amax(dim=(2, 3), keepdim=True)
        x = x * torch.sigmoid(self.mlp(avg) + self.mlp(peak))
        pooled = torch.cat([x.mean(dim=1, keepdim=True), x.amax(dim=1, keepdim=True)], dim=1)
        return x * torch.sigmoid(self.spatial(pooled))


MULTISCALE = ModelSpec(
    "attention",
    MultiScaleAttention,
    MultiScaleConfig,
    "the paper's multi-scale attention (eq. 1); returns concat(X, X'), doubling the channels",
)
NONE = ModelSpec("attention", NoAttention, NoAttentionConfig, "identity: no attention (the ablation)")
SE = ModelSpec(
    "attention", SqueezeExcitation, SEConfig, "squeeze-and-excitation channel gates (Hu et al. 2018)"
)
CBAM = ModelSpec("attention", CBAMAttention, CBAMConfig, "CBAM: channel then spatial gates (Woo et al. 2018)")
