"""A trained model file as an MLflow model: photos in, maps out, loadable and servable by MLflow.

Needs mlflow (``pip install svbrdf-models[mlflow]``); nothing else in this package imports it::

    from svbrdf_models.modelfile.pyfunc import log_pyfunc_model
    info = log_pyfunc_model("ours.pt", registered_model_name="svbrdf-ours")

    import mlflow
    model = mlflow.pyfunc.load_model("models:/svbrdf-ours/1")
    maps = model.predict(photos)                        # (N, H, W, 3) -> {"normal": (N, R, R, 3), ...}
    maps = model.predict(photos, params={"refine": 100})   # + refined against the photos

    mlflow models serve -m models:/svbrdf-ours/1 --env-manager local -h 127.0.0.1 -p 5001
    curl 127.0.0.1:5001/invocations -H 'Content-Type: application/json' \\
         -d '{"inputs": [[[[0.5, 0.4, 0.3], ...]]], "params": {"refine": 0}}'
    # -> {"predictions": {"normal": [...], "diffuse": [...], "roughness": [...], "specular": [...]}}

The logged model is a folder in MLflow's format: ``MLmodel`` (the ``python_function`` flavour,
its signature and requirements), ``artifacts/NAME.pt`` (the model file, unchanged:
:func:`svbrdf_models.load_model` reads it from a ``models:/`` URI too) and ``svbrdf_model.py``,
three lines that build :class:`SVBRDFPythonModel` (MLflow's "model from code": nothing is
pickled). Loading it needs svbrdf-models installed, as the requirements say.

Photos and maps are channels-last arrays ``(N, H, W, C)``, not this project's ``(N, C, H, W)``
tensors: MLflow's tensor signature and its JSON protocol follow the numpy image convention
(the leading -1 is the batch; ``"inputs"`` nests rows of pixels of channels), which is how
every image reader returns a photo, so a client sends ``np.asarray(image)[None]`` as it is.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import logging
import tempfile
from pathlib import Path
from typing import Any

import mlflow
import numpy as np
import torch
from mlflow.exceptions import MlflowException
from mlflow.models import Model, ModelSignature
from mlflow.models.model import ModelInfo
from mlflow.protos.databricks_pb2 import INVALID_PARAMETER_VALUE
from mlflow.pyfunc import PythonModel
from mlflow.types.schema import ParamSchema, ParamSpec, Schema, TensorSpec

from svbrdf_render import MAP_NAMES
from svbrdf_render.maps import MAP_CHANNELS

from ..errors import DataError
from .download import PYFUNC_ARTIFACT
from .files import load_model
from .serve import maps_arrays
from .serve_limits import ServeLimits, check_photo_array, refine_budget
from .trained import TrainedModel

__all__ = [
    "SERVE_LIMITS",
    "SVBRDFPythonModel",
    "PhotoInputError",
    "serve_limit",
    "log_pyfunc_model",
    "signature",
    "input_example",
    "pip_requirements",
    "check_photos",
]

# The model-from-code file logged with every model: MLflow runs it to build the model.
_CODE = """\
# The MLflow model of an svbrdf model file (see svbrdf_models.modelfile.pyfunc); its weights: artifacts/*.pt.
import mlflow.models
from svbrdf_models.modelfile.pyfunc import SVBRDFPythonModel
mlflow.models.set_model(SVBRDFPythonModel())
"""


class PhotoInputError(DataError, MlflowException):
    """Photos or parameters :meth:`SVBRDFPythonModel.predict` cannot take: a :class:`DataError`
    for Python callers, and an MlflowException (invalid parameter: HTTP 400 with this message)
    for MLflow's scoring server."""

    def __init__(self, message: str):
        MlflowException.__init__(self, message, error_code=INVALID_PARAMETER_VALUE)


def check_photos(photos: Any) -> np.ndarray:
    """``photos`` as a float32 ``(N, H, W, 3)`` array of linear RGB in [0, 1] (an ``(H, W, 3)``
    photo gets a batch axis), or a :class:`PhotoInputError` that says what is wrong
    (:func:`svbrdf_models.modelfile.serve_limits.check_photo_array` under ``SVBRDF_SERVE_MAX_PIXELS``)."""
    try:
        return check_photo_array(photos, serve_limit("MAX_PIXELS"), "SVBRDF_SERVE_MAX_PIXELS")
    except DataError as e:
        raise PhotoInputError(str(e)) from None


def _refine_steps(params: dict[str, Any] | None) -> int:
    """The refinement budget of ``params`` (``{"refine": STEPS}``, default 0)."""
    try:
        refine = (params or {}).get("refine", 0)
        return refine_budget(refine, serve_limit("MAX_REFINE"), "SVBRDF_SERVE_MAX_REFINE")
    except DataError as e:
        raise PhotoInputError(str(e)) from None


#: What one request may ask of a served model, each changed by ``SVBRDF_SERVE_<NAME>``: the
#: pixels of all its photos (4 megapixels: a 2048x2048 photo, about 2 GB refined), and the
#: refinement steps (500: minutes for a large photo, never a worker held for good).
SERVE_LIMITS = {"MAX_PIXELS": ServeLimits.pixels, "MAX_REFINE": ServeLimits.refine}


def serve_limit(name: str) -> int:
    """The limit ``name`` of :data:`SERVE_LIMITS`, or the whole number ``SVBRDF_SERVE_<NAME>``
    sets (a value that is not one is ignored: the default holds)."""
    import os

    text = os.environ.get(f"SVBRDF_SERVE_{name}", "").strip()
    return int(text) if text.isdigit() and int(text) > 0 else SERVE_LIMITS[name]


class SVBRDFPythonModel(PythonModel):
    """MLflow's python_function flavour of a model file (logged as artifact ``model_file``).

    ``mlflow.pyfunc.load_model(URI, model_config={"device": "cuda"})`` runs it on a GPU
    (default: the CPU).
    """

    model: TrainedModel | None = None

    def load_context(self, context) -> None:
        device = (context.model_config or {}).get("device", "cpu")
        self.model = load_model(context.artifacts[PYFUNC_ARTIFACT], device)

    # np.ndarray: what MLflow hands under the tensor signature; a hint MLflow infers nothing from
    def predict(
        self, context, model_input: np.ndarray, params: dict[str, Any] | None = None
    ) -> dict[str, np.ndarray]:
        """The four maps of photos, as channels-last float32 arrays.

        Args:
            model_input: linear RGB photos (not sRGB-encoded), float32 with values in [0, 1]:
                ``(N, H, W, 3)``, or one ``(H, W, 3)`` when called on this class directly
                (MLflow's signature asks for the batch axis). Channels last, as MLflow's tensor
                signature and JSON protocol carry images (see the module).
            params: ``{"refine": STEPS}``: after the network, refine the maps against each photo
                for STEPS steps of inverse rendering (0, the default: the network's maps alone;
                see :meth:`svbrdf_models.TrainedModel.predict`).

        Returns:
            ``{"normal": (N, R, R, 3) unit vectors, "diffuse": (N, R, R, 3), "roughness":
            (N, R, R, 1), "specular": (N, R, R, 3)}``: R is the model's resolution (the largest
            centred square of the photo is resized to it); with refinement, R is the photo's
            shorter side (at least 16 px).

        Raises:
            PhotoInputError: photos of another shape, NaN or out of [0, 1]; a bad ``refine``.
        """
        if self.model is None:
            raise RuntimeError("SVBRDFPythonModel.predict before load_context: load it with mlflow.pyfunc")
        photos = torch.from_numpy(check_photos(model_input)).permute(0, 3, 1, 2)
        steps = _refine_steps(params)
        try:
            maps = self.model.predict(photos, refine=steps, seconds=_serving_seconds() if steps else None)
        except DataError as e:  # a photo too small to refine against
            raise PhotoInputError(str(e)) from None
        return maps_arrays(maps)


def _serving_seconds() -> float | None:
    """Under ``mlflow models serve``: 80% of its request timeout (``MLFLOW_SCORING_SERVER_REQUEST_TIMEOUT``,
    default 60 s), so that a refinement ends before MLflow answers 504 and never holds the worker
    after it; None elsewhere (no time bound)."""
    import os

    if os.environ.get("_MLFLOW_IS_IN_SERVING_ENVIRONMENT", "").lower() != "true":
        return None
    text = os.environ.get("MLFLOW_SCORING_SERVER_REQUEST_TIMEOUT", "60").strip()
    try:
        return max(1.0, 0.8 * float(text))
    except ValueError:
        return 48.0


# -- logging ------------------------------------------------------------------------------------


@contextlib.contextmanager
def _quiet(name: str):
    """MLflow's INFO lines of logger ``name`` silenced (its "Validating input example" in a fit's
    output); warnings still show."""
    logger = logging.getLogger(name)
    level = logger.level
    logger.setLevel(max(level, logging.WARNING))
    try:
        yield
    finally:
        logger.setLevel(level)


def signature() -> ModelSignature:
    """Photos ``(-1, -1, -1, 3)`` float32 in; the four maps out (named tensors); ``refine``."""
    photos = Schema([TensorSpec(np.dtype(np.float32), (-1, -1, -1, 3))])
    maps = Schema([TensorSpec(np.dtype(np.float32), (-1, -1, -1, MAP_CHANNELS[m]), m) for m in MAP_NAMES])
    return ModelSignature(photos, maps, ParamSchema([ParamSpec("refine", "long", 0)]))


def input_example(size: int = 16) -> np.ndarray:
    """A small photo ``(1, size, size, 3)``: a flash highlight on a warm albedo, linear, in [0, 1]
    (16 px: large enough to refine against)."""
    y, x = np.mgrid[-1 : 1 : size * 1j, -1 : 1 : size * 1j]
    highlight = np.exp(-4.0 * (x * x + y * y))
    photo = (0.1 + 0.8 * highlight)[..., None] * np.array([0.9, 0.7, 0.5])
    return np.round(photo, 4).astype(np.float32)[None]


def pip_requirements() -> list[str]:
    """What a serving environment installs: this package and the renderer at the versions
    installed here, torch and numpy (MLflow adds itself)."""
    reqs = [f"{dist}=={importlib.metadata.version(dist)}" for dist in ("svbrdf-models", "svbrdf-render")]
    return [*reqs, f"torch=={torch.__version__.split('+')[0]}", f"numpy=={np.__version__}"]


def log_pyfunc_model(
    model_file: str | Path,
    artifact_path: str = "model",
    *,
    registered_model_name: str | None = None,
    run_id: str | None = None,
    step: int | None = None,
) -> ModelInfo:
    """Log a model file as an MLflow model (python_function flavour), to the tracking store.

    Args:
        model_file: a file :func:`svbrdf_models.save_model` wrote (``svbrdf-train export``);
            it is loaded first, so a bad file is refused before anything is logged.
        artifact_path: the logged model's name (``runs:/RUN_ID/NAME`` finds it).
        registered_model_name: also register it as a new version of this registered model.
        run_id: the run that made it (made a logged model of that run, in its experiment; the
            run is left as it is); default: the active run. With neither, MLflow puts it in
            the active experiment, else its default one (artifacts in ``./mlruns``).
        step: the run's step the model is of: the run's metrics at that step are linked to the
            model (default: the training steps the file records).

    Returns:
        MLflow's ``ModelInfo``: ``model_uri`` (``models:/MODEL_ID``), ``model_id``,
        ``registered_model_version``.

    Raises:
        ModelFileError: ``model_file`` is not a model file this package loads.
    """
    trained = load_model(model_file)
    run_id = run_id or (run.info.run_id if (run := mlflow.active_run()) else None)
    tags = {
        "svbrdf.generator": trained.name,
        "svbrdf.resolution": str(trained.resolution),
        "svbrdf.precision": trained.precision,
        "svbrdf.sha256": trained.sha256,
    }
    model_id = _run_model_id(run_id, artifact_path, tags)
    with tempfile.TemporaryDirectory() as tmp, _quiet("mlflow.pyfunc"):
        code = Path(tmp) / "svbrdf_model.py"
        code.write_text(_CODE)
        return Model.log(
            name=artifact_path,
            flavor=mlflow.pyfunc,
            python_model=str(code),
            artifacts={PYFUNC_ARTIFACT: str(Path(model_file).resolve())},
            signature=signature(),
            input_example=(input_example(), {"refine": 0}),
            pip_requirements=pip_requirements(),
            registered_model_name=registered_model_name,
            run_id=run_id,
            model_id=model_id,
            tags=tags,
            step=trained.steps if step is None else step,
            artifact_path=None,
        )


def _run_model_id(run_id: str | None, name: str, tags: dict[str, str]) -> str | None:
    """The id of a new logged model of run ``run_id`` (in the run's experiment, with its params),
    or None without a run: MLflow would put the model in the active (or default) experiment."""
    if run_id is None:
        return None
    client = mlflow.MlflowClient()
    run = client.get_run(run_id)
    return client.create_logged_model(
        run.info.experiment_id, name, run_id, tags=tags, params=run.data.params
    ).model_id
