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
target, so a fit killed at any instant leaves the previous checkpoint or the new one, never a
mix. A small ``last.json`` beside it says which step and run it holds, for people and scripts.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import torch

from .errors import CheckpointError

__all__ = ["FORMAT", "CHECKPOINT_NAME", "save_checkpoint", "load_checkpoint", "rng_state", "set_rng_state"]

FORMAT = 1
CHECKPOINT_NAME = "last.pt"


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # not every platform opens folders
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _atomic_write(path: Path, write) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    _fsync_dir(path.parent)


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> Path:
    """Write ``state`` to ``path`` atomically, and a ``.json`` summary beside it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {"format": FORMAT, **state}
    _atomic_write(path, lambda f: torch.save(state, f))
    summary = {k: state.get(k) for k in ("step", "epoch", "run_id", "train_seconds", "world_size")}
    summary["recipe"] = (state.get("recipe") or {}).get("name")
    _atomic_write(path.with_suffix(".json"), lambda f: f.write(json.dumps(summary, indent=2).encode()))
    return path


def load_checkpoint(
    path: str | Path, map_location: str | torch.device = "cpu", *, mmap: bool = False
) -> dict[str, Any]:
    """Read a checkpoint written by :func:`save_checkpoint` (tensors only: no code is unpickled).

    ``mmap=True`` maps the file instead of reading it: cheap when only a few fields are needed.
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no checkpoint there")
    try:
        state = torch.load(path, map_location=map_location, weights_only=True, mmap=mmap)
    except Exception as e:  # torch raises many kinds for a damaged or foreign file
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        raise CheckpointError(
            f"{path}: not a readable svbrdf-train checkpoint ({type(e).__name__}: {first[:200]})"
        ) from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        got = state.get("format") if isinstance(state, dict) else type(state).__name__
        raise CheckpointError(
            f"{path}: not an svbrdf-train checkpoint of format {FORMAT} (got {got!r}); "
            "it was written by another tool or version"
        )
    return state


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
