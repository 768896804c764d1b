"""The simulated phone flash photo of a training sample: camera, flash, exposure, noise, JPEG.

It photographs the maps of every generated sample, procedural materials
(:mod:`svbrdf_train.data.procedural`) and real material strips (:mod:`svbrdf_train.data.real`)
alike. Each sample's photo is drawn once (:func:`draw_photo`) from its own streams
(:mod:`.seeds`), within the ranges of :class:`PhotoSettings` (named captures:
:data:`CAPTURE_PRESETS`): a camera at a jittered distance held a little off the patch's axis,
a flash offset from the lens and coloured by the white balance, exposure, read and shot noise,
clip, gamma for a share of the photos, and a JPEG round trip for another share.
:func:`photographs` renders the photos of a batch of materials with svbrdf-render.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import torch
from torch import Tensor

from svbrdf_models.errors import DataError
from svbrdf_render import EFFECTS, PHOTO_EFFECTS, SVBRDF, Camera, Flash, Scene, apply_image_effects, render

from .jpeg import jpeg_roundtrip
from .seeds import PHOTO, Stream, key

__all__ = [
    "CAPTURE_PRESETS",
    "Photo",
    "PhotoSettings",
    "draw_photo",
    "photo_jpeg_quality",
    "photo_scene",
    "photographs",
]


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
    flash_offset_min: float = 0.0
    """Smallest distance of the flash from the lens (half-widths): with a positive value the
    flash is drawn uniformly over the ring between it and ``flash_offset``, as a phone's LED,
    which always sits beside the lens. 0: the disc."""
    beam_exponent: tuple[float, float] | None = None
    """Range of the flash beam's ``cos^exponent`` fall-off (the renderer's ``beam`` effect,
    aimed at the patch centre), drawn uniformly; None: no beam (an ideal point light)."""
    vignetting: tuple[float, float] | None = None
    """Range of the lens's vignetting strength (the renderer's ``vignetting`` effect: 1 is the
    full ``cos^4``), drawn uniformly; None: none."""
    tone_power: tuple[float, float] | None = None
    """Range of the residual tone curve's power (the renderer's ``tone`` effect: what a phone's
    curve leaves in a photo linearised as sRGB), drawn log-uniformly; None: no tone effect."""
    tone_shoulder: tuple[float, float] = (0.0, 0.0)
    """Range of the tone curve's highlight shoulder (uniform); used with ``tone_power``."""

    def __post_init__(self):
        self._check_phone_ranges()
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

    def _check_phone_ranges(self) -> None:
        limits = {"beam_exponent": (0.0, 1000.0), "vignetting": (0.0, 1.0), "tone_power": (0.25, 4.0),
                  "tone_shoulder": (0.0, 20.0)}
        for name, (lo, hi) in limits.items():
            value = getattr(self, name)
            if value is None:
                continue
            ok = len(value) == 2 and all(isinstance(v, (int, float)) and math.isfinite(v) for v in value)
            if not (ok and lo <= value[0] <= value[1] <= hi):
                raise DataError(
                    f"PhotoSettings.{name}: expected (low, high) with {lo} <= low <= high <= {hi}, "
                    f"got {value}"
                )
        if not 0 <= self.flash_offset_min <= self.flash_offset:
            raise DataError(
                f"PhotoSettings.flash_offset_min: expected 0 <= flash_offset_min <= flash_offset "
                f"({self.flash_offset}), got {self.flash_offset_min}"
            )

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
#:
#: ``handheld``: ``phone`` plus what a phone's flash and camera do that the fitted flashes
#: leave out (issue 46): the LED 0.08-0.3 half-widths beside the lens (about 1 cm on a patch
#: 7-12 cm wide), its beam ``cos^0-6`` (half power from 29 degrees off its axis to none), the
#: camera up to 0.6 half-widths off the patch's axis (the highlight anywhere in the central
#: half; at distance 2.3 that is a tilt of up to 15 degrees aimed at the centre, which the beam
#: and vignetting follow), vignetting up to 0.6 of the ``cos^4``, a residual tone curve (power
#: 0.85-1.2, highlight shoulder 0-1.5), white balance within 10%, exposure 0 to +1 EV, des18's
#: noise (a phone denoises what a wider range would add) and half of the photos JPEG at
#: quality 80-95. Measured against DATA/real-dev's photos (``benchmarks/phone_capture.py``):
#: the beam and the tone curve bring the photos' fall-off and level towards real phone
#: photos'; real photos fall off faster and are brighter than a first setting's (beam
#: ``cos^0-4``, -0.25 to +0.75 EV), and JPEG at 70-95 on 80% of the photos made them blockier
#: than real ones (saved at full size, then cropped and resized), hence these ranges. Its draws
#: come from a stream of their own: the other presets' photos are what they were.
_PHONE: dict[str, Any] = {
    "distance": (1.8, 3.7),
    "intensity": (10.0, 21.0),
    "exposure_ev": (0.0, 0.5),
    "white_balance": 0.08,
    "jpeg_probability": 0.5,
    "jpeg_quality": (75, 95),
}
CAPTURE_PRESETS: dict[str, dict[str, Any]] = {
    "des18": {},
    "phone": _PHONE,
    "handheld": {
        **_PHONE,
        "exposure_ev": (0.0, 1.0),
        "white_balance": 0.1,
        "jpeg_quality": (80, 95),
        "flash_offset": 0.3,
        "flash_offset_min": 0.08,
        "camera_shift": (0.0, 0.6),
        "beam_exponent": (0.0, 6.0),
        "vignetting": (0.0, 0.6),
        "tone_power": (0.85, 1.2),
        "tone_shoulder": (0.0, 1.5),
    },
}


def _capture_draws(seed: int, index: int, s: PhotoSettings) -> tuple[float | None, Tensor | None, int | None]:
    """The draws of a photo beyond the des18 ones, from a stream of their own (so that the
    des18 draws, and photos under the default settings, stay what they were): the flash
    intensity (None: ``pi * d^2``), the flash colour (None: white) and the JPEG quality
    (None: no JPEG). Each is drawn whatever the settings, so one setting never moves another's
    draw."""
    e = Stream(key(seed, index, PHOTO, 1))
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


def _handheld_effects(seed: int, index: int, s: PhotoSettings) -> list[Any]:
    """The declared beam, vignetting and tone of a photo under ``s`` (none under the presets
    without them), drawn from a stream of their own so that the other draws stay put."""
    h = Stream(key(seed, index, PHOTO, 2))
    u_beam, u_vignetting, u_power, u_shoulder = h.uniform(), h.uniform(), h.uniform(), h.uniform()
    out: list[Any] = []
    if s.beam_exponent is not None:
        low, high = s.beam_exponent
        out.append({"beam": {"exponent": low + (high - low) * u_beam}})
    if s.vignetting is not None:
        low, high = s.vignetting
        out.append({"vignetting": {"strength": low + (high - low) * u_vignetting}})
    if s.tone_power is not None:
        low, high = math.log(s.tone_power[0]), math.log(s.tone_power[1])
        lo_s, hi_s = s.tone_shoulder
        power, shoulder = math.exp(low + (high - low) * u_power), lo_s + (hi_s - lo_s) * u_shoulder
        out.append({"tone": {"power": power, "shoulder": shoulder}})
    return out


class Photo(NamedTuple):
    """The drawn photo of one sample (:func:`draw_photo`): what :func:`photographs` makes of it."""

    #: The camera, the flash and the effects the maps are rendered under.
    scene: Scene
    #: The quality of the photo's JPEG round trip; None: it is not JPEG-compressed.
    jpeg_quality: int | None


def draw_photo(seed: int, index: int, settings: PhotoSettings | None = None) -> Photo:
    """The simulated phone flash photo of sample ``index``: camera, flash and effects, and the
    JPEG quality, each stream drawn once.

    A camera at the height its jittered field of view frames the patch from (or at a drawn
    ``settings.distance``, with the field of view that frames the patch from there), shifted
    off the patch's axis by ``settings.camera_shift`` (the image still covers the patch), a
    flash of intensity ``pi * distance^2`` (or drawn from ``settings.intensity``) offset a
    little from the lens, white or coloured by ``settings.white_balance``, and exactly these
    effects: :data:`svbrdf_render.PHOTO_EFFECTS` (the Des18 shading, exposure, noise seeded
    from ``(seed, index)`` so that the photo reproduces, clip), and gamma only for the
    ``settings.gamma_probability`` share of photos. The JPEG round trip is no effect of the
    renderer: ``jpeg_quality`` says whether the photo gets it (the
    ``settings.jpeg_probability`` share does).

    Tilt is not drawn: the renderer's image is the patch itself (pixel ``p`` shows surface
    point ``p``), so a phone tilted to keep the patch in frame differs from one shifted
    off-axis (``camera_shift``, up to 0.3: 8 degrees at 2.2) only by the keystone warp of an
    unrectified photo, which the maps would have to share and which real captures crop away.
    """
    s = settings or PhotoSettings()
    d = Stream(key(seed, index, PHOTO))
    if s.distance is None:
        fov = d.uniform(*s.fov)
        distance = 1.0 / math.tan(math.radians(fov) / 2)
    else:  # the same one draw, so the draws after it stay those of the des18 settings
        distance = d.log_uniform(*s.distance)
        fov = 2 * math.degrees(math.atan(1.0 / distance))
    u_radius = d.uniform()
    if s.flash_offset_min > 0:  # uniform over the ring between the two radii
        low2 = s.flash_offset_min * s.flash_offset_min
        radius = math.sqrt(low2 + (s.flash_offset * s.flash_offset - low2) * u_radius)
    else:
        radius = s.flash_offset * math.sqrt(u_radius)  # uniform over the disc
    cs, sn = d.angle()
    ev, sigma, shot = d.uniform(*s.exposure_ev), d.uniform(*s.noise_sigma), d.uniform(*s.noise_shot)
    noise_seed = d.seed()
    gamma = d.chance(s.gamma_probability)
    shift = d.uniform(*s.camera_shift)
    shift_cos, shift_sin = d.angle()
    drawn = {"exposure": {"ev": ev}, "noise": {"sigma": sigma, "shot": shot, "seed": noise_seed}}
    effects: list[Any] = [{name: drawn[name]} if name in drawn else name for name in PHOTO_EFFECTS]
    effects += _handheld_effects(seed, index, s)
    if gamma:
        effects.append({"gamma": {"gamma": s.gamma}})
    camera = Camera(torch.tensor([shift * shift_cos, shift * shift_sin, distance]), fov)
    intensity, color, quality = _capture_draws(seed, index, s)
    if intensity is None:
        intensity = math.pi * distance * distance
    offset = torch.tensor([radius * cs, radius * sn, 0.0])
    flash = Flash(intensity, offset) if color is None else Flash(intensity, offset, color)
    return Photo(Scene(camera, (flash,), effects), quality)


def photo_scene(seed: int, index: int, settings: PhotoSettings | None = None) -> Scene:
    """The scene of sample ``index``'s photo (:func:`draw_photo`): camera, flash and effects."""
    return draw_photo(seed, index, settings).scene


def photo_jpeg_quality(seed: int, index: int, settings: PhotoSettings | None = None) -> int | None:
    """The JPEG quality of sample ``index``'s photo (:func:`draw_photo`), or None when it is not
    JPEG-compressed; it reads only the stream that holds the quality."""
    return _capture_draws(seed, index, settings or PhotoSettings())[2]


#: The image stages :func:`_photos` runs per photo, read from the renderer's registry: its
#: ``image`` phase, in its order, but for the stages that read the camera (vignetting, the first
#: of the phase), which run in the batched render with the shading.
_IMAGE_STAGES = tuple(name for name, e in EFFECTS.items() if e.phase == "image" and not e.needs_camera)
#: The image stages every photo scene declares (exposure, noise, clip).
_PHOTO_IMAGE_STAGES = frozenset(name for name in PHOTO_EFFECTS if name in _IMAGE_STAGES)


def _shading(effects: dict) -> dict:
    """What :func:`_photos` renders in one batch: ``effects`` but its per-photo image stages."""
    return {name: params for name, params in effects.items() if name not in _IMAGE_STAGES}


def _batchable(scenes: Sequence[Scene]) -> bool:
    """Whether :func:`_photos` can render ``scenes`` together: photo scenes (one flash, a
    camera at a finite position) with the same shading and no image stage but its own."""
    shading = _shading(scenes[0].effects)
    return all(
        len(s.lights) == 1
        and isinstance(s.lights[0], Flash)
        and s.camera.directional is False
        and s.camera.position.shape == (3,)
        and s.lights[0].intensity.dim() == 0
        and s.lights[0].color.shape == (3,)
        and _PHOTO_IMAGE_STAGES <= set(s.effects)
        and _shading(s.effects) == shading
        for s in scenes
    )


def _photos(packed: Tensor, scenes: Sequence[Scene]) -> Tensor:
    """The photos ``(B, 3, R, R)`` of the materials ``packed`` ``(B, 10, R, R)``, sample ``k``
    under ``scenes[k]`` (from :func:`draw_photo`), in one render on the maps' device.

    The cameras and flashes become per-sample configurations of one scene (shape ``(B, 1)``)
    for the shading, the costly part; each photo's exposure, noise, clip and gamma then run
    through the renderer's own image stages (:func:`svbrdf_render.apply_image_effects`), noise
    seeded from its scene as :func:`render` seeds it. So each photo is what
    ``render(maps[k], scenes[k])`` makes on that device (on the CPU the very bytes: tested;
    to rounding where the flashes' colours differ, which the shading then takes as white and
    a gain of each photo after it, the same product in another order).
    Used on accelerators, where one render of ``B`` samples replaces ``B`` renders of small
    kernels; :func:`photographs` keeps one render per sample on the CPU, where that is faster
    (8 photos at 256 px on one thread: 46 ms one by one, 75 ms batched, which spills the caches).
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
    x = render(svbrdf, Scene(camera, (flash,), _shading(scenes[0].effects)))
    if not one_color:  # the renderer takes one colour per light; radiance is linear in it
        x = x * colors.to(x.device, x.dtype).view(b, 1, 3, 1, 1)
    # Each photo's own image stages, by the renderer's own code (they need no geometry).
    photos = []
    for k, s in enumerate(scenes):
        stages = {name: v for name, v in s.effects.items() if name in _IMAGE_STAGES}
        photos.append(apply_image_effects(x[k : k + 1], stages))
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
            out[j : j + 1] = apply_image_effects(out[j : j + 1], {"gamma": gammas[k]})
    return photos.index_copy(0, where, out)


def photographs(packed: Tensor, photos: Sequence[Photo]) -> Tensor:
    """The photos ``(B, 3, R, R)`` of the materials ``packed`` ``(B, 10, R, R)``, on their
    device: photo ``k`` rendered under ``photos[k].scene``, then through the JPEG round trip at
    ``photos[k].jpeg_quality`` (None: none), ``photos`` as :func:`draw_photo` draws them.

    On the CPU one render per sample: there faster than one batched render, and the bytes
    :data:`~svbrdf_train.data.procedural.GENERATOR_VERSION` tracks; on another device one render
    of the batch (:func:`_photos`).
    """
    # A JPEG comes after the clip and before any gamma: such photos are rendered without
    # their gamma, which _jpeg applies after the round trip.
    qualities = [p.jpeg_quality for p in photos]
    gammas = [p.scene.effects.get("gamma") if p.jpeg_quality is not None else None for p in photos]
    scenes = [p.scene for p in photos]
    scenes = [
        s if g is None else s.with_effects({k: v for k, v in s.effects.items() if k != "gamma"})
        for s, g in zip(scenes, gammas, strict=True)
    ]
    with torch.no_grad():
        if packed.device.type == "cpu":
            x = torch.cat(
                [render(SVBRDF.unpack(packed[k : k + 1], validate=False), s) for k, s in enumerate(scenes)]
            )
        else:
            x = _photos(packed, scenes)
        return _jpeg(x, qualities, gammas)
