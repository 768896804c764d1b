"""Trained generators as single files: what ``svbrdf-train export`` writes and inference loads.

Loading needs only this package and svbrdf-render (and mlflow for MLflow URIs)::

    import svbrdf_models as sm
    model = sm.load_model("pretrained")               # the model shipped with this package
    model = sm.load_model("model.pt")                 # a file svbrdf-train export wrote
    model = sm.load_model("https://host/ours-1a2b3c4d.pt")  # downloaded once, SHA-256 checked
    model = sm.load_model("models:/svbrdf-ours/3")    # the MLflow model registry (mlflow installed)
    maps = model.predict(photo)                       # (3, H, W) linear photo -> SVBRDF of one
    maps = model.predict(photo, refine=150)           # + refined against the photo, at its size

This module saves model files and finds the one a source names; the public names of model files
are stated by :mod:`svbrdf_models.modelfile`, each defined in one module:
:mod:`~svbrdf_models.modelfile.trained` (:class:`~svbrdf_models.modelfile.trained.TrainedModel`,
the predictor), :mod:`~svbrdf_models.modelfile.modelcheck` (reading and checking a local file)
and :mod:`~svbrdf_models.modelfile.download` (URLs and MLflow URIs).

A model file is one ``torch.save`` dict of tensors and plain values, read with
``weights_only=True`` (no code is unpickled):

===========  ===================================================================================
key          what
===========  ===================================================================================
format       ``"svbrdf-model"``; ``version``: :data:`.modelcheck.FORMAT_VERSION`
generator    ``{"name": registry name, "config": its complete resolved config}``
weights      the generator's ``state_dict``: float32, or float16 with ``precision: "fp16"``
precision    ``"fp32"`` or ``"fp16"`` (the weights are rounded; they run in float32)
resolution   the side in pixels the generator was trained at: photos are resized to it
recipe       the training recipe (a dict), for people
provenance   where the weights came from: git sha, steps, training time, data, run, hardware
metrics      figures measured on the weights (name -> float), possibly empty
===========  ===================================================================================

An MLflow URI names an MLflow model (:mod:`svbrdf_models.modelfile.pyfunc`: what fits and ``svbrdf-train
export --register`` log; its model file is the artifact :data:`.download.PYFUNC_ARTIFACT`), a
folder holding one ``.pt`` file (versions registered before the MLflow model), or a file.

Every key is checked against that table (types, ranges, the provenance fields tools read)
before anything uses the file: a field of the wrong type or out of range is one line naming the
file and the field. A file whose ``NAME.sha256`` sidecar (what ``svbrdf-train export`` writes
beside it) gives another SHA-256 is refused: it changed after it was written. A file whose zip
archive declares more than :data:`.modelcheck.MAX_EXPANDED_BYTES`, or more than
:data:`.modelcheck.MAX_EXPANSION` times its own size, is refused before it is unpacked:
``torch.save`` stores tensors uncompressed, so
a model file is about as large on disk as in memory, and one that inflates far beyond its size
was packed by another tool to exhaust the memory of whoever loads it.

A URL is downloaded into torch.hub's cache (``TORCH_HOME``, or ``model_dir``). Its file name
must end in ``-HEX.EXT``, HEX being the first 8 or more hex digits of the file's SHA-256
(``svbrdf-train export --hash-name`` names files so). The SHA-256 is compared here, on the
whole name's last ``-HEX`` (torch.hub's own check reads the first ``-`` of the name and passes
``x-.y-deadbeef.pt`` unchecked). A download goes to a temporary file beside the cache's copy
and is moved in only once it matched its hash and loaded; any refusal, an interrupt or a
timeout leaves nothing in the cache. A server that sends nothing for
``SVBRDF_DOWNLOAD_TIMEOUT`` seconds (default :data:`.download.DOWNLOAD_TIMEOUT`) is given up
on, in one line naming the URL and the setting. A cached copy that no longer matches its name is refused.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from .._config import config_to_dict
from .._registry import resolve_config
from ..errors import ModelFileError
from .download import MLFLOW_SCHEMES, _from_mlflow, _from_url
from .modelcheck import FORMAT, FORMAT_VERSION, file_sha256, read_model_file
from .trained import TrainedModel

__all__ = ["PRETRAINED", "card_path", "load_model", "model_dict", "pretrained_path", "save_model"]

#: The model shipped inside this package (``pretrained/NAME.pt``, its card ``NAME.md``): what
#: ``load_model("pretrained")`` and ``svbrdf-models predict`` without ``--model`` use.
PRETRAINED = "ours-general-cpu"
_PRETRAINED_DIR = Path(__file__).parent.parent / "pretrained"


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
    from svbrdf_render.plumbing import atomic_output

    path = Path(path)
    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        torch.save(contents, f)
    return file_sha256(path)


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
    if text.startswith(MLFLOW_SCHEMES):
        return _from_mlflow(text, device)
    return read_model_file(Path(text).expanduser(), device, text)
