"""Discriminators: judge a map set as real or fake, patch by patch.

Every discriminator has the same call interface, so the trainer never asks which one it has::

    logits = D(maps=svbrdf, renderings=r)    # r: (B, N, 3, H, W), e.g. render(svbrdf, scene)
    # -> list of logit maps (B, 1, h, w); the GAN loss averages over the list

==============  ===========================================================================
name            what
==============  ===========================================================================
``patchgan``    one 70x70 PatchGAN (Isola et al. 2017) on the N renderings concatenated
                along channels (the paper's unified discriminator; reads ``renderings``)
``multi``       one PatchGAN per map: normal, diffuse, roughness, specular (the paper's
                MultiGAN ablation; reads ``maps``)
==============  ===========================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from torch import Tensor, nn

from svbrdf_render import MAP_NAMES, SVBRDF

from .._config import param
from .._registry import ModelSpec
from .generators import MAX_PARAMETERS, normal_init

__all__ = [
    "PatchGANConfig",
    "PatchGAN",
    "PatchGANDiscriminator",
    "MultiGANConfig",
    "MultiGANDiscriminator",
    "PATCHGAN",
    "MULTI",
    "PRESETS",
]

_MAP_CHANNELS = {"normal": 3, "diffuse": 3, "roughness": 1, "specular": 3}
#: The most strided layers a config may ask for: inputs must be at least ``3 * 2**layers`` px, and
#: 3 * 2**11 = 6144 px is the largest that fits the 8192 px maps the tools make (MAX_DEPTH of the
#: generators), so more layers judge nothing they are given.
MAX_LAYERS = 11


class PatchGAN(nn.Module):
    """Isola et al. 2017 PatchGAN: C64 - C128 - C256 - C512 (stride 1) - 1, 4x4 kernels.

    With ``layers=3`` each output logit sees a 70x70 patch of the input. The first layer has no
    norm; LeakyReLU(0.2) throughout; no sigmoid (the loss takes logits).
    Shapes: ``(B, in_channels, H, W)`` -> ``(B, 1, H/8 - 2, W/8 - 2)`` for ``layers=3``.
    """

    def __init__(self, in_channels: int, base_channels: int = 64, layers: int = 3, norm: str = "instance"):
        super().__init__()
        seq: list[nn.Module] = [
            nn.Conv2d(in_channels, base_channels, 4, stride=2, padding=1),
            nn.LeakyReLU(0.2),
        ]
        ch = base_channels
        for i in range(1, layers + 1):
            out = base_channels * min(2**i, 8)
            stride = 2 if i < layers else 1
            seq += [nn.Conv2d(ch, out, 4, stride=stride, padding=1), _norm(norm, out), nn.LeakyReLU(0.2)]
            ch = out
        seq.append(nn.Conv2d(ch, 1, 4, stride=1, padding=1))
        self.net = nn.Sequential(*seq)

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x)


def _patchgan_parameters(in_channels: int, base: int, layers: int, norm: str) -> int:
    """The parameter count of ``PatchGAN(in_channels, base, layers, norm)``, without building it."""
    total = (in_channels * 16 + 1) * base
    ch = base
    for i in range(1, layers + 1):
        out = base * min(2**i, 8)
        total += (ch * 16 + 1) * out + (2 * out if norm == "batch" else 0)
        ch = out
    return total + ch * 16 + 1


def _norm(kind: str, channels: int) -> nn.Module:
    if kind == "instance":
        return nn.InstanceNorm2d(channels)
    if kind == "batch":
        return nn.BatchNorm2d(channels)
    return nn.Identity()


@dataclass(frozen=True)
class MultiGANConfig:
    """The PatchGAN layout, shared by both discriminators (``multi`` builds one per map)."""

    base_channels: int = param(64, "channels of the first layer (doubled per layer up to 8x)")
    layers: int = param(3, "strided layers after the first; 3 gives the 70x70 receptive field")
    norm: str = param(
        "instance", "normalisation after each inner conv", choices=("instance", "batch", "none")
    )
    init_std: float = param(0.02, "std of the normal init of conv weights (pix2pix); 0 keeps torch's")

    def __post_init__(self):
        if self.base_channels < 1 or self.layers < 1:
            raise ValueError(
                f"base_channels and layers must be positive, got {self.base_channels} and {self.layers}"
            )
        if not 0.0 <= self.init_std < math.inf:
            raise ValueError(f"init_std must be a finite number >= 0 (0: torch's init), got {self.init_std}")
        if self.layers > MAX_LAYERS:
            raise ValueError(
                f"layers must be at most {MAX_LAYERS} (inputs are at least 3 * 2**layers px; "
                f"3 * 2**{MAX_LAYERS} px is the largest the 8192 px maps allow), got {self.layers}"
            )
        params = self.parameter_estimate()
        if params > MAX_PARAMETERS:
            raise ValueError(
                f"base_channels {self.base_channels} and layers {self.layers} make about "
                f"{params / 1e6:,.0f} million parameters, over the {MAX_PARAMETERS / 1e6:,.0f} million a "
                "discriminator may have (the paper's has 3); lower base_channels or layers"
            )

    def in_channels(self) -> tuple[int, ...]:
        """The input channels of each PatchGAN this config builds (one per map for ``multi``)."""
        return tuple(_MAP_CHANNELS.values())

    def parameter_estimate(self) -> int:
        """The weights and biases of the PatchGAN(s) this config builds, counted from the config
        alone (checked before a layer is built; equal to the built network's count)."""
        size = (self.base_channels, self.layers, self.norm)
        return sum(_patchgan_parameters(c, *size) for c in self.in_channels())

    def check_input_size(self, height: int, width: int) -> None:
        """Raise ValueError when ``height x width`` inputs leave no logit: each of the ``layers``
        strided convolutions halves the size and the last two 4x4 convolutions take 2 more."""
        least = 3 * 2**self.layers
        if min(height, width) < least:
            raise ValueError(
                f"H and W must be at least {least} (3 * 2**layers, layers {self.layers}), "
                f"got {height}x{width}"
            )


@dataclass(frozen=True)
class PatchGANConfig(MultiGANConfig):
    renderings: int = param(9, "N: renderings per map set, concatenated along channels (3N input channels)")

    def __post_init__(self):
        super().__post_init__()
        if self.renderings < 1:
            raise ValueError(f"renderings must be positive, got {self.renderings}")

    def in_channels(self) -> tuple[int, ...]:
        return (3 * self.renderings,)


def _check_renderings(renderings: Tensor, n: int) -> None:
    if renderings.dim() != 5 or renderings.shape[1] != n or renderings.shape[2] != 3:
        raise ValueError(
            f"discriminator: expected renderings of shape (B, {n}, 3, H, W), got {tuple(renderings.shape)}"
        )


class PatchGANDiscriminator(nn.Module):
    """The paper's unified discriminator: one PatchGAN on the N renderings of a map set.

    Call: ``D(maps=..., renderings=(B, N, 3, H, W))`` -> ``[logits (B, 1, h, w)]``;
    ``maps`` is accepted for the common interface and not read.
    """

    def __init__(self, config: PatchGANConfig):
        super().__init__()
        self.config = config
        self.net = PatchGAN(3 * config.renderings, config.base_channels, config.layers, config.norm)
        if config.init_std > 0:
            normal_init(self, config.init_std)

    def forward(self, maps: SVBRDF | None = None, renderings: Tensor | None = None) -> list[Tensor]:
        if renderings is None:
            raise ValueError("discriminator 'patchgan' judges renderings: pass renderings=(B, N, 3, H, W)")
        _check_renderings(renderings, self.config.renderings)
        return [self.net(renderings.flatten(1, 2))]


class MultiGANDiscriminator(nn.Module):
    """The MultiGAN ablation: one PatchGAN per map, each on that map alone.

    Call: ``D(maps=SVBRDF, renderings=...)`` -> four logit maps in the order normal, diffuse,
    roughness, specular; ``renderings`` is accepted for the common interface and not read.
    Maps are shifted from [0, 1] to [-1, 1] (normals already are) so all inputs are centred.
    """

    def __init__(self, config: MultiGANConfig):
        super().__init__()
        self.config = config
        self.nets = nn.ModuleDict(
            {
                name: PatchGAN(_MAP_CHANNELS[name], config.base_channels, config.layers, config.norm)
                for name in MAP_NAMES
            }
        )
        if config.init_std > 0:
            normal_init(self, config.init_std)

    def forward(self, maps: SVBRDF | None = None, renderings: Tensor | None = None) -> list[Tensor]:
        if maps is None:
            raise ValueError("discriminator 'multi' judges each map: pass maps=SVBRDF")
        out = []
        for name in MAP_NAMES:
            m = getattr(maps, name)
            out.append(self.nets[name](m if name == "normal" else m * 2.0 - 1.0))
        return out


#: ``tiny`` keeps tests fast; ``paper`` is the default.
PRESETS = {"paper": {}, "small": {"base_channels": 32}, "tiny": {"base_channels": 8, "layers": 2}}

PATCHGAN = ModelSpec(
    "discriminator",
    PatchGANDiscriminator,
    PatchGANConfig,
    "70x70 PatchGAN on N renderings concatenated (the paper's unified discriminator)",
    presets=PRESETS,
)
MULTI = ModelSpec(
    "discriminator",
    MultiGANDiscriminator,
    MultiGANConfig,
    "one PatchGAN per map (the paper's MultiGAN ablation)",
    presets=PRESETS,
)
