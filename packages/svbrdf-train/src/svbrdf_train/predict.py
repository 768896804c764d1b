"""Maps from photos with a trained generator: a model file (svbrdf-models), a training
checkpoint, or an MLflow run.

::

    from svbrdf_train.predict import Predictor
    p = Predictor.from_model("pretrained")            # or a file, URL, models:/NAME/VERSION
    p = Predictor.from_checkpoint("runs/ours-cpu/last.pt")
    svbrdf = p.predict(photo)           # (3, H, W) linear photo -> SVBRDF of 1 at p.resolution
    svbrdfs = p.predict_batch(photos)   # (N, 3, R, R) linear photos at p.resolution -> SVBRDF of N
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor, nn

from svbrdf_models.modelfile import is_model_file, load_model, square_photo
from svbrdf_render import SVBRDF

from .checkpoint import load_checkpoint
from .errors import CheckpointError
from .inference import load_generator
from .init import RUN_CHECKPOINT, download_run_checkpoint

__all__ = ["Predictor", "RUN_CHECKPOINT"]


class Predictor:
    """A trained generator in eval mode, its name, and the resolution it was trained at."""

    def __init__(
        self,
        generator: nn.Module,
        name: str,
        resolution: int,
        *,
        source: str,
        step: int = 0,
        device: str | torch.device = "cpu",
        card: str | None = None,
    ):
        self.generator = generator.to(device).eval()
        self.name = name
        self.resolution = int(resolution)
        self.source = source
        self.step = int(step)
        self.device = torch.device(device)
        self.card = card  # one line about a model file's training, for people

    @classmethod
    def from_state(cls, checkpoint: dict, device: str | torch.device = "cpu", source: str = "checkpoint"):
        """From a training checkpoint's state (``last.pt`` or ``weights.pt`` loaded)."""
        try:
            generator, recipe = load_generator(checkpoint, device, source)
        except (KeyError, RuntimeError) as e:
            raise CheckpointError(f"{source}: the generator cannot be rebuilt from it ({e})") from None
        return cls(
            generator,
            recipe.generator.name,
            recipe.train.resolution,
            source=source,
            step=int(checkpoint.get("step", 0)),
            device=device,
        )

    @classmethod
    def from_model(cls, source: str | Path, device: str | torch.device = "cpu") -> Predictor:
        """From a model file (``svbrdf-train export``): a path, URL, MLflow URI or ``pretrained``."""
        model = load_model(source, device)
        return cls(
            model.generator,
            model.name,
            model.resolution,
            source=model.source,
            step=model.steps,
            device=device,
            card=model.describe(),
        )

    @classmethod
    def from_checkpoint(cls, path: str | Path, device: str | torch.device = "cpu") -> Predictor:
        """From a training checkpoint, or a model file given where a checkpoint is expected."""
        if is_model_file(path):
            return cls.from_model(path, device)
        return cls.from_state(load_checkpoint(path), device, source=str(path))

    @classmethod
    def from_run(cls, run_id: str, device: str | torch.device = "cpu") -> Predictor:
        """Download the run's checkpoint from the MLflow store (``MLFLOW_TRACKING_URI`` or the default)."""
        return cls.from_state(download_run_checkpoint(run_id), device, source=f"run {run_id}")

    @torch.no_grad()
    def predict(self, photo: Tensor) -> SVBRDF:
        """``(3, H, W)`` linear photo -> maps of one material at :attr:`resolution` (centre square)."""
        x = square_photo(photo.float(), self.resolution).to(self.device)
        return self.generator(x[None]).detach().to("cpu")

    @torch.no_grad()
    def predict_batch(self, photos: Tensor) -> SVBRDF:
        """``(N, 3, S, S)`` linear photos, ``S`` a size the generator takes (its resolution) -> maps of N."""
        return self.generator(photos.float().to(self.device)).detach().to("cpu")
