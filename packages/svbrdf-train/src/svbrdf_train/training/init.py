"""``fit --init``: start a new fit from the weights of another (fine-tuning).

The source is a checkpoint file, the ``--out`` folder of a fit (its ``last.pt``), a model file
(``pretrained[:NAME]``, shipped with svbrdf-models, or a file ``export`` wrote: the generator
alone), or an MLflow run id (the checkpoint that run logged). The new fit takes the generator's
weights, and the
discriminator's when both recipes have the same one; its optimisers, schedule, step count and
time budget start from zero, and its MLflow run is a new one that records where the weights
came from (tags ``svbrdf.init``, ``svbrdf.init_run``, ``svbrdf.init_step`` and
``svbrdf.init_train_seconds``, the training time behind those weights, which ``svbrdf-bench``
adds to the fit's own on its learning curves).
"""

from __future__ import annotations

import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from svbrdf_models import config_to_dict, resolve_config

from ..errors import CheckpointError, RecipeError
from ..recipe import NetworkSection, Recipe, recipe_from_dict
from .checkpoint import CHECKPOINT_NAME, WEIGHTS_NAME, load_checkpoint

__all__ = ["InitWeights", "load_init", "take_init", "RUN_CHECKPOINT", "download_run_checkpoint"]

#: Where a fit logs its weights in its MLflow run (``OUT/weights.pt``: no optimiser state).
RUN_CHECKPOINT = f"checkpoints/{WEIGHTS_NAME}"
#: Where fits before the weights file logged their whole checkpoint; still read.
_OLD_RUN_CHECKPOINT = f"checkpoints/{CHECKPOINT_NAME}"
_RUN_ID = re.compile(r"^[0-9a-f]{32}$")


@dataclass
class InitWeights:
    """Weights to start from, and where they came from."""

    source: str
    generator: dict[str, Any]
    discriminator: dict[str, Any] | None
    recipe: Recipe
    run_id: str | None
    step: int
    train_seconds: float = 0.0

    def tags(self) -> dict[str, str]:
        out = {
            "svbrdf.init": self.source,
            "svbrdf.init_step": str(self.step),
            "svbrdf.init_train_seconds": f"{self.train_seconds:.1f}",
        }
        if self.run_id:
            out["svbrdf.init_run"] = self.run_id
        return out


def download_run_checkpoint(run_id: str) -> dict[str, Any]:
    """The checkpoint an MLflow run logged (``MLFLOW_TRACKING_URI`` or the default store)."""
    from mlflow import MlflowClient

    from ..tracking import check_store, quiet_store_logs, tracking_uri

    check_store(tracking_uri())  # a file that is not an MLflow store is refused before MLflow writes to it
    with tempfile.TemporaryDirectory() as tmp, quiet_store_logs():  # a new store's notices: not for predict
        client = MlflowClient()
        try:
            try:
                local = client.download_artifacts(run_id, RUN_CHECKPOINT, tmp)
            except Exception:
                local = client.download_artifacts(run_id, _OLD_RUN_CHECKPOINT, tmp)
        except Exception as e:  # MlflowException for a missing run or artifact, OSError, HTTP errors
            first = str(e).splitlines()[0] if str(e) else ""
            raise CheckpointError(
                f"MLflow run {run_id}: no {RUN_CHECKPOINT} to load from {client.tracking_uri} "
                f"({type(e).__name__}: {first}); check the run id and MLFLOW_TRACKING_URI, "
                "or give the checkpoint file"
            ) from None
        return load_checkpoint(local, source=f"MLflow run {run_id}")


def load_init(arg: str) -> InitWeights:
    """The weights ``--init ARG`` names: a checkpoint file, a fit's folder, or an MLflow run id.

    Raises:
        CheckpointError: nothing of the kind there, or a checkpoint without a generator.
    """
    model = _model_file(arg)
    if model is not None:
        return model
    path = Path(arg).expanduser()
    run_id = None
    if path.is_dir() and (path / CHECKPOINT_NAME).is_file():
        path = path / CHECKPOINT_NAME
    if path.is_file():
        state = load_checkpoint(path)
        source = str(path)
    elif _RUN_ID.match(arg):
        state = download_run_checkpoint(arg)
        source, run_id = f"run {arg}", arg
    else:
        raise CheckpointError(
            f"--init {arg}: not a checkpoint file, a fit's folder holding {CHECKPOINT_NAME}, "
            "a model file (pretrained[:NAME] or a .pt svbrdf-train export wrote), "
            "nor an MLflow run id (32 hex digits)"
        )
    if state.get("generator") is None or not state.get("recipe"):
        raise CheckpointError(f"--init {source}: the checkpoint holds no generator weights or no recipe")
    recipe = recipe_from_dict(state["recipe"], where=f"--init {source}")
    return InitWeights(
        source=source,
        generator=state["generator"],
        discriminator=state.get("discriminator"),
        recipe=recipe,
        run_id=run_id or state.get("run_id"),
        step=int(state.get("step", 0)),
        train_seconds=float(state.get("train_seconds", 0.0)),
    )


def _model_file(arg: str) -> InitWeights | None:
    """The generator of a model file (``pretrained[:NAME]`` or a file ``export`` wrote), checked
    as ``load_model`` checks it, with the recipe, steps and training time it records; None when
    ``arg`` names no model file. A model file holds no discriminator: a new one is trained."""
    import torch

    from svbrdf_models.modelfile.files import PRETRAINED, pretrained_path
    from svbrdf_models.modelfile.modelcheck import is_model_file, read_model_file

    text = str(arg)
    if text == "pretrained" or text.startswith("pretrained:"):
        path = pretrained_path(text.partition(":")[2] or PRETRAINED)
    else:
        path = Path(text).expanduser()
        if not (path.is_file() and is_model_file(path)):
            return None
    read_model_file(path, "cpu", text)  # header, sidecar, size and weights checked
    state = torch.load(path, map_location="cpu", weights_only=True)
    provenance = state.get("provenance") or {}
    return InitWeights(
        source=text,
        generator={k: v.float() for k, v in state["weights"].items()},
        discriminator=None,
        recipe=recipe_from_dict(state["recipe"], where=f"--init {text}"),
        run_id=provenance.get("run_id"),
        step=int(provenance.get("steps", 0)),
        train_seconds=float(provenance.get("train_seconds", 0.0)),
    )


def _describe(kind: str, section: NetworkSection) -> tuple[str, dict[str, Any]]:
    return section.name, config_to_dict(resolve_config(kind, section.name, section.config))


def check_generator(init: InitWeights, recipe: Recipe) -> None:
    """Refuse weights of another generator (name or resolved config) than the recipe's."""
    have = _describe("generator", init.recipe.generator)
    want = _describe("generator", recipe.generator)
    if have != want:
        diff = sorted(k for k in set(have[1]) | set(want[1]) if have[1].get(k) != want[1].get(k))
        what = (
            f"{have[0]} against {want[0]}"
            if have[0] != want[0]
            else ", ".join(f"{k} {have[1].get(k)!r} against {want[1].get(k)!r}" for k in diff[:4])
        )
        raise RecipeError(
            f"--init {init.source}: its generator does not match recipe {recipe.name!r} ({what}); "
            "give weights of the same generator, or a recipe with that generator "
            "(--set generator.config.preset=...)"
        )


def same_discriminator(init: InitWeights, recipe: Recipe) -> bool:
    """Whether the discriminator weights can be taken as well."""
    a, b = init.recipe.discriminator, recipe.discriminator
    if a is None or b is None or init.discriminator is None:
        return False
    return _describe("discriminator", a) == _describe("discriminator", b)


def take_init(gan: Any, source: str, recipe: Recipe) -> dict[str, str]:
    """The generator's weights of ``--init`` into ``gan`` (a :class:`~svbrdf_train.training.step.GanStep`),
    and the discriminator's when it is the same one; the MLflow tags that say so."""
    init = load_init(source)
    check_generator(init, recipe)
    both = gan.discriminator is not None and same_discriminator(init, recipe)
    gan.load_weights(f"--init {init.source}", init.generator, init.discriminator if both else None)
    taken = "taken" if both else ("new" if gan.discriminator is not None else "none")
    return {**init.tags(), "svbrdf.init_discriminator": taken}
