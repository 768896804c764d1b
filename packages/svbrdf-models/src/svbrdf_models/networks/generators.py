"""Generators: a flash photo ``(B, 3, H, W)`` in, the four maps as an SVBRDF out.

One network class, :class:`UNetGenerator`, serves every built-in name through its config:

==========  =================================================================
name        what
==========  =================================================================
``ours``    the paper: U-Net + global track, multi-scale attention per level
``unet``    the same without the global track
``no-attn`` ``ours`` with the ``none`` attention module ("w/o attention");
            this is Deschaintre et al. 2018's network
==========  =================================================================

Down block (level l): conv 4x4/2 -> attention -> InstanceNorm -> (+ FC output of the global
track at level l) -> LeakyReLU(0.2). The FC of level l takes [FC output of level l-1,
spatial mean of level l's attention output] and passes through SELU (as in Deschaintre 2018).
Up block: deconv 4x4/2 -> InstanceNorm -> LeakyReLU(0.2) -> dropout, fed with the previous
up block and the skip of equal size. With ``upsample: resize`` each deconv becomes a nearest
x2 resize then a 3x3 conv (Odena et al. 2016, "Deconvolution and Checkerboard Artifacts"):
a stride-2 transposed convolution gives the two pixel phases of each axis different weights,
so its maps carry a 2-pixel pattern; a resize followed by one convolution treats every
output pixel alike.

Input: the photo is log-encoded (:func:`encode_photo`). With ``input_norm: median`` it is
first scaled so that its median is :data:`NORM_LEVEL` (a Des18 photo's typical median), which
makes the maps independent of exposure; ``input_level`` gives the network the log2 of that
scale back, through the global track only, so it may learn how much the absolute level says. The last up block produces 9 channels through tanh:
normal x, y (z = 1 before normalising, so z > 0), diffuse 3, roughness 1, specular 3, the
albedos and roughness mapped from [-1, 1] to [0, 1].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from svbrdf_render import SVBRDF

from .._config import param
from .._registry import ModelSpec, create_attention

__all__ = [
    "GeneratorConfig",
    "UNetGenerator",
    "encode_photo",
    "normal_init",
    "normalise_exposure",
    "OURS",
    "UNET",
    "NO_ATTN",
    "PRESETS",
]

#: Output channels of the last up block: normal xy, diffuse, roughness, specular.
OUTPUT_CHANNELS = 9
#: Offset of the log encoding of input photos (Deschaintre 2018 uses the same).
LOG_EPS = 0.01
#: The median a photo is scaled to with ``input_norm: median`` (des18-dev's median photo
#: value is 0.088; the simulated phone photos' 0.088 too).
NORM_LEVEL = 0.1
#: The input normalisations and the upsampling layers a generator may use.
INPUT_NORMS = ("none", "median")
UPSAMPLES = ("transpose", "resize")
#: The deepest U-Net a config may ask for: its inputs are multiples of ``2**depth`` pixels, and
#: 2**13 = 8192 px is the largest side the tools make maps at (``svbrdf-models predict
#: --map-size``), so a deeper network takes no input they give it.
MAX_DEPTH = 13
#: The most parameters a generator config may ask for (:meth:`GeneratorConfig.parameter_estimate`):
#: 500 million, 2 GB in float32 (8 GB with Adam's moments and the gradients), about five times
#: the paper's generator (105 million). A config over it is refused before a layer is built,
#: rather than left to exhaust the memory while building.
MAX_PARAMETERS = 500_000_000


def normal_init(module: nn.Module, std: float) -> None:
    """pix2pix's init for every conv, deconv and linear layer inside ``module``: weights
    ~ N(0, std), biases 0. Other layers (norms, attention plugins' own) are left alone. The
    built-in networks' one init: the discriminators use it too."""

    def visit(m: nn.Module) -> None:
        if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d, nn.Linear)):
            nn.init.normal_(m.weight, 0.0, std)
            if m.bias is not None:
                nn.init.zeros_(m.bias)

    module.apply(visit)


@dataclass(frozen=True)
class GeneratorConfig:
    depth: int = param(8, "U-Net levels; each halves the size, so H and W must be multiples of 2**depth")
    base_channels: int = param(64, "channels of the first down convolution; doubled per level")
    max_channels: int = param(512, "cap on the channels of any down convolution")
    attention: str | tuple[str, ...] = param(
        "multiscale", "registered attention module after each down conv: one name, or one name per level"
    )
    attention_config: dict = param({}, "config dict passed to the attention module(s)")
    global_track: bool = param(True, "Deschaintre's fully connected global track beside the encoder")
    dropout: float = param(0.5, "dropout probability of the up blocks that use it")
    dropout_levels: int = param(3, "how many of the innermost up blocks apply dropout (pix2pix: 3)")
    upsample: str = param(
        "transpose",
        "how up blocks double the size: transpose (4x4/2 transposed conv, the paper's) or resize "
        "(nearest x2 then 3x3 conv: no 2-pixel checkerboard)",
        choices=UPSAMPLES,
    )
    input_norm: str = param(
        "none",
        "none (the photo as given, the paper's) or median (scaled so its median is 0.1 first: "
        "the maps no longer depend on exposure)",
        choices=INPUT_NORMS,
    )
    input_level: bool = param(
        False,
        "with input_norm median and the global track, feed log2 of the scale the photo was "
        "normalised by to the global track, so the network may learn to use the exposure",
    )
    normal_scale: float = param(
        1.0,
        "factor of the predicted relief: the normal's x and y are scaled before normalising, so "
        "below 1 flattens the normals toward +z (set after training from held-out materials, "
        "benchmarks/normal_scale.py); 1: the network's own",
    )
    init_std: float = param(
        0.02,
        "std of the normal init of the U-Net's conv and FC weights (pix2pix); attention modules keep "
        "their own init; 0 keeps torch's",
    )

    def __post_init__(self):
        if not 2 <= self.depth <= MAX_DEPTH:
            raise ValueError(
                f"depth must be from 2 to {MAX_DEPTH} (inputs are multiples of 2**depth px; "
                f"2**{MAX_DEPTH} = {2**MAX_DEPTH} px is the largest map size), got {self.depth}"
            )
        if self.base_channels < 1 or self.max_channels < self.base_channels:
            raise ValueError(
                f"need 1 <= base_channels <= max_channels, got {self.base_channels} and {self.max_channels}"
            )
        params = self.parameter_estimate()
        if params > MAX_PARAMETERS:
            raise ValueError(
                f"depth {self.depth}, base_channels {self.base_channels} and max_channels "
                f"{self.max_channels} make about {_millions(params)} parameters, over the "
                f"{MAX_PARAMETERS / 1e6:,.0f} million a generator may have (the paper's has 105); "
                "lower max_channels, base_channels or depth"
            )
        if not isinstance(self.attention, str) and len(self.attention) != self.depth:
            raise ValueError(
                f"attention lists {len(self.attention)} names for {self.depth} levels; give one name "
                "or exactly one per level"
            )
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")
        if not 0 <= self.dropout_levels <= self.depth:
            raise ValueError(f"dropout_levels must be in [0, depth], got {self.dropout_levels}")
        if self.upsample not in UPSAMPLES:
            raise ValueError(f"upsample must be one of {', '.join(UPSAMPLES)}, got {self.upsample!r}")
        if self.input_norm not in INPUT_NORMS:
            raise ValueError(f"input_norm must be one of {', '.join(INPUT_NORMS)}, got {self.input_norm!r}")
        if self.input_level and (self.input_norm == "none" or not self.global_track):
            raise ValueError(
                "input_level feeds the normalisation's scale to the global track: it needs "
                "input_norm: median and global_track: true"
            )
        if not 0.0 <= self.normal_scale <= 1.0:
            raise ValueError(f"normal_scale must be in [0, 1] (0: flat normals), got {self.normal_scale}")
        if not 0.0 <= self.init_std < math.inf:
            raise ValueError(f"init_std must be a finite number >= 0 (0: torch's init), got {self.init_std}")

    def parameter_estimate(self) -> int:
        """Parameters of the U-Net this config builds, counted from the config alone (nothing
        is built). Attention modules are counted as the paper's (output 2C, one C x C conv), the
        largest built-in; a plugin's own weights are not known here. The up blocks are counted
        with 4x4 kernels (``upsample: resize`` uses 3x3, fewer)."""
        conv = [min(self.base_channels * 2**i, self.max_channels) for i in range(self.depth)]
        total, in_ch, g_ch = 0, 3, 0
        for level, c in enumerate(conv):
            total += in_ch * c * 16 + c + c * c + c  # down conv, attention's 1x1 conv
            if self.global_track:
                extra = 1 if self.input_level and level == 0 else 0
                total += (g_ch + extra + 2 * c) * 2 * c + 2 * c
            in_ch = g_ch = 2 * c
        for k, c in enumerate(conv):
            up_in = 2 * c if k == self.depth - 1 else 3 * c
            up_out = OUTPUT_CHANNELS if k == 0 else conv[k - 1]
            total += up_in * up_out * 16 + up_out
        return total

    def sub_networks(self) -> tuple[tuple[str, str, str, str, dict], ...]:
        """``(name field, config field, kind, name, config)`` of each registered module this
        generator creates: the attention module of every level, so a config naming an unknown
        one, or an attention_config it does not take, is refused before any layer is built
        (see :meth:`svbrdf_models.Registry.resolve_config`)."""
        names = dict.fromkeys(self.level_attention())  # each name once, in level order
        return tuple(("attention", "attention_config", "attention", n, self.attention_config) for n in names)

    @property
    def input_multiple(self) -> int:
        """H and W of a photo must be multiples of this: ``2**depth``."""
        return 2**self.depth

    def check_input_size(self, height: int, width: int) -> None:
        """Raise ValueError when a ``height x width`` photo cannot go through this U-Net."""
        m = self.input_multiple
        if height % m or width % m or min(height, width) < m:
            lo = max(m, min(height, width) // m * m)
            raise ValueError(
                f"H and W must be multiples of {m} (2**depth, depth {self.depth}), got {height}x{width}; "
                f"the nearest sizes are {lo} and {lo + m}"
            )

    def level_attention(self) -> tuple[str, ...]:
        """The attention module name of each level, outermost first."""
        if isinstance(self.attention, str):
            return (self.attention,) * self.depth
        return tuple(self.attention)


def _millions(count: int) -> str:
    return f"{count / 1e6:,.0f} million" if count < 10**15 else f"{float(count):.1e}"


#: Named partial configs. ``paper`` is the default (8 levels x 64 channels at 256x256);
#: ``small`` trains on a CPU in minutes at 128-256 px; ``tiny`` is for tests (32-64 px).
PRESETS = {
    "paper": {},
    "small": {"depth": 6, "base_channels": 16, "max_channels": 128},
    "tiny": {"depth": 4, "base_channels": 8, "max_channels": 32},
}


def normalise_exposure(photo: Tensor) -> tuple[Tensor, Tensor]:
    """Scale each photo of ``(B, 3, H, W)`` so that its median (over pixels and channels) is
    :data:`NORM_LEVEL`; returns the scaled photos and ``log2`` of each scale ``(B, 1)``.

    A black photo (median 0) is scaled by at most ``2**16``, never by infinity. Clipping is
    not undone: a photo with a saturated highlight keeps it at ``scale`` after scaling, which
    is what the same scene exposed differently would show only below the clip.
    """
    flat = photo.clamp_min(0.0).flatten(1)
    median = flat.median(dim=1).values.clamp_min(NORM_LEVEL * 2.0**-16)
    scale = NORM_LEVEL / median
    return photo * scale[:, None, None, None], torch.log2(scale)[:, None]


def encode_photo(photo: Tensor) -> Tensor:
    """Linear radiance ``(B, 3, H, W)``, nominally in [0, 1] -> log-encoded, [0, 1] -> [-1, 1].

    Flash photos span orders of magnitude between the highlight and the corners; the log
    keeps both in range. Negative values (noise) are clamped before the log.
    """
    lo, hi = math.log(LOG_EPS), math.log(1.0 + LOG_EPS)
    return (torch.log(photo.clamp_min(0.0) + LOG_EPS) - lo) * (2.0 / (hi - lo)) - 1.0


class DownBlock(nn.Module):
    """conv 4x4/2 -> attention -> InstanceNorm -> (+ global FC) -> LeakyReLU(0.2).

    The innermost level skips the norm: at the paper's 256 px it is 1x1, where instance
    normalisation would zero every activation (pix2pix does the same).
    """

    def __init__(
        self, in_ch: int, conv_ch: int, attention: nn.Module, *, norm: bool, global_in: int | None, extra: int = 0
    ):
        super().__init__()
        self.conv = nn.Conv2d(in_ch, conv_ch, 4, stride=2, padding=1)
        self.attention = attention
        out_ch = attention.out_channels
        self.out_channels = out_ch
        self.norm = nn.InstanceNorm2d(out_ch) if norm else nn.Identity()
        # global_in: size of the previous level's global vector (0 at level 1), None without a track.
        # extra: inputs of the first level's FC beyond the mean (the exposure level).
        self.fc = nn.Linear(global_in + extra + out_ch, out_ch) if global_in is not None else None

    def forward(self, x: Tensor, g: Tensor | None) -> tuple[Tensor, Tensor | None]:
        h = self.attention(self.conv(x))
        y = self.norm(h)
        if self.fc is not None:
            mean = h.mean(dim=(2, 3))
            g = F.selu(self.fc(mean if g is None else torch.cat([g, mean], dim=1)))
            y = y + g[:, :, None, None]
        return F.leaky_relu(y, 0.2), g


def upsampling_layer(in_ch: int, out_ch: int, kind: str) -> nn.Module:
    """A layer doubling H and W: the paper's 4x4/2 transposed conv, or nearest x2 + 3x3 conv."""
    if kind == "transpose":
        return nn.ConvTranspose2d(in_ch, out_ch, 4, stride=2, padding=1)
    return nn.Sequential(nn.Upsample(scale_factor=2, mode="nearest"), nn.Conv2d(in_ch, out_ch, 3, padding=1))


class UpBlock(nn.Module):
    """deconv 4x4/2 (or resize + conv) -> InstanceNorm -> LeakyReLU(0.2) -> dropout."""

    def __init__(self, in_ch: int, out_ch: int, dropout: float, upsample: str = "transpose"):
        super().__init__()
        self.deconv = upsampling_layer(in_ch, out_ch, upsample)
        self.norm = nn.InstanceNorm2d(out_ch)
        self.dropout = nn.Dropout(dropout) if dropout > 0 else nn.Identity()

    def forward(self, x: Tensor) -> Tensor:
        return self.dropout(F.leaky_relu(self.norm(self.deconv(x)), 0.2))


class UNetGenerator(nn.Module):
    """U-Net generator with optional global track and a registered attention module per level.

    Args:
        config: a :class:`GeneratorConfig` (build one from a dict with
            ``svbrdf_models.resolve_config("generator", name, {...})``).

    Shapes: photo ``(B, 3, H, W)``, linear radiance, H and W multiples of ``2**depth`` ->
    :class:`~svbrdf_render.SVBRDF` with maps of the same size: unit normals with z > 0,
    diffuse, roughness and specular in [0, 1].

    Example:
        >>> g = UNetGenerator(GeneratorConfig(**PRESETS["tiny"]))
        >>> g(torch.rand(2, 3, 32, 32)).normal.shape
        torch.Size([2, 3, 32, 32])
    """

    def __init__(self, config: GeneratorConfig):
        super().__init__()
        self.config = config
        depth = config.depth
        conv_ch = [min(config.base_channels * 2**i, config.max_channels) for i in range(depth)]
        names = config.level_attention()

        self.down = nn.ModuleList()
        in_ch, g_ch = 3, 0
        for level in range(depth):
            att = create_attention(names[level], conv_ch[level], config.attention_config)
            block = DownBlock(
                in_ch,
                conv_ch[level],
                att,
                norm=level < depth - 1,
                global_in=g_ch if config.global_track else None,
                extra=1 if config.input_level and level == 0 else 0,
            )
            self.down.append(block)
            in_ch = g_ch = block.out_channels
        skip_ch = [b.out_channels for b in self.down]

        # up[k] restores the size of down level k; up[depth-1] is the innermost.
        self.up = nn.ModuleList()
        for k in range(depth):
            inner = k == depth - 1
            up_in = skip_ch[k] if inner else conv_ch[k] + skip_ch[k]
            up_out = OUTPUT_CHANNELS if k == 0 else conv_ch[k - 1]
            use_dropout = k >= depth - config.dropout_levels and k > 0
            if k == 0:
                self.up.append(upsampling_layer(up_in, up_out, config.upsample))
            else:
                self.up.append(UpBlock(up_in, up_out, config.dropout if use_dropout else 0.0, config.upsample))
        if config.init_std > 0:
            # The generator's own layers only: attention modules (plugins) keep their own init.
            own = [m for b in self.down for m in (b.conv, b.fc)] + [m for m in self.up]
            for layer in own:
                if layer is not None:
                    normal_init(layer, config.init_std)

    def forward(self, photo: Tensor) -> SVBRDF:
        _check_photo(photo, 2**self.config.depth)
        g = None
        if self.config.input_norm == "median":
            photo, level = normalise_exposure(photo)
            if self.config.input_level:
                g = level  # the first level's FC reads [level, mean] (see DownBlock)
        x = encode_photo(photo)
        skips = []
        for block in self.down:
            x, g = block(x, g)
            skips.append(x)
        y = skips[-1]
        for k in range(self.config.depth - 1, -1, -1):
            if k < self.config.depth - 1:
                y = torch.cat([y, skips[k]], dim=1)
            y = self.up[k](y)
        return maps_from_output(torch.tanh(y), self.config.normal_scale)


def maps_from_output(t: Tensor, normal_scale: float = 1.0) -> SVBRDF:
    """The 9-channel tanh output ``(B, 9, H, W)`` in [-1, 1] -> SVBRDF.

    Normal: (x, y, 1) normalised, so unit length with z > 0 and never degenerate; x and y are
    first scaled by ``normal_scale`` (1: as the network gives them).
    Albedos and roughness: (t + 1) / 2, within [0, 1].
    The maps are float32 whatever the network ran in: under autocast some ops of this head
    (rsqrt on CUDA) run in float32 and others not, and the maps must share one dtype.
    """
    t = t.float()
    nxy = t[:, 0:2] if normal_scale == 1.0 else t[:, 0:2] * normal_scale
    n = torch.cat([nxy, torch.ones_like(t[:, :1])], dim=1)
    n = n * torch.rsqrt(1.0 + (nxy * nxy).sum(dim=1, keepdim=True))
    rest = (t[:, 2:] + 1.0) * 0.5
    return SVBRDF(n, rest[:, 0:3], rest[:, 3:4], rest[:, 4:7], validate=False)


def _check_photo(photo: Tensor, multiple: int) -> None:
    if photo.dim() != 4 or photo.shape[1] != 3:
        raise ValueError(f"generator input: expected a photo of shape (B, 3, H, W), got {tuple(photo.shape)}")
    h, w = photo.shape[-2:]
    if h % multiple or w % multiple:
        raise ValueError(
            f"generator input: H and W must be multiples of {multiple} (2**depth), got {h}x{w}; "
            "crop or resize the photo, or use a smaller depth"
        )


_DESCRIPTION = "U-Net with global track and multi-scale attention per level (the paper's generator)"
OURS = ModelSpec("generator", UNetGenerator, GeneratorConfig, _DESCRIPTION, presets=PRESETS)
UNET = ModelSpec(
    "generator",
    UNetGenerator,
    GeneratorConfig,
    "ours without the global track (U-Net with multi-scale attention)",
    defaults={"global_track": False},
    presets=PRESETS,
)
NO_ATTN = ModelSpec(
    "generator",
    UNetGenerator,
    GeneratorConfig,
    "ours with the 'none' attention module: the w/o-attention ablation (Deschaintre 2018's network)",
    defaults={"attention": "none"},
    presets=PRESETS,
)
