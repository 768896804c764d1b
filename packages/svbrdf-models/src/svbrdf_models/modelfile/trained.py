"""A trained generator ready to predict: :class:`TrainedModel`, what :func:`svbrdf_models.load_model`
returns (and svbrdf-train's ``Predictor`` is, for training checkpoints too).

::

    maps = model.predict(photo)                 # (3, H, W) linear photo -> SVBRDF of one
    maps = model.predict(photo, refine=150)     # + refined against the photo, at its size
    maps = model.predict_batch(squares)         # (N, 3, S, S) at a size the generator takes

Photos are linear float tensors; the network sees the largest centred square of each
(:func:`~svbrdf_models.capture.photos.square_photo`), resized to the resolution the generator was trained at.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from svbrdf_render import SVBRDF

from ..capture.photos import square_photo

__all__ = ["TrainedModel"]


#: Largest value a photo may hold (linear values are in [0, 1]; a little over 1 is rounding or
#: a highlight a resize overshot), and how far below 0 noise may take it.
_MAX_VALUE, _VALUE_SLACK = 1.05, 0.05
#: The shortest photo side predict takes (the smallest size any network here trains at).
_MIN_PHOTO_SIDE = 8
#: Below this short side predict warns that the photo gives little: the command line's least
#: (:data:`svbrdf_models.capture.photos.MIN_SIDE`, which refuses smaller photos).
SMALL_PHOTO_SIDE = 64


@dataclass
class TrainedModel:
    """A trained generator (eval mode, float32) and what its file says about it.

    ``sha256`` is the model file's (None for weights not read from a model file: a training
    checkpoint, in svbrdf-train); ``provenance["steps"]`` the training steps behind the weights.
    """

    generator: nn.Module
    name: str
    config: dict[str, Any]
    resolution: int
    precision: str
    source: str
    sha256: str | None
    recipe: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)
    metrics: dict[str, float] = field(default_factory=dict)

    @property
    def steps(self) -> int:
        return int(self.provenance.get("steps", 0))

    @property
    def device(self) -> torch.device:
        return next(self.generator.parameters()).device

    def to(self, device: str | torch.device) -> TrainedModel:
        self.generator.to(device)
        return self

    def predict(
        self,
        photo: Tensor,
        refine: int = 0,
        *,
        seconds: float | None = None,
        scene=None,
        callback=None,
        backend: str | None = None,
        reference=None,
        metal: str = "auto",
    ) -> SVBRDF:
        """Maps of linear photos: ``(3, H, W)`` (one material) or ``(N, 3, H, W)``.

        The photo contract: a float tensor of *linear* values in ``[0, 1]`` (radiance as the
        sensor saw it, not sRGB-encoded), RGB channels first, any size of at least a few
        pixels (under 64 px on the short side, a ``UserWarning``: that gives little to read a
        material from); the largest centred square is used. :func:`svbrdf_models.load_photo` turns a
        JPEG or PNG file into exactly that (``load_photo(path)[0]``; ``linear=True`` for files
        that hold linear values). Integer codes, values outside ``[0, 1]`` (a photo still in
        0-255, or negative values), NaN and empty tensors are refused with one line
        (:class:`~svbrdf_models.errors.DataError`), never guessed at.

        ``refine=0``: the largest centred square is resized to :attr:`resolution` (antialiased,
        on linear values) when it is not that size already; the maps are at :attr:`resolution`.

        ``refine=STEPS > 0``: the network's maps of that square are then refined against the
        square at its own resolution (:func:`svbrdf_models.capture.refining.refine_prediction`, start
        and prior the network's maps) for at most STEPS steps, and in about ``seconds`` seconds
        all told (the network, the refinement's start, its steps: they get what is left), under
        ``scene`` (default: the flash found from the network's maps), with the renderer's
        ``backend`` (default :data:`svbrdf_models.capture.refining.BACKEND`); ``callback(step, total,
        loss)`` follows it. The maps are at the square's size (the photo's shorter side), which
        must be at least :data:`svbrdf_render.MIN_REFINE_SIDE`; a refinement this machine's
        free memory cannot hold (about 1.4 KB a pixel) is refused before it starts.

        ``reference``: a matte card of known albedo in one photo, ``"X,Y,W,H:ALBEDO"`` in its
        pixels (or a :class:`~svbrdf_models.capture.reference.Reference`): the flash measured on
        it (:func:`~svbrdf_models.capture.reference.pin_flash`), the network shown the photo
        without it, the refinement run under that flash with the card held; not with ``scene``.
        ``metal="none"``: the material is no metal: specular F0 0.04 grey everywhere (metallic 0),
        and a refinement held to it (:data:`~svbrdf_models.capture.refining.METALS`).

        ``refine`` is 0 by default here: the network alone, what a caller in a loop wants.
        ``svbrdf-models predict`` refines by default
        (:data:`svbrdf_render.DEFAULT_REFINE_STEPS` steps, at most 1024 px): give
        ``refine=100`` for the command line's maps.
        """
        batch = self._check_photo(photo)
        _warn_if_small(batch, str(self.source))
        from ..capture.refining import as_dielectric, check_metal, check_refine

        steps, how = check_refine(refine, seconds), (seconds, scene, callback, backend, check_metal(metal))
        if reference is not None:
            return self._predict_with_reference(batch, steps, reference, *how)
        if steps == 0:
            return self._network(batch) if metal == "auto" else as_dielectric(self._network(batch))
        return self._refined(batch, steps, *how)

    def _refined(self, batch, steps, seconds, scene, callback, backend, metal) -> SVBRDF:
        """:meth:`predict` refined, without a reference (see there)."""
        from ..capture.refining import BACKEND, check_refine_memory, refine_prediction, seconds_left

        began, side = time.monotonic(), min(batch.shape[-2:])  # seconds covers the network too
        remedy = "resize the photo smaller first, or refine=0"
        check_refine_memory(side, steps, str(self.source), count=batch.shape[0], remedy=remedy)
        squares = torch.stack([square_photo(p.float(), None) for p in batch])
        network = self._network(squares).to(self.device)
        result = refine_prediction(
            squares, network, steps, seconds=seconds_left(seconds, began), scene=scene,
            callback=callback, backend=backend or BACKEND, metal=metal,
        )  # fmt: skip
        return result.svbrdf

    def _predict_with_reference(self, batch, steps, reference, seconds, scene, callback, backend,
                                metal="auto") -> SVBRDF:  # fmt: skip
        """:meth:`predict` with a reference card (see there)."""
        from ..capture.reference import Reference, fill_card, pin_flash, reference_mask
        from ..capture.refining import (
            BACKEND, as_dielectric, check_refine_memory, refine_prediction, seconds_left,
        )  # fmt: skip
        from ..errors import DataError

        began = time.monotonic()  # seconds covers the network too
        if batch.shape[0] != 1:
            raise DataError(f"a reference is for one photo; got {batch.shape[0]} photos: predict them one by one")
        if scene is not None:
            raise DataError("a reference measures the flash and a scene gives it: give one of them")
        ref = reference if isinstance(reference, Reference) else Reference.parse(str(reference))
        _, _, h, w = batch.shape
        side = min(h, w)
        box = ((w - side) // 2, (h - side) // 2, side, w, h)
        where = f"{self.source}"
        full = square_photo(batch[0].float(), None)
        seen = fill_card(full, reference_mask(ref, box, side, where))  # the network is not shown the card
        if steps == 0:
            square = square_photo(full, self.resolution)
            network = self._network(square_photo(seen, self.resolution)[None])
            network = as_dielectric(network) if metal == "none" else network
            return pin_flash(square, network, ref, box, where).start(network)
        check_refine_memory(side, steps, where, remedy="resize the photo smaller first, or refine=0")
        square = full
        network = self._network(square_photo(seen, self.resolution)[None])
        network = as_dielectric(network) if metal == "none" else network
        pinned = pin_flash(square, network, ref, box, where)
        result = refine_prediction(
            square[None], pinned.start(network).to(self.device), steps, seconds=seconds_left(seconds, began),
            scene=pinned.scene,
            callback=callback, backend=backend or BACKEND, held=(pinned.mask, pinned.card), metal=metal,
        )  # fmt: skip
        return result.svbrdf

    def _check_photo(self, photo: Tensor) -> Tensor:
        """``photo`` as a batch ``(N, 3, H, W)``; :class:`~svbrdf_models.errors.DataError` (one
        line) for another shape, integer values or NaN/infinite values.

        Integer photos (uint8 codes up to 255, 16-bit PNG codes) are refused, not converted:
        their encoding (sRGB or linear) and scale are not in the tensor, and a guess would give
        maps of the wrong brightness without a word. Read files with
        :func:`svbrdf_models.capture.one.load_photo`, or convert 8-bit sRGB codes with
        ``svbrdf_render.srgb_to_linear(photo / 255)``. NaN or infinite values would come out as
        maps of NaN (a convolution spreads them to every pixel).
        """
        from ..errors import DataError

        if not isinstance(photo, Tensor):
            raise DataError(f"{self.source}: expected a photo tensor (3, H, W), got {type(photo).__name__}")
        _check_tensor_kind(photo, str(self.source))
        batch = photo[None] if photo.dim() == 3 else photo
        if batch.dim() != 4 or batch.shape[1] != 3:
            raise DataError(
                f"{self.source}: expected a photo (3, H, W) or (N, 3, H, W), got {tuple(photo.shape)}"
            )
        if not batch.is_floating_point():
            raise DataError(
                f"{self.source}: the photo holds {str(batch.dtype).replace('torch.', '')} codes, not "
                "linear values; convert 8-bit sRGB with svbrdf_render.srgb_to_linear(photo / 255), or "
                "read the file with svbrdf_models.capture.one.load_photo"
            )
        if batch.numel() == 0:
            raise DataError(
                f"{self.source}: the photo is empty ({tuple(photo.shape)}); give a photo with pixels"
            )
        if min(batch.shape[-2:]) < _MIN_PHOTO_SIDE:
            raise DataError(
                f"{self.source}: the photo is {batch.shape[-1]}x{batch.shape[-2]} px, under "
                f"{_MIN_PHOTO_SIDE} px on its "
                "short side: too few pixels to read a material from (the command line takes 64 px and more)"
            )
        bad = int((~torch.isfinite(batch)).sum())
        if not bad:
            low, high = float(batch.min()), float(batch.max())
            if high > _MAX_VALUE or low < -_VALUE_SLACK:
                raise DataError(
                    f"{self.source}: the photo's values run from {low:.3g} to {high:.3g}, not linear "
                    "values in [0, 1]"
                    + (
                        "; a photo in 0-255 needs svbrdf_render.srgb_to_linear(photo / 255)"
                        if high > _MAX_VALUE
                        else ""
                    )
                    + "; or read the file with svbrdf_models.load_photo"
                )
        if bad:
            raise DataError(
                f"{self.source}: the photo holds {bad} NaN or infinite values of {batch.numel()}; "
                "the maps would be NaN: fix or drop the photo"
            )
        return batch

    @torch.no_grad()
    def predict_batch(self, photos: Tensor) -> SVBRDF:
        """The generator's maps of ``(N, 3, S, S)`` linear photos taken as they are (no crop, no
        resize): ``S`` must be a size the generator takes, such as :attr:`resolution` (the tiles
        of :func:`svbrdf_models.capture.one.tile_predict`). Checked as :meth:`predict` checks."""
        batch = self._check_photo(photos)
        return self.generator(batch.float().to(self.device)).detach().to("cpu")

    def _network(self, batch: Tensor) -> SVBRDF:
        """The generator's maps of ``(N, 3, H, W)`` photos' centre squares at :attr:`resolution`."""
        return self.predict_batch(torch.stack([square_photo(p.float(), self.resolution) for p in batch]))

    def describe(self) -> str:
        """One line for people: generator, resolution, steps, precision, where from."""
        hours = float(self.provenance.get("train_seconds", 0.0)) / 3600
        return (
            f"generator {self.name} ({self.resolution}x{self.resolution}, {self.steps} steps, "
            f"{hours:.1f} h of training, {self.precision}) from {self.source}"
        )


def _check_tensor_kind(photo: Tensor, where: str) -> None:
    """A :class:`~svbrdf_models.errors.DataError` (one line, what to do) for a tensor that holds
    no ordinary values to read: a meta tensor (a shape with no values), a nested, sparse or
    quantized one, complex or float8 values. Each used to fail deep in torch with an error
    that named none of it."""
    from ..errors import DataError

    kind, fix = None, ""
    if photo.is_meta:
        kind, fix = "a meta tensor (a shape with no values)", "give a tensor that holds the photo's values"
    elif photo.is_nested:
        kind, fix = "a nested tensor", "give one (3, H, W) tensor, or photos of one size stacked (N, 3, H, W)"
    elif photo.layout != torch.strided:
        kind, fix = f"a sparse tensor ({photo.layout})", "give a dense one: photo.to_dense()"
    elif photo.is_quantized:
        kind, fix = f"a quantized tensor ({photo.dtype})", "give its values: photo.dequantize()"
    elif photo.is_complex():
        kind, fix = f"complex values ({photo.dtype})", "give real linear values (photo.real when they are)"
    elif photo.is_floating_point() and photo.element_size() == 1:
        kind, fix = f"{photo.dtype} values", "give float16, bfloat16, float32 or float64: photo.float()"
    if kind is not None:
        raise DataError(f"{where}: the photo is given as {kind}, which predict cannot read; {fix}")


def _warn_if_small(batch: Tensor, where: str) -> None:
    """A ``UserWarning`` (one line) for photos under :data:`SMALL_PHOTO_SIDE` on the short side:
    taken, but a 16 px photo gives the network a few hundred pixels to read a material from."""
    side = min(batch.shape[-2:])
    if side < SMALL_PHOTO_SIDE:
        import warnings

        warnings.warn(
            f"{where}: the photo is {batch.shape[-1]}x{batch.shape[-2]} px, under the {SMALL_PHOTO_SIDE} px "
            "the command line takes: so few pixels give little to read a material from, and the maps are "
            "mostly the network's guess; give a larger photo",
            UserWarning,
            stacklevel=3,
        )
