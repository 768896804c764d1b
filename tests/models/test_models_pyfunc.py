"""A model file as an MLflow model (svbrdf_models.modelfile.pyfunc): logged with a signature and an input
example, loaded by ``mlflow.pyfunc`` in a fresh process, served by ``mlflow models serve`` on
loopback, and still read by ``svbrdf_models.load_model``, old registered versions included.

Runs go to the suite's temporary MLflow store (tests/conftest.py), in an experiment whose
artifacts are in a temporary folder.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import urllib.error
import urllib.request

import numpy as np
import pytest
import torch

import svbrdf_models as sm
from conftest import free_port, serving

mlflow = pytest.importorskip("mlflow")
pyfunc = pytest.importorskip("svbrdf_models.modelfile.pyfunc")

NAME = "svbrdf-test-pyfunc"
MAPS = {"normal": 3, "diffuse": 3, "roughness": 1, "specular": 3}


def _photos(n: int = 2, h: int = 40, w: int = 48, seed: int = 0) -> np.ndarray:
    """Linear photos (n, h, w, 3) in [0, 1], as MLflow's signature takes them."""
    return np.random.default_rng(seed).uniform(0.02, 0.9, (n, h, w, 3)).astype(np.float32)


def _reference(model: sm.TrainedModel, photos: np.ndarray, refine: int = 0) -> dict[str, np.ndarray]:
    """What svbrdf_models predicts for channels-last photos, channels last."""
    maps = model.predict(torch.from_numpy(photos).permute(0, 3, 1, 2), refine=refine)
    return {k: t.permute(0, 2, 3, 1).numpy() for k, t in maps.maps().items()}


@pytest.fixture(scope="module")
def run_id(tmp_path_factory):
    """A run of an experiment whose artifacts (and logged models) go to a temporary folder."""
    client = mlflow.MlflowClient()
    name = "tests-pyfunc"
    found = client.get_experiment_by_name(name)
    exp = found.experiment_id if found else client.create_experiment(
        name, artifact_location=tmp_path_factory.mktemp("pyfunc-artifacts").as_uri()
    )
    return client.create_run(exp).info.run_id


@pytest.fixture(scope="module")
def registered(run_id):
    """The shipped pretrained model logged as an MLflow model and registered as NAME version 1."""
    info = pyfunc.log_pyfunc_model(sm.pretrained_path(), registered_model_name=NAME, run_id=run_id)
    assert info.registered_model_version == 1
    return info


@pytest.fixture(scope="module")
def loaded(registered):
    return mlflow.pyfunc.load_model(f"models:/{NAME}/1")


def test_a_fresh_process_loads_the_registered_model_and_predicts_what_load_model_predicts(
    registered, tmp_path
):
    """Only mlflow is imported by the fresh process: the MLmodel brings in svbrdf_models."""
    photos = _photos()
    np.save(tmp_path / "photos.npy", photos)
    code = (
        "import sys, numpy as np, torch, mlflow\n"
        f"torch.set_num_threads({torch.get_num_threads()})\n"
        f"model = mlflow.pyfunc.load_model('models:/{NAME}/1')\n"
        f"photos = np.load({str(tmp_path / 'photos.npy')!r})\n"
        "np.savez(sys.argv[1], **model.predict(photos))\n"
        "np.savez(sys.argv[2], **model.predict(photos, params={'refine': 3}))\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / "maps.npz"), str(tmp_path / "refined.npz")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    model = sm.load_model(f"models:/{NAME}/1")
    for file, refine, side in (("maps.npz", 0, model.resolution), ("refined.npz", 3, 40)):
        got, want = np.load(tmp_path / file), _reference(model, photos, refine)
        assert set(got.files) == set(MAPS)
        for name, channels in MAPS.items():
            assert got[name].shape == (2, side, side, channels) and got[name].dtype == np.float32
            assert np.abs(got[name] - want[name]).max() <= 1e-6, (file, name)
        assert np.allclose(np.linalg.norm(got["normal"], axis=-1), 1, atol=1e-4)
        for name in ("diffuse", "roughness", "specular"):
            assert 0 <= got[name].min() and got[name].max() <= 1


def test_the_logged_model_carries_signature_example_requirements_and_the_file(registered, run_id, loaded):
    meta = loaded.metadata
    (photo,) = meta.get_input_schema().inputs
    assert photo.shape == (-1, -1, -1, 3) and photo.type == np.dtype(np.float32)
    outputs = {spec.name: spec.shape for spec in meta.get_output_schema().inputs}
    assert outputs == {name: (-1, -1, -1, c) for name, c in MAPS.items()}
    (refine,) = meta.get_params_schema().params
    assert (refine.name, refine.default) == ("refine", 0)
    folder = mlflow.artifacts.download_artifacts(registered.model_uri)
    reqs = open(os.path.join(folder, "requirements.txt")).read().split()
    assert any(r.startswith("svbrdf-models==") for r in reqs)
    assert any(r.startswith("svbrdf-render==") for r in reqs)
    example = meta.load_input_example(folder)
    assert example.shape[0] == 1 and example.shape[-1] == 3 and 0 <= example.min() and example.max() <= 1
    assert set(loaded.predict(example)) == set(MAPS)
    # the model file, byte for byte: load_model reads it, and the logged model says which it is
    sha = sm.load_model(sm.pretrained_path()).sha256
    assert sm.load_model(registered.model_uri).sha256 == sha
    logged = mlflow.MlflowClient().get_logged_model(registered.model_id)
    assert logged.tags["svbrdf.sha256"] == sha and logged.source_run_id == run_id
    assert sm.load_model(f"runs:/{run_id}/model").sha256 == sha  # the run finds its model by name


@pytest.mark.parametrize(
    "photos, says",
    [
        (np.zeros((1, 3, 16, 16), np.float32), "channels go last"),
        (np.zeros((16, 16), np.float32), "got shape (16, 16)"),
        (np.zeros((1, 0, 16, 3), np.float32), "got shape (1, 0, 16, 3)"),
        (np.full((1, 16, 16, 3), 255.0, np.float32), "scale 8-bit values by 1/255"),
        (np.full((1, 16, 16, 3), -0.5, np.float32), "linear radiance is never below 0"),
        (np.where(np.eye(16) > 0, np.nan, 0.5)[None, ..., None].repeat(3, -1).astype(np.float32), "48 values"),
        (np.array([["a", "b", "c"]]), "expected numbers"),
    ],
)
def test_bad_photos_are_refused_in_one_line(loaded, photos, says):
    """The model itself says what is wrong; through MLflow too, unless MLflow's own signature
    check (the shape of the batch) refuses them first."""
    model = pyfunc.SVBRDFPythonModel()
    model.model = sm.load_model(sm.pretrained_path())
    with pytest.raises(pyfunc.PhotoInputError) as e:
        model.predict(None, photos)
    text = str(e.value)
    assert says in text and "\n" not in text and "(N, H, W, 3)" in text
    assert isinstance(e.value, sm.DataError)  # a ValueError of this project
    if photos.ndim == 4 and photos.dtype == np.float32:
        with pytest.raises(mlflow.exceptions.MlflowException) as e:
            loaded.predict(photos)
        assert says in str(e.value) or "shape" in str(e.value).lower()


@pytest.mark.parametrize(
    "params, photos, says",
    [
        ({"refine": -1}, _photos(1, 16, 16), "whole number of refinement steps"),
        ({"refine": 2}, _photos(1, 8, 8), "smaller than 16 px"),
        ({"refine": 10**9}, _photos(1, 16, 16), "over this server's limit of 500 steps"),
        ({"refine": 501}, _photos(1, 16, 16), "SVBRDF_SERVE_MAX_REFINE"),
    ],
)
def test_bad_refinement_is_refused_in_one_line(loaded, params, photos, says):
    with pytest.raises(pyfunc.PhotoInputError) as e:
        loaded.predict(photos, params=params)
    assert says in str(e.value) and "\n" not in str(e.value)


def test_one_photo_without_batch_axis_gives_maps_of_one(loaded):
    model = pyfunc.SVBRDFPythonModel()
    model.model = sm.load_model(sm.pretrained_path())
    one = _photos(1)
    a, b = model.predict(None, one[0]), loaded.predict(one)
    for name in MAPS:
        assert a[name].shape[0] == 1 and np.array_equal(a[name], b[name])


def test_versions_registered_before_the_flavour_still_load(run_id, tmp_path):
    """A version whose source is a folder holding the bare .pt (how export --register logged
    files before): load_model finds the file; an MLflow model without one is refused."""
    client = mlflow.MlflowClient()
    client.log_artifact(run_id, str(sm.pretrained_path()), "model/0123abcd")
    name = f"{NAME}-old"
    client.create_registered_model(name)
    client.create_model_version(name, source=f"runs:/{run_id}/model/0123abcd", run_id=run_id)
    model = sm.load_model(f"models:/{name}/1")
    assert model.sha256 == sm.load_model(sm.pretrained_path()).sha256
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "MLmodel").write_text("flavors:\n  python_function:\n    loader_module: x\n")
    client.log_artifacts(run_id, str(tmp_path / "other"), "other")
    with pytest.raises(sm.ModelFileError) as e:
        sm.load_model(f"runs:/{run_id}/other")
    assert "without an svbrdf model file" in str(e.value) and "\n" not in str(e.value)


def test_a_bad_model_file_is_refused_before_anything_is_logged(run_id, tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_text("not a model\n")
    before = mlflow.MlflowClient().get_run(run_id).outputs
    with pytest.raises(sm.ModelFileError):
        pyfunc.log_pyfunc_model(bad, "bad", run_id=run_id)
    assert mlflow.MlflowClient().get_run(run_id).outputs == before


# -- mlflow models serve ---------------------------------------------------------------------------


def _post(url: str, body: dict) -> tuple[int, dict]:
    request = urllib.request.Request(
        url, data=json.dumps(body).encode(), headers={"Content-Type": "application/json"}
    )
    try:
        with urllib.request.urlopen(request, timeout=120) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


@pytest.fixture(scope="module")
def server(registered, tmp_path_factory):
    """``mlflow models serve`` of NAME/1 on loopback (this environment: --env-manager local),
    stopped with its whole process group."""
    url = f"http://127.0.0.1:{free_port()}"
    bin_dir = os.path.dirname(sys.executable)  # the server runs `uvicorn` from PATH: this environment's
    command = [os.path.join(bin_dir, "mlflow"), "models", "serve", "-m", f"models:/{NAME}/1",
               "--env-manager", "local", "-h", "127.0.0.1", "-p", url.rsplit(":", 1)[1], "--workers", "1"]  # fmt: skip
    env = {**os.environ, "PATH": bin_dir + os.pathsep + os.environ.get("PATH", "")}
    with serving(command, f"{url}/ping", tmp_path_factory.mktemp("serve") / "serve.log", env=env):
        yield url


@pytest.mark.slow
def test_served_model_answers_a_posted_photo_with_its_maps(server):
    photos = _photos(1, 24, 20, seed=3)
    status, body = _post(f"{server}/invocations", {"inputs": photos.tolist(), "params": {"refine": 0}})
    assert status == 200, body
    maps = body["predictions"]
    want = _reference(sm.load_model(f"models:/{NAME}/1"), photos)
    assert set(maps) == set(MAPS)
    for name in MAPS:
        got = np.asarray(maps[name], np.float32)
        assert got.shape == want[name].shape and np.abs(got - want[name]).max() <= 1e-6
    status, body = _post(f"{server}/invocations", {"inputs": photos.tolist(), "params": {"refine": 2}})
    assert status == 200 and np.asarray(body["predictions"]["diffuse"]).shape == (1, 20, 20, 3)


@pytest.mark.slow
def test_served_model_refuses_a_bad_photo_with_the_reason(server):
    status, body = _post(f"{server}/invocations", {"inputs": (_photos(1, 16, 16) * 255).tolist()})
    assert status == 400 and "scale 8-bit values by 1/255" in body["message"]


def test_a_request_over_the_pixel_limit_is_refused_before_any_work(loaded, monkeypatch):
    """Issue 36: a 4096x4096 photo drove a served model past 7.6 GB. The limit is per request,
    checked on the shape before a value is converted; SVBRDF_SERVE_MAX_PIXELS changes it."""
    monkeypatch.setenv("SVBRDF_SERVE_MAX_PIXELS", str(2 * 16 * 16 - 1))
    with pytest.raises(pyfunc.PhotoInputError, match="512 pixels in one request, over this server's limit of 511"):
        loaded.predict(_photos(2, 16, 16))
    monkeypatch.setenv("SVBRDF_SERVE_MAX_PIXELS", "512")
    assert loaded.predict(_photos(2, 16, 16))["normal"].shape[0] == 2


def test_under_mlflow_serve_a_refinement_ends_before_the_request_timeout(loaded, monkeypatch):
    """Issue 36: under ``mlflow models serve`` a request with a huge budget was answered 504 after
    60 s while its work went on, and held the worker for good. Served, a refinement now stops at
    80% of MLflow's request timeout (here 2 s: 100 000 steps would take minutes)."""
    monkeypatch.setenv("SVBRDF_SERVE_MAX_REFINE", "100000")
    assert pyfunc._serving_seconds() is None  # not serving: no bound
    monkeypatch.setenv("_MLFLOW_IS_IN_SERVING_ENVIRONMENT", "true")
    monkeypatch.setenv("MLFLOW_SCORING_SERVER_REQUEST_TIMEOUT", "2")
    assert pyfunc._serving_seconds() == pytest.approx(1.6)
    maps = loaded.predict(_photos(1, 32, 32), params={"refine": 100000})
    assert maps["diffuse"].shape == (1, 32, 32, 3) and np.isfinite(maps["diffuse"]).all()
