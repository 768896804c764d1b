"""Maps from photos with a trained generator: a model file (svbrdf-models), a training
checkpoint, or an MLflow run.

::

    from svbrdf_train.predict import Predictor
    p = Predictor.from_model("pretrained")            # or a file, URL, models:/NAME/VERSION
    p = Predictor.from_checkpoint("runs/ours-cpu/last.pt")
    svbrdf = p.predict(photo)           # (3, H, W) linear photo -> SVBRDF of 1 at p.resolution
    svbrdfs = p.predict_batch(photos)   # (N, 3, R, R) linear photos at p.resolution -> SVBRDF of N

A :class:`Predictor` is svbrdf-models' :class:`~svbrdf_models.modelfile.trained.TrainedModel` (the one
implementation of prediction: the photo checks, the centre square, refinement) that can also be
made from what training writes.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

import torch

from svbrdf_models.modelfile.files import load_model
from svbrdf_models.modelfile.modelcheck import is_model_file
from svbrdf_models.modelfile.trained import TrainedModel

from .errors import CheckpointError
from .inference import load_generator
from .training.checkpoint import load_checkpoint
from .training.init import download_run_checkpoint

__all__ = ["Predictor"]


@dataclass
class Predictor(TrainedModel):
    """A :class:`~svbrdf_models.modelfile.trained.TrainedModel` from a model file, a training checkpoint or
    an MLflow run; ``card`` is one line about a model file's training, for people (None for a
    checkpoint)."""

    card: str | None = None

    @classmethod
    def from_state(cls, checkpoint: dict, device: str | torch.device = "cpu", source: str = "checkpoint"):
        """From a training checkpoint's state (``last.pt`` or ``weights.pt`` loaded)."""
        try:
            generator, recipe = load_generator(checkpoint, device, source)
        except (KeyError, RuntimeError) as e:
            raise CheckpointError(f"{source}: the generator cannot be rebuilt from it ({e})") from None
        return cls(
            generator=generator,
            name=recipe.generator.name,
            config=dict(recipe.generator.config or {}),
            resolution=int(recipe.train.resolution),
            precision="fp32",
            source=source,
            sha256=None,
            recipe=dict(checkpoint.get("recipe") or {}),
            provenance={"steps": int(checkpoint.get("step", 0))},
        )

    @classmethod
    def from_model(cls, source: str | Path, device: str | torch.device = "cpu") -> Predictor:
        """From a model file (``svbrdf-train export``): a path, URL, MLflow URI or ``pretrained``."""
        model = load_model(source, device)
        return cls(**{f.name: getattr(model, f.name) for f in fields(model)}, card=model.describe())

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
