"""What the renderer's stages pass each other, typed (as PyTorch3D's ``Fragments`` between its
rasteriser and shader).

A render runs three stages (:mod:`svbrdf_render.renderer`):

1. :func:`~svbrdf_render.renderer.place_scene` places the scene on the patch: a
   :class:`SceneGeometry`;
2. the plan's :attr:`~svbrdf_render.renderer.RenderPlan.shade` (a :data:`ShadeStage`) turns the
   four maps and that geometry into radiance, summed over the lights;
3. the plan's :attr:`~svbrdf_render.renderer.RenderPlan.finish` (a :data:`FinishStage`) runs the
   image effects on the radiance; the geometry is None where no image effect reads the camera
   (:func:`~svbrdf_render.renderer.apply_image_effects`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = ["SceneGeometry", "ShadeStage", "FinishStage"]

#: One light placed for broadcasting: its position ``(..., 3, 1, 1)``, its point weight (1 for a
#: point light, 0 for a directional one; a tensor when the configurations mix them) and its RGB
#: radiance ``(..., 3, 1, 1)``.
PlacedLight = tuple[Tensor, Tensor | float, Tensor]


@dataclass(frozen=True)
class SceneGeometry:
    """A scene placed on the patch: what the shading and the image stages read of it.

    The tensors are in the render's compute dtype and on the maps' device, shaped to broadcast
    against the maps: ``S + (C, 1, 1)`` for the configuration shape ``S`` of the scene.
    """

    #: The patch's surface points ``(3, H, W)`` (z = 0; x, y in [-1, 1]).
    positions: Tensor
    #: The camera's position ``S + (3, 1, 1)``.
    camera: Tensor
    #: 1 for a point camera, 0 for a directional one (a tensor ``S + (1, 1, 1)`` when mixed).
    camera_w: Tensor | float
    #: Each light of the scene, placed (:data:`PlacedLight`).
    lights: tuple[PlacedLight, ...]

    def requires_grad(self) -> bool:
        """Whether a gradient flows into the camera or a light (not only into the maps)."""
        tensors = [self.camera, self.camera_w, *(t for light in self.lights for t in light)]
        return any(isinstance(t, Tensor) and t.requires_grad for t in tensors)


#: The shading stage: ``shade(normal, diffuse, roughness, specular, geometry) -> radiance``.
ShadeStage = Callable[[Tensor, Tensor, Tensor, Tensor, SceneGeometry], Tensor]
#: The image stage: ``finish(radiance, geometry, generator) -> image``; ``geometry`` None where
#: no image effect reads the camera, ``generator`` None for the ``noise`` effect's own seed.
FinishStage = Callable[[Tensor, SceneGeometry | None, torch.Generator | None], Tensor]
