"""``svbrdf-train export``: a checkpoint or a run -> a model file that svbrdf-models loads alone;
``--register`` puts it in the MLflow model registry, and predict takes every kind of source."""

from __future__ import annotations

import hashlib
import json

import pytest
import torch

import svbrdf_models as sm
from conftest import des18_strips, run_cli, run_cli_here
from svbrdf_train.predict import Predictor
from svbrdf_train.training.checkpoint import load_checkpoint


@pytest.fixture(scope="module")
def fit_dir(tmp_path_factory):
    """A smoke fit of ours-mix on 3 Des18 strips and procedural materials, tracked in MLflow."""
    root = tmp_path_factory.mktemp("export")
    strips = des18_strips(root / "strips", count=3)
    out = root / "fit"
    mix = "[{source: procedural, weight: 0.5}, {source: des18, weight: 0.5, validation: 0}]"
    r = run_cli(
        "fit", "--recipe", "ours-mix", "--size", "smoke", "--data", str(strips), "--out", str(out), "-q",
        "--set", f"data.mix={mix}", "--experiment", "export-tests",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture(scope="module")
def exported(fit_dir, tmp_path_factory):
    path = tmp_path_factory.mktemp("out") / "model.pt"
    r = run_cli("export", str(fit_dir), "-o", str(path))
    assert r.returncode == 0, r.stderr
    return path, r


def test_the_file_holds_generator_config_resolution_and_provenance(exported, fit_dir):
    path, r = exported
    assert r.stdout.strip() == str(path)
    state = torch.load(path, weights_only=True)
    ckpt = load_checkpoint(fit_dir / "last.pt")
    assert set(state) >= {"format", "generator", "weights", "resolution", "recipe", "provenance", "precision"}
    assert "discriminator" not in state and "optimizers" not in state and "rng" not in state
    assert state["resolution"] == ckpt["recipe"]["train"]["resolution"] == 32
    assert state["generator"]["name"] == "ours"
    # the complete resolved config (every field), so the file needs no recipe to rebuild the network
    assert set(state["generator"]["config"]) == {f.name for f in sm.describe("generator", "ours").fields}
    info = state["provenance"]
    assert info["steps"] == ckpt["step"] > 0
    assert info["train_seconds"] == pytest.approx(ckpt["train_seconds"])
    assert info["git_sha"] == ckpt["made_with"]["git_sha"] and info["git_sha"]
    assert "cores of" in info["hardware"]  # a CPU fit: core count and model
    assert info["run_id"] == json.loads((fit_dir / "last.json").read_text())["run_id"]
    sources = {s["source"]: s for s in info["data"]["sources"]}
    assert set(sources) == {"procedural", "des18"}
    assert sources["des18"]["files"] == [f"{i:07d};MatAXMatB;0X1.png" for i in range(3)]
    for name, w in state["weights"].items():
        assert torch.equal(w, ckpt["generator"][name])


def test_sha256_is_printed_and_written_beside(exported):
    path, r = exported
    sha = hashlib.sha256(path.read_bytes()).hexdigest()
    assert sha in r.stderr
    assert path.with_name(path.name + ".sha256").read_text().split() == [sha, path.name]


def test_the_export_predicts_what_the_checkpoint_predicts(exported, fit_dir):
    path, _ = exported
    photo = torch.rand(3, 40, 48)
    a = Predictor.from_checkpoint(fit_dir / "last.pt").predict(photo)
    b = sm.load_model(path).predict(photo)
    c = Predictor.from_checkpoint(path).predict(photo)  # a model file where a checkpoint is expected
    for m in ("normal", "diffuse", "roughness", "specular"):
        assert torch.equal(getattr(a, m), getattr(b, m)) and torch.equal(getattr(a, m), getattr(c, m))


def test_half_and_hash_name(fit_dir, tmp_path, exported):
    r = run_cli("export", str(fit_dir / "last.pt"), "-o", str(tmp_path / "m.pt"), "--half", "--hash-name")
    assert r.returncode == 0, r.stderr
    (path,) = tmp_path.glob("m-*.pt")
    sha = hashlib.sha256(path.read_bytes()).hexdigest()
    assert path.name == f"m-{sha[:8]}.pt" and r.stdout.strip() == str(path)
    assert path.stat().st_size < 0.6 * exported[0].stat().st_size
    effect = torch.load(path, weights_only=True)["provenance"]["half_effect"]
    assert set(effect) == {"normal", "diffuse", "roughness", "specular"}
    assert all(0 <= e["rmse"] <= e["max"] < 0.05 for e in effect.values())
    assert "float16 weights move the maps" in r.stderr


def test_export_from_run_and_register(fit_dir, tmp_path):
    run_id = json.loads((fit_dir / "last.json").read_text())["run_id"]
    path = tmp_path / "ours.pt"
    r = run_cli(
        "export", "--run", run_id, "-o", str(path), "--register", "svbrdf-test-ours", "--metric", "x/y=0.5"
    )
    assert r.returncode == 0, r.stderr
    uri = r.stdout.strip()
    assert uri.startswith("models:/svbrdf-test-ours/")
    state = torch.load(path, weights_only=True)
    assert state["metrics"]["x/y"] == 0.5
    assert any(k.startswith("val/") for k in state["metrics"])  # the run's validation figures
    from mlflow import MlflowClient

    version = MlflowClient().get_model_version("svbrdf-test-ours", uri.rsplit("/", 1)[1])
    assert version.tags["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    assert version.tags["generator"] == "ours" and version.run_id == run_id
    # the version is an MLflow model logged in the training run, named after the file's hash
    assert version.source.startswith("models:/m-")
    logged = MlflowClient().get_logged_model(version.source.removeprefix("models:/"))
    assert logged.source_run_id == run_id and logged.tags["svbrdf.sha256"] == version.tags["sha256"]
    sha = version.tags["sha256"]
    for source in (
        uri,
        version.source,
        f"runs:/{run_id}/model-{sha[:8]}",
        f"runs:/{run_id}/model-{sha[:8]}/artifacts/ours.pt",
    ):
        model = sm.load_model(source)
        assert model.source == source and model.sha256 == version.tags["sha256"]


def test_the_registered_version_is_an_mlflow_model_that_predicts_the_maps(fit_dir, tmp_path):
    """mlflow.pyfunc loads what --register made (it failed on the bare file it logged before) and
    predicts, channels last, the maps the model file predicts; mlflow.pytorch does not load it
    (the model is a python_function, not a pickled torch module)."""
    import mlflow
    import numpy as np

    r = run_cli("export", str(fit_dir), "-o", str(tmp_path / "m.pt"), "--register", "svbrdf-test-pyfunc-x")
    assert r.returncode == 0, r.stderr
    uri = r.stdout.strip()
    photos = np.random.default_rng(0).uniform(0, 1, (2, 40, 36, 3)).astype(np.float32)
    got = mlflow.pyfunc.load_model(uri).predict(photos)
    want = sm.load_model(tmp_path / "m.pt").predict(torch.from_numpy(photos).permute(0, 3, 1, 2))
    for name, t in want.maps().items():
        assert np.abs(got[name] - t.permute(0, 2, 3, 1).numpy()).max() <= 1e-6
    with pytest.raises(mlflow.exceptions.MlflowException):
        mlflow.pytorch.load_model(uri)


def test_a_finished_fit_logs_its_generator_as_an_mlflow_model(fit_dir):
    """The fit's run holds MLflow model ``model`` at its last step: the weights of the checkpoint,
    loadable by svbrdf_models and by mlflow.pyfunc, in the run's experiment."""
    import mlflow

    run_id = json.loads((fit_dir / "last.json").read_text())["run_id"]
    client = mlflow.MlflowClient()
    run = client.get_run(run_id)
    ckpt = load_checkpoint(fit_dir / "last.pt")
    (output,) = [o for o in run.outputs.model_outputs if client.get_logged_model(o.model_id).name == "model"]
    assert output.step == ckpt["step"]
    logged = client.get_logged_model(output.model_id)
    assert logged.source_run_id == run_id and logged.experiment_id == run.info.experiment_id
    assert str(logged.status) == "READY"
    assert any(m.key.startswith("val/") for m in logged.metrics or [])  # the last validation's
    model = sm.load_model(f"runs:/{run_id}/model")
    for name, w in model.generator.state_dict().items():
        assert torch.equal(w, ckpt["generator"][name])
    assert set(mlflow.pyfunc.load_model(f"models:/{logged.model_id}").predict(
        torch.rand(1, 32, 32, 3).numpy()
    )) == {"normal", "diffuse", "roughness", "specular"}  # fmt: skip


def test_predict_takes_a_registry_uri(fit_dir, tmp_path):
    run_cli("export", str(fit_dir), "-o", str(tmp_path / "m.pt"), "--register", "svbrdf-test-predict")
    photo = tmp_path / "photo.png"
    from svbrdf_render import write_image
    from svbrdf_train.data import ProceduralMaterials

    write_image(photo, ProceduralMaterials(1, 64, seed=3)[0]["input"])
    r = run_cli(
        "predict", str(photo), "--model", "models:/svbrdf-test-predict/1", "-o", str(tmp_path / "maps")
    )
    assert r.returncode == 0, r.stderr
    assert "models:/svbrdf-test-predict/1" in r.stderr
    assert (tmp_path / "maps" / "photo" / "diffuse.png").is_file()
    summary = json.loads((tmp_path / "maps" / "summary.json").read_text())
    assert summary["model"] == "models:/svbrdf-test-predict/1"


@pytest.mark.parametrize(
    "args, says",
    [
        ([], "CHECKPOINT"),
        (["CKPT", "--run", "0" * 32], "CHECKPOINT"),
        (["nowhere.pt"], "no checkpoint there"),
        (["CKPT", "--metric", "x"], "NAME=NUMBER"),
    ],
)
def test_bad_arguments_one_line_exit_2(fit_dir, tmp_path, args, says):
    args = [str(fit_dir / "last.pt") if a == "CKPT" else a for a in args]
    r = run_cli_here("export", *args, "-o", str(tmp_path / "m.pt"))  # in this process (a fresh one: below)
    assert r.returncode == 2 and says in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "m.pt").exists()


def test_export_over_a_checkpoint_or_another_file_is_refused_without_force(fit_dir, exported, tmp_path):
    """-o at the fit's own last.pt would leave a fit that cannot resume: refused, the checkpoint kept;
    a model file over a model file is fine, and --force replaces anything."""
    before = (fit_dir / "last.pt").read_bytes()
    r = run_cli("export", str(fit_dir), "-o", str(fit_dir / "last.pt"))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "--force" in r.stderr and "checkpoint" in r.stderr
    assert (fit_dir / "last.pt").read_bytes() == before
    notes = tmp_path / "notes.txt"  # the rest in this process: the same command, no fresh interpreter
    notes.write_text("mine\n")
    r = run_cli_here("export", str(fit_dir), "-o", str(notes))
    assert r.returncode == 2 and str(notes) in r.stderr and notes.read_text() == "mine\n", r.stderr
    model = tmp_path / "model.pt"
    model.write_bytes(exported[0].read_bytes())
    assert run_cli_here("export", str(fit_dir), "-o", str(model)).returncode == 0
    r = run_cli_here("export", str(fit_dir), "-o", str(notes), "--force")
    assert r.returncode == 0, r.stderr
    assert sm.load_model(notes).steps == load_checkpoint(fit_dir / "last.pt")["step"]
