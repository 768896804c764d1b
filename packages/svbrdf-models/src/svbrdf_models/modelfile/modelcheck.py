"""Reading and checking one local model file, before anything uses it.

:func:`read_model_file` checks, in order: the file's ``NAME.sha256`` sidecar if it has one
(:func:`check_sidecar`), its size once unpacked (:func:`check_archive`), every field of its
header against the table of :mod:`svbrdf_models.modelfile.files` (:func:`check_contents`), then the
generator's config and size, and the weights' names, shapes and values; only then is the
generator built (a :class:`~svbrdf_models.modelfile.trained.TrainedModel`). Each refusal is one line
(:class:`~svbrdf_models.errors.ModelFileError`) naming the file and what is wrong.

:func:`nonfinite_tensors`, :func:`weights_mismatch` and :func:`unreadable_reason` are shared
with svbrdf-train's training checkpoints.
"""

from __future__ import annotations

import hashlib
import math
import re
import zipfile
from pathlib import Path
from typing import Any

import torch
from torch import nn

from .._registry import check_input_size, create_generator, list_models, resolve_config
from ..errors import ModelFileError, RegistryError, UnknownNameError
from ..networks.generators import MAX_PARAMETERS
from .trained import TrainedModel

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "MAX_RESOLUTION",
    "MAX_EXPANDED_BYTES",
    "MAX_EXPANSION",
    "file_sha256",
    "is_model_file",
    "read_model_file",
    "check_sidecar",
    "check_archive",
    "check_contents",
    "nonfinite_tensors",
    "weights_mismatch",
    "unreadable_reason",
]

FORMAT = "svbrdf-model"
FORMAT_VERSION = 1
#: The largest training resolution a model file may give: 8192 px, the largest map size the
#: tools make (``svbrdf-models predict --map-size``); photos are resized to it before the network.
MAX_RESOLUTION = 8192
#: What a model file may expand to when loaded: the weights of the largest generator a config
#: may ask for (:data:`svbrdf_models.networks.generators.MAX_PARAMETERS`, 500 million float32 values, 2 GB)
#: and 64 MiB for its recipe and provenance.
MAX_EXPANDED_BYTES = 4 * MAX_PARAMETERS + 64 * 2**20
#: How many times its size on disk a model file may expand to. ``torch.save`` stores every entry
#: uncompressed (expansion 1); a copy re-packed with compression gains little on float weights.
MAX_EXPANSION = 2.0


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file (hex), read in blocks of 1 MiB."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def is_model_file(path: str | Path) -> bool:
    """Whether ``path`` is a model file (cheap: the file is mapped, not read); False for anything
    else, including a training checkpoint, an unreadable file or one over the size bounds."""
    try:
        check_archive(Path(path), str(path))
        state = torch.load(Path(path), map_location="cpu", weights_only=True, mmap=True)
    except Exception:  # not a torch zip file, or holds more than tensors: not ours
        return False
    return isinstance(state, dict) and state.get("format") == FORMAT


def read_model_file(
    path: Path, device: str | torch.device = "cpu", source: str | None = None
) -> TrainedModel:
    """Load and check one local model file (see :func:`svbrdf_models.modelfile.files.load_model`): its
    ``.sha256`` sidecar if it has one, its size once unpacked, every field of its header, then
    its weights."""
    source = source or str(path)
    if not path.is_file():
        what = "a folder, not a model file" if path.is_dir() else "no model file there"
        raise ModelFileError(f"{source}: {what}")
    sha = file_sha256(path)
    check_sidecar(path, sha, source)
    return _load_checked(path, device, source, sha)


def _load_checked(path: Path, device, source: str, sha256: str) -> TrainedModel:
    """The model of a file whose SHA-256 is known (checked against a sidecar or a URL's name):
    its size once unpacked, then its header, then its generator and weights."""
    check_archive(path, source)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many kinds for a damaged or foreign file
        raise ModelFileError(f"{source}: not a readable model file ({unreadable_reason(e)})") from None
    return _build(check_contents(state, source), device, source, sha256)


def check_sidecar(path: Path, sha256: str, source: str | None = None) -> None:
    """Refuse a model file whose ``NAME.sha256`` sidecar (``HEX  NAME``, as ``sha256sum`` and
    ``svbrdf-train export`` write it) gives another SHA-256 than ``sha256``, the file's own:
    the file changed after it was written (damaged in transfer, or tampered with). A file
    without a sidecar is read as it is."""
    source = source or str(path)
    sidecar = path.with_name(path.name + ".sha256")
    if not sidecar.is_file():
        return
    try:
        words = sidecar.read_text(encoding="utf-8", errors="replace").split()
    except OSError as e:
        raise ModelFileError(
            f"{source}: its checksum file {sidecar} cannot be read ({e.strerror or e})"
        ) from None
    want = words[0].lower().lstrip("\\") if words else ""
    if not re.fullmatch(r"[0-9a-f]{64}", want):
        raise ModelFileError(
            f"{source}: its checksum file {sidecar} holds no SHA-256 (64 hex digits); "
            "write it again with sha256sum, or delete it"
        )
    if want != sha256:
        raise ModelFileError(
            f"{source}: its SHA-256 is {sha256[:16]}..., but {sidecar.name} beside it says "
            f"{want[:16]}...: the file changed after it was written (damaged or tampered with); "
            "get the file again, or delete the stale .sha256 if you changed it on purpose"
        )


def check_archive(path: Path, source: str | None = None) -> None:
    """Refuse a model file whose zip archive declares more than :data:`MAX_EXPANDED_BYTES` once
    unpacked, or more than :data:`MAX_EXPANSION` times its size on disk, before torch unpacks it.

    The sizes are those of the archive's central directory, which torch's reader allocates by.
    A file that is not a zip archive is left for ``torch.load`` to judge (it reads no compressed
    entries then)."""
    source = source or str(path)
    try:
        with zipfile.ZipFile(path) as archive:
            expanded = sum(info.file_size for info in archive.infolist())
    except (zipfile.BadZipFile, OSError, ValueError, EOFError):
        return
    on_disk = max(1, path.stat().st_size)
    if expanded > MAX_EXPANDED_BYTES or expanded > MAX_EXPANSION * on_disk:
        raise ModelFileError(
            f"{source}: it would expand to {_bytes(expanded)} from {_bytes(on_disk)} on disk; a model "
            f"file holds at most {_bytes(MAX_EXPANDED_BYTES)} and is stored uncompressed (at most "
            f"{MAX_EXPANSION:g} times its size): not a file svbrdf-train export wrote"
        )


def _bytes(n: int) -> str:
    for unit, size in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n} bytes"


# -- the header's schema --------------------------------------------------------------------


def _shown(value: Any) -> str:
    if isinstance(value, torch.Tensor):
        return f"a tensor of shape {tuple(value.shape)}"
    try:
        text = repr(value)
    except ValueError:  # an int too long to print
        text = f"a {type(value).__name__}"
    text = text if len(text) <= 60 else text[:57] + "..."
    return f"{text} ({type(value).__name__})"


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_text_list(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(v, str) for v in value)


def _count_at_least(low: int) -> Any:
    return lambda v: _is_int(v) and v >= low


def _finite_seconds(value: Any) -> bool:
    return _is_number(value) and math.isfinite(value) and value >= 0


#: The provenance fields that tools read (``show``, the benchmark), and what each must be.
_PROVENANCE = {
    "steps": (_count_at_least(0), "an integer >= 0"),
    "samples": (_count_at_least(0), "an integer >= 0"),
    "world_size": (_count_at_least(1), "an integer >= 1"),
    "train_seconds": (_finite_seconds, "a finite number of seconds >= 0"),
    "wall_seconds": (_finite_seconds, "a finite number of seconds >= 0"),
    "data": (lambda v: v is None or isinstance(v, dict), "a dict"),
    "half_effect": (lambda v: v is None or isinstance(v, dict), "a dict"),
}
_SOURCE = {
    "source": (lambda v: isinstance(v, str), "a name"),
    "weight": (_is_number, "a number"),
    "seed": (_is_int, "an integer"),
    "path": (_is_text_list, "a list of paths"),
    "files": (_is_text_list, "a list of file names"),
}


def check_contents(state: Any, source: str) -> dict[str, Any]:
    """``state`` if it is a model file's dict of a format this version reads and every field of
    the table of :mod:`svbrdf_models.modelfile.files` has its type and range, else one line naming the
    file and the field."""
    _check_format(state, source)

    def bad(key: str, expected: str, value: Any) -> ModelFileError:
        return ModelFileError(
            f"{source}: damaged model file: field {key!r} must be {expected}, got {_shown(value)}"
        )

    if state["version"] < 1:
        raise bad("version", f"an integer from 1 to {FORMAT_VERSION}", state["version"])
    _check_network(state, bad)
    _check_records(state, bad)
    return state


def _check_format(state: Any, source: str) -> None:
    """Refuse what is not a model file, a format newer than :data:`FORMAT_VERSION`, and a file
    without the fields every model file has."""
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        hint = (
            "a training checkpoint: make a model file of it with `svbrdf-train export`"
            if isinstance(state, dict) and "generator" in state and "recipe" in state
            else "a file of another tool"
        )
        raise ModelFileError(f"{source}: not an svbrdf model file ({hint})")
    version = state.get("version")
    if not _is_int(version) or version > FORMAT_VERSION:
        raise ModelFileError(
            f"{source}: model file format {version!r} is newer than this svbrdf-models reads "
            f"({FORMAT_VERSION}); upgrade svbrdf-models"
        )
    missing = [k for k in ("generator", "weights", "resolution") if k not in state]
    if missing:
        raise ModelFileError(f"{source}: damaged model file (no {', '.join(missing)})")


def _check_network(state: dict[str, Any], bad) -> None:
    """The fields the generator is built from: its name and config, the weights (named tensors,
    at most :data:`svbrdf_models.networks.generators.MAX_PARAMETERS` values), resolution and precision."""
    generator = state["generator"]
    if not isinstance(generator, dict):
        raise bad("generator", "a dict of name and config", generator)
    name = generator.get("name")
    if not isinstance(name, str) or not name:
        raise bad("generator.name", "a registered generator's name", name)
    config = generator.get("config")
    if config is not None and not (isinstance(config, dict) and all(isinstance(k, str) for k in config)):
        raise bad("generator.config", "a dict of config fields", config)
    weights = state["weights"]
    if not isinstance(weights, dict) or not weights:
        raise bad("weights", "a non-empty dict of named tensors (a state_dict)", weights)
    for key, value in weights.items():
        if not isinstance(key, str) or not isinstance(value, torch.Tensor):
            raise bad(f"weights[{key!r}]", "a tensor named by a string", value)
    count = sum(t.numel() for t in weights.values())
    if count > MAX_PARAMETERS:
        raise bad("weights", f"at most {MAX_PARAMETERS:,} values", f"{count:,} values")
    resolution = state["resolution"]
    if not _is_int(resolution) or not 1 <= resolution <= MAX_RESOLUTION:
        raise bad("resolution", f"an integer number of pixels from 1 to {MAX_RESOLUTION}", resolution)
    precision = state.get("precision", "fp32")
    if precision not in ("fp32", "fp16"):
        raise bad("precision", "'fp32' or 'fp16'", precision)


def _check_records(state: dict[str, Any], bad) -> None:
    """The fields for people and tools: recipe, provenance (the fields tools read) and metrics."""
    for key in ("recipe", "provenance", "metrics"):
        if state.get(key) is not None and not isinstance(state[key], dict):
            raise bad(key, "a dict", state[key])
    provenance = state.get("provenance") or {}
    for key, (fits, expected) in _PROVENANCE.items():
        if key in provenance and not fits(provenance[key]):
            raise bad(f"provenance.{key}", expected, provenance[key])
    sources = (provenance.get("data") or {}).get("sources")
    if sources is not None and not isinstance(sources, list):
        raise bad("provenance.data.sources", "a list", sources)
    for i, entry in enumerate(sources or []):
        if not isinstance(entry, dict):
            raise bad(f"provenance.data.sources[{i}]", "a dict", entry)
        for key, (fits, expected) in _SOURCE.items():
            if key in entry and not fits(entry[key]):
                raise bad(f"provenance.data.sources[{i}].{key}", expected, entry[key])
    for map_name, effect in (provenance.get("half_effect") or {}).items():
        if not (isinstance(effect, dict) and all(_is_number(effect.get(k)) for k in ("rmse", "max"))):
            raise bad(f"provenance.half_effect.{map_name}", "a dict of numbers rmse and max", effect)
    for key, value in (state.get("metrics") or {}).items():
        if not isinstance(key, str) or not _is_number(value):
            raise bad(f"metrics[{key!r}]", "a number named by a string", value)


def _build(state: dict[str, Any], device: str | torch.device, source: str, sha256: str) -> TrainedModel:
    """The generator of a checked header (:func:`check_contents`): its config resolved and
    bounded (:data:`svbrdf_models.networks.generators.MAX_PARAMETERS`) and the resolution checked against
    it before any layer is built, then the weights' names and shapes, then their values."""
    name = state["generator"]["name"]
    config = state["generator"].get("config") or {}
    try:
        resolve_config("generator", name, config)
    except UnknownNameError:
        raise ModelFileError(
            f"{source}: its generator {name!r} is not installed here (installed: "
            f"{', '.join(list_models('generator'))}); install the plugin that provides it"
        ) from None
    except RegistryError as e:
        raise ModelFileError(
            f"{source}: its generator config does not fit the installed {name!r} ({e})"
        ) from None
    resolution = state["resolution"]
    try:
        check_input_size("generator", name, config, resolution)
    except RegistryError as e:
        raise ModelFileError(
            f"{source}: damaged model file: field 'resolution' ({resolution}) does not fit its "
            f"generator ({e})"
        ) from None
    generator = create_generator(name, config)
    weights = state["weights"]
    why = weights_mismatch(generator, weights)  # shapes first: the generator's are bounded
    if why:
        raise ModelFileError(f"{source}: the weights do not fit generator {name!r} ({why})")
    bad = nonfinite_tensors(weights)
    if bad:
        raise ModelFileError(
            f"{source}: {len(bad)} weight tensors hold NaN or infinite values (first {bad[0]!r})"
        )
    generator.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in weights.items()})
    return TrainedModel(
        generator=generator.to(device).eval(),
        name=name,
        config=dict(config),
        resolution=resolution,
        precision=str(state.get("precision", "fp32")),
        source=source,
        sha256=sha256,
        recipe=dict(state.get("recipe") or {}),
        provenance=dict(state.get("provenance") or {}),
        metrics=dict(state.get("metrics") or {}),
    )


# -- checks shared with training checkpoints ----------------------------------------------------


def nonfinite_tensors(weights: dict[str, Any] | None) -> list[str]:
    """Names of the floating-point tensors of a state dict holding NaN or infinite values."""
    return [
        name
        for name, t in (weights or {}).items()
        if isinstance(t, torch.Tensor) and t.is_floating_point() and not bool(torch.isfinite(t).all())
    ]


def weights_mismatch(module: nn.Module, weights: dict[str, Any]) -> str | None:
    """How a state dict differs from ``module``'s, in a few words; None when it fits."""
    own = module.state_dict()
    missing = [k for k in own if k not in weights]
    extra = [k for k in weights if k not in own]
    reshaped = [
        k
        for k in own
        if k in weights and isinstance(weights[k], torch.Tensor) and weights[k].shape != own[k].shape
    ]
    parts = [
        f"{len(keys)} {word}" + (f" (e.g. {keys[0]!r})" if keys else "")
        for keys, word in ((missing, "missing"), (extra, "unexpected"), (reshaped, "of another shape"))
        if keys
    ]
    return f"{', '.join(parts)} of {len(own)} tensors" if parts else None


def _first_line(error: Exception) -> str:
    text = str(error).strip()
    return text.splitlines()[0][:200] if text else type(error).__name__


def unreadable_reason(error: Exception) -> str:
    """torch's reason in a few words; never its advice to unpickle the file unsafely."""
    text = str(error)
    if "weights_only" in text or "Weights only load failed" in text:
        return (
            "it holds Python objects besides tensors, which are never unpickled here since they "
            "could run code: a file from another tool, or one that was tampered with"
        )
    if "central directory" in text or "failed finding" in text or "EOF" in text or "truncated" in text:
        return f"truncated or damaged: {type(error).__name__}"
    return f"{type(error).__name__}: {_first_line(error)}" if text.strip() else type(error).__name__
