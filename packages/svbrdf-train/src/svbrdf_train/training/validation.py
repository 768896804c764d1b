"""Validation during a fit: RMSE of each map and of renderings, and a grid of samples.

``val/rmse/<map>`` on the held-out set, ``val_real/rmse/<map>`` on the real validation set
(``data.real_validation``) when there is one, and ``val_fold/rmse/<map>`` on the materials a
``materials`` source holds out (``data.fold``) when it does; ``<map>`` is each of :data:`METRIC_NAMES`
(the four maps and a rendering under the evaluation lights). The grid shows
:data:`GRID_SAMPLES` held-out samples: input, true and predicted maps and a flash rendering.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.utils.data import DataLoader, Dataset

from svbrdf_render import MAP_NAMES, SVBRDF, evaluation_scene
from svbrdf_render.compare import METRIC_NAMES, display_rendering, map_rmse, render_rmse

from ..metrics import preview_flash

__all__ = ["GRID_SAMPLES", "GRID_MIN_SIZE", "Validator"]

#: Samples drawn in the sample grid of each validation.
GRID_SAMPLES = 4
#: Tiles of the sample grid smaller than this many pixels are enlarged (nearest neighbour).
GRID_MIN_SIZE = 96


class Validator:
    """Validates a generator on ``held_out`` and, if given, ``real`` and ``fold`` (module doc)."""

    def __init__(
        self,
        held_out: Dataset,
        real: Dataset | None,
        batch: int,
        device: torch.device,
        fold: Dataset | None = None,
    ):
        self.held_out, self.real, self.batch, self.device = held_out, real, batch, device
        self.fold = fold
        self.eval_scene = evaluation_scene(device=device)
        self.flash = preview_flash(device)

    @torch.no_grad()
    def __call__(self, g: nn.Module) -> tuple[dict[str, float], Tensor | None]:
        """The metrics of both sets and the sample grid of the held-out set."""
        g.eval()
        try:
            metrics, grid = self._validate_set(g, self.held_out, "val", grid=True)
            for prefix, data in (("val_real", self.real), ("val_fold", self.fold)):
                if data is not None:
                    metrics.update(self._validate_set(g, data, prefix, grid=False)[0])
        finally:
            g.train()
        return metrics, grid

    def _validate_set(
        self, g: nn.Module, data: Dataset, prefix: str, *, grid: bool
    ) -> tuple[dict[str, float], Tensor | None]:
        if len(data) == 0:
            return {}, None
        sums = dict.fromkeys(METRIC_NAMES, 0.0)
        rows: list = []
        labels: list[str] = []
        # its own generator: validating must not draw from the training random state
        loader = DataLoader(data, batch_size=self.batch, generator=torch.Generator().manual_seed(0))
        for batch in loader:
            photo = batch["input"].to(self.device)
            target = SVBRDF.unpack(batch["maps"].to(self.device), validate=False)
            pred = g(photo)
            for name, v in map_rmse(pred, target).items():
                sums[name] += float(v.sum())
            sums["render"] += float(render_rmse(pred, target, self.eval_scene).sum())
            if grid and len(rows) < 2 * GRID_SAMPLES:
                rows += self._grid_rows(photo, pred, target)
                labels += [f"{n} {k}" for n in batch["name"] for k in ("true", "pred")]
        metrics = {f"{prefix}/rmse/{k}": v / len(data) for k, v in sums.items()}
        return metrics, (self._sheet(rows, labels) if grid else None)

    @staticmethod
    def _sheet(rows: list, labels: list[str]) -> Tensor:
        from svbrdf_models.capture.figures import image_grid

        keep = 2 * GRID_SAMPLES
        return image_grid(
            rows[:keep],
            ("input", *MAP_NAMES, "flash"),
            [s[-28:] for s in labels[:keep]],
            min_tile=GRID_MIN_SIZE,
        )

    def _grid_rows(self, photo: Tensor, pred: SVBRDF, target: SVBRDF) -> list:
        from svbrdf_render import linear_to_srgb

        from ..data.sheet import map_tiles

        rows = []
        shown = linear_to_srgb(photo.float().cpu())
        looks = {
            "true": display_rendering(target, self.flash).cpu(),
            "pred": display_rendering(pred, self.flash).cpu(),
        }
        for k in range(photo.shape[0]):
            for which, maps in (("true", target), ("pred", pred)):
                rows.append([shown[k], *map_tiles(maps.pack()[k]), looks[which][k]])
        return rows
