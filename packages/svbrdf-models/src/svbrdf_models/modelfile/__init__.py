"""Model files: a trained generator as one file, loaded for inference.

The public API (:data:`__all__`) is that of :mod:`~svbrdf_models.modelfile.files` (saving,
loading, the shipped models); the work is done beneath it:

- :mod:`~svbrdf_models.modelfile.trained`: :class:`TrainedModel`, the predictor;
- :mod:`~svbrdf_models.modelfile.modelcheck`: reading and checking a local file;
- :mod:`~svbrdf_models.modelfile.download`: URLs and MLflow URIs;
- :mod:`~svbrdf_models.modelfile.pyfunc`: the MLflow model of a file (needs mlflow);
- :mod:`~svbrdf_models.modelfile.serve`: ``svbrdf-models serve`` (needs starlette, uvicorn), with
  :mod:`~svbrdf_models.modelfile.serve_limits` (what a request may ask),
  :mod:`~svbrdf_models.modelfile.serve_json` (large bodies parsed in a child process, answers
  written by numpy) and :mod:`~svbrdf_models.modelfile.serve_log` (one log line per kind of failure).
"""

from .files import *  # noqa: F403
from .files import __all__  # noqa: F401
