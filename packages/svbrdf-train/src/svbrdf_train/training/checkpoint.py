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
target (:func:`svbrdf_render.plumbing.atomic_output`), so a fit killed at any instant leaves the
previous checkpoint or the new one, never a mix; a full disk leaves the previous one and no
temporary file. A fit killed by SIGKILL mid-write leaves its ``.last.pt.PID.tmp``:
:func:`remove_leftovers` clears such files when the next fit in that folder starts. A small
``last.json`` beside the checkpoint says which step and run it holds, for people and scripts.

``weights.pt`` (:data:`WEIGHTS_NAME`) beside it holds the same minus ``optimizers``,
``schedule`` and ``rng``: what predicting or ``--init`` needs, and what a fit uploads to its
MLflow run (``checkpoints/weights.pt``), about a third of the size with Adam's two moments.

Loading checks the header against :data:`HEADER` before anything uses it (a field of the wrong
type or out of range is one line naming the file and the field), refuses NaN or infinite
weights (naming the checkpoint), and :func:`load_weights` says in one line how weights differ
from a network instead of torch's list of every key. :func:`check_resumable` checks what only
``--resume`` needs (optimiser and random states), field by field as well.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from svbrdf_models.modelfile.modelcheck import file_sha256, nonfinite_tensors, unreadable_reason, weights_mismatch
from svbrdf_render.plumbing import atomic_output, remove_stale_temporaries, write_text

from ..errors import CheckpointError

__all__ = [
    "FORMAT",
    "CHECKPOINT_NAME",
    "WEIGHTS_NAME",
    "BEST_NAME",
    "save_checkpoint",
    "load_checkpoint",
    "load_weights",
    "check_finite",
    "check_checksum",
    "HEADER",
    "check_header",
    "check_resumable",
    "check_run_kept",
    "remove_leftovers",
    "rng_state",
    "set_rng_state",
]

FORMAT = 1
CHECKPOINT_NAME = "last.pt"
#: The weights alone (no optimiser or random state), written beside it: what MLflow gets.
WEIGHTS_NAME = "weights.pt"
#: The weights of the best validation so far (``train.keep_best``), in weights.pt's form plus
#: ``best``: ``{"metric", "value", "step"}``.
BEST_NAME = "best.pt"
#: The folder of the weights saved at training budgets (``train.snapshot_minutes`` and
#: ``train.snapshot_steps``): ``minutes-M.pt`` and ``steps-N.pt``, weights.pt's form plus
#: ``snapshot``: ``{"kind", "mark", "step", "seconds"}``.
SNAPSHOTS_DIR = "snapshots"


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
    summary["sha256"] = file_sha256(path)
    try:
        write_text(path.with_suffix(".json"), json.dumps(summary, indent=2))
    except BaseException:  # the old summary would call the new checkpoint damaged: it goes
        path.with_suffix(".json").unlink(missing_ok=True)
        raise
    return path


def check_checksum(path: str | Path, source: str) -> None:
    """Refuse a checkpoint whose bytes differ from the SHA-256 that :func:`save_checkpoint`
    recorded in the summary beside it (no summary, or one without a checksum: nothing to check).
    A zip's own checks miss most damage: 64 zeroed bytes in a tensor read back as other weights."""
    path = Path(path)
    try:
        recorded = json.loads(path.with_suffix(".json").read_text()).get("sha256")
    except (OSError, ValueError, AttributeError):
        return
    if isinstance(recorded, str) and recorded != file_sha256(path):
        raise CheckpointError(
            f"{source}: its bytes do not match the SHA-256 recorded beside it "
            f"({path.with_suffix('.json').name}) when it was written: the file is damaged (disk, "
            "copy); use another copy, resume from the weights alone (--init OUT/weights.pt, without "
            "the optimiser's state) or start afresh (--force)"
        )


def remove_leftovers(folder: str | Path) -> list[Path]:
    """Remove the temporary checkpoint files of fits in ``folder`` that were killed mid-write."""
    names = [n for name in (CHECKPOINT_NAME, WEIGHTS_NAME, BEST_NAME) for n in (name, Path(name).stem + ".json")]
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
        CheckpointError: missing, unreadable, of another format, with a header field of the wrong
            type or range (:data:`HEADER`), or with NaN/infinite weights.
    """
    path = Path(path)
    source = source or str(path)
    if not path.is_file():
        raise CheckpointError(f"{source}: no checkpoint there")
    check_checksum(path, source)
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
    check_header(state, source)
    if (not mmap) if check is None else check:
        for key in ("generator", "discriminator"):
            check_finite(state.get(key), f"{source}: the {key}'s weights")
    return state


def _count(value: Any, low: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= low


def _seconds(value: Any) -> bool:
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    return number and math.isfinite(value) and value >= 0


def _tensors(value: Any) -> bool:
    return isinstance(value, Mapping) and all(isinstance(v, torch.Tensor) for v in value.values())


def _names(value: Any) -> bool:
    return value is None or (isinstance(value, Mapping) and all(isinstance(v, str) for v in value.values()))


#: What each header field of a checkpoint must be, when it is there: (check, what it must be).
#: ``recipe`` and ``generator`` are required by the commands that need them (:func:`load_init`,
#: ``--resume``, predict); the rest may be missing from files of older versions.
HEADER: dict[str, tuple[Any, str]] = {
    "recipe": (lambda v: isinstance(v, Mapping), "a mapping of recipe sections"),
    "step": (lambda v: _count(v, 0), "a whole number of steps >= 0"),
    "epoch": (lambda v: _count(v, 0), "a whole number >= 0"),
    "generator": (_tensors, "a mapping of weight names to tensors"),
    "discriminator": (lambda v: v is None or _tensors(v), "a mapping of weight names to tensors, or None"),
    "train_seconds": (_seconds, "a finite number of seconds >= 0"),
    "wall_seconds": (_seconds, "a finite number of seconds >= 0"),
    "world_size": (lambda v: _count(v, 1), "a whole number of processes >= 1"),
    "run_id": (lambda v: v is None or isinstance(v, str), "an MLflow run id or None"),
    "init": (_names, "a mapping of tag names to text, or None"),
    "made_with": (_names, "a mapping of names to text, or None"),
}


def _refuse(source: str, field: str, value: Any, expected: str) -> CheckpointError:
    shown = type(value).__name__ if isinstance(value, (Mapping, list, tuple, torch.Tensor)) else repr(value)
    return CheckpointError(
        f"{source}: field {field!r} must be {expected}, got {shown[:80]}; the checkpoint is damaged "
        "or was not written by svbrdf-train: use another one"
    )


def check_header(state: Mapping[str, Any], source: str) -> None:
    """Refuse a checkpoint whose header fields (:data:`HEADER`) have the wrong type or range.

    Raises:
        CheckpointError: naming ``source`` and the field.
    """
    for field, (ok, expected) in HEADER.items():
        if field in state and not ok(state[field]):
            raise _refuse(source, field, state[field], expected)


def _optimizer_ok(value: Any) -> bool:
    groups = value.get("param_groups") if isinstance(value, Mapping) else None
    return (
        isinstance(value.get("state") if isinstance(value, Mapping) else None, Mapping)
        and isinstance(groups, list)
        and bool(groups)
        and all(isinstance(g, Mapping) and isinstance(g.get("params"), list) for g in groups)
    )


def _byte_state(value: Any) -> bool:
    return isinstance(value, torch.Tensor) and value.dtype == torch.uint8 and value.dim() == 1


def check_resumable(state: Mapping[str, Any], source: str) -> None:
    """Refuse a checkpoint that ``--resume`` cannot continue: besides :func:`check_header`, it
    must hold the recipe, the step, the generator, an Adam state per network (``optimizers``:
    ``g``, and ``d`` with a discriminator) and every process's random state (``rng``: torch's
    CPU state, as long as this torch's, and the scene sampler's).

    Raises:
        CheckpointError: naming ``source`` and the field.
    """
    check_header(state, source)
    for field in ("recipe", "step", "generator"):
        if field not in state:
            raise CheckpointError(f"{source}: no {field!r} in the checkpoint; it cannot be resumed")
    optimizers = state.get("optimizers")
    names = ("g", "d") if state.get("discriminator") is not None else ("g",)
    if not isinstance(optimizers, Mapping) or any(not _optimizer_ok(optimizers.get(n)) for n in names):
        expected = f"the Adam states of {' and '.join(repr(n) for n in names)} (state and param_groups)"
        raise _refuse(source, "optimizers", optimizers, expected)
    rng = state.get("rng")
    world = state.get("world_size", 1)
    size = torch.get_rng_state().numel()
    if not isinstance(rng, (list, tuple)) or len(rng) != world:
        raise _refuse(source, "rng", rng, f"a list of {world} random state(s), one per process")
    for rank, one in enumerate(rng):
        torch_state = one.get("torch") if isinstance(one, Mapping) else None
        if not _byte_state(torch_state) or torch_state.numel() != size:
            expected = f"torch's CPU random state ({size} bytes)"
            raise _refuse(source, f"rng[{rank}].torch", torch_state, expected)
        scene = one.get("scene")
        if scene is not None and not _byte_state(scene):
            raise _refuse(source, f"rng[{rank}].scene", scene, "a generator's random state (bytes)")
        cuda = one.get("cuda")
        if cuda is not None and not (isinstance(cuda, (list, tuple)) and all(map(_byte_state, cuda))):
            raise _refuse(source, f"rng[{rank}].cuda", cuda, "a list of CUDA random states (bytes)")


def check_run_kept(run_id: str, what: str, hint: str) -> None:
    """Refuse an MLflow run that was deleted (``lifecycle_stage`` deleted): MLflow still serves
    its artifacts and takes its metrics until the trash is emptied, so reading its checkpoint or
    resuming into it would go on without a word. ``what`` starts the message and ``hint`` says
    what to do. A store that lacks the run is left to the caller's own reading of the run to
    report in its words.

    Raises:
        CheckpointError: the run is deleted.
        TrackingError: the store cannot be used (:func:`svbrdf_train.tracking.open_client`'s
            bounded, one-line refusal: not waited for twice).
    """
    from ..errors import TrackingError
    from ..tracking import open_client, quiet_store_logs, tracking_uri

    uri = tracking_uri()
    try:
        with quiet_store_logs():
            stage = open_client(uri).get_run(run_id).info.lifecycle_stage
    except TrackingError:
        raise
    except Exception:  # MlflowException for a missing run, database errors: reported elsewhere
        return
    if stage == "deleted":
        raise CheckpointError(f"{what}: MLflow run {run_id} was deleted from {uri}; {hint}")


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
