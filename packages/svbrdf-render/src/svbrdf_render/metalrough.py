"""Converting maps between this project's convention and glTF 2.0's metal/rough convention.

This project's maps (the Deschaintre 2018 convention, "des18") give each pixel a diffuse albedo
``d`` (RGB), a specular albedo ``s`` (RGB, the Fresnel reflectance at normal incidence, F0), a
roughness ``r`` and a normal. glTF 2.0 and the tools that read it (Blender, Substance, game
engines, web viewers) give a base colour ``b`` (RGB), a grey ``metallic`` ``m``, the same
roughness and a normal.

The two BRDFs, side by side (``D``, ``V`` the GGX lobe and its visibility, identical in both)::

    des18:  f = d (1 - s) / pi            + F(s) D V / 4
    glTF:   f = c_diff (1 - F(F0)) / pi   + F(F0) D V / 4
            c_diff = b (1 - m),   F0 = 0.04 (1 - m) + b m

(glTF 2.0 specification, appendix B, "complete model": a dielectric reflects 0.04 at normal
incidence, a metal its base colour, and ``metallic`` blends the two.) des18 weighs its diffuse
by ``1 - s``, glTF by ``1 - F``: the same split, taken at normal incidence by des18. So the
terms match one for one with::

    d = c_diff = b (1 - m)          s = F0 = 0.04 (1 - m) + b m          (to the des18 maps)

An engine whose diffuse is ``c_diff / pi`` with no ``1 - F`` factor renders dielectrics up to 4%
brighter than the des18 maps (``1 / (1 - 0.04)``); that is the engine's approximation, not a
difference of the maps.

metal/rough -> des18 (:func:`from_metal_rough`)
    The two lines above, per channel. Exact, no division, values stay in [0, 1].

des18 -> metal/rough (:func:`to_metal_rough`)
    des18 has six colour values per pixel (``d``, ``s``), metal/rough four (``b``, ``m``). The
    metallic value is solved from the luminances ``Yd``, ``Ys`` (linear Rec. 709 weights
    0.2126, 0.7152, 0.0722; luminance is linear, so it obeys the same two equations as each
    channel). Eliminating ``b = d / (1 - m)`` leaves a quadratic in ``m``::

        0.04 m^2 + B m - (Ys - 0.04) = 0,     B = Yd + Ys - 0.08

    Where ``Ys <= 0.04`` the material is a dielectric: ``m = 0``. Otherwise the product of the
    roots is negative and the positive root is taken; it lies in ``(0, 1]`` (the quadratic is
    ``-(Ys - 0.04) < 0`` at 0 and ``Yd >= 0`` at 1). It is computed in the form that does not
    cancel: ``2 (Ys - 0.04) / (B + sqrt(disc))`` when ``B >= 0``, ``(sqrt(disc) - B) / 0.08``
    when ``B < 0``, with ``disc = B^2 + 0.16 (Ys - 0.04)``.

    The base colour, per channel, blends the value the diffuse implies, ``d / (1 - m)``, with
    the value the specular implies, ``(s - 0.04 (1 - m)) / m``, weighted ``1 - m^2`` and
    ``m^2`` (the idea of Khronos's specular/glossiness -> metal/rough converter: trust the
    diffuse for dielectrics, the specular for metals). Multiplied out, the divisions cancel::

        b = (1 + m) d + m s - 0.04 m (1 - m),    then clamped to [0, 1]

    so the blend has no singularity at ``m = 0`` or ``m = 1``.

Which direction is exact
    metal/rough -> des18 -> metal/rough gives back ``b`` and ``m`` (up to float rounding) for
    every pixel with ``m = 0`` or a base colour luminance above 0.04: there ``m`` is the unique
    root, and the blend returns ``b`` exactly for any weights. Below (a metal darker than a
    dielectric's reflectance) the specular luminance falls under 0.04 and the pixel comes back
    as a dielectric. At ``Y(b) = 0.04`` every ``m`` gives the same des18 maps and ``m = 0`` is
    returned; renderings agree either way.

    des18 -> metal/rough -> des18 is lossy. What it keeps: roughness and normal (passed through
    untouched), and the luminances of ``d`` and ``s`` wherever ``s`` reaches 0.04 and ``b`` is
    not clamped. What it loses:

    - the colours of ``d`` and ``s`` separately: one base colour carries both, so a coloured
      specular on a dielectric (or a diffuse tint on a metal) comes back mixed into the other;
    - specular below 0.04 (glTF's dielectric floor): it comes back as 0.04;
    - bright diffuse *and* bright specular on one pixel: then ``b`` exceeds 1 and is clamped,
      since metal/rough maps satisfy ``d + s = b + 0.04 (1 - m) <= 1.04``.

    ``metallic`` here is whatever reproduces ``d`` and ``s``, not a claim that the pixel is a
    metal: a dark dielectric with a specular slightly above 0.04 comes out partly metallic with
    a dark base colour, which renders the same.

Numerical hard cases (forward and backward finite and bounded; see ``tests/render``):
``s = 0`` and ``s = 1``, ``d = 0`` and ``d = 1``, ``m -> 1``, half precision (computed in
float32). Specular luminances within :data:`DIELECTRIC_TOLERANCE` (1e-6) of 0.04 count as
dielectric: a grey 0.04 is ``m = 0`` whatever the rounding of its luminance, and the inverse
stays away from its branch point at ``Yd = Ys = 0.04``, where the exact ``dm/dYs`` is infinite
(it grows as ``1 / sqrt(Ys - 0.04)``): every metallic pixel has ``disc >= 0.16e-6``, which holds
``|dm/dYs|`` below ``5 / sqrt(1e-6) = 5e3``. On dielectric pixels the unused root is computed
from a discriminant clamped at 1e-12, so its masked gradient is finite too.

Files: glTF stores ``baseColorTexture`` sRGB-encoded (:func:`svbrdf_render.linear_to_srgb`) and
``metallicRoughnessTexture`` linear (roughness in green, metallic in blue); its normal maps are
tangent space with +y up, as here, stored ``(n + 1) / 2`` (DirectX-style engines flip green).
The values returned here are linear.

Example:
    >>> from svbrdf_render import SVBRDF
    >>> from svbrdf_render.metalrough import from_metal_rough, to_metal_rough
    >>> gold = SVBRDF.constant(1, 4, diffuse=(0, 0, 0), specular=(1.0, 0.78, 0.34))
    >>> mr = to_metal_rough(gold)
    >>> round(float(mr.metallic.mean()), 4), [round(float(c), 2) for c in mr.basecolor[0, :, 0, 0]]
    (1.0, [1.0, 0.78, 0.34])
    >>> from_metal_rough(mr).specular.shape
    torch.Size([1, 3, 4, 4])
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .compare import map_rmse, render_rmse
from .errors import MapError
from .maps import SVBRDF, check_map_set
from .sampling import evaluation_scene
from .scene import Scene

__all__ = [
    "DIELECTRIC_F0",
    "DIELECTRIC_TOLERANCE",
    "LUMINANCE",
    "METAL_ROUGH_NAMES",
    "MetalRough",
    "to_metal_rough",
    "from_metal_rough",
    "roundtrip_error",
]

#: glTF's reflectance of every dielectric at normal incidence (index of refraction 1.5).
DIELECTRIC_F0 = 0.04
#: Specular luminances up to ``DIELECTRIC_F0 + DIELECTRIC_TOLERANCE`` convert to ``metallic = 0``.
DIELECTRIC_TOLERANCE = 1e-6
_TINY = 1e-12
#: Linear luminance weights (Rec. 709 primaries, those of linear sRGB).
LUMINANCE = (0.2126, 0.7152, 0.0722)
METAL_ROUGH_NAMES = ("basecolor", "metallic", "roughness", "normal")
_CHANNELS = {"basecolor": 3, "metallic": 1, "roughness": 1, "normal": 3}


@dataclass(frozen=True, eq=False)
class MetalRough:
    """glTF 2.0 metal/rough maps of a batch of materials, validated on construction.

    Args:
        basecolor: ``(B, 3, H, W)`` linear base colour in ``[0, 1]`` (glTF files store it sRGB).
        metallic: ``(B, 1, H, W)`` in ``[0, 1]``.
        roughness: ``(B, 1, H, W)`` in ``[0, 1]``; GGX alpha is ``roughness**2``, as in des18.
        normal: ``(B, 3, H, W)`` unit tangent-space normals, +z out, +y up (OpenGL, as glTF).
        validate: check value ranges too (one device sync). Shapes, dtypes and devices are
            always checked.

    Raises:
        MapError: a map of the wrong type, shape, channel count, dtype, device or range.
    """

    basecolor: Tensor
    metallic: Tensor
    roughness: Tensor
    normal: Tensor
    validate: bool = True

    def __post_init__(self):
        check_map_set(
            self.maps(),
            _CHANNELS,
            ("basecolor", "metallic", "roughness") if self.validate else (),
            what="metal/rough map",
            first="the base colour",
            hint="clamp the map, and decode an sRGB base colour to linear first",
        )

    def maps(self) -> dict[str, Tensor]:
        return {name: getattr(self, name) for name in METAL_ROUGH_NAMES}

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(B, H, W)``."""
        b, _, h, w = self.basecolor.shape
        return (b, h, w)


def _compute_dtype(dtype: torch.dtype) -> torch.dtype:
    return torch.float64 if dtype == torch.float64 else torch.float32


def _luminance(rgb: Tensor) -> Tensor:
    """``(B, 3, H, W)`` -> ``(B, 1, H, W)``; the weights sum to 1 in the tensor's dtype."""
    w = torch.tensor(LUMINANCE, dtype=rgb.dtype, device=rgb.device)
    w = (w / w.sum()).view(1, 3, 1, 1)
    return (rgb * w).sum(dim=1, keepdim=True)


def _solve_metallic(yd: Tensor, ys: Tensor) -> Tensor:
    """The root in ``[0, 1]`` of ``0.04 m^2 + (yd + ys - 0.08) m - (ys - 0.04) = 0`` (0 for dielectrics)."""
    f0 = DIELECTRIC_F0
    excess = (ys - f0).clamp_min(0)  # 0 on dielectrics: every branch below stays finite there
    b = yd + ys - 2 * f0
    root = torch.sqrt((b * b + 4 * f0 * excess).clamp_min(_TINY))
    positive = b >= 0
    # B >= 0: -B + root would cancel, so the root is taken as c/(...); B < 0: no cancellation.
    m_pos = 2 * excess / torch.where(positive, b + root, torch.ones_like(b))
    m_neg = (root - b) / (2 * f0)
    m = torch.where(positive, m_pos, m_neg)
    dielectric = ys <= f0 + DIELECTRIC_TOLERANCE
    return torch.where(dielectric, torch.zeros_like(m), m).clamp(0, 1)


def to_metal_rough(svbrdf: SVBRDF) -> MetalRough:
    """des18 maps -> glTF metal/rough maps (lossy; see the module doc for what is lost).

    Args:
        svbrdf: maps ``(B, C, H, W)`` in the project's convention.

    Returns:
        :class:`MetalRough` of the same batch, size, dtype and device; roughness and normal are
        the input tensors themselves. Differentiable (finite gradients at every valid input).

    Raises:
        MapError: ``svbrdf`` is not an :class:`~svbrdf_render.SVBRDF`.
    """
    if not isinstance(svbrdf, SVBRDF):
        raise MapError(
            f"to_metal_rough: expected an SVBRDF (des18 maps), got {type(svbrdf).__name__}; "
            "build one with SVBRDF(normal, diffuse, roughness, specular)"
        )
    dtype = svbrdf.dtype
    cdtype = _compute_dtype(dtype)
    d, s = svbrdf.diffuse.to(cdtype), svbrdf.specular.to(cdtype)
    m = _solve_metallic(_luminance(d), _luminance(s))
    f0 = DIELECTRIC_F0
    # (1 - m^2) d/(1 - m) + m^2 (s - f0 (1 - m))/m, multiplied out: no division left.
    base = ((1 + m) * d + m * s - f0 * m * (1 - m)).clamp(0, 1)
    return MetalRough(base.to(dtype), m.to(dtype), svbrdf.roughness, svbrdf.normal, validate=False)


def from_metal_rough(mr: MetalRough) -> SVBRDF:
    """glTF metal/rough maps -> des18 maps: ``d = b (1 - m)``, ``s = 0.04 (1 - m) + b m``.

    Args:
        mr: :class:`MetalRough` maps (linear base colour).

    Returns:
        An :class:`~svbrdf_render.SVBRDF` of the same batch, size, dtype and device; roughness
        and normal are the input tensors themselves.

    Raises:
        MapError: ``mr`` is not a :class:`MetalRough`.
    """
    if not isinstance(mr, MetalRough):
        raise MapError(
            f"from_metal_rough: expected MetalRough maps, got {type(mr).__name__}; "
            "build them with MetalRough(basecolor, metallic, roughness, normal)"
        )
    dtype = mr.basecolor.dtype
    cdtype = _compute_dtype(dtype)
    b, m = mr.basecolor.to(cdtype), mr.metallic.to(cdtype)
    d = b * (1 - m)
    s = DIELECTRIC_F0 * (1 - m) + b * m
    return SVBRDF(mr.normal, d.to(dtype), mr.roughness, s.to(dtype), validate=False)


def roundtrip_error(svbrdf: SVBRDF, scene: Scene | None = None) -> dict[str, Tensor]:
    """How much des18 -> metal/rough -> des18 changes ``svbrdf``, per material.

    Args:
        svbrdf: maps ``(B, C, H, W)``.
        scene: where the renderings are compared; default
            :func:`~svbrdf_render.evaluation_scene` (the 6 fixed light/view pairs every model
            of the project is judged under).

    Returns:
        ``{name: (B,) float32 RMSE}`` for each map (``normal``, ``diffuse``, ``roughness``,
        ``specular``; on the values a map file stores, normal as ``(n + 1) / 2``) and
        ``render`` (renderings clipped to [0, 1] and sRGB-encoded, as the project's benchmark
        compares them). No gradient.
    """
    if not isinstance(svbrdf, SVBRDF):
        raise MapError(f"roundtrip_error: expected an SVBRDF, got {type(svbrdf).__name__}")
    scene = scene if scene is not None else evaluation_scene(device=svbrdf.device)
    with torch.no_grad():
        back = from_metal_rough(to_metal_rough(svbrdf))
        return {**map_rmse(svbrdf, back), "render": render_rmse(back, svbrdf, scene)}
