"""Model files: a trained generator as one file, loaded for inference.

The public API is :data:`__all__` below, each name imported here from the module that defines
it (its one address beside this one):

- :mod:`~svbrdf_models.modelfile.files`: saving, loading, the shipped models (the file's keys);
- :mod:`~svbrdf_models.modelfile.trained`: :class:`TrainedModel`, the predictor;
- :mod:`~svbrdf_models.modelfile.modelcheck`: reading and checking a local file;
- :mod:`~svbrdf_models.modelfile.download`: URLs and MLflow URIs;
- :mod:`~svbrdf_models.modelfile.pyfunc`: the MLflow model of a file (needs mlflow);
- :mod:`~svbrdf_models.modelfile.serve`: ``svbrdf-models serve`` (needs starlette, uvicorn), with
  :mod:`~svbrdf_models.modelfile.serve_limits` (what a request may ask),
  :mod:`~svbrdf_models.modelfile.serve_json` (large bodies parsed in a child process, answers
  written by numpy) and :mod:`~svbrdf_models.modelfile.serve_log` (one log line per kind of failure).
"""

from .download import DOWNLOAD_TIMEOUT, PYFUNC_ARTIFACT, download_timeout, hash_name
from .files import PRETRAINED, card_path, load_model, model_dict, pretrained_path, save_model
from .modelcheck import (
    FORMAT,
    FORMAT_VERSION,
    MAX_EXPANDED_BYTES,
    MAX_EXPANSION,
    MAX_RESOLUTION,
    check_archive,
    check_contents,
    check_sidecar,
    file_sha256,
    is_model_file,
    nonfinite_tensors,
    read_model_file,
    unreadable_reason,
    weights_mismatch,
)
from .trained import TrainedModel

__all__ = [
    "DOWNLOAD_TIMEOUT",
    "FORMAT",
    "FORMAT_VERSION",
    "MAX_EXPANDED_BYTES",
    "MAX_EXPANSION",
    "MAX_RESOLUTION",
    "PRETRAINED",
    "PYFUNC_ARTIFACT",
    "TrainedModel",
    "card_path",
    "check_archive",
    "check_contents",
    "check_sidecar",
    "download_timeout",
    "file_sha256",
    "hash_name",
    "is_model_file",
    "load_model",
    "model_dict",
    "nonfinite_tensors",
    "pretrained_path",
    "read_model_file",
    "save_model",
    "unreadable_reason",
    "weights_mismatch",
]
