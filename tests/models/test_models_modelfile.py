"""Model files: written by save_model, read back by load_model from a path or a URL (a server on
loopback: nothing is fetched from outside), refused in one line when they are not ours."""

from __future__ import annotations

import functools
import http.server
import threading

import pytest
import torch

import svbrdf_models as sm
from svbrdf_models.modelfile import (
    FORMAT_VERSION,
    file_sha256,
    hash_name,
    is_model_file,
    load_model,
    model_dict,
    save_model,
)

RES = 32


@pytest.fixture(scope="module")
def trained():
    """A tiny generator with non-default weights, as a trained one would have."""
    torch.manual_seed(0)
    g = sm.create_generator("ours", {"preset": "tiny"})
    with torch.no_grad():
        for p in g.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return g.eval()


def _contents(g, **kw):
    return model_dict(
        "ours",
        {"preset": "tiny"},
        g.state_dict(),
        resolution=RES,
        recipe={"name": "ours", "size": "smoke"},
        provenance={"steps": 7, "train_seconds": 3600.0, "git_sha": "abc"},
        metrics={"des18-dev/rmse/render": 0.1},
        **kw,
    )


@pytest.fixture(scope="module")
def model_file(tmp_path_factory, trained):
    path = tmp_path_factory.mktemp("models") / "tiny.pt"
    save_model(path, _contents(trained))
    return path


def test_round_trip_keeps_weights_config_and_provenance(model_file, trained):
    model = load_model(model_file)
    assert model.name == "ours" and model.resolution == RES and model.precision == "fp32"
    # the complete config, not just what was given: every field of the generator's config
    assert set(model.config) == {f.name for f in sm.describe("generator", "ours").fields}
    assert model.steps == 7 and model.provenance["git_sha"] == "abc"
    assert model.metrics == {"des18-dev/rmse/render": pytest.approx(0.1)}
    assert model.sha256 == file_sha256(model_file)
    assert not model.generator.training
    photo = torch.rand(1, 3, RES, RES)
    with torch.no_grad():
        want, got = trained(photo), model.generator(photo)
    for m in ("normal", "diffuse", "roughness", "specular"):
        assert torch.equal(getattr(want, m), getattr(got, m))
    assert "ours" in model.describe() and "7 steps" in model.describe()


def test_predict_takes_any_photo_size(model_file):
    model = load_model(model_file)
    maps = model.predict(torch.rand(3, 50, 70))
    assert maps.diffuse.shape == (1, 3, RES, RES)
    assert torch.isfinite(maps.normal).all()
    assert model.predict(torch.rand(2, 3, RES, RES)).roughness.shape == (2, 1, RES, RES)
    with pytest.raises(ValueError, match="expected a photo"):
        model.predict(torch.rand(RES, RES))


def test_half_precision_halves_the_file_and_moves_maps_little(tmp_path, trained, model_file):
    path = tmp_path / "half.pt"
    save_model(path, _contents(trained, half=True))
    assert path.stat().st_size < 0.6 * model_file.stat().st_size
    full, half = load_model(model_file), load_model(path)
    assert half.precision == "fp16"
    assert next(half.generator.parameters()).dtype == torch.float32  # widened to run
    photo = torch.rand(3, RES, RES)
    a, b = full.predict(photo), half.predict(photo)
    diff = (a.diffuse - b.diffuse).abs().max()
    assert 0 < diff < 1e-2


def test_hash_name_carries_the_sha_prefix(tmp_path):
    assert hash_name(tmp_path / "m.pt", "0123456789abcdef" * 4).name == "m-01234567.pt"
    assert hash_name(tmp_path / "m-deadbeef.pt", "0123456789abcdef" * 4).name == "m-01234567.pt"


def _one_line(error) -> str:
    text = str(error.value)
    assert "\n" not in text and "Traceback" not in text
    return text


def _bad_file(tmp_path, trained, model_file, kind):
    path = tmp_path / f"{kind.replace(' ', '-')}.pt"
    if kind == "missing":
        return tmp_path / "nowhere.pt"
    if kind == "folder":
        path.mkdir()
    elif kind == "truncated":
        path.write_bytes(model_file.read_bytes()[: model_file.stat().st_size // 2])
    elif kind == "text":
        path.write_text("not a model\n")
    elif kind == "pickled code":
        torch.save({"format": "svbrdf-model", "code": functools.partial(print)}, path)
    elif kind == "foreign torch file":
        torch.save({"state_dict": {"w": torch.zeros(2)}}, path)
    elif kind == "training checkpoint":
        torch.save({"format": 1, "recipe": {"name": "ours"}, "generator": trained.state_dict()}, path)
    elif kind == "newer format":
        torch.save({**_contents(trained), "version": FORMAT_VERSION + 1}, path)
    elif kind == "generator not installed":
        c = _contents(trained)
        torch.save({**c, "generator": {"name": "not-installed-net", "config": {}}}, path)
    elif kind == "config of another version":
        c = _contents(trained)
        torch.save({**c, "generator": {"name": "ours", "config": {"no_such_field": 3}}}, path)
    elif kind == "weights of another network":
        c = _contents(trained)
        torch.save({**c, "weights": {"w": torch.zeros(2)}}, path)
    elif kind == "NaN weights":
        c = _contents(trained)
        w = dict(c["weights"])
        k = next(iter(w))
        w[k] = torch.full_like(w[k], float("nan"))
        torch.save({**c, "weights": w}, path)
    return path


@pytest.mark.parametrize(
    "kind, says",
    [
        ("missing", "no model file there"),
        ("folder", "a folder"),
        ("truncated", "not a readable model file"),
        ("text", "not a readable model file"),
        ("pickled code", "never unpickled"),
        ("foreign torch file", "another tool"),
        ("training checkpoint", "svbrdf-train export"),
        ("newer format", "upgrade svbrdf-models"),
        ("generator not installed", "not installed here"),
        ("config of another version", "does not fit the installed"),
        ("weights of another network", "do not fit generator"),
        ("NaN weights", "NaN"),
    ],
)
def test_bad_files_get_one_line(tmp_path, trained, model_file, kind, says):
    path = _bad_file(tmp_path, trained, model_file, kind)
    with pytest.raises(sm.ModelFileError) as e:
        load_model(path)
    text = _one_line(e)
    assert text.startswith(str(path)) and says in text
    # files of our format with bad contents are still told apart from checkpoints and foreign files
    ours = (
        kind in ("newer format", "generator not installed", "config of another version") or "weights" in kind
    )
    assert is_model_file(path) == ours


def test_is_model_file(model_file):
    assert is_model_file(model_file)


# -- URLs: a server on loopback -------------------------------------------------------------------


@pytest.fixture(scope="module")
def server(tmp_path_factory, model_file):
    """An HTTP server on 127.0.0.1 serving a folder with the model under its hash name, and
    under names with a wrong hash and none."""
    root = tmp_path_factory.mktemp("www")
    sha = file_sha256(model_file)
    data = model_file.read_bytes()
    (root / hash_name("tiny.pt", sha).name).write_bytes(data)
    (root / "tiny-00000000.pt").write_bytes(data)
    (root / "tiny.pt").write_bytes(data)
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(root))
    handler.log_message = lambda *a: None
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}", sha
    httpd.shutdown()


def test_url_with_its_hash_downloads_once_and_loads(tmp_path, server, model_file):
    base, sha = server
    url = f"{base}/{hash_name('tiny.pt', sha).name}"
    model = load_model(url, model_dir=tmp_path / "cache")
    assert model.sha256 == sha and model.source == url
    cached = tmp_path / "cache" / hash_name("tiny.pt", sha).name
    assert cached.read_bytes() == model_file.read_bytes()
    assert load_model(url, model_dir=tmp_path / "cache").sha256 == sha  # from the cache


def test_url_whose_download_does_not_match_its_hash_is_refused(tmp_path, server):
    base, _ = server
    with pytest.raises(sm.ModelFileError) as e:
        load_model(f"{base}/tiny-00000000.pt", model_dir=tmp_path / "cache")
    assert "does not match the SHA-256" in _one_line(e)
    assert not (tmp_path / "cache" / "tiny-00000000.pt").exists()


def test_a_cached_copy_that_changed_is_refused(tmp_path, server):
    base, sha = server
    name = hash_name("tiny.pt", sha).name
    load_model(f"{base}/{name}", model_dir=tmp_path / "cache")
    cached = tmp_path / "cache" / name
    cached.write_bytes(cached.read_bytes()[:-10] + b"0123456789")
    with pytest.raises(sm.ModelFileError) as e:
        load_model(f"{base}/{name}", model_dir=tmp_path / "cache")
    assert "delete it" in _one_line(e)


@pytest.mark.parametrize(
    "name, says", [("tiny.pt", "no SHA-256 prefix"), ("gone-01234567.pt", "cannot be fetched")]
)
def test_url_without_hash_or_file_is_refused(tmp_path, server, name, says):
    base, _ = server
    with pytest.raises(sm.ModelFileError) as e:
        load_model(f"{base}/{name}", model_dir=tmp_path / "cache")
    assert says in _one_line(e)


def test_mlflow_uri_without_mlflow_says_what_to_install(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "mlflow", None)
    monkeypatch.setitem(sys.modules, "mlflow.artifacts", None)
    with pytest.raises(sm.ModelFileError) as e:
        load_model("models:/svbrdf-ours/1")
    assert "pip install mlflow" in _one_line(e)


def test_loading_pulls_no_trainer_tracking_or_io_library(model_file):
    import subprocess
    import sys

    code = (
        "import sys, torch, svbrdf_models as sm\n"
        f"m = sm.load_model({str(model_file)!r}); m.predict(torch.rand(3, 40, 40))\n"
        "bad = sorted(n for n in ('mlflow', 'h5py', 'PIL', 'yaml', 'click', 'svbrdf_train', 'svbrdf_bench') "
        "if n in sys.modules)\n"
        "print(','.join(bad))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == ""


def test_show_says_what_a_file_holds(model_file, capsys):
    from svbrdf_models.cli import main

    assert main(["show", str(model_file)]) == 0
    out = capsys.readouterr().out
    assert "generator ours" in out and file_sha256(model_file) in out
    assert "7 steps" in out and "code abc" in out and "des18-dev/rmse/render = 0.1" in out


def test_show_of_a_bad_file_is_one_line(tmp_path, capsys):
    from svbrdf_models.cli import main

    assert main(["show", str(tmp_path / "nowhere.pt")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("svbrdf-models: error: ") and err.count("\n") == 1
