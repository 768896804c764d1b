"""Checkpoints: everything a fit needs to go on exactly where it stopped, written atomically.

A checkpoint is one ``torch.save`` file (``last.pt`` in the fit's output folder) holding:

=================  ==============================================================================
key                what
=================  ==============================================================================
format             :data:`FORMAT`, bumped when the layout changes
recipe             the resolved recipe (``Recipe.to_dict()``), so ``--resume`` needs nothing else
step, epoch        generator steps done, and the epoch they are in
generator          the generator's ``state_dict`` (unwrapped from DistributedDataParallel)
discriminator      the discriminator's, or None without an adversarial loss
optimizers         ``{"g": ..., "d": ...}`` Adam states
schedule           samples seen and the learning-rate factor (for people: resuming recomputes it)
rng                per process: the torch CPU (and CUDA) RNG states; and the scene sampler's
run_id             the MLflow run to continue
train_seconds      training time so far (the time budget spans resumes)
world_size         processes of the fit (a resume must use as many)
=================  ==============================================================================

Writing goes to a temporary file in the same folder, flushed to disk, then renamed over the
target (:func:`svbrdf_render.files.atomic_output`), so a fit killed at any instant leaves the
previous checkpoint or the new one, never a mix; a full disk leaves the previous one and no
temporary file. A fit killed by SIGKILL mid-write leaves its ``.last.pt.PID.tmp``:
:func:`remove_leftovers` clears such files when the next fit in that folder starts. A small
``last.json`` beside the checkpoint says which step and run it holds, for people and scripts.

``weights.pt`` (:data:`WEIGHTS_NAME`) beside it holds the same minus ``optimizers``,
``schedule`` and ``rng``: what predicting or ``--init`` needs, and what a fit uploads to its
MLflow run (``checkpoints/weights.pt``), about a third of the size with Adam's two moments.

Loading refuses NaN or infinite weights (naming the checkpoint), and :func:`load_weights` says
in one line how weights differ from a network instead of torch's list of every key.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch

from svbrdf_models.modelfile import nonfinite_tensors, unreadable_reason, weights_mismatch
from svbrdf_render.files import atomic_output, remove_stale_temporaries, write_text

from .errors import CheckpointError

__all__ = [
    "FORMAT",
    "CHECKPOINT_NAME",
    "WEIGHTS_NAME",
    "save_checkpoint",
    "load_checkpoint",
    "load_weights",
    "check_finite",
    "remove_leftovers",
    "rng_state",
    "set_rng_state",
]

FORMAT = 1
CHECKPOINT_NAME = "last.pt"
#: The weights alone (no optimiser or random state), written beside it: what MLflow gets.
WEIGHTS_NAME = "weights.pt"


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> Path:
    """Write ``state`` to ``path`` atomically, and a ``.json`` summary beside it.

    Raises:
        OutputError: the disk refused it (full, read-only...); ``path`` is as it was before.
    """
    path = Path(path)
    state = {"format": FORMAT, **state}
    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        torch.save(state, f)  # through a Python file, so a failed write keeps its errno
    summary = {k: state.get(k) for k in ("step", "epoch", "run_id", "train_seconds", "world_size")}
    summary["recipe"] = (state.get("recipe") or {}).get("name")
    write_text(path.with_suffix(".json"), json.dumps(summary, indent=2))
    return path


def remove_leftovers(folder: str | Path) -> list[Path]:
    """Remove the temporary checkpoint files of fits in ``folder`` that were killed mid-write."""
    names = [n for name in (CHECKPOINT_NAME, WEIGHTS_NAME) for n in (name, Path(name).stem + ".json")]
    return remove_stale_temporaries(folder, names)


def load_checkpoint(
    path: str | Path,
    map_location: str | torch.device = "cpu",
    *,
    mmap: bool = False,
    source: str | None = None,
    check: bool | None = None,
) -> dict[str, Any]:
    """Read a checkpoint written by :func:`save_checkpoint` (tensors only: no code is unpickled).

    ``mmap=True`` maps the file instead of reading it: cheap when only a few fields are needed,
    and a paper-size checkpoint (over 1 GB with both Adam states) is read as it is used. The
    weights are checked for NaN and infinite values unless ``check`` is False (default: only
    without ``mmap``). ``source`` names the checkpoint in messages when
    ``path`` is not what the user gave (a file downloaded from an MLflow run).

    Raises:
        CheckpointError: missing, unreadable, of another format, or with NaN/infinite weights.
    """
    path = Path(path)
    source = source or str(path)
    if not path.is_file():
        raise CheckpointError(f"{source}: no checkpoint there")
    try:
        state = torch.load(path, map_location=map_location, weights_only=True, mmap=mmap)
    except Exception as e:  # torch raises many kinds for a damaged or foreign file
        raise CheckpointError(
            f"{source}: not a readable svbrdf-train checkpoint ({unreadable_reason(e)})"
        ) from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        got = state.get("format") if isinstance(state, dict) else type(state).__name__
        raise CheckpointError(
            f"{source}: not an svbrdf-train checkpoint of format {FORMAT} (got {got!r}); "
            "it was written by another tool or version"
        )
    if (not mmap) if check is None else check:
        for key in ("generator", "discriminator"):
            check_finite(state.get(key), f"{source}: the {key}'s weights")
    return state


def check_finite(weights: dict[str, Any] | None, what: str) -> None:
    """Refuse a state dict holding NaN or infinite values; ``what`` starts the message."""
    bad = nonfinite_tensors(weights)
    if bad:
        raise CheckpointError(
            f"{what} hold NaN or infinite values ({len(bad)} of {len(weights)} tensors, first "
            f"{bad[0]!r}); they cannot predict anything: use an earlier checkpoint"
        )


def load_weights(module: torch.nn.Module, weights: dict[str, Any], what: str) -> None:
    """``module.load_state_dict(weights)``, or one line saying how they differ.

    ``what`` names the weights and the network, e.g. ``"run/last.pt: generator 'ours'"``.
    """
    why = weights_mismatch(module, weights)
    if why:
        raise CheckpointError(
            f"{what}: the weights do not fit the network ({why}); "
            "they were trained with another network or config"
        )
    module.load_state_dict(weights)


def rng_state(scene_generator: torch.Generator | None = None) -> dict[str, Any]:
    """This process's random state: torch CPU, every CUDA device, and the scene sampler."""
    state: dict[str, Any] = {"torch": torch.get_rng_state()}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    if scene_generator is not None:
        state["scene"] = scene_generator.get_state()
    return state


def set_rng_state(state: dict[str, Any], scene_generator: torch.Generator | None = None) -> None:
    """Restore what :func:`rng_state` captured."""
    torch.set_rng_state(state["torch"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])
    if scene_generator is not None and "scene" in state:
        scene_generator.set_state(state["scene"])
