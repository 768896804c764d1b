"""Starting a fit in its folder: refuse to overwrite a checkpoint silently, and resume one.

``--resume`` continues the checkpoint ``OUT/last.pt`` with its own recipe; a recipe given
with it may differ only in :data:`RESUMABLE_CHANGES` (budgets, cadences, loader workers).
Everything else the checkpoint holds (weights, optimisers, step, random states, the MLflow run)
is restored by the fit, so the resumed fit reaches the same weights as one that never stopped.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..errors import CheckpointError
from ..recipe import Recipe, check_recipe, recipe_differences, recipe_from_dict, with_overrides
from .checkpoint import CHECKPOINT_NAME, load_checkpoint, remove_leftovers

__all__ = ["RESUMABLE_CHANGES", "check_out", "resolve_resume", "check_world"]

#: Recipe fields a ``--resume`` may change: budgets, cadences and loader workers.
RESUMABLE_CHANGES = (
    "train.epochs",
    "train.max_steps",
    "train.max_minutes",
    "train.log_every",
    "train.validate_every",
    "train.keep_best",
    "train.snapshot_minutes",
    "train.snapshot_steps",
    "train.checkpoint_every",
    "train.checkpoint_minutes",
    "train.upload_minutes",
    "data.workers",
)


def check_out(out: Path, *, resume: bool, force: bool, init: str | None, main: bool = True) -> dict | None:
    """The checkpoint to resume from (``resume``), after refusing to overwrite one silently.

    Temporary checkpoint files left by a fit killed mid-write are removed first (by the main
    process). The checkpoint is memory-mapped: a paper-size one is read as it is used.
    """
    ckpt = Path(out) / CHECKPOINT_NAME
    if main:
        remove_leftovers(out)
    if resume and init:
        raise CheckpointError(
            "--init starts a new fit from trained weights and --resume continues one; give one of them"
        )
    if resume:
        if not ckpt.is_file():
            raise CheckpointError(
                f"{ckpt}: nothing to resume; run without --resume to start, or give the --out of the fit"
            )
        return load_checkpoint(ckpt, mmap=True, check=True)
    if ckpt.is_file() and not force:
        raise CheckpointError(
            f"{ckpt}: a checkpoint of an earlier fit is there; pass --resume to continue it, "
            "--force to start again over it, or choose another --out"
        )
    return None


def resolve_resume(
    recipe: Recipe | None,
    state: dict | None,
    ckpt: str | Path = CHECKPOINT_NAME,
    overrides: Mapping[str, Any] | None = None,
) -> Recipe:
    """The recipe to run: the given one, or the checkpoint's (from ``state``, read from ``ckpt``)
    with the given budgets: those of ``recipe``, or else the dotted ``overrides`` (``--set``,
    ``--max-steps``...) applied to the checkpoint's recipe.

    The result is checked (:func:`~svbrdf_train.recipe.check_recipe`) once: a checked
    ``recipe`` stays checked (it equals the checkpoint's in every field the checks read), the
    checkpoint's recipe is checked here, naming ``ckpt``.

    Raises:
        CheckpointError: the given recipe or overrides change more than :data:`RESUMABLE_CHANGES`.
        RecipeError: the checkpoint's recipe or the overrides are wrong.
    """
    if state is None:
        assert recipe is not None
        return recipe
    saved = recipe_from_dict(state["recipe"], where=str(ckpt), check=False)
    if recipe is None:
        recipe = with_overrides(saved, overrides or {})  # checked when it changes anything
    changed = recipe_differences(saved, recipe, ignore=RESUMABLE_CHANGES)
    if changed:
        raise CheckpointError(
            "--resume with a recipe that differs from the checkpoint's in "
            + "; ".join(changed)
            + f". A resumed fit may change only {', '.join(RESUMABLE_CHANGES)}; "
            "start a new fit (another --out) "
            "to train something else"
        )
    # every other field is the checkpoint's: keep its name, size and source too
    meta = {"name": saved.name, "size": saved.size, "description": saved.description, "source": saved.source}
    out = recipe.with_meta(**meta)
    if not out.checked:
        check_recipe(out, str(ckpt))
    return out


def check_world(state: dict, world: int, ckpt: Path) -> None:
    """Refuse to resume with another number of processes than the checkpoint's."""
    if state.get("world_size", 1) != world:
        raise CheckpointError(
            f"{ckpt}: written by {state.get('world_size')} process(es), resumed with "
            f"{world}; resume with --nproc_per_node={state.get('world_size')} "
            "(the data order and batch depend on it)"
        )
