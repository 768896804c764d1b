"""Procedural SVBRDF materials photographed by a simulated phone: training data with no download.

Every sample is a seeded function of ``(seed, index)``: a material of one of ten
:data:`FAMILIES`, drawn with :data:`FAMILY_WEIGHTS` (or, with probability ``mix``, two of
them blended through a soft noise mask, as Deschaintre et al. 2018 mix materials), its
diffuse albedo shown at a drawn brightness and chroma (from greyer to more saturated than
its palette), its relief scaled by a drawn strength (30% of materials flattened, some
nearly flat), and its photo rendered by
svbrdf-render under a jittered phone flash held a little off the patch's axis
(:func:`photo_scene`). The ranges were moved towards real materials with
``svbrdf-train data compare`` (README, "Training data").

=========  ===================================================================
family     what it draws
=========  ===================================================================
stone      marble with veins, granite, sandstone, slate: domain-warped fBm
tiles      tiles, bricks, mosaics; grout recessed, rougher, another colour;
           some with metal studs where the tiles meet
cells      leather, cobbles, cracked earth and paint: Worley cells
wood       rings, fibres, pores; optionally planks with seams
metal      brushed, polished and scratched, hammered, sandblasted, embossed;
           coloured specular (measured F0, or tarnished and anodised: darker),
           dark diffuse
fabric     plain, twill and satin weaves of round threads; stripes and checks
plaster    plaster, stucco, concrete: broad low bumps, stucco dabs, pores and
           air holes (recessed, rougher); near-grey, rough
rusted     painted and rusted steel: paint chipped down to the metal, rust
           patches (orange-brown rough dielectric, flaky) on the bare metal
bark       plates between deep furrows along the trunk (darker, rougher),
           cracks across the plates, weathered tops, lichen
rock       rough rock with strong warped low-frequency relief and folds,
           crevices (darker, rougher), lichen and moss patches
=========  ===================================================================

Example:
    >>> data = ProceduralMaterials(count=1000, resolution=256, seed=0)
    >>> sample = data[3]                       # {"input", "maps", "name"}
    >>> sample["maps"].shape, sample["name"]
    (torch.Size([10, 256, 256]), 'procedural:0:3')
    >>> batch = data.batch([3, 4])             # the same samples, stacked, faster
    >>> batch = data.batch([3, 4], device="cuda")   # computed on a GPU (see below)  # doctest: +SKIP

Reproducibility: the output for ``(seed, index, resolution)`` is the same bytes in any
process, DataLoader worker, thread count and batch (``batch([3, 4])`` equals
``[data[3], data[4]]`` stacked): each sample draws from generators seeded by a hash of
``(seed, index)``, never from the global RNG, and the batched fields use only ops that
compute each sample alike whatever the batch (see :mod:`.procedural_noise`). Across
machines the bytes agree where torch runs the same CPU kernels (AVX2 and AVX512 builds
agree; torch's scalar fallback rounds ``grid_sample`` differently in the last bit).
:data:`GENERATOR_VERSION` changes whenever the output on one machine does.

On a training device (``batch(indices, device="cuda")``, what ``data.generate: device``
uses): the per-sample draws are made on the CPU as above and copied over, the pixel grid,
fields, normals and photos are computed on the device, the whole batch at once. A sample is
the same material under the same camera, flash and exposure as on the CPU; its values
differ in rounding, and its photo noise is the device generator's draw from the same seed.
The same ``(seed, indices)`` gives the same bytes every time on the same device model.

Maps: heights become normals by central differences in patch units (the patch spans
``[-1, 1]^2``; normal ``(-dh/dx, -dh/dy, 1)`` normalised, x right, y up, image row 0 at
``y = +1``), computed on a grid one pixel larger than the image so that edges are exact.
Diffuse, roughness and specular are clamped to ``[0, 1]``.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor
from torch.utils.data import Dataset

from svbrdf_render import DES18_EFFECTS, SVBRDF, Camera, Flash, Scene, render
from svbrdf_render.renderer import build_plan

from ..errors import DataError
from .jpeg import jpeg_roundtrip
from .procedural_families import FAMILY_TABLE, Fields, pixel_grid, stack_choices
from .procedural_noise import Draw, fbm, smoothstep
from .procedural_noise import mix as blend

__all__ = [
    "GENERATOR_VERSION",
    "FAMILIES",
    "FAMILY_WEIGHTS",
    "PhotoSettings",
    "ProceduralMaterials",
    "material",
    "materials",
    "photo_jpeg_quality",
    "photo_scene",
]

#: Changes whenever the output for a given (seed, index, resolution) changes; recorded in shards.
GENERATOR_VERSION = "3"
#: The material families, in the order they are drawn from.
FAMILIES: tuple[str, ...] = tuple(FAMILY_TABLE)
#: How often each family is drawn, relatively. The families of the Des18 materials (stone,
#: tiles, cells, metal) keep the bulk (about 55%), metals a little more (often dark, often
#: coloured); the surfaces Des18 lacks share the rest: painted and rusted metal most of them
#: (metal and dielectric in one material, as Des18's bumpy metal is too), plaster and rock
#: (common, and the low and the strong relief of rough near-grey surfaces), wood and fabric,
#: and bark least (the narrowest look).
FAMILY_WEIGHTS: dict[str, float] = {
    "stone": 1.0,
    "tiles": 1.0,
    "cells": 1.0,
    "wood": 0.6,
    "metal": 1.2,
    "fabric": 0.5,
    "plaster": 0.6,
    "rusted": 0.7,
    "bark": 0.4,
    "rock": 0.6,
}

# Streams of random numbers of one sample, so that each part can be drawn on its own.
_MATERIAL, _PHOTO, _COMPONENT, _MASK = 1, 2, 3, 4
_MASK64 = (1 << 64) - 1
#: Pixels generated together (see :func:`materials`).
_CHUNK_PIXELS = 2 * 256 * 256


def _splitmix64(x: int) -> int:
    x = (x + 0x9E3779B97F4A7C15) & _MASK64
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _MASK64
    return x ^ (x >> 31)


def _key(*parts: int) -> int:
    """A 63-bit seed from integers, the same in every process (unlike ``hash``)."""
    h = 0x5EED
    for p in parts:
        h = _splitmix64(h ^ _splitmix64(p & _MASK64))
    return h >> 1


# -- the simulated phone photo -------------------------------------------------------------


@dataclass(frozen=True)
class PhotoSettings:
    """Jitter ranges of the simulated phone flash photo; each sample draws within them.

    Ranges are ``(low, high)``, drawn uniformly unless said otherwise. The default renders
    *linear* photos (no gamma), the input convention of the networks here and of the Des18
    data. The defaults are the ``"des18"`` preset; ``PhotoSettings.preset("phone")`` is
    capture like the flashes fitted to real phone photos (:data:`CAPTURE_PRESETS`).
    """

    fov: tuple[float, float] = (40.0, 58.0)
    """Full field of view in degrees of the on-axis camera that just frames the patch; the
    camera distance is ``1 / tan(fov / 2)`` (48.9 degrees: 2.2, the Des18 distance)."""
    flash_offset: float = 0.2
    """Largest distance of the flash from the lens, in patch half-widths (drawn uniformly
    over a disc in the lens plane)."""
    camera_shift: tuple[float, float] = (0.03, 0.3)
    """Distance of the camera, and the flash with it, from the patch's axis, in patch
    half-widths (uniform in this range, in a uniform direction): the phone is not held
    exactly over the centre, so the highlight, which lies under the flash, is off-centre.
    The flash fitted to each des18-dev photo sits 0.08-0.30 off the axis (0.20 on average);
    the image still covers the patch ``[-1, 1]^2``."""
    exposure_ev: tuple[float, float] = (-0.75, 0.75)
    """Exposure in stops. The flash intensity is ``pi * distance^2`` (unless ``intensity`` is
    set), which shows a white Lambertian patch at 1.0 in the centre at 0 EV."""
    noise_sigma: tuple[float, float] = (0.002, 0.012)
    """Standard deviation of the Gaussian read noise."""
    noise_shot: tuple[float, float] = (0.0, 0.01)
    """Shot noise: the noise variance grows by this times the signal."""
    gamma_probability: float = 0.0
    """Probability that a photo is gamma-encoded (``x ** (1 / gamma)`` after clipping)."""
    gamma: float = 2.2
    """The gamma of gamma-encoded photos."""
    distance: tuple[float, float] | None = None
    """Camera distance in patch half-widths, drawn log-uniformly, in place of ``fov``: the
    field of view follows as ``2 atan(1 / distance)``, so the image still frames the patch.
    None: the distance follows from ``fov``."""
    intensity: tuple[float, float] | None = None
    """Flash intensity, drawn log-uniformly and independently of the distance, in place of
    ``pi * distance^2``: the centre irradiance ``intensity / distance^2`` then varies from
    photo to photo, as it does between real captures. None: ``pi * distance^2``."""
    white_balance: float = 0.0
    """Largest relative deviation of the red and blue gains from the green one (each drawn
    uniformly in ``[1 - w, 1 + w]``, green 1): the colour of the flash as the phone's white
    balance leaves it, applied as the flash's ``color``. 0: a white flash."""
    jpeg_probability: float = 0.0
    """Probability that a photo goes through a JPEG encode and decode (4:2:0, the standard
    tables scaled to a quality drawn from ``jpeg_quality``; :func:`.jpeg.jpeg_roundtrip`),
    after the clip and before any gamma: the photo stays linear."""
    jpeg_quality: tuple[int, int] = (75, 95)
    """JPEG quality range (integers 1-100, drawn uniformly, both ends included)."""

    def __post_init__(self):
        for name in ("fov", "exposure_ev", "noise_sigma", "noise_shot", "camera_shift", "jpeg_quality"):
            low, high = getattr(self, name)
            if not low <= high:
                raise DataError(f"PhotoSettings.{name}: expected low <= high, got ({low}, {high})")
        if not (0 < self.fov[0] and self.fov[1] < 180):
            raise DataError(f"PhotoSettings.fov: expected degrees in (0, 180), got {self.fov}")
        if min(self.flash_offset, self.noise_sigma[0], self.noise_shot[0], self.camera_shift[0]) < 0:
            raise DataError(
                "PhotoSettings: flash_offset, camera_shift, noise_sigma and noise_shot must be >= 0"
            )
        if not 0 <= self.gamma_probability <= 1 or self.gamma <= 0:
            raise DataError(
                f"PhotoSettings: expected gamma_probability in [0, 1] and gamma > 0, got "
                f"{self.gamma_probability} and {self.gamma}"
            )
        for name in ("distance", "intensity"):
            value = getattr(self, name)
            if value is None:
                continue
            ok = len(value) == 2 and all(math.isfinite(v) for v in value)
            if not (ok and 0 < value[0] <= value[1]):
                raise DataError(
                    f"PhotoSettings.{name}: expected (low, high) with 0 < low <= high, or None, got {value}"
                )
        if not 0 <= self.white_balance < 1:
            raise DataError(
                f"PhotoSettings.white_balance: expected a gain deviation in [0, 1), got {self.white_balance}"
            )
        if not 0 <= self.jpeg_probability <= 1:
            raise DataError(
                "PhotoSettings.jpeg_probability: expected a probability in [0, 1], got "
                f"{self.jpeg_probability}"
            )
        q = self.jpeg_quality
        if not (all(int(v) == v for v in q) and 1 <= q[0] and q[1] <= 100):
            raise DataError(f"PhotoSettings.jpeg_quality: expected integers in [1, 100], got {q}")

    @classmethod
    def preset(cls, name: str) -> PhotoSettings:
        """The settings of a named capture (:data:`CAPTURE_PRESETS`): ``"des18"``, today's
        defaults, or ``"phone"``, capture like real phone photos."""
        if name not in CAPTURE_PRESETS:
            raise DataError(f"unknown capture {name!r}; choose from {', '.join(CAPTURE_PRESETS)}")
        return cls(**CAPTURE_PRESETS[name])


#: Named captures for :meth:`PhotoSettings.preset` (and the recipe field ``data.capture``).
#:
#: ``des18``: the defaults: distance from a 40-58 degree field of view (1.8-2.75), the
#: centre irradiance fixed by ``pi * d^2`` and varied by +-0.75 EV, linear, white, no JPEG.
#:
#: ``phone``: the flashes fitted to the Des18 test photos, 10th-90th percentile: distance
#: 1.8-3.7 and intensity 10-21, independent (median near 2.3 and 15), both log-uniform. They
#: already carry each photo's brightness (the fit sees the photo as it was exposed), so the
#: exposure range is not a second level range on top: ``intensity / distance^2`` alone spans
#: 0.73-6.5, 3.2 stops, against 1.5 stops (+-0.75 EV) for des18. The exposure only moves
#: the median level of the draws (14.5 / 2.58^2 = 2.2) towards the fitted median's
#: (15 / 2.3^2 = 2.8), +0.25 EV, and rounds off the edges of the range by +-0.25 EV. White
#: balance within 8% (R and B gains against G), half the photos JPEG-compressed at quality
#: 75-95 (what phone cameras save), flash offset and camera shift as des18.
CAPTURE_PRESETS: dict[str, dict[str, Any]] = {
    "des18": {},
    "phone": {
        "distance": (1.8, 3.7),
        "intensity": (10.0, 21.0),
        "exposure_ev": (0.0, 0.5),
        "white_balance": 0.08,
        "jpeg_probability": 0.5,
        "jpeg_quality": (75, 95),
    },
}


def _capture_draws(seed: int, index: int, s: PhotoSettings) -> tuple[float | None, Tensor | None, int | None]:
    """The draws of a photo beyond the des18 ones, from a stream of their own (so that the
    des18 draws, and photos under the default settings, stay what they were): the flash
    intensity (None: ``pi * d^2``), the flash colour (None: white) and the JPEG quality
    (None: no JPEG). Each is drawn whatever the settings, so one setting never moves another's
    draw."""
    e = Draw(_key(seed, index, _PHOTO, 1))
    u_intensity, red, blue = e.uniform(), e.uniform(-1.0, 1.0), e.uniform(-1.0, 1.0)
    jpeg, quality = e.chance(s.jpeg_probability), e.integer(int(s.jpeg_quality[0]), int(s.jpeg_quality[1]))
    intensity = None
    if s.intensity is not None:
        low, high = math.log(s.intensity[0]), math.log(s.intensity[1])
        intensity = math.exp(low + (high - low) * u_intensity)
    color = None
    if s.white_balance > 0:
        color = torch.tensor([1.0 + s.white_balance * red, 1.0, 1.0 + s.white_balance * blue])
    return intensity, color, (quality if jpeg else None)


def photo_scene(seed: int, index: int, settings: PhotoSettings | None = None) -> Scene:
    """The simulated phone flash photo of sample ``index``: camera, flash and effects.

    A camera at the height its jittered field of view frames the patch from (or at a drawn
    ``settings.distance``, with the field of view that frames the patch from there), shifted
    off the patch's axis by ``settings.camera_shift`` (the image still covers the patch), a
    flash of intensity ``pi * distance^2`` (or drawn from ``settings.intensity``) offset a
    little from the lens, white or coloured by ``settings.white_balance``, and exactly these
    effects: the Des18 shading (diffuse, specular, fresnel, masking, cosine, falloff),
    exposure, noise (seeded from ``(seed, index)``, so the photo reproduces), clip, and
    gamma only for the ``settings.gamma_probability`` share of photos. The JPEG round trip
    is no effect of the renderer: :func:`photo_jpeg_quality` says which photos get it.

    Tilt is not drawn: the renderer's image is the patch itself (pixel ``p`` shows surface
    point ``p``), so a phone tilted to keep the patch in frame differs from one shifted
    off-axis (``camera_shift``, up to 0.3: 8 degrees at 2.2) only by the keystone warp of an
    unrectified photo, which the maps would have to share and which real captures crop away.
    """
    s = settings or PhotoSettings()
    d = Draw(_key(seed, index, _PHOTO))
    if s.distance is None:
        fov = d.uniform(*s.fov)
        distance = 1.0 / math.tan(math.radians(fov) / 2)
    else:  # the same one draw, so the draws after it stay those of the des18 settings
        distance = d.log_uniform(*s.distance)
        fov = 2 * math.degrees(math.atan(1.0 / distance))
    radius = s.flash_offset * math.sqrt(d.uniform())  # uniform over the disc
    cs, sn = d.angle()
    ev, sigma, shot = d.uniform(*s.exposure_ev), d.uniform(*s.noise_sigma), d.uniform(*s.noise_shot)
    noise_seed = d.seed()
    gamma = d.chance(s.gamma_probability)
    shift = d.uniform(*s.camera_shift)
    shift_cos, shift_sin = d.angle()
    effects: list[Any] = [
        *DES18_EFFECTS,
        {"exposure": {"ev": ev}},
        {"noise": {"sigma": sigma, "shot": shot, "seed": noise_seed}},
        "clip",
    ]
    if gamma:
        effects.append({"gamma": {"gamma": s.gamma}})
    camera = Camera(torch.tensor([shift * shift_cos, shift * shift_sin, distance]), fov)
    intensity, color, _ = _capture_draws(seed, index, s)
    if intensity is None:
        intensity = math.pi * distance * distance
    offset = torch.tensor([radius * cs, radius * sn, 0.0])
    flash = Flash(intensity, offset) if color is None else Flash(intensity, offset, color)
    return Scene(camera, (flash,), effects)


def photo_jpeg_quality(seed: int, index: int, settings: PhotoSettings | None = None) -> int | None:
    """The JPEG quality of sample ``index``'s photo, or None when it is not JPEG-compressed
    (the ``settings.jpeg_probability`` share of photos is)."""
    return _capture_draws(seed, index, settings or PhotoSettings())[2]


#: The image stages of a photo scene that :func:`_photos` applies per sample, in the order
#: the renderer runs them (the rest of a photo scene's effects is the shading).
_IMAGE_STAGES = ("exposure", "noise", "clip", "gamma")


def _batchable(scenes: Sequence[Scene]) -> bool:
    """Whether :func:`_photos` can render ``scenes`` together: photo scenes (one flash, a
    camera at a finite position) with the same shading and no image stage but its own."""
    fx = scenes[0].effects
    shading = {k: v for k, v in fx.items() if k not in _IMAGE_STAGES}
    return all(
        len(s.lights) == 1
        and isinstance(s.lights[0], Flash)
        and s.camera.directional is False
        and s.camera.position.shape == (3,)
        and s.lights[0].intensity.dim() == 0
        and s.lights[0].color.shape == (3,)
        and {"exposure", "noise", "clip"} <= set(s.effects)
        and {k: v for k, v in s.effects.items() if k not in _IMAGE_STAGES} == shading
        for s in scenes
    )


def _photos(packed: Tensor, scenes: Sequence[Scene]) -> Tensor:
    """The photos ``(B, 3, R, R)`` of the materials ``packed`` ``(B, 10, R, R)``, sample ``k``
    under ``scenes[k]`` (from :func:`photo_scene`), in one render on the maps' device.

    The cameras and flashes become per-sample configurations of one scene (shape ``(B, 1)``)
    for the shading, the costly part; each photo's exposure, noise, clip and gamma then run
    through the renderer's own image stages (:func:`svbrdf_render.renderer.build_plan`), noise
    seeded from its scene as :func:`render` seeds it. So each photo is what
    ``render(maps[k], scenes[k])`` makes on that device (on the CPU the very bytes: tested;
    to rounding where the flashes' colours differ, which the shading then takes as white and
    a gain of each photo after it, the same product in another order).
    Used on accelerators, where one render of ``B`` samples replaces ``B`` renders of small
    kernels; :meth:`ProceduralMaterials.batch` keeps
    one render per sample on the CPU, where that is faster (8 photos at 256 px on one
    thread: 46 ms one by one, 75 ms batched, which spills the caches).
    """
    b = packed.shape[0]
    svbrdf = SVBRDF.unpack(packed, validate=False)
    if not _batchable(scenes):  # not photo scenes: one render each
        return torch.cat([render(svbrdf[k : k + 1], s) for k, s in enumerate(scenes)])
    flashes = [s.lights[0] for s in scenes]
    # The field of view only matters to vignetting, which photo scenes do not declare.
    camera = Camera(torch.stack([s.camera.position for s in scenes]).view(b, 1, 3), scenes[0].camera.fov)
    colors = torch.stack([f.color for f in flashes])
    one_color = bool((colors == colors[0]).all())
    flash = Flash(
        torch.stack([f.intensity for f in flashes]).view(b, 1),
        torch.stack([f.offset for f in flashes]).view(b, 1, 3),
        flashes[0].color if one_color else torch.ones(3),
    )
    shading = {k: v for k, v in scenes[0].effects.items() if k not in _IMAGE_STAGES}
    x = render(svbrdf, Scene(camera, (flash,), shading))
    if not one_color:  # the renderer takes one colour per light; radiance is linear in it
        x = x * colors.to(x.device, x.dtype).view(b, 1, 3, 1, 1)
    # Each photo's own image stages, by the renderer's own code (they need no geometry).
    photos = []
    for k, s in enumerate(scenes):
        stages = {name: v for name, v in s.effects.items() if name in _IMAGE_STAGES}
        photos.append(build_plan(stages).finish(x[k : k + 1], None, None, None))
    return torch.cat(photos)[:, 0]


def _jpeg(photos: Tensor, qualities: Sequence[int | None], gammas: Sequence[dict | None]) -> Tensor:
    """``photos`` with photo ``k`` through the JPEG round trip at ``qualities[k]`` (None: left
    as it is), then gamma-encoded by the renderer's own stage where ``gammas[k]`` (the gamma
    effect's parameters) says so. The round trip computes each photo alike in any batch."""
    coded = [k for k, q in enumerate(qualities) if q is not None]
    if not coded:
        return photos
    where = torch.tensor(coded, device=photos.device)
    out = jpeg_roundtrip(photos.index_select(0, where), [qualities[k] for k in coded])
    for j, k in enumerate(coded):
        if gammas[k] is not None:
            out[j : j + 1] = build_plan({"gamma": gammas[k]}).finish(out[j : j + 1], None, None, None)
    return photos.index_copy(0, where, out)


# -- materials -----------------------------------------------------------------------------


@dataclass(frozen=True)
class _Recipe:
    """What one sample is made of: its family name, components ``(family, seed)``, the seed
    of the mixing mask, a bump strength, the scale of its diffuse albedo's value
    (brightness) and chroma (distance from grey), and its relief scale (1, or a flattening
    below 1); the heights are scaled by ``bump * relief``."""

    family: str
    components: tuple[tuple[str, int], ...]
    mask_seed: int
    bump: float
    value: float = 1.0
    chroma: float = 1.0
    relief: float = 1.0


def _check_families(families: Sequence[str] | None) -> tuple[str, ...]:
    if families is None:
        return FAMILIES
    if isinstance(families, str):
        families = [families]
    families = tuple(families)
    if not families:
        raise DataError(f"families: expected at least one of {', '.join(FAMILIES)}")
    unknown = [f for f in families if f not in FAMILY_TABLE]
    if unknown:
        raise DataError(
            f"unknown material famil{'y' if len(unknown) == 1 else 'ies'} "
            f"{', '.join(repr(f) for f in unknown)}; choose from {', '.join(FAMILIES)}"
        )
    return families


def _recipe(seed: int, index: int, families: tuple[str, ...], mix_p: float, family: str | None) -> _Recipe:
    d = Draw(_key(seed, index, _MATERIAL))
    weights = [FAMILY_WEIGHTS[f] for f in families]
    mixed, first, second = d.chance(mix_p), d.choice(families, weights), d.choice(families, weights)
    bump = d.log_uniform(0.8, 2.4)
    # Albedos: every material is shown at a brightness of 30-100% of its palette's (real
    # albedos are darker than the palettes alone) and a chroma of 0.2-2x its palette's,
    # log-uniform (geometric mean 0.63; about 30% above the palette's, eased near the
    # gamut's edge, see _packed). A spread, not one set's level: the Des18 materials are
    # greyish (mean HSV saturation 0.25 [p10 0.09, p90 0.53] on des18-dev), scanned bark,
    # rust, wood and fabric more saturated (0.47 [0.16, 0.75] on unseen-dev); the v2 range
    # of 20-90% matched only the first. On 256 samples W1 of the saturation moves from
    # 0.07 to 0.13 against des18-dev and from 0.17 to 0.12 against unseen-dev.
    value, chroma = d.log_uniform(0.3, 1.0), d.log_uniform(0.2, 2.0)
    # Relief: the bump above spans the Des18 relief (slope p90 0.07-1.0), but real scanned
    # surfaces are often much flatter (plaster, paint, fabric, polished stone: slope p90
    # below 0.01 for a third of unseen-dev). So 30% of materials, of any family, are
    # flattened by a factor log-uniform in 0.02-1 (down to a slope p90 of a few
    # thousandths, nearly a flat normal map), the rest keep their relief: on 256 samples W1
    # of slope p90 falls from 0.33 to 0.22 against unseen-dev and rises from 0.07 to 0.12
    # against des18-dev (its noise floor: 0.11-0.17). Drawn last, so the draws above stay
    # what they were.
    flat, flattening = d.chance(0.3), d.log_uniform(0.02, 1.0)
    relief = flattening if flat else 1.0
    if family is not None:
        names = tuple(family.split("+"))
        if len(names) > 2:
            raise DataError(f"family {family!r}: expected one family or two joined by '+'")
        _check_families(names)
    else:
        names = (first, second) if mixed else (first,)
    components = tuple((name, _key(seed, index, _COMPONENT, slot)) for slot, name in enumerate(names))
    return _Recipe("+".join(names), components, _key(seed, index, _MASK), bump, value, chroma, relief)


def _mask(seeds: list[int], x: Tensor, y: Tensor) -> tuple[Tensor, Tensor]:
    """Soft masks ``(B, 1, H, W)`` in [0, 1] that blend two materials: thresholded fBm, on
    the device of ``x`` and ``y``.

    Returns the mask of the albedos and roughness, and a wider one for the heights: two
    families' surfaces lie at different levels, and a sharp step between them would be a
    cliff of near-horizontal normals.
    """
    choices = []
    for s in seeds:
        d = Draw(s)
        cs, sn = d.angle()
        choices.append(
            {
                "cos": cs,
                "sin": sn,
                "freq": d.uniform(0.6, 2.0),
                "threshold": d.uniform(-0.3, 0.3),
                "softness": d.log_uniform(0.01, 0.2),
                "lattice": d.lattice(1),
            }
        )
    p = stack_choices(choices, x.device)
    u = (x * p["cos"] - y * p["sin"]) * p["freq"]
    v = (x * p["sin"] + y * p["cos"]) * p["freq"]
    n = fbm(p["lattice"], u, v, 4)
    t, soft = p["threshold"], p["softness"]
    return smoothstep(t - soft, t + soft, n), smoothstep(t - soft - 0.1, t + soft + 0.1, n)


def _fields(recipes: list[_Recipe], resolution: int, device: torch.device | None = None) -> Fields:
    """The (mixed) fields of every recipe on the grid with a one-pixel margin, computed on
    ``device`` (default the CPU); the draws are made on the CPU and copied there."""
    x, y = pixel_grid(resolution, margin=1, device=device)
    b = len(recipes)
    # Jobs: every sample's first component, then the second of the mixed ones.
    jobs = [r.components[0] for r in recipes]
    mixed = [i for i, r in enumerate(recipes) if len(r.components) == 2]
    jobs += [recipes[i].components[1] for i in mixed]
    # One batched computation per family; then back to job order.
    order: list[int] = []
    parts: list[Fields] = []
    for name in dict.fromkeys(f for f, _ in jobs):
        members = [j for j, (f, _) in enumerate(jobs) if f == name]
        family = FAMILY_TABLE[name]
        choices = stack_choices([family.draw(Draw(jobs[j][1])) for j in members], device)
        parts.append(family.fields(choices, x, y))
        order += members
    inverse = torch.empty(len(jobs), dtype=torch.long)
    inverse[torch.tensor(order)] = torch.arange(len(jobs))
    inverse = inverse.to(x.device)
    maps = []
    for k in range(4):
        t = torch.cat([p[k].expand(-1, -1, resolution + 2, resolution + 2) for p in parts])
        maps.append(t.index_select(0, inverse))
    if mixed:
        mask, height_mask = _mask([recipes[i].mask_seed for i in mixed], x, y)
        idx = torch.tensor(mixed, device=x.device)
        for k in range(4):
            first, second = maps[k][idx], maps[k][b:]
            m = height_mask if k == 0 else mask
            maps[k] = maps[k][:b].index_copy(0, idx, blend(first, second, m))
    else:
        maps = [t[:b] for t in maps]
    return Fields(*maps, {})


def _normals(height: Tensor) -> Tensor:
    """Unit normals ``(B, 3, H, W)`` of heights ``(B, 1, H + 2, W + 2)`` in patch units."""
    h, w = height.shape[-2] - 2, height.shape[-1] - 2
    # Central differences over two pixels of 2/W (2/H) patch units; rows go down, y up.
    dhdx = (height[..., 1:-1, 2:] - height[..., 1:-1, :-2]) * (w / 4)
    dhdy = (height[..., :-2, 1:-1] - height[..., 2:, 1:-1]) * (h / 4)
    length = torch.sqrt(dhdx * dhdx + dhdy * dhdy + 1)
    return torch.cat([-dhdx / length, -dhdy / length, 1 / length], dim=1)


def _device(device: torch.device | str | None) -> torch.device:
    """``device`` as a ``torch.device``; ``None`` is the CPU."""
    return torch.device("cpu") if device is None else torch.device(device)


def _check_index(index, count: int | None = None) -> int:
    try:
        i = operator.index(index)
    except TypeError:
        raise TypeError(f"sample index: expected an integer, got {index!r}") from None
    if i < 0 or (count is not None and i >= count):
        raise IndexError(f"sample index {i} out of range for {count} samples")
    return i


def _check_resolution(resolution: int) -> int:
    r = operator.index(resolution)
    if r < 2:
        raise DataError(f"resolution: expected at least 2 pixels, got {r}")
    return r


def _packed(
    seed: int,
    indices: Sequence[int],
    resolution: int,
    families: Sequence[str] | None,
    mix: float,
    family: str | None,
    device: torch.device | str | None = None,
) -> tuple[Tensor, list[str]]:
    """:func:`materials` as one ``(B, 10, R, R)`` tensor in the ``SVBRDF.pack`` layout, on
    ``device`` (default the CPU)."""
    families = _check_families(families)
    resolution = _check_resolution(resolution)
    if not 0 <= mix <= 1:
        raise DataError(f"mix: expected a probability in [0, 1], got {mix}")
    indices = [_check_index(i) for i in indices]
    if not indices:
        raise DataError("materials: expected at least one sample index")
    recipes = [_recipe(seed, i, families, mix, family) for i in indices]
    device = _device(device)
    # On the CPU, chunks of about _CHUNK_PIXELS: larger batches spill the noise octaves out
    # of the caches and run slower (measured: 2 samples at 256 x 256 are fastest on 2 cores).
    # On an accelerator the whole batch at once: fewer, larger kernels.
    chunk = max(1, _CHUNK_PIXELS // (resolution * resolution)) if device.type == "cpu" else len(recipes)
    crop = (..., slice(1, -1), slice(1, -1))
    parts = []
    with torch.no_grad():
        for first in range(0, len(recipes), chunk):
            part = recipes[first : first + chunk]
            f = _fields(part, resolution, device)
            bump, value, chroma, relief = (
                torch.tensor([getattr(r, k) for r in part], dtype=torch.float32).view(-1, 1, 1, 1).to(device)
                for k in ("bump", "value", "chroma", "relief")
            )
            diffuse = f.diffuse[crop]
            grey = (diffuse[:, 0:1] + diffuse[:, 1:2] + diffuse[:, 2:3]) / 3
            # A chroma below 1 applies as drawn. Above 1 its excess is eased, pixel by pixel,
            # towards the headroom left before the lowest channel reaches 0 (the chroma
            # ``grey / (grey - low)``, less 1): 1 / excess' = 1 / excess + 1 / headroom. Small
            # boosts pass nearly whole, none reaches that edge: no channel is pushed below 0
            # (clipped), the hue stays, and no pixel turns a pure colour (HSV saturation 1).
            low = torch.minimum(torch.minimum(diffuse[:, 0:1], diffuse[:, 1:2]), diffuse[:, 2:3])
            headroom = (grey / (grey - low).clamp_min(1e-6) - 1).clamp_min(0.0)
            excess = (chroma - 1).clamp_min(0.0)
            eased = excess * headroom / (excess + headroom).clamp_min(1e-6)
            diffuse = (grey + (chroma.clamp_max(1.0) + eased) * (diffuse - grey)) * value
            maps = [
                _normals(f.height * (bump * relief)),
                diffuse.clamp(0, 1),
                f.roughness[crop].clamp(0, 1),
                f.specular[crop].clamp(0, 1),
            ]
            parts.append(torch.cat(maps, dim=1))
    return torch.cat(parts), [r.family for r in recipes]


def materials(
    seed: int,
    indices: Sequence[int],
    resolution: int,
    *,
    families: Sequence[str] | None = None,
    mix: float = 0.3,
    family: str | None = None,
    device: torch.device | str | None = None,
) -> tuple[SVBRDF, list[str]]:
    """The maps of samples ``indices`` of ``seed``, batched, and their family names.

    Args:
        families: the families to draw from (default: all of :data:`FAMILIES`).
        mix: probability that a sample blends two materials (named ``"a+b"``).
        family: force this family (or ``"a+b"``) for every sample instead of drawing one.
        device: where the maps are computed and returned (default the CPU); the random
            draws are made on the CPU either way.

    Returns:
        ``(SVBRDF of (B, C, R, R), names)``; float32, values in range, unit normals.
    """
    packed, names = _packed(seed, indices, resolution, families, mix, family, device)
    maps = SVBRDF.unpack(packed, validate=False)
    return SVBRDF(*(t.contiguous() for t in maps.maps().values()), validate=False), names


def material(
    seed: int,
    index: int,
    resolution: int,
    family: str | None = None,
    *,
    families: Sequence[str] | None = None,
    mix: float = 0.3,
) -> tuple[SVBRDF, str]:
    """The maps of one sample (batch of one) and its family name, e.g. ``"tiles"`` or
    ``"stone+metal"``. ``family`` forces the family; see :func:`materials`."""
    svbrdf, names = materials(seed, [index], resolution, families=families, mix=mix, family=family)
    return svbrdf, names[0]


# -- the data set --------------------------------------------------------------------------


class ProceduralMaterials(Dataset):
    """``count`` procedural samples in the common sample layout (:mod:`.sample`).

    Args:
        count: number of samples (indices ``0 .. count - 1``).
        resolution: square size of the maps and the photo, in pixels (any size).
        seed: selects the whole data set; sample ``i`` depends on ``(seed, i)`` only.
        families: families to draw from (default all :data:`FAMILIES`).
        mix: probability that a sample blends two materials through a mask.
        photo: the jitter of the simulated phone photo (default :class:`PhotoSettings`).

    Each item is ``{"input": (3, R, R) linear photo in [0, 1], "maps": (10, R, R),
    "name": "procedural:<seed>:<index>"}``; :meth:`batch` returns the same, stacked.
    """

    def __init__(
        self,
        count: int,
        resolution: int = 256,
        seed: int = 0,
        families: Sequence[str] | None = None,
        mix: float = 0.3,
        photo: PhotoSettings | None = None,
    ):
        count = operator.index(count)
        if count < 0:
            raise DataError(f"count: expected a number of samples >= 0, got {count}")
        if not 0 <= mix <= 1:
            raise DataError(f"mix: expected a probability in [0, 1], got {mix}")
        self.count = count
        self.resolution = _check_resolution(resolution)
        self.seed = operator.index(seed)
        self.families = _check_families(families)
        self.mix = float(mix)
        self.photo = photo or PhotoSettings()

    def __len__(self) -> int:
        return self.count

    def __repr__(self) -> str:
        return (
            f"ProceduralMaterials(count={self.count}, resolution={self.resolution}, seed={self.seed}, "
            f"families={list(self.families)}, mix={self.mix})"
        )

    def family(self, index: int) -> str:
        """The family name of sample ``index`` (cheap: nothing is generated)."""
        i = _check_index(index, self.count)
        return _recipe(self.seed, i, self.families, self.mix, None).family

    def scene(self, index: int) -> Scene:
        """The simulated phone flash that photographs sample ``index``."""
        return photo_scene(self.seed, _check_index(index, self.count), self.photo)

    def jpeg_quality(self, index: int) -> int | None:
        """The JPEG quality of sample ``index``'s photo, or None: not JPEG-compressed."""
        return photo_jpeg_quality(self.seed, _check_index(index, self.count), self.photo)

    def __getitem__(self, index: int) -> dict[str, Any]:
        b = self.batch([index])
        return {"input": b["input"][0], "maps": b["maps"][0], "name": b["name"][0]}

    def __getitems__(self, indices: Sequence[int]) -> list[dict[str, Any]]:
        """What a DataLoader fetches for one batch: generated together (see :meth:`batch`)."""
        b = self.batch(indices)
        return [
            {"input": b["input"][k], "maps": b["maps"][k], "name": b["name"][k]} for k in range(len(indices))
        ]

    def batch(self, indices: Sequence[int], device: torch.device | str | None = None) -> dict[str, Any]:
        """Samples ``indices`` stacked: ``input`` ``(B, 3, R, R)``, ``maps`` ``(B, 10, R, R)``,
        ``name`` a list. The same values as one by one, in less time.

        ``device``: where the maps and photos are computed and returned (default the CPU,
        whose bytes are the reference :data:`GENERATOR_VERSION` tracks). The random draws
        stay on the CPU (they define the distribution), so on any device a sample is the
        same material under the same camera, flash and exposure; an accelerator computes it
        in one pass over the whole batch and one render, with values that differ from the
        CPU's in rounding, and photo noise drawn by the device's own generator from the
        same seed: other noise than the CPU's, the same bytes every time on that device.
        """
        indices = [_check_index(i, self.count) for i in indices]
        device = _device(device)
        packed, _ = _packed(self.seed, indices, self.resolution, self.families, self.mix, None, device)
        scenes = [self.scene(i) for i in indices]
        qualities = [self.jpeg_quality(i) for i in indices]
        # A JPEG comes after the clip and before any gamma: such photos are rendered without
        # their gamma, which _jpeg applies after the round trip.
        gammas = [
            s.effects.get("gamma") if q is not None else None for s, q in zip(scenes, qualities, strict=True)
        ]
        scenes = [
            s if g is None else s.with_effects({k: v for k, v in s.effects.items() if k != "gamma"})
            for s, g in zip(scenes, gammas, strict=True)
        ]
        with torch.no_grad():
            if device.type == "cpu":
                # One render per sample: on the CPU faster than one batched render (_photos).
                photos = torch.cat(
                    [
                        render(SVBRDF.unpack(packed[k : k + 1], validate=False), s)
                        for k, s in enumerate(scenes)
                    ]
                )
            else:
                photos = _photos(packed, scenes)
            photos = _jpeg(photos, qualities, gammas)
        return {
            "input": photos,
            "maps": packed,
            "name": [f"procedural:{self.seed}:{i}" for i in indices],
        }
