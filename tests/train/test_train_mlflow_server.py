"""``svbrdf-train fit`` and ``predict --run`` against an MLflow tracking server over HTTP.

A real ``mlflow server`` (sqlite backend, artifacts proxied to a folder of its own) runs for the
module; the fit and the prediction reach it only through ``MLFLOW_TRACKING_URI=http://...``.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
from types import SimpleNamespace

import pytest
import torch

from conftest import free_port, run_cli, run_cli_here, serving
from svbrdf_render import read_image, write_image
from svbrdf_render.formats.mapfiles import linear_to_srgb, srgb_to_linear
from svbrdf_train.data import ProceduralMaterials
from svbrdf_train.predict import Predictor

pytestmark = pytest.mark.slow

MAPS = ("normal", "diffuse", "roughness", "specular")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """``mlflow server`` on a free local port; skips the module when it cannot start here."""
    root = tmp_path_factory.mktemp("mlflow-server")
    url = f"http://127.0.0.1:{free_port()}"
    artifacts = root / "artifacts"
    env = {k: v for k, v in os.environ.items() if k != "MLFLOW_TRACKING_URI"}
    env["MLFLOW_SERVER_ENABLE_JOB_EXECUTION"] = "false"  # no job runner and huey workers: fewer processes
    command = [
        sys.executable, "-m", "mlflow", "server",
        "--host", "127.0.0.1",
        "--port", url.rsplit(":", 1)[1],
        "--workers", "1",
        "--backend-store-uri", f"sqlite:///{root / 'srv.db'}",
        "--artifacts-destination", str(artifacts),
    ]  # fmt: skip
    log_path = root / "server.log"
    with serving(command, f"{url}/health", log_path, env=env, cwd=root, timeout=60, on_failure=pytest.skip):
        yield SimpleNamespace(url=url, root=root, artifacts=artifacts, log=log_path)


@pytest.fixture(scope="module")
def fitted(server, tmp_path_factory):
    """A smoke fit tracked by the server, run from an empty working folder."""
    base = tmp_path_factory.mktemp("fit")
    cwd, out = base / "cwd", base / "ours-smoke"
    cwd.mkdir()
    result = run_cli(
        "fit", "--recipe", "ours", "--size", "smoke", "--out", str(out), "-q",
        cwd=cwd, env={"MLFLOW_TRACKING_URI": server.url},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr + server.log.read_text()[-2000:]
    run_id = json.loads((out / "last.json").read_text())["run_id"]
    return SimpleNamespace(cwd=cwd, out=out, run_id=run_id, result=result)


@pytest.fixture(scope="module")
def client(server):
    from mlflow import MlflowClient

    return MlflowClient(server.url)


def test_fit_logs_one_finished_run_to_the_server(server, fitted, client):
    """The run lands in experiment "svbrdf" on the server, FINISHED, with the recipe's params,
    the identifying tags and the validation metrics; the fit prints its id."""
    assert fitted.run_id in fitted.result.stdout
    experiment = client.get_experiment_by_name("svbrdf")
    assert experiment is not None
    runs = client.search_runs([experiment.experiment_id])
    assert [r.info.run_id for r in runs] == [fitted.run_id]
    run = runs[0]
    assert run.info.status == "FINISHED"
    assert run.data.params["loss.adv"] == "0.1"
    assert run.data.params["train.resolution"] == "32"
    assert run.data.tags["recipe"] == "ours" and run.data.tags["recipe.size"] == "smoke"
    assert run.data.tags["version.svbrdf-train"] not in ("", "not installed")
    for key in ("val/rmse/render", "val/rmse/normal", "train/loss"):
        assert key in run.data.metrics, key
    assert 0 < run.data.metrics["val/rmse/render"] < 1


def test_artifacts_go_to_the_server_folder(server, fitted, client):
    """Artifacts are uploaded through the server (mlflow-artifacts:) into its artifact folder: the
    weights there are the fit's weights.pt, and nothing is written in the fit's working folder."""
    run = client.get_run(fitted.run_id)
    assert run.info.artifact_uri.startswith("mlflow-artifacts:")
    assert {a.path for a in client.list_artifacts(fitted.run_id)} == {"config", "checkpoints", "samples", "images"}
    assert [a.path for a in client.list_artifacts(fitted.run_id, "config")] == ["config/recipe.yaml"]
    listed = {a.path: a.file_size for a in client.list_artifacts(fitted.run_id, "checkpoints")}
    local = fitted.out / "weights.pt"
    assert listed == {"checkpoints/weights.pt": local.stat().st_size}
    stored = list(server.artifacts.rglob("weights.pt"))
    assert len(stored) == 1 and fitted.run_id in stored[0].parts
    assert stored[0].read_bytes() == local.read_bytes()
    assert len(list(server.artifacts.rglob("recipe.yaml"))) == 1
    assert list(fitted.cwd.iterdir()) == []


def test_predict_from_a_run_on_the_server(server, fitted, tmp_path):
    """``predict --run RUN_ID`` downloads the checkpoint through the server and writes the maps
    the local checkpoint gives."""
    photo = ProceduralMaterials(1, 64, seed=7)[0]["input"]  # capture refuses < 64 px (MIN_SIDE)
    path = write_image(tmp_path / "shot.png", linear_to_srgb(photo))
    out = tmp_path / "maps"
    result = run_cli(
        "predict", str(path), "--run", fitted.run_id, "-o", str(out), env={"MLFLOW_TRACKING_URI": server.url}
    )
    assert result.returncode == 0, result.stderr
    assert f"run {fitted.run_id}" in result.stderr
    expected = Predictor.from_checkpoint(fitted.out / "last.pt").predict(srgb_to_linear(read_image(path)))
    diffuse = read_image(out / "shot" / "diffuse.png")
    assert diffuse.shape == (3, 32, 32)
    assert float((diffuse - linear_to_srgb(expected.diffuse[0])).abs().max()) <= 1 / 255 + 1e-6  # sRGB
    normal = read_image(out / "shot" / "normal.png") * 2 - 1
    assert float((normal - torch.nn.functional.normalize(expected.normal, dim=1)[0]).abs().max()) <= 2 / 255
    written = {p.name for p in (out / "shot").iterdir()}
    material = {"basecolor.png", "metallic.png", "metallic_roughness.png", "material.json", "material.gltf",
                "material.mtlx", "index.html"}  # the material folder's (svbrdf_models.capture.material)
    assert written == {f"{n}.png" for n in (*MAPS, "input", "rerender")} | {"relit.gif"} | material


def test_fit_with_an_unreachable_server_is_a_one_line_error(tmp_path):
    """A tracking URI nobody answers at is a usage error: exit 2, one line naming the URI."""
    url = f"http://127.0.0.1:{free_port()}"
    result = run_cli(
        "fit", "--recipe", "ours", "--size", "smoke", "--out", str(tmp_path / "run"), "-q",
        env={"MLFLOW_TRACKING_URI": url, "MLFLOW_HTTP_REQUEST_MAX_RETRIES": "0"},
    )  # fmt: skip
    assert "Traceback" not in result.stderr
    assert result.returncode == 2
    assert result.stderr.startswith("svbrdf-train: error: ") and result.stderr.count("\n") == 1
    assert url in result.stderr


@pytest.mark.slow
def test_fits_started_together_on_a_new_sqlite_store_all_keep_their_runs(tmp_path):
    """Three fits on a store that does not exist yet: MLflow creates its tables on first use,
    without a lock, and the losers of that race used to die before training."""
    import sys

    store = f"sqlite:///{tmp_path / 'new' / 'mlflow.db'}"
    env = {**os.environ, "MLFLOW_TRACKING_URI": store}
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "svbrdf_train", "fit", "--recipe", "no-adv", "--size", "smoke", "-q",
             "--out", str(tmp_path / f"fit{k}"), "--experiment", "together"],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        for k in range(3)
    ]
    results = [p.communicate(timeout=300) for p in procs]
    for p, (_, err) in zip(procs, results, strict=True):
        assert p.returncode == 0, err
    from mlflow import MlflowClient

    client = MlflowClient(store)
    runs = client.search_runs([client.get_experiment_by_name("together").experiment_id])
    assert len(runs) == 3 and all(r.info.status == "FINISHED" for r in runs)


def _fresh(*args, env):
    """The command in a fresh process, bounded by a killing timeout (MLflow retries for minutes)."""
    return run_cli(*args, env=env, timeout=120)


def _one_line(result) -> str:
    assert "Traceback" not in result.stderr, result.stderr
    assert result.returncode == 2, result.stderr
    assert result.stderr.startswith("svbrdf-train: error: ") and result.stderr.count("\n") == 1, result.stderr
    return result.stderr


def test_a_server_that_refuses_or_never_answers_is_given_up_on_with_its_timeout_setting(tmp_path):
    """MLflow's own retries (7, with back-off) kept a fit silent for over 4 minutes: the URI and the
    setting that bounds the wait are named in one line. The bound is a killing timeout."""
    import socket

    refused = f"http://127.0.0.1:{free_port()}"
    with socket.socket() as mute:  # accepts connections (the backlog) and never answers
        mute.bind(("127.0.0.1", 0))
        mute.listen(8)
        silent = f"http://127.0.0.1:{mute.getsockname()[1]}"
        for url in (refused, silent):
            env = {"MLFLOW_TRACKING_URI": url}
            result = run_cli("fit", "--recipe", "ours", "--size", "smoke", "-q",
                             "--out", str(tmp_path / "run"), env=env, timeout=120)  # fmt: skip
            line = _one_line(result)
            assert url in line and "MLFLOW_HTTP_REQUEST_TIMEOUT" in line, line
            assert not (tmp_path / "run" / "last.pt").exists()


def test_a_sqlite_store_that_is_not_mlflows_is_refused_before_anything_is_written(tmp_path):
    """A folder, an empty file, another program's database, a file that is no database: MLflow would
    write its tables into them (or retry for minutes); each is refused in one line, left as it was."""
    import sqlite3

    (tmp_path / "folder.db").mkdir()
    (tmp_path / "empty.db").write_bytes(b"")
    with contextlib.closing(sqlite3.connect(tmp_path / "other.db")) as db:
        db.execute("CREATE TABLE invoices (id INTEGER, total REAL)")
        db.commit()
    (tmp_path / "text.db").write_text("not a database\n")
    for name in ("folder.db", "empty.db", "other.db", "text.db"):
        store = tmp_path / name
        before = None if store.is_dir() else store.read_bytes()
        run = _fresh if name == "folder.db" else run_cli_here  # one in a fresh process, the rest here
        result = run("fit", "--recipe", "ours", "--size", "smoke", "-q", "--out", str(tmp_path / "run"),
                     env={"MLFLOW_TRACKING_URI": f"sqlite:///{store}"})  # fmt: skip
        line = _one_line(result)
        assert str(store) in line and "MLflow store" in line, line
        assert before is None or store.read_bytes() == before, f"{name} was written into"
        assert not (tmp_path / "run" / "last.pt").exists()
    assert list((tmp_path / "folder.db").iterdir()) == []


def test_commands_that_read_runs_refuse_a_store_that_is_not_mlflows(tmp_path):
    """predict --run, fit --init, export --run and svbrdf-bench report only read a store, but
    MLflow creates its tables in whatever file the URI names: the same check refuses an empty
    file or another program's database before MLflow opens it, leaving the file as it was."""
    import sqlite3

    (tmp_path / "empty.db").write_bytes(b"")
    with contextlib.closing(sqlite3.connect(tmp_path / "other.db")) as db:
        db.execute("CREATE TABLE invoices (id INTEGER, total REAL)")
        db.commit()
    run_id = "0" * 32
    photo = tmp_path / "photo.png"
    write_image(photo, torch.full((3, 64, 64), 0.3))
    commands = {
        "predict": ["predict", str(photo), "--run", run_id, "-o", str(tmp_path / "maps")],
        "fit --init": ["fit", "--recipe", "ours", "--size", "smoke", "-q", "--init", run_id,
                       "--out", str(tmp_path / "run")],
        "export": ["export", "--run", run_id, "-o", str(tmp_path / "x.pt")],
    }  # fmt: skip
    for name in ("empty.db", "other.db"):
        store = tmp_path / name
        before = store.read_bytes()
        env = {"MLFLOW_TRACKING_URI": f"sqlite:///{store}"}
        for what, args in commands.items():  # predict on other.db in a fresh process; the rest here
            run = _fresh if (name, what) == ("other.db", "predict") else run_cli_here
            line = _one_line(run(*args, env=env))
            assert str(store) in line and "MLflow store" in line, (what, line)
        report = ("report", run_id, "-o", str(tmp_path / "r"))
        if name == "other.db":  # svbrdf-bench in a fresh process once
            bench = subprocess.run([sys.executable, "-m", "svbrdf_bench", *report],
                                   env={**os.environ, **env}, capture_output=True, text=True, timeout=120)  # fmt: skip
        else:
            bench = run_cli_here(*report, env=env, program="svbrdf_bench")
        assert "Traceback" not in bench.stderr and bench.returncode == 2, bench.stderr
        assert bench.stderr.startswith("svbrdf-bench: error: ") and bench.stderr.count("\n") == 1, bench.stderr
        assert str(store) in bench.stderr and "MLflow store" in bench.stderr, bench.stderr
        assert store.read_bytes() == before, f"{name} was written into"
