"""A network's maps refined against their photo (inverse rendering), and how well each explains it.

The network sees the photo at its training resolution; :func:`refine_prediction` then runs
:func:`svbrdf_render.refine_maps` at the photo's own resolution, starting from the network's
maps and pulled toward them (start = prior = the network's maps, without their 2-pixel
pattern and without the flash's ring around the photo's highlight: :func:`svbrdf_render.refinement.rings.dering`)::

    from svbrdf_models.capture.refining import refine_prediction, rerender, rerender_rmse
    result = refine_prediction(photo, network_maps, 100)      # a svbrdf_render.Refinement
    rmse = rerender_rmse(rerender(result.svbrdf, result.scene), photo)   # (B,)

:meth:`svbrdf_models.TrainedModel.predict` (``refine=STEPS``) and the photo tool
(:mod:`svbrdf_models.capture.one`, ``--refine``) both go through it.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import time
from collections.abc import Callable

import torch
from torch import Tensor

from svbrdf_render import BACKENDS as RENDER_BACKENDS
from svbrdf_render import (
    MIN_REFINE_SIDE,
    SVBRDF,
    RefineSettings,
    Refinement,
    Scene,
    refine_maps,
    refine_start,
    render,
)
from svbrdf_render.compare import per_sample_rmse
from svbrdf_render.metalrough import DIELECTRIC_F0  # glTF's F0 of every non-metal: metallic 0
from svbrdf_render.refinement.fit import axis_flash
from svbrdf_render.refinement.rings import dering, highlight_point

from ..errors import DataError

__all__ = [
    "without_checkerboard",
    "BACKEND",
    "BACKENDS",
    "COMPILE_PIXELS",
    "pick_backend",
    "DEFAULT_MAP_SIZE",
    "FULL",
    "check_refine_memory",
    "refine_cost",
    "refine_map_size",
    "MAX_UNTIMED_REFINE", "check_refine", "load_scene", "refine_prediction", "rerender", "rerender_rmse",
    "AFTER_REFINE_SECONDS_PER_PIXEL", "seconds_left", "steps_seconds",
    "METALS", "as_dielectric", "check_metal"]

#: The renderer backend the photo tools refine with. ``"auto"``: ``compiled`` for photos of at
#: least :data:`COMPILE_PIXELS` pixels, ``eager`` below. Measured on 2 CPU cores, 100 steps
#: (``benchmarks/refine_speed.py``): 256 px eager 1.5 s, compiled 1.2 s after a compile of about
#: 4 s (warm cache; ~20 s cold); 1024 px eager 27 s, compiled 19 s.
BACKEND = "auto"
#: Photos with at least this many pixels are refined with the compiled renderer under ``"auto"``.
COMPILE_PIXELS = 512 * 512
#: What ``--backend`` takes.
BACKENDS = ("auto", *RENDER_BACKENDS)


#: The side refined maps are made at when the photo's square is larger (``--map-size`` sets
#: another, ``--map-size full`` the square's own). A refinement holds about
#: :data:`REFINE_BYTES_PER_PIXEL` a pixel and its time grows with the pixels: at 1024 px about
#: 1.5 GB and 25 s for the default 100 steps on 2 CPU cores, where a 12-megapixel phone photo's
#: 3000 px square would need 13 GB and minutes. 1024 px is more detail than the network's
#: 128 px gives and what texture tools commonly take.
DEFAULT_MAP_SIZE = 1024
#: ``--map-size full``: refine at the photo's square's own side.
FULL = "full"
#: Peak memory of a refinement per pixel of its maps (measured on the CPU, eager renderer:
#: 1.2-1.4 KB from 512 to 1024 px, plus the model and the photo), and its time per pixel and
#: step on 2 idle CPU cores (256 px 1.5 s, 1024 px 19-27 s for 100 steps:
#: ``benchmarks/refine_speed.py``). Estimates, to warn and refuse, not to promise.
REFINE_BYTES_PER_PIXEL = 1400
REFINE_SECONDS_PER_PIXEL_STEP = 2.6e-7
#: The stages of a captured photo after its refinement (re-renderings, the comparison figure,
#: the relit preview, the maps and files written), per pixel of the maps: what a photo's time
#: budget (``--refine-seconds``) keeps back for them. Measured on one busy core: 7.4 s at
#: 1024 px, 32 s at 2048 px, most of it writing the PNGs.
AFTER_REFINE_SECONDS_PER_PIXEL = 7e-6


def seconds_left(seconds: float | None, since: float) -> float | None:
    """What is left of a time budget of ``seconds`` counted from ``since`` (``time.monotonic()``),
    at least 0; None for no budget."""
    return None if seconds is None else max(0.0, seconds - (time.monotonic() - since))


def steps_seconds(seconds: float | None, since: float, pixels: int, photo: bool) -> float | None:
    """The steps' own budget (:func:`svbrdf_render.refine_maps`'s ``seconds``): what is left of
    ``seconds`` since ``since``, less :data:`AFTER_REFINE_SECONDS_PER_PIXEL` when the budget is a
    captured ``photo``'s; 0, no step, when that cannot hold the first step (about two steps'
    worth: a step, once begun, ends)."""
    left = seconds_left(seconds, since)
    if left is None:
        return None
    left -= pixels * AFTER_REFINE_SECONDS_PER_PIXEL if photo else 0.0
    return left if left >= 2 * pixels * REFINE_SECONDS_PER_PIXEL_STEP else 0.0


#: ``--metal`` (``metal=``): ``auto``, the maps say where the material is a metal (the network,
#: then the refinement); ``none``, it is a dielectric (plastic, paint, wood, stone, fabric): the
#: specular albedo F0 is the grey 0.04 (:data:`svbrdf_render.metalrough.DIELECTRIC_F0`) at every
#: pixel, metallic 0 in the metal/rough maps, and the refinement holds it there
#: (``RefineSettings(hold=("specular",))``).
METALS = ("auto", "none")


def check_metal(metal) -> str:
    """``metal`` when it is one of :data:`METALS`, else a :class:`DataError` (one line)."""
    if not isinstance(metal, str) or metal not in METALS:
        raise DataError(
            f"metal must be auto (the maps say where the material is a metal) or none (it is no metal: "
            f"specular 0.04 grey everywhere), got {metal!r}"
        )
    return metal


def as_dielectric(maps: SVBRDF) -> SVBRDF:
    """``maps`` with the specular albedo of a dielectric, the grey 0.04, at every
    pixel (metallic 0 once converted to metal/rough); normal, diffuse and roughness kept."""
    specular = torch.full_like(maps.specular, DIELECTRIC_F0)
    return SVBRDF(maps.normal, maps.diffuse, maps.roughness, specular, validate=False)


def refine_map_size(side: int, map_size: int | str | None) -> int:
    """The side refined maps are made at for a square of ``side`` px: ``map_size`` when given,
    the square's own for :data:`FULL`, else ``side`` bounded by :data:`DEFAULT_MAP_SIZE`."""
    if map_size == FULL:
        return int(side)
    if map_size is not None:
        return int(map_size)
    return min(int(side), DEFAULT_MAP_SIZE)


def refine_cost(size: int, steps: int) -> tuple[float, int]:
    """``(seconds, bytes)``: about what refining ``size`` px maps for ``steps`` steps takes."""
    pixels = int(size) * int(size)
    return pixels * steps * REFINE_SECONDS_PER_PIXEL_STEP, pixels * REFINE_BYTES_PER_PIXEL


def check_refine_memory(size: int, steps: int, where: str, *, count: int = 1, remedy: str | None = None) -> None:
    """Refuse (:class:`DataError`, one line naming ``where``) refining ``count`` maps of ``size``
    px at once when this machine's free memory cannot hold it; ``remedy`` says what to do (the
    command line's by default)."""
    from svbrdf_render.plumbing import machine

    need = refine_cost(size, steps)[1] * count
    free = machine.available_memory()
    if free is not None and need > free:
        default = refine_cost(DEFAULT_MAP_SIZE, steps)[1] / 2**30
        what = f"{count} x {size} px maps" if count > 1 else f"{size} px maps"
        raise DataError(
            f"{where}: refining {what} needs about {need / 2**30:.1f} GB, and this machine has "
            f"{free / 2**30:.1f} GB free; "
            + (remedy or f"give a smaller --map-size (the default, {DEFAULT_MAP_SIZE}, needs about {default:.1f} GB) or --refine 0")
        )


def pick_backend(backend: str, height: int, width: int) -> str:
    """The renderer backend of ``backend`` (one of :data:`BACKENDS`) for an ``height x width`` photo."""
    if backend not in BACKENDS:
        raise DataError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if backend != "auto":
        return backend
    return "compiled" if height * width >= COMPILE_PIXELS else "eager"


#: The most refinement steps run without a time limit (``--refine-seconds``, ``seconds=``):
#: about 7 h at 1024 px on 2 CPU cores (:data:`REFINE_SECONDS_PER_PIXEL_STEP`), a thousand times
#: the default 100. More steps must come with seconds, which then bound the run.
MAX_UNTIMED_REFINE = 100_000


def check_refine(refine, seconds=None) -> int:
    """``refine`` as a number of steps: an integer >= 0 (not a bool), at most
    :data:`MAX_UNTIMED_REFINE` unless ``seconds`` bounds the run; ``seconds`` None or a finite
    number >= 0. A :class:`DataError` (one line) otherwise."""
    if isinstance(refine, bool) or not isinstance(refine, numbers.Integral) or refine < 0:
        raise DataError(
            f"refine must be a whole number of refinement steps >= 0 (0: the network's maps "
            f"only), got {refine!r}"
        )
    if seconds is not None and (
        isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not math.isfinite(seconds)
        or seconds < 0
    ):  # fmt: skip
        raise DataError(f"refine seconds must be a finite number >= 0 (or None), got {seconds!r}")
    if seconds is None and refine > MAX_UNTIMED_REFINE:
        raise DataError(
            f"refine {refine} steps with no time limit: at most {MAX_UNTIMED_REFINE} steps run without "
            "one; give fewer steps, or seconds (--refine-seconds S; seconds= in Python) to stop it"
        )
    return int(refine)


def load_scene(path) -> Scene:
    """The scene file ``path`` for refining one photo (``--scene``), refused in one line naming
    it (a :class:`~svbrdf_render.SceneError`) when it cannot be read or is not one camera and one
    view (configuration shape ``()`` or ``(1, 1)``): what :func:`svbrdf_render.refine_maps` says
    of it, asked at once on a 1-pixel photo."""
    from svbrdf_render import SceneError, SVBRDFError

    scene = Scene.load(path)  # a SceneError naming the file when it cannot be read or parsed
    try:
        refine_maps(torch.zeros(1, 3, 1, 1), SVBRDF.constant(1, 1), scene=scene, steps=0)
    except SVBRDFError as e:
        raise SceneError(f"--scene {path}: {e}") from None
    return scene


def without_checkerboard(maps: SVBRDF) -> SVBRDF:
    """``maps`` with a binomial ``[1, 2, 1] / 4`` filter applied in each direction (edges
    replicated; normals renormalised): its response is 0 at a 2-pixel period, so the pattern
    transposed convolutions leave at the network's resolution is gone, while coarser detail
    is kept (the response is 0.5 at a 4-pixel period). The start and prior of a refinement of
    network maps, which would otherwise pull the refined maps back toward the pattern."""
    import torch.nn.functional as F

    k = torch.tensor([0.25, 0.5, 0.25], dtype=maps.dtype, device=maps.device)
    kernel = (k[:, None] * k[None, :])[None, None]

    def smooth(t: Tensor) -> Tensor:
        c = t.shape[1]
        padded = F.pad(t, (1, 1, 1, 1), mode="replicate")
        return F.conv2d(padded, kernel.expand(c, 1, 3, 3), groups=c)

    return maps.filtered(smooth)


def refine_prediction(
    photo: Tensor,
    start: SVBRDF,
    steps: int,
    *,
    seconds: float | None = None,
    scene: Scene | None = None,
    callback: Callable[[int, int, float], None] | None = None,
    backend: str = BACKEND,
    held: tuple[Tensor, SVBRDF] | None = None,
    camera: Tensor | None = None,
    metal: str = "auto",
    highlight: Tensor | None = None,
    began: float | None = None,
) -> Refinement:
    """Refine ``start`` (a network's maps, any size) against ``photo`` at the photo's size.

    Args:
        photo: ``(B, 3, H, W)`` linear photos (the squares the maps are of), ``H, W >=``
            :data:`svbrdf_render.MIN_REFINE_SIDE`.
        start: a network's maps of B materials; without their 2-pixel pattern
            (:func:`without_checkerboard`) and their ring around the photo's highlight
            (:func:`svbrdf_render.refinement.rings.dering`), the start and the prior of the refinement.
        steps, seconds, began: at most ``steps`` steps, all of this call in about ``seconds`` (from
            ``began``, a photo's start, when given): the steps get what is left (:func:`steps_seconds`).
        scene: the capture (default: :func:`svbrdf_render.refinement.fit.axis_flash` over the photo's
            highlight, or over its centre when it shows none).
        callback: ``callback(step, total, loss)`` after each step.
        backend: the renderer's backend (:data:`BACKEND` by default).
        held: ``(mask (B or 1, 1, H, W), maps)``: a reference card's pixels (:func:`svbrdf_models.
            capture.reference.pin_flash`), held at its maps and ignored by the highlight finder.
        camera: ``(3,)`` or ``(B, 3)``: where camera and flash stood (:mod:`svbrdf_models.capture.geometry`):
            the default scene's place, instead of over the highlight (which still centres the rings).
        metal: one of :data:`METALS`; ``"none"``: the maps are refined as a dielectric's, specular
            held at 0.04 (:func:`as_dielectric`), not a free parameter.
        highlight: ``(B, 2)``: the point under the flash when the caller found it already
            (:func:`svbrdf_render.refinement.rings.find_highlight`, with ``held``'s mask ignored).

    The refinement runs on ``start``'s device with gradients on (also under ``torch.no_grad`` or
    ``torch.inference_mode``); the :class:`~svbrdf_render.Refinement` comes back on the CPU.
    """
    steps, since = check_refine(steps, seconds), time.monotonic() if began is None else began
    dielectric = check_metal(metal) == "none"
    photo = _refinable(photo)
    (h, w), device = photo.shape[-2:], start.device
    # Gradients on, even under torch.no_grad or torch.inference_mode (whose tensors are copied
    # into ordinary ones: autograd cannot save inference tensors for the backward pass).
    with torch.inference_mode(False), torch.enable_grad():
        photo = photo.detach().to(device, torch.float32).clone()
        start, point = _start(photo, start, dielectric, None if held is None else held[0], highlight)
        if scene is None:  # the flash at the camera, else over the highlight (the centre when none)
            scene = axis_flash(start, photo, over=point, position=camera)
        result = refine_maps(
            photo, start, scene=scene.to(device), steps=steps, callback=callback, held=held,
            seconds=steps_seconds(seconds, since, photo.numel() // 3, began is not None),
            backend=pick_backend(backend, h, w), highlight=None if camera is None else point,  # None: light's
            settings=RefineSettings(hold=("specular",)) if dielectric else None,
        )  # fmt: skip
    maps = as_dielectric(result.svbrdf) if dielectric else result.svbrdf  # 0.04 exactly, not its logit's
    return dataclasses.replace(result, svbrdf=maps.to("cpu"), scene=result.scene.to("cpu"))


def _start(photo: Tensor, start: SVBRDF, dielectric: bool, ignore: Tensor | None, point: Tensor | None):
    """``(start, point)``: a refinement's start, a copy of ``start`` (a dielectric's with
    ``dielectric``) without its 2-pixel pattern and its ring around the point under the flash,
    at the photo's size; and that point (``point``, else found on ``photo``, ``ignore`` left out)."""
    copy = SVBRDF(**{k: t.detach().clone() for k, t in start.maps().items()}, validate=False)
    copy = as_dielectric(copy) if dielectric else copy
    point = point if point is not None else highlight_point(photo, ignore=ignore)
    start = dering(without_checkerboard(copy), point.to(copy.device))
    return refine_start(start, tuple(photo.shape[-2:])), point  # once: refine_maps takes it as it is


def _refinable(photo: Tensor) -> Tensor:
    """``photo`` as a batch, refused (:class:`DataError`) when too small to refine against."""
    photo = photo[None] if photo.dim() == 3 else photo
    h, w = photo.shape[-2:]
    if min(h, w) < MIN_REFINE_SIDE:
        raise DataError(
            f"the photo is {w}x{h}, smaller than {MIN_REFINE_SIDE} px: too few pixels to refine "
            "maps against; give a larger photo, or refine 0 (the network's maps only)"
        )
    return photo


@torch.no_grad()
def rerender(svbrdf: SVBRDF, scene: Scene, size: tuple[int, int] | None = None) -> Tensor:
    """``(B, 3, H, W)`` rendering of ``svbrdf`` (brought to ``size`` first, as a refinement's
    start is) under ``scene`` (one view), clipped to [0, 1] as a camera saturates."""
    if size is not None:
        svbrdf = refine_start(svbrdf, tuple(size))
    image = render(svbrdf.detach().to(torch.float32), scene.to(svbrdf.device))
    if image.dim() == 5:  # (B, 1, 3, H, W): one configuration per material
        image = image[:, 0]
    return image.clamp(0, 1)


def rerender_rmse(rendering: Tensor, photo: Tensor) -> Tensor:
    """``(B,)`` RMSE of clipped renderings against linear photos ``(B, 3, H, W)``."""
    photo = photo[None] if photo.dim() == 3 else photo
    return per_sample_rmse(rendering, photo.to(rendering).clamp(0, 1))
