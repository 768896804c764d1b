"""Maps from photos with a trained generator (from a checkpoint file or an MLflow run).

::

    from svbrdf_train.predict import Predictor
    p = Predictor.from_checkpoint("runs/ours-cpu/last.pt")
    svbrdf = p.predict(photo)           # (3, H, W) linear photo -> SVBRDF of 1 at p.resolution
    svbrdfs = p.predict_batch(photos)   # (N, 3, R, R) linear photos at p.resolution -> SVBRDF of N
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor

from svbrdf_render import SVBRDF

from .checkpoint import load_checkpoint
from .data.photos import square_photo
from .errors import CheckpointError
from .inference import load_generator
from .init import RUN_CHECKPOINT, download_run_checkpoint

__all__ = ["Predictor", "RUN_CHECKPOINT"]


class Predictor:
    """A trained generator in eval mode, and the resolution it was trained at."""

    def __init__(self, checkpoint: dict, device: str | torch.device = "cpu", source: str = "checkpoint"):
        try:
            self.generator, self.recipe = load_generator(checkpoint, device, source)
        except (KeyError, RuntimeError) as e:
            raise CheckpointError(f"{source}: the generator cannot be rebuilt from it ({e})") from None
        self.device = torch.device(device)
        self.resolution = self.recipe.train.resolution
        self.step = int(checkpoint.get("step", 0))
        self.source = source

    @classmethod
    def from_checkpoint(cls, path: str | Path, device: str | torch.device = "cpu") -> Predictor:
        return cls(load_checkpoint(path), device, source=str(path))

    @classmethod
    def from_run(cls, run_id: str, device: str | torch.device = "cpu") -> Predictor:
        """Download the run's checkpoint from the MLflow store (``MLFLOW_TRACKING_URI`` or the default)."""
        return cls(download_run_checkpoint(run_id), device, source=f"run {run_id}")

    @torch.no_grad()
    def predict(self, photo: Tensor) -> SVBRDF:
        """``(3, H, W)`` linear photo -> maps of one material at :attr:`resolution` (centre square)."""
        x = square_photo(photo.float(), self.resolution).to(self.device)
        return self.generator(x[None]).detach().to("cpu")

    @torch.no_grad()
    def predict_batch(self, photos: Tensor) -> SVBRDF:
        """``(N, 3, S, S)`` linear photos, ``S`` a size the generator takes (its resolution) -> maps of N."""
        return self.generator(photos.float().to(self.device)).detach().to("cpu")
