"""Model files from elsewhere: URLs (downloaded once into a cache, SHA-256 checked) and MLflow
URIs (:mod:`svbrdf_models.modelfile.pyfunc` models, or a folder with one ``.pt`` file).

A URL's file name must end in ``-HEX.EXT``, HEX being the first 8 or more hex digits of the
file's SHA-256 (:func:`hash_name` names files so). The download goes to a temporary file beside
the cache's copy and is moved in only once it matched its hash and loaded; a server that sends
nothing for ``SVBRDF_DOWNLOAD_TIMEOUT`` seconds (default :data:`DOWNLOAD_TIMEOUT`) is given up on.
"""

from __future__ import annotations

import hashlib
import os
import re
import sys
import tempfile
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import torch

from svbrdf_render.plumbing import positive_number

from ..errors import ModelFileError
from .modelcheck import MAX_EXPANDED_BYTES, _bytes, _first_line, _load_checked, file_sha256, read_model_file
from .trained import TrainedModel

__all__ = ["DOWNLOAD_TIMEOUT", "MLFLOW_SCHEMES", "PYFUNC_ARTIFACT", "download_timeout", "hash_name"]

_HASH_IN_NAME = re.compile(r"-([0-9a-f]{8,64})\.[A-Za-z0-9]+$")
#: How MLflow URIs start: registered models and runs.
MLFLOW_SCHEMES = ("models:/", "runs:/")
#: The name of the model file among the artifacts of an MLflow model (:mod:`svbrdf_models.modelfile.pyfunc`).
PYFUNC_ARTIFACT = "model_file"
#: Seconds a download may wait for the server's next bytes (``SVBRDF_DOWNLOAD_TIMEOUT`` overrides).
DOWNLOAD_TIMEOUT = 30.0


def hash_name(path: str | Path, sha256: str) -> Path:
    """``NAME.pt`` -> ``NAME-<first 8 hex digits of sha256>.pt``: the name torch.hub checks."""
    path = Path(path)
    stem = (
        _HASH_IN_NAME.sub("", path.name).rsplit(".", 1)[0] if _HASH_IN_NAME.search(path.name) else path.stem
    )
    return path.with_name(f"{stem}-{sha256[:8]}{path.suffix or '.pt'}")


def download_timeout() -> float:
    """Seconds a download waits for the server's next bytes: ``SVBRDF_DOWNLOAD_TIMEOUT`` (a
    number > 0), else :data:`DOWNLOAD_TIMEOUT`."""
    raw = os.environ.get("SVBRDF_DOWNLOAD_TIMEOUT", "").strip()
    if not raw:
        return DOWNLOAD_TIMEOUT
    value = positive_number(raw)
    if value is None:
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
    from svbrdf_render.plumbing import temporary_path, write_failure

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
    from svbrdf_render.plumbing import write_failure

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
    by :mod:`svbrdf_models.modelfile.pyfunc`) names, else the folder's one ``.pt`` file (how versions
    registered before the pyfunc flavour were logged)."""
    if (folder / "MLmodel").is_file():
        from mlflow.models import Model

        flavour = Model.load(str(folder)).flavors.get("python_function") or {}
        entry = (flavour.get("artifacts") or {}).get(PYFUNC_ARTIFACT)
        if not entry:
            raise ModelFileError(
                f"{uri}: an MLflow model without an svbrdf model file (no artifact {PYFUNC_ARTIFACT!r}); "
                "log model files with svbrdf_models.modelfile.pyfunc.log_pyfunc_model"
            )
        return folder / entry["path"]
    files = sorted(folder.rglob("*.pt"))
    if len(files) != 1:
        raise ModelFileError(
            f"{uri}: expected one .pt model file there, found {len(files)}; name the file in the URI"
        )
    return files[0]
