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

A URL is fetched with :func:`torch.hub.load_state_dict_from_url` into torch.hub's cache
(``TORCH_HOME``). Its file name must end in ``-HEX.pt``, HEX being the first 8 or more hex
digits of the file's SHA-256 (``svbrdf-train export --hash-name`` names files so): the download
is refused when they differ, and so is a cached file that no longer matches.
"""

from __future__ import annotations

import hashlib
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from svbrdf_render import SVBRDF

from ._config import config_to_dict
from ._registry import create_generator, list_models, resolve_config
from .errors import ModelFileError, RegistryError, UnknownNameError

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
        batch = photo[None] if photo.dim() == 3 else photo
        if batch.dim() != 4 or batch.shape[1] != 3:
            raise ValueError(
                f"{self.source}: expected a photo (3, H, W) or (N, 3, H, W), got {tuple(photo.shape)}"
            )
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
    else, including a training checkpoint or an unreadable file."""
    try:
        state = torch.load(Path(path), map_location="cpu", weights_only=True, mmap=True)
    except Exception:  # not a torch zip file, or holds more than tensors: not ours
        return False
    return isinstance(state, dict) and state.get("format") == FORMAT


def read_model_file(
    path: Path, device: str | torch.device = "cpu", source: str | None = None
) -> TrainedModel:
    """Load and check one local model file (see :func:`load_model`)."""
    source = source or str(path)
    if not path.is_file():
        what = "a folder, not a model file" if path.is_dir() else "no model file there"
        raise ModelFileError(f"{source}: {what}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many kinds for a damaged or foreign file
        raise ModelFileError(f"{source}: not a readable model file ({unreadable_reason(e)})") from None
    contents = check_contents(state, source)
    return _build(contents, device, source, file_sha256(path))


def check_contents(state: Any, source: str) -> dict[str, Any]:
    """``state`` if it is a model file's dict of a format this version reads, else one line why."""
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        hint = (
            "a training checkpoint: make a model file of it with `svbrdf-train export`"
            if isinstance(state, dict) and "generator" in state and "recipe" in state
            else "a file of another tool"
        )
        raise ModelFileError(f"{source}: not an svbrdf model file ({hint})")
    version = state.get("version")
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise ModelFileError(
            f"{source}: model file format {version!r} is newer than this svbrdf-models reads "
            f"({FORMAT_VERSION}); upgrade svbrdf-models"
        )
    missing = [k for k in ("generator", "weights", "resolution") if k not in state]
    if missing or not isinstance(state["generator"], dict) or "name" not in state["generator"]:
        raise ModelFileError(f"{source}: damaged model file (no {', '.join(missing) or 'generator name'})")
    return state


def _build(state: dict[str, Any], device: str | torch.device, source: str, sha256: str) -> TrainedModel:
    name = state["generator"]["name"]
    config = state["generator"].get("config") or {}
    try:
        generator = create_generator(name, config)
    except UnknownNameError:
        raise ModelFileError(
            f"{source}: its generator {name!r} is not installed here (installed: "
            f"{', '.join(list_models('generator'))}); install the plugin that provides it"
        ) from None
    except RegistryError as e:
        raise ModelFileError(
            f"{source}: its generator config does not fit the installed {name!r} ({e})"
        ) from None
    weights = state["weights"]
    bad = nonfinite_tensors(weights)
    if bad:
        raise ModelFileError(
            f"{source}: {len(bad)} weight tensors hold NaN or infinite values (first {bad[0]!r})"
        )
    why = weights_mismatch(generator, weights)
    if why:
        raise ModelFileError(f"{source}: the weights do not fit generator {name!r} ({why})")
    generator.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in weights.items()})
    return TrainedModel(
        generator=generator.to(device).eval(),
        name=name,
        config=dict(config),
        resolution=int(state["resolution"]),
        precision=str(state.get("precision", "fp32")),
        source=source,
        sha256=sha256,
        recipe=dict(state.get("recipe") or {}),
        provenance=dict(state.get("provenance") or {}),
        metrics=dict(state.get("metrics") or {}),
    )


def _from_url(url: str, device, model_dir, progress: bool) -> TrainedModel:
    name = url.split("?")[0].rstrip("/").rsplit("/", 1)[-1]
    match = _HASH_IN_NAME.search(name)
    if not match:
        raise ModelFileError(
            f"{url}: its file name carries no SHA-256 prefix (NAME-HEX.pt), so the download "
            "cannot be checked; publish it under the name `svbrdf-train export --hash-name` gives"
        )
    folder = Path(model_dir) if model_dir is not None else Path(torch.hub.get_dir()) / "checkpoints"
    try:
        state = torch.hub.load_state_dict_from_url(
            url,
            model_dir=str(folder),
            map_location="cpu",
            progress=progress,
            check_hash=True,
            weights_only=True,
        )
    except RuntimeError as e:
        text = str(e)
        if "invalid hash value" in text:
            raise ModelFileError(
                f"{url}: the download does not match the SHA-256 in its name ({text})"
            ) from None
        raise ModelFileError(f"{url}: not a readable model file ({unreadable_reason(e)})") from None
    except Exception as e:  # URLError, HTTPError, OSError, unpickling errors
        raise ModelFileError(
            f"{url}: cannot be fetched or read ({type(e).__name__}: {_first_line(e)})"
        ) from None
    local = folder / name
    sha = file_sha256(local)
    if not sha.startswith(match.group(1)):  # torch.hub checks downloads only, not its cache
        raise ModelFileError(
            f"{url}: the cached copy {local} does not match the SHA-256 in its name; "
            "delete it to download again"
        )
    return _build(check_contents(state, url), device, url, sha)


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
