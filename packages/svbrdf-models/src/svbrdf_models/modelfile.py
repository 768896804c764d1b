"""Trained generators as single files: what ``svbrdf-train export`` writes and inference loads.

Loading needs only this package and svbrdf-render (and mlflow for MLflow URIs)::

    import svbrdf_models as sm
    model = sm.load_model("pretrained")               # the model shipped with this package
    model = sm.load_model("model.pt")                 # a file svbrdf-train export wrote
    model = sm.load_model("https://host/ours-1a2b3c4d.pt")  # downloaded once, SHA-256 checked
    model = sm.load_model("models:/svbrdf-ours/3")    # the MLflow model registry (mlflow installed)
    maps = model.predict(photo)                       # (3, H, W) linear photo -> SVBRDF of one
    maps = model.predict(photo, refine=150)           # + refined against the photo, at its size

A model file is one ``torch.save`` dict of tensors and plain values, read with
``weights_only=True`` (no code is unpickled):

===========  ===================================================================================
key          what
===========  ===================================================================================
format       ``"svbrdf-model"``; ``version``: :data:`FORMAT_VERSION`
generator    ``{"name": registry name, "config": its complete resolved config}``
weights      the generator's ``state_dict``: float32, or float16 with ``precision: "fp16"``
precision    ``"fp32"`` or ``"fp16"`` (the weights are rounded; they run in float32)
resolution   the side in pixels the generator was trained at: photos are resized to it
recipe       the training recipe (a dict), for people
provenance   where the weights came from: git sha, steps, training time, data, run, hardware
metrics      figures measured on the weights (name -> float), possibly empty
===========  ===================================================================================

An MLflow URI names an MLflow model (:mod:`svbrdf_models.pyfunc`: what fits and ``svbrdf-train
export --register`` log; its model file is the artifact :data:`PYFUNC_ARTIFACT`), a folder
holding one ``.pt`` file (versions registered before the MLflow model), or a file.

Every key is checked against that table (types, ranges, the provenance fields tools read)
before anything uses the file: a field of the wrong type or out of range is one line naming the
file and the field. A file whose ``NAME.sha256`` sidecar (what ``svbrdf-train export`` writes
beside it) gives another SHA-256 is refused: it changed after it was written. A file whose zip
archive declares more than :data:`MAX_EXPANDED_BYTES`, or more than :data:`MAX_EXPANSION` times
its own size, is refused before it is unpacked: ``torch.save`` stores tensors uncompressed, so
a model file is about as large on disk as in memory, and one that inflates far beyond its size
was packed by another tool to exhaust the memory of whoever loads it.

A URL is downloaded into torch.hub's cache (``TORCH_HOME``, or ``model_dir``). Its file name
must end in ``-HEX.EXT``, HEX being the first 8 or more hex digits of the file's SHA-256
(``svbrdf-train export --hash-name`` names files so). The SHA-256 is compared here, on the
whole name's last ``-HEX`` (torch.hub's own check reads the first ``-`` of the name and passes
``x-.y-deadbeef.pt`` unchecked). A download goes to a temporary file beside the cache's copy
and is moved in only once it matched its hash and loaded; any refusal, an interrupt or a
timeout leaves nothing in the cache. A server that sends nothing for
``SVBRDF_DOWNLOAD_TIMEOUT`` seconds (default :data:`DOWNLOAD_TIMEOUT`) is given up on, in one
line naming the URL and the setting. A cached copy that no longer matches its name is refused.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import sys
import tempfile
import urllib.error
import urllib.request
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from svbrdf_render import SVBRDF

from ._config import config_to_dict
from ._registry import check_input_size, create_generator, list_models, resolve_config
from .errors import ModelFileError, RegistryError, UnknownNameError
from .generators import MAX_PARAMETERS

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "PRETRAINED",
    "PYFUNC_ARTIFACT",
    "TrainedModel",
    "load_model",
    "save_model",
    "model_dict",
    "pretrained_path",
    "card_path",
    "file_sha256",
    "hash_name",
    "square_photo",
    "weights_mismatch",
    "nonfinite_tensors",
    "unreadable_reason",
    "read_model_file",
    "is_model_file",
    "check_contents",
    "check_sidecar",
    "check_archive",
    "MAX_RESOLUTION",
    "MAX_EXPANDED_BYTES",
    "MAX_EXPANSION",
    "DOWNLOAD_TIMEOUT",
    "download_timeout",
]

FORMAT = "svbrdf-model"
FORMAT_VERSION = 1
#: The model shipped inside this package (``pretrained/NAME.pt``, its card ``NAME.md``).
PRETRAINED = "ours-mix-cpu"
_PRETRAINED_DIR = Path(__file__).parent / "pretrained"
_HASH_IN_NAME = re.compile(r"-([0-9a-f]{8,64})\.[A-Za-z0-9]+$")
_MLFLOW_SCHEMES = ("models:/", "runs:/")
#: The name of the model file among the artifacts of an MLflow model (:mod:`svbrdf_models.pyfunc`).
PYFUNC_ARTIFACT = "model_file"
#: The largest training resolution a model file may give: 8192 px, the largest map size the
#: tools make (``svbrdf-models predict --map-size``); photos are resized to it before the network.
MAX_RESOLUTION = 8192
#: What a model file may expand to when loaded: the weights of the largest generator a config
#: may ask for (:data:`svbrdf_models.generators.MAX_PARAMETERS`, 500 million float32 values, 2 GB)
#: and 64 MiB for its recipe and provenance.
MAX_EXPANDED_BYTES = 4 * MAX_PARAMETERS + 64 * 2**20
#: How many times its size on disk a model file may expand to. ``torch.save`` stores every entry
#: uncompressed (expansion 1); a copy re-packed with compression gains little on float weights.
MAX_EXPANSION = 2.0
#: Seconds a download may wait for the server's next bytes (``SVBRDF_DOWNLOAD_TIMEOUT`` overrides).
DOWNLOAD_TIMEOUT = 30.0


@dataclass
class TrainedModel:
    """A trained generator (eval mode, float32) and what its file says about it."""

    generator: nn.Module
    name: str
    config: dict[str, Any]
    resolution: int
    precision: str
    source: str
    sha256: str
    recipe: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)
    metrics: dict[str, float] = field(default_factory=dict)

    @property
    def steps(self) -> int:
        return int(self.provenance.get("steps", 0))

    @property
    def device(self) -> torch.device:
        return next(self.generator.parameters()).device

    def to(self, device: str | torch.device) -> TrainedModel:
        self.generator.to(device)
        return self

    def predict(
        self,
        photo: Tensor,
        refine: int = 0,
        *,
        seconds: float | None = None,
        scene=None,
        callback=None,
        backend: str | None = None,
    ) -> SVBRDF:
        """Maps of linear photos: ``(3, H, W)`` (one material) or ``(N, 3, H, W)``.

        ``refine=0``: the largest centred square is resized to :attr:`resolution` (antialiased,
        on linear values) when it is not that size already; the maps are at :attr:`resolution`.

        ``refine=STEPS > 0``: the network's maps of that square are then refined against the
        square at its own resolution (:func:`svbrdf_models.refining.refine_prediction`, start
        and prior the network's maps) for at most STEPS steps and ``seconds`` seconds, under
        ``scene`` (default: the flash found from the network's maps), with the renderer's
        ``backend`` (default :data:`svbrdf_models.refining.BACKEND`); ``callback(step, total,
        loss)`` follows it. The maps are at the square's size (the photo's shorter side), which
        must be at least :data:`svbrdf_render.MIN_REFINE_SIDE`.
        """
        batch = self._check_photo(photo)
        from .refining import BACKEND, check_refine, refine_prediction

        steps = check_refine(refine, seconds)
        if steps == 0:
            return self._network(batch)
        squares = torch.stack([square_photo(p.float(), None) for p in batch])
        result = refine_prediction(
            squares,
            self._network(squares).to(self.device),
            steps,
            seconds=seconds,
            scene=scene,
            callback=callback,
            backend=backend or BACKEND,
        )
        return result.svbrdf

    def _check_photo(self, photo: Tensor) -> Tensor:
        """``photo`` as a batch ``(N, 3, H, W)``; :class:`~svbrdf_models.errors.DataError` (one
        line) for another shape, integer values or NaN/infinite values.

        Integer photos (uint8 codes up to 255, 16-bit PNG codes) are refused, not converted:
        their encoding (sRGB or linear) and scale are not in the tensor, and a guess would give
        maps of the wrong brightness without a word. Read files with
        :func:`svbrdf_models.capture.load_photo`, or convert 8-bit sRGB codes with
        ``svbrdf_render.srgb_to_linear(photo / 255)``. NaN or infinite values would come out as
        maps of NaN (a convolution spreads them to every pixel).
        """
        from .errors import DataError

        if not isinstance(photo, Tensor):
            raise DataError(f"{self.source}: expected a photo tensor (3, H, W), got {type(photo).__name__}")
        batch = photo[None] if photo.dim() == 3 else photo
        if batch.dim() != 4 or batch.shape[1] != 3:
            raise DataError(
                f"{self.source}: expected a photo (3, H, W) or (N, 3, H, W), got {tuple(photo.shape)}"
            )
        if not batch.is_floating_point():
            raise DataError(
                f"{self.source}: the photo holds {str(batch.dtype).replace('torch.', '')} codes, not "
                "linear values; convert 8-bit sRGB with svbrdf_render.srgb_to_linear(photo / 255), or "
                "read the file with svbrdf_models.capture.load_photo"
            )
        bad = int((~torch.isfinite(batch)).sum())
        if bad:
            raise DataError(
                f"{self.source}: the photo holds {bad} NaN or infinite values of {batch.numel()}; "
                "the maps would be NaN: fix or drop the photo"
            )
        return batch

    @torch.no_grad()
    def _network(self, batch: Tensor) -> SVBRDF:
        """The generator's maps of ``(N, 3, H, W)`` photos' centre squares at :attr:`resolution`."""
        x = torch.stack([square_photo(p.float(), self.resolution) for p in batch])
        return self.generator(x.to(self.device)).detach().to("cpu")

    def describe(self) -> str:
        """One line for people: generator, resolution, steps, precision, where from."""
        hours = float(self.provenance.get("train_seconds", 0.0)) / 3600
        return (
            f"generator {self.name} ({self.resolution}x{self.resolution}, {self.steps} steps, "
            f"{hours:.1f} h of training, {self.precision}) from {self.source}"
        )


def square_photo(photo: Tensor, size: int | None) -> Tensor:
    """Centre-crop ``(C, H, W)`` to its shorter side, then resample to ``size`` if given.

    Resampling is bilinear with antialiasing (a triangle filter: no overshoot, so values stay
    in range) and happens on linear values, where averaging is physically meaningful.
    """
    _, h, w = photo.shape
    s = min(h, w)
    top, left = (h - s) // 2, (w - s) // 2
    photo = photo[:, top : top + s, left : left + s]
    if size is not None and s != size:
        photo = F.interpolate(
            photo[None], size=(size, size), mode="bilinear", align_corners=False, antialias=True
        )[0]
    return photo.contiguous()


# -- writing ------------------------------------------------------------------------------------


def model_dict(
    generator: str,
    config: dict[str, Any] | None,
    weights: dict[str, Tensor],
    *,
    resolution: int,
    recipe: dict[str, Any] | None = None,
    provenance: dict[str, Any] | None = None,
    metrics: dict[str, float] | None = None,
    half: bool = False,
) -> dict[str, Any]:
    """The contents of a model file; ``config`` is completed with the generator's defaults."""
    full = config_to_dict(resolve_config("generator", generator, config))
    cast = torch.float16 if half else torch.float32
    return {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "generator": {"name": generator, "config": full},
        "weights": {
            k: (v.detach().to("cpu", cast) if v.is_floating_point() else v.detach().cpu()).contiguous()
            for k, v in weights.items()
        },
        "precision": "fp16" if half else "fp32",
        "resolution": int(resolution),
        "recipe": dict(recipe or {}),
        "provenance": dict(provenance or {}),
        "metrics": {k: float(v) for k, v in (metrics or {}).items()},
    }


def save_model(path: str | Path, contents: dict[str, Any]) -> str:
    """Write a :func:`model_dict` to ``path`` atomically; its SHA-256 (hex)."""
    from svbrdf_render.files import atomic_output

    path = Path(path)
    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        torch.save(contents, f)
    return file_sha256(path)


def file_sha256(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def hash_name(path: str | Path, sha256: str) -> Path:
    """``NAME.pt`` -> ``NAME-<first 8 hex digits of sha256>.pt``: the name torch.hub checks."""
    path = Path(path)
    stem = (
        _HASH_IN_NAME.sub("", path.name).rsplit(".", 1)[0] if _HASH_IN_NAME.search(path.name) else path.stem
    )
    return path.with_name(f"{stem}-{sha256[:8]}{path.suffix or '.pt'}")


# -- reading ------------------------------------------------------------------------------------


def pretrained_path(name: str = PRETRAINED) -> Path:
    """The file of a model shipped in this package."""
    path = _PRETRAINED_DIR / f"{name}.pt"
    if not path.is_file():
        have = sorted(p.stem for p in _PRETRAINED_DIR.glob("*.pt")) if _PRETRAINED_DIR.is_dir() else []
        raise ModelFileError(
            f"pretrained:{name}: no such shipped model (shipped: {', '.join(have) or 'none'}); "
            "this installation may lack its package data: reinstall svbrdf-models"
        )
    return path


def card_path(name: str = PRETRAINED) -> Path:
    """The model card (Markdown) of a shipped model: data, training, figures on real materials."""
    return _PRETRAINED_DIR / f"{name}.md"


def load_model(
    source: str | Path,
    device: str | torch.device = "cpu",
    *,
    model_dir: str | Path | None = None,
    progress: bool = False,
) -> TrainedModel:
    """The trained generator a model file holds, from wherever ``source`` says.

    ``source``: ``"pretrained"`` or ``"pretrained:NAME"`` (shipped with this package), a file
    path, an ``http(s)://`` or ``file://`` URL whose name carries its hash (see the module),
    or an MLflow model URI (``models:/NAME/VERSION``, ``models:/NAME@ALIAS``, ``runs:/ID/PATH``;
    needs mlflow, reads ``MLFLOW_TRACKING_URI``). ``model_dir``: torch.hub's cache for URLs.

    Raises:
        ModelFileError: one line: nothing there, not a model file, truncated, a newer format,
            a generator that is not installed, weights that do not fit it or are not finite.
    """
    text = str(source)
    if text == "pretrained" or text.startswith("pretrained:"):
        name = text.partition(":")[2] or PRETRAINED
        return read_model_file(pretrained_path(name), device, f"pretrained:{name}")
    if text.startswith(("http://", "https://", "file://")):
        return _from_url(text, device, model_dir, progress)
    if text.startswith(_MLFLOW_SCHEMES):
        return _from_mlflow(text, device)
    return read_model_file(Path(text).expanduser(), device, text)


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
    """Load and check one local model file (see :func:`load_model`): its ``.sha256`` sidecar
    if it has one, its size once unpacked, every field of its header, then its weights."""
    source = source or str(path)
    if not path.is_file():
        what = "a folder, not a model file" if path.is_dir() else "no model file there"
        raise ModelFileError(f"{source}: {what}")
    sha = file_sha256(path)
    check_sidecar(path, sha, source)
    return _load_checked(path, device, source, sha)


def _load_checked(path: Path, device, source: str, sha256: str) -> TrainedModel:
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
    the module's table has its type and range, else one line naming the file and the field."""
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

    def bad(key: str, expected: str, value: Any) -> ModelFileError:
        return ModelFileError(
            f"{source}: damaged model file: field {key!r} must be {expected}, got {_shown(value)}"
        )

    if version < 1:
        raise bad("version", f"an integer from 1 to {FORMAT_VERSION}", version)
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
    return state


def _build(state: dict[str, Any], device: str | torch.device, source: str, sha256: str) -> TrainedModel:
    """The generator of a checked header (:func:`check_contents`): its config resolved and
    bounded (:data:`svbrdf_models.generators.MAX_PARAMETERS`) and the resolution checked against
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


# -- URLs -------------------------------------------------------------------------------------


def download_timeout() -> float:
    """Seconds a download waits for the server's next bytes: ``SVBRDF_DOWNLOAD_TIMEOUT`` (a
    number > 0), else :data:`DOWNLOAD_TIMEOUT`."""
    raw = os.environ.get("SVBRDF_DOWNLOAD_TIMEOUT", "").strip()
    if not raw:
        return DOWNLOAD_TIMEOUT
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ModelFileError(
            f"SVBRDF_DOWNLOAD_TIMEOUT={raw!r}: expected a number of seconds > 0 "
            f"(default {DOWNLOAD_TIMEOUT:g})"
        )
    return value


def _from_url(url: str, device, model_dir, progress: bool) -> TrainedModel:
    name = url.split("?")[0].rstrip("/").rsplit("/", 1)[-1]
    match = _HASH_IN_NAME.search(name)
    if not match:
        raise ModelFileError(
            f"{url}: its file name carries no SHA-256 prefix (NAME-HEX.pt), so the download "
            "cannot be checked; publish it under the name `svbrdf-train export --hash-name` gives"
        )
    prefix = match.group(1)
    folder = Path(model_dir) if model_dir is not None else Path(torch.hub.get_dir()) / "checkpoints"
    local = folder / name
    if local.is_file():
        sha = file_sha256(local)
        if not sha.startswith(prefix):
            raise ModelFileError(
                f"{url}: the cached copy {local} does not match the SHA-256 in its name; "
                "delete it to download again"
            )
        return _load_checked(local, device, url, sha)
    from svbrdf_render.files import temporary_path, write_failure

    timeout = download_timeout()
    tmp = temporary_path(local)
    try:
        sha = _download(url, tmp, local, timeout, progress)
        if not sha.startswith(prefix):
            raise ModelFileError(
                f"{url}: the download does not match the SHA-256 in its name (it starts "
                f"{sha[: len(prefix)]}, the name says {prefix}); nothing was kept"
            )
        model = _load_checked(tmp, device, url, sha)
        try:
            os.replace(tmp, local)  # kept only once it matched and loaded
        except OSError as e:
            raise write_failure(local, e, "keep the download as") from None
        return model
    finally:
        tmp.unlink(missing_ok=True)


def _download(url: str, tmp: Path, target: Path, timeout: float, progress: bool) -> str:
    """Fetch ``url`` into ``tmp`` (the temporary file of the cache's ``target``); its SHA-256.
    One line (:class:`ModelFileError`) for a server that is silent for ``timeout`` seconds, an
    HTTP error, or more bytes than a model file holds."""
    from svbrdf_render.files import write_failure

    setting = f"SVBRDF_DOWNLOAD_TIMEOUT={timeout:g} s"
    digest, total = hashlib.sha256(), 0
    request = urllib.request.Request(url, headers={"User-Agent": "svbrdf-models"})
    try:
        tmp.parent.mkdir(parents=True, exist_ok=True)
        out = open(tmp, "wb")
    except OSError as e:
        raise write_failure(target, e, "download") from None
    with out:
        try:
            with urllib.request.urlopen(request, timeout=timeout) as response:
                length = response.headers.get("Content-Length")
                if length and length.isdigit() and int(length) > MAX_EXPANDED_BYTES:
                    raise ModelFileError(
                        f"{url}: the server offers {_bytes(int(length))}, more than a model file holds "
                        f"({_bytes(MAX_EXPANDED_BYTES)}); not downloaded"
                    )
                if progress:
                    print(f"downloading {url} ({_bytes(int(length)) if length else 'size unknown'})",
                          file=sys.stderr)  # fmt: skip
                while chunk := response.read(1 << 20):
                    total += len(chunk)
                    if total > MAX_EXPANDED_BYTES:
                        raise ModelFileError(
                            f"{url}: the download passed {_bytes(MAX_EXPANDED_BYTES)}, more than a "
                            "model file holds; stopped, nothing was kept"
                        )
                    digest.update(chunk)
                    try:
                        out.write(chunk)
                    except OSError as e:
                        raise write_failure(target, e, "download") from None
        except TimeoutError:
            raise ModelFileError(
                f"{url}: the server sent nothing for {timeout:g} s ({setting}); try again later, or "
                "raise SVBRDF_DOWNLOAD_TIMEOUT for a slow server"
            ) from None
        except urllib.error.HTTPError as e:
            raise ModelFileError(f"{url}: cannot be fetched (HTTP {e.code} {e.reason})") from None
        except urllib.error.URLError as e:
            if isinstance(e.reason, TimeoutError):
                raise ModelFileError(
                    f"{url}: no connection within {timeout:g} s ({setting}); check the address"
                ) from None
            raise ModelFileError(f"{url}: cannot be fetched ({_first_line_of(e.reason)})") from None
        except OSError as e:  # the connection reset, a file:// path missing
            raise ModelFileError(f"{url}: cannot be fetched ({type(e).__name__}: {_first_line(e)})") from None
    return digest.hexdigest()


def _first_line_of(reason: Any) -> str:
    return _first_line(reason) if isinstance(reason, Exception) else str(reason)


def _from_mlflow(uri: str, device) -> TrainedModel:
    try:
        import mlflow.artifacts
    except ImportError:
        raise ModelFileError(f"{uri}: MLflow URIs need mlflow (pip install mlflow)") from None
    with tempfile.TemporaryDirectory() as tmp:
        try:
            local = Path(mlflow.artifacts.download_artifacts(artifact_uri=uri, dst_path=tmp))
        except Exception as e:  # MlflowException (no such model/run/artifact), OSError, HTTP errors
            raise ModelFileError(
                f"{uri}: not found in the MLflow store {mlflow.get_tracking_uri()} ({_first_line(e)}); "
                "check the name/version or run id and MLFLOW_TRACKING_URI"
            ) from None
        if local.is_dir():
            local = _file_in_folder(local, uri)
        return read_model_file(local, device, uri)


def _file_in_folder(folder: Path, uri: str) -> Path:
    """The model file of a downloaded MLflow folder: the one an MLflow model (``MLmodel``, logged
    by :mod:`svbrdf_models.pyfunc`) names, else the folder's one ``.pt`` file (how versions
    registered before the pyfunc flavour were logged)."""
    if (folder / "MLmodel").is_file():
        from mlflow.models import Model

        flavour = Model.load(str(folder)).flavors.get("python_function") or {}
        entry = (flavour.get("artifacts") or {}).get(PYFUNC_ARTIFACT)
        if not entry:
            raise ModelFileError(
                f"{uri}: an MLflow model without an svbrdf model file (no artifact {PYFUNC_ARTIFACT!r}); "
                "log model files with svbrdf_models.pyfunc.log_pyfunc_model"
            )
        return folder / entry["path"]
    files = sorted(folder.rglob("*.pt"))
    if len(files) != 1:
        raise ModelFileError(
            f"{uri}: expected one .pt model file there, found {len(files)}; name the file in the URI"
        )
    return files[0]


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
