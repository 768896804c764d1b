"""Rebuilding a trained generator from a checkpoint, for inference.

This module sits below the trainer: prediction and the benchmark import it to turn a
checkpoint into a generator without loading any training code (the trainer, losses,
schedules, tracking, training data).

::

    from svbrdf_train.training.checkpoint import load_checkpoint
    from svbrdf_train.inference import load_generator
    generator, recipe = load_generator(load_checkpoint("runs/ours-cpu/last.pt"))
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from svbrdf_models import create_generator

from .errors import CheckpointError
from .recipe import Recipe, recipe_from_dict
from .training.checkpoint import load_weights

__all__ = ["load_generator"]


def load_generator(
    checkpoint: dict[str, Any], device: str | torch.device = "cpu", source: str = "checkpoint"
) -> tuple[nn.Module, Recipe]:
    """The generator of a checkpoint (eval mode) and the recipe it was trained with."""
    recipe = recipe_from_dict(checkpoint.get("recipe") or {}, where=f"{source}: its recipe")
    if recipe.generator is None or checkpoint.get("generator") is None:
        raise CheckpointError(f"{source}: it names no generator (its recipe or weights are missing)")
    g = create_generator(recipe.generator.name, recipe.generator.config)
    load_weights(g, checkpoint["generator"], f"{source}: generator {recipe.generator.name!r}")
    return g.to(device).eval(), recipe
