"""Bringing a sample to a model's resolution without changing its field of view.

The renderer maps an image onto the surface ``[-1, 1]^2`` whatever its pixel count, and the
photo of a sample was taken of that whole surface. A model trained at 128 px sees the whole
surface at 128 px; shown the centre 128 px of a 288 px tile it sees 44% of the surface's
width and a highlight more than twice as large as any it trained on. So a larger sample is
brought to a smaller model by *resizing*: an area filter (the mean of the pixels each output
pixel covers) for the photo, the albedos and the roughness; the normals are averaged the same
way and renormalised. A crop is consistent only when the scene is told the crop's extent.

:func:`resize_sample` works on the sample dicts of :mod:`svbrdf_train.data.sample`.
"""

from __future__ import annotations

from typing import Any

import torch.nn.functional as F
from torch import Tensor

from svbrdf_render import SVBRDF

__all__ = ["resize_photo", "resize_maps", "resize_sample"]


def resize_photo(photo: Tensor, resolution: int) -> Tensor:
    """``(..., 3, H, W)`` -> ``(..., 3, resolution, resolution)`` by the area filter."""
    if photo.shape[-1] == resolution and photo.shape[-2] == resolution:
        return photo
    lead = photo.shape[:-3]
    flat = photo.reshape(-1, *photo.shape[-3:]).float()
    out = F.interpolate(flat, size=(resolution, resolution), mode="area")
    return out.reshape(*lead, *out.shape[-3:])


def resize_maps(maps: SVBRDF, resolution: int) -> SVBRDF:
    """Maps at ``resolution``: area filter for every map, normals renormalised."""
    if maps.size == (resolution, resolution):
        return maps
    return maps.resize(resolution, resolution, mode="area")


def resize_sample(sample: dict[str, Any], resolution: int) -> dict[str, Any]:
    """A sample dict (``input`` ``(3, H, W)``, optional ``maps`` ``(10, H, W)``) at ``resolution``."""
    out = dict(sample)
    out["input"] = resize_photo(sample["input"], resolution).contiguous()
    if "maps" in sample:
        maps = SVBRDF.unpack(sample["maps"][None].float(), validate=False)
        out["maps"] = resize_maps(maps, resolution).pack()[0].contiguous()
    return out
