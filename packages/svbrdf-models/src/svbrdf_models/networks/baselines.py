"""Baselines: generators with no trained parameters, the bar every trained model must clear.

==========  ======================================================================================
name        what
==========  ======================================================================================
``mean``    constant maps from the photo's statistics: flat normal (0, 0, 1); diffuse =
            ``diffuse_scale`` x the photo's per-channel median (the median ignores the flash
            highlight); one roughness; one grey specular
``photo``   the photo as diffuse: the flash's fall-off divided out, times ``diffuse_scale``,
            clamped to [0, 1]; flat normal; specular 0; one roughness
==========  ======================================================================================

The fall-off of ``photo``: camera and flash on the axis at ``distance`` (Des18: 2.2) above the
surface ``[-1, 1]^2`` that the image covers, a pixel at ``(x, y)`` receives irradiance
proportional to ``d / r^3`` with ``r^2 = x^2 + y^2 + d^2`` (inverse square times the cosine), and a
Lambertian surface sends it back to the camera whatever the angle. Dividing the photo by
``(d / r)^3`` (1 at the centre) leaves the albedo times one constant, which ``diffuse_scale``
undoes.

The constants are chosen to make each baseline as strong as a trivial rule can be: each default
minimises the mean per-image RMSE of its own map on the 21 Deschaintre 2018 test strips of
``des18-dev``, whole tiles brought to 128 px with the area filter as ``svbrdf-bench`` tests
(``benchmarks/baseline_constants.py`` prints them and what they score; ``photo`` shares
``mean``'s roughness). They were read off those very images, which favours the baselines: the bar
they set for a model is, if anything, too high. On des18-dev at 128 px (mean per-image RMSE on
the stored encodings; render: the 6 evaluation light/view pairs, sRGB):

=========  =============================================  ======  =======  =========  ========  ======
baseline   constants                                      normal  diffuse  roughness  specular  render
=========  =============================================  ======  =======  =========  ========  ======
``mean``   diffuse_scale 0.782, roughness 0.367,          0.0709  0.0366   0.1580     0.0363    0.1200
           specular 0.063
``photo``  diffuse_scale 0.298, roughness 0.367           0.0709  0.0643   0.1580     0.0760    0.1549
=========  =============================================  ======  =======  =========  ========  ======

The map-tuned constants are not the render-tuned ones: on the same images ``mean`` renders at
0.105 with roughness 0.4 and specular 0.03, and ``photo`` at 0.117 with diffuse_scale 0.7. The
per-map columns are the bar at its highest; the render column could be lowered by retuning.

The modules are deterministic, hold no parameters and no buffers, and ignore any seed; the
outputs are float32 on the photo's device. They are registered through the same entry points
as every generator (``svbrdf.generators``), so every tool that takes a generator name takes them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from svbrdf_render import DES18_DISTANCE, SVBRDF, surface_positions

from .._config import param
from .._registry import ModelSpec

__all__ = ["MeanConfig", "MeanBaseline", "PhotoConfig", "PhotoBaseline", "flash_falloff", "MEAN", "PHOTO"]

# Read off des18-dev by benchmarks/baseline_constants.py (see the module doc).
MEAN_DIFFUSE_SCALE = 0.782
PHOTO_DIFFUSE_SCALE = 0.298
ROUGHNESS = 0.367
SPECULAR = 0.063


def _unit(value: float, what: str) -> None:
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"{what} must be in [0, 1], got {value}")


def _tuned(default: float, doc: str) -> Any:
    """A config field whose default was read off des18-dev (see the module doc)."""
    return param(default, f"{doc} (default read off des18-dev)")


@dataclass(frozen=True)
class MeanConfig:
    diffuse_scale: float = _tuned(
        MEAN_DIFFUSE_SCALE, "diffuse = this x the photo's per-channel median, clamped to [0, 1]"
    )
    roughness: float = _tuned(ROUGHNESS, "the roughness of every pixel")
    specular: float = _tuned(SPECULAR, "the grey specular albedo of every pixel")

    def __post_init__(self):
        if not self.diffuse_scale >= 0:
            raise ValueError(f"diffuse_scale must be >= 0, got {self.diffuse_scale}")
        _unit(self.roughness, "roughness")
        _unit(self.specular, "specular")


@dataclass(frozen=True)
class PhotoConfig:
    diffuse_scale: float = _tuned(
        PHOTO_DIFFUSE_SCALE, "diffuse = this x the photo, its flash fall-off divided out, clamped to [0, 1]"
    )
    roughness: float = _tuned(ROUGHNESS, "the roughness of every pixel")
    distance: float = param(
        DES18_DISTANCE,
        "height of the on-axis camera and flash above the surface [-1, 1]^2 the image covers (Des18: 2.2)",
    )

    def __post_init__(self):
        if not self.diffuse_scale >= 0:
            raise ValueError(f"diffuse_scale must be >= 0, got {self.diffuse_scale}")
        _unit(self.roughness, "roughness")
        if not self.distance > 0:
            raise ValueError(f"distance must be > 0, got {self.distance}")


def _check_photo(photo: Tensor) -> Tensor:
    if photo.dim() != 4 or photo.shape[1] != 3:
        raise ValueError(f"generator input: expected a photo of shape (B, 3, H, W), got {tuple(photo.shape)}")
    return photo.float()


def _constant(photo: Tensor, values: tuple[float, ...]) -> Tensor:
    b, _, h, w = photo.shape
    v = torch.tensor(values, dtype=torch.float32, device=photo.device).view(1, -1, 1, 1)
    return v.expand(b, -1, h, w).contiguous()


def flash_falloff(height: int, width: int, distance: float = DES18_DISTANCE, *, device=None) -> Tensor:
    """``(1, 1, H, W)``: the irradiance of an on-axis flash at ``distance`` relative to the centre's.

    ``(d / r)^3`` with ``r^2 = x^2 + y^2 + d^2`` at the pixel centres of the surface ``[-1, 1]^2``
    (inverse square fall-off times the cosine at the surface).
    """
    p = surface_positions(height, width, device=device)
    r2 = p[0] ** 2 + p[1] ** 2 + distance**2
    return ((distance**2 / r2) ** 1.5)[None, None]


class MeanBaseline(nn.Module):
    """Constant maps from the photo's statistics (see the module doc); no parameters.

    Example:
        >>> g = MeanBaseline(MeanConfig(diffuse_scale=2.0))
        >>> float(g(torch.full((1, 3, 8, 8), 0.25)).diffuse[0, 0, 0, 0])
        0.5
    """

    def __init__(self, config: MeanConfig):
        super().__init__()
        self.config = config

    def forward(self, photo: Tensor) -> SVBRDF:
        x = _check_photo(photo)
        median = x.flatten(2).median(dim=2).values  # (B, 3): the highlight is a minority of pixels
        diffuse = (self.config.diffuse_scale * median).clamp(0.0, 1.0)[:, :, None, None].expand_as(x)
        c = self.config
        return SVBRDF(
            _constant(x, (0.0, 0.0, 1.0)),
            diffuse.contiguous(),
            _constant(x, (c.roughness,)),
            _constant(x, (c.specular,) * 3),
            validate=False,
        )


class PhotoBaseline(nn.Module):
    """The photo, its flash fall-off divided out, as the diffuse map (see the module doc); no parameters."""

    def __init__(self, config: PhotoConfig):
        super().__init__()
        self.config = config

    def forward(self, photo: Tensor) -> SVBRDF:
        x = _check_photo(photo)
        c = self.config
        falloff = flash_falloff(x.shape[-2], x.shape[-1], c.distance, device=x.device)
        diffuse = (x * (c.diffuse_scale / falloff)).clamp(0.0, 1.0)
        return SVBRDF(
            _constant(x, (0.0, 0.0, 1.0)),
            diffuse,
            _constant(x, (c.roughness,)),
            _constant(x, (0.0, 0.0, 0.0)),
            validate=False,
        )


MEAN = ModelSpec(
    "generator",
    MeanBaseline,
    MeanConfig,
    "baseline, no training: flat normal, diffuse = scale x the photo's median, constant roughness/specular",
)
PHOTO = ModelSpec(
    "generator",
    PhotoBaseline,
    PhotoConfig,
    "baseline, no training: the photo with the flash fall-off divided out as diffuse, flat normal, "
    "no specular",
)
