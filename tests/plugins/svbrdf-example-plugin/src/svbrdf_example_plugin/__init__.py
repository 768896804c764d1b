"""An example svbrdf-models plugin: one attention module, one discriminator.

Everything a plugin needs is a config dataclass (fields declared with ``param``), an
``nn.Module`` built from it, and a :class:`svbrdf_models.ModelSpec` named by an entry point
in the plugin's pyproject.toml.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from svbrdf_models import ModelSpec, param


@dataclass(frozen=True)
class SpatialGateConfig:
    bias: float = param(0.0, "initial bias of the gate logits (0 starts every gate at one half)")


class SpatialGate(nn.Module):
    """A per-pixel gate from a 1x1 conv: ``X * sigmoid(w . X + b)``. Keeps the channels."""

    def __init__(self, config: SpatialGateConfig, channels: int):
        super().__init__()
        self.in_channels = self.out_channels = channels
        self.logit = nn.Conv2d(channels, 1, 1)
        nn.init.constant_(self.logit.bias, config.bias)

    def forward(self, x: Tensor) -> Tensor:
        return x * torch.sigmoid(self.logit(x))


@dataclass(frozen=True)
class PixelGANConfig:
    renderings: int = param(9, "renderings per map set, concatenated along channels")
    channels: int = param(32, "hidden channels of the 1x1 convolutions")


class PixelGAN(nn.Module):
    """Isola et al.'s 1x1 PixelGAN on the renderings: one logit per pixel, no spatial context."""

    def __init__(self, config: PixelGANConfig):
        super().__init__()
        self.config = config
        c = config.channels
        self.net = nn.Sequential(
            nn.Conv2d(3 * config.renderings, c, 1),
            nn.LeakyReLU(0.2),
            nn.Conv2d(c, 2 * c, 1),
            nn.LeakyReLU(0.2),
            nn.Conv2d(2 * c, 1, 1),
        )

    def forward(self, maps=None, renderings: Tensor | None = None) -> list[Tensor]:
        return [self.net(renderings.flatten(1, 2))]


SPATIAL_GATE = ModelSpec(
    "attention", SpatialGate, SpatialGateConfig, "per-pixel sigmoid gate from a 1x1 conv"
)
PIXELGAN = ModelSpec(
    "discriminator",
    PixelGAN,
    PixelGANConfig,
    "1x1 PixelGAN on the renderings",
    presets={"tiny": {"channels": 8}},
)
