"""Model files: written by save_model, read back by load_model from a path or a URL (a server on
loopback: nothing is fetched from outside), refused in one line when they are not ours."""

from __future__ import annotations

import functools
import http.server
import io
import os
import socket
import subprocess
import sys
import threading
import zipfile

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


# -- the header checked against its schema (issue 27) -------------------------------------------


def _header(contents, key, value):
    """``contents`` with ``key`` (``a.b`` for a nested field) set to ``value``."""
    out = {**contents, "generator": dict(contents["generator"]), "provenance": dict(contents["provenance"])}
    head, _, tail = key.partition(".")
    if tail:
        out[head] = {**out[head], tail: value}
    else:
        out[head] = value
    return out


#: (case, field set, value, the field the one line names)
HEADERS = [
    ("config-list", "generator.config", [1, 2], "'generator.config'"),
    ("name-list", "generator.name", ["ours"], "'generator.name'"),
    ("metrics-str", "metrics", "0.1", "'metrics'"),
    ("provenance-list", "provenance", [1, 2], "'provenance'"),
    ("steps-str", "provenance.steps", "7", "'provenance.steps'"),
    ("seconds-nan", "provenance.train_seconds", float("nan"), "'provenance.train_seconds'"),
    ("sources-str", "provenance.data", {"sources": "des18"}, "'provenance.data.sources'"),
    ("resolution-str", "resolution", "32", "'resolution'"),
    ("resolution-nan", "resolution", float("nan"), "'resolution'"),
    ("resolution-zero", "resolution", 0, "'resolution'"),
    ("resolution-negative", "resolution", -32, "'resolution'"),
    ("resolution-huge", "resolution", 10**9, "'resolution'"),
    ("resolution-unfit", "resolution", 40, "'resolution'"),  # tiny takes multiples of 16
    ("weights-list", "weights", [torch.zeros(2)], "'weights'"),
    ("weights-tensor", "weights", torch.zeros(2), "'weights'"),
    ("precision-word", "precision", "fp8", "'precision'"),
    ("version-zero", "version", 0, "'version'"),
]


@pytest.mark.parametrize("case, key, value, field", HEADERS, ids=[h[0] for h in HEADERS])
def test_a_header_field_of_the_wrong_type_or_range_is_one_line_naming_file_and_field(
    tmp_path, trained, case, key, value, field, capsys
):
    from svbrdf_models.cli import main

    path = tmp_path / f"{case}.pt"
    torch.save(_header(_contents(trained), key, value), path)
    with pytest.raises(sm.ModelFileError) as e:
        load_model(path)
    text = _one_line(e)
    assert text.startswith(f"{path}: damaged model file: field {field}"), text
    assert main(["show", str(path)]) == 2  # show never describes it as fine
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1 and field in captured.err


def test_a_config_asking_for_an_absurd_network_is_refused_before_building(tmp_path, trained):
    """Checked in a child process that is killed after 120 s: show once never returned."""
    paths = []
    for name, config in (("deep", {"depth": 100_000}), ("wide", {"max_channels": 10**6, "base_channels": 10**6})):
        c = _contents(trained)
        path = tmp_path / f"{name}.pt"
        torch.save({**c, "generator": {"name": "ours", "config": {**c["generator"]["config"], **config}}}, path)
        paths.append(path)
    code = (
        "import sys\nfrom svbrdf_models.cli import main\n"
        "sys.exit(max(main(['show', p]) for p in sys.argv[1:]))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, *map(str, paths)], capture_output=True, text=True, timeout=120,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 2 and "Traceback" not in done.stderr, done.stderr
    assert lines[0].startswith(f"svbrdf-models: error: {paths[0]}:") and "depth must be from 2 to 13" in lines[0]
    assert lines[1].startswith(f"svbrdf-models: error: {paths[1]}:") and "million parameters" in lines[1]


def test_the_size_bound_admits_the_paper_and_counts_its_parameters():
    """The estimate the bound reads is the parameter count of the networks it admits."""
    for name, config in (("ours", {}), ("unet", {}), ("ours", {"preset": "small"})):
        estimate = sm.resolve_config("generator", name, config).parameter_estimate()
        built = sum(p.numel() for p in sm.create_generator(name, config).parameters())
        assert estimate == built
    with pytest.raises(sm.ConfigError, match="max_channels"):
        sm.resolve_config("generator", "ours", {"max_channels": 2048})
    for name, config in (("patchgan", {}), ("multi", {}), ("patchgan", {"layers": 5, "norm": "batch"})):
        estimate = sm.resolve_config("discriminator", name, config).parameter_estimate()
        built = sum(p.numel() for p in sm.create_discriminator(name, config).parameters())
        assert estimate == built
    with pytest.raises(sm.ConfigError, match="million parameters"):
        sm.resolve_config("discriminator", "multi", {"base_channels": 100_000})


# -- the .sha256 sidecar ------------------------------------------------------------------------


def test_a_sidecar_that_does_not_match_is_refused_by_show_and_predict(tmp_path, model_file, capsys):
    from svbrdf_models.cli import main

    path = tmp_path / model_file.name
    path.write_bytes(model_file.read_bytes())
    sidecar = path.with_name(path.name + ".sha256")
    sidecar.write_text(f"{file_sha256(path)}  {path.name}\n")  # as svbrdf-train export writes it
    assert load_model(path).sha256 == file_sha256(path)
    sidecar.write_text(f"{'0' * 64}  {path.name}\n")
    with pytest.raises(sm.ModelFileError) as e:
        load_model(path)
    assert _one_line(e).startswith(str(path)) and "tiny.pt.sha256" in str(e.value)
    photo = tmp_path / "photo.png"
    from svbrdf_render import write_image

    write_image(photo, torch.full((3, 64, 64), 0.4))
    for argv in (["show", str(path)], ["predict", str(photo), "--model", str(path), "--refine", "0",
                                       "-o", str(tmp_path / "maps")]):  # fmt: skip
        assert main(argv) == 2
        err = capsys.readouterr().err
        lines = [line for line in err.splitlines() if "error:" in line]
        assert len(lines) == 1 and str(path) in lines[0] and ".sha256" in lines[0], err
    assert not (tmp_path / "maps" / "photo").exists()
    sidecar.write_text("not a checksum\n")
    with pytest.raises(sm.ModelFileError, match="holds no SHA-256"):
        load_model(path)


# -- a zip that expands far beyond its size -------------------------------------------------------


def _repacked(source_bytes: bytes, path, compression=zipfile.ZIP_DEFLATED):
    """The torch zip ``source_bytes`` written again with its entries compressed."""
    with zipfile.ZipFile(io.BytesIO(source_bytes)) as src, zipfile.ZipFile(path, "w", compression) as dst:
        for info in src.infolist():
            dst.writestr(info.filename, src.read(info.filename))
    return path


def test_a_model_file_that_expands_far_beyond_its_size_is_refused_before_loading(tmp_path, trained):
    buffer = io.BytesIO()
    blob = torch.zeros(16 * 2**20 // 4)  # 16 MiB of zeros: a few KiB once deflated
    torch.save({**_contents(trained), "recipe": {"name": "ours", "blob": blob}}, buffer)
    bomb = _repacked(buffer.getvalue(), tmp_path / "bomb.pt")
    assert bomb.stat().st_size < 2**20
    assert torch.load(bomb, weights_only=True)["recipe"]["blob"].numel() == blob.numel()  # torch reads it
    with pytest.raises(sm.ModelFileError) as e:
        load_model(bomb)
    text = _one_line(e)
    assert text.startswith(f"{bomb}: it would expand to 16.") and "uncompressed" in text, text
    assert not is_model_file(bomb)
    # a model file re-packed with compression stays within the bound: weights compress little
    repacked = _repacked(_saved(trained), tmp_path / "ok.pt")
    assert load_model(repacked).name == "ours"


def _saved(trained) -> bytes:
    buffer = io.BytesIO()
    torch.save(_contents(trained), buffer)
    return buffer.getvalue()


# -- TrainedModel.predict on photos that are not linear values ------------------------------------


def test_predict_refuses_nan_and_integer_photos_and_predicts_a_black_one(model_file):
    model = load_model(model_file)
    photo = torch.rand(3, RES, RES)
    photo[1, 3, 4] = float("nan")
    for bad, says in ((photo, "NaN"), ((torch.rand(3, RES, RES) * 255).to(torch.uint8), "uint8 codes")):
        with pytest.raises(sm.DataError) as e:
            model.predict(bad)
        assert says in _one_line(e)
    with pytest.raises(sm.DataError, match="NaN"):
        model.predict(photo, refine=2)  # checked before refinement too
    maps = model.predict(torch.zeros(3, RES, RES))  # black: a photo like any other here
    for m in ("normal", "diffuse", "roughness", "specular"):
        assert torch.isfinite(getattr(maps, m)).all()


# -- URLs: a server that never answers, hostile names and contents ---------------------------------


@pytest.fixture(scope="module")
def silent_server():
    """A loopback TCP server that accepts connections and never answers (``/silent``), or sends
    headers and part of the body, then nothing (``/stall``)."""
    listener = socket.create_server(("127.0.0.1", 0))
    held: list[socket.socket] = []
    stop = threading.Event()

    def serve():
        listener.settimeout(0.2)
        while not stop.is_set():
            try:
                conn, _ = listener.accept()
            except TimeoutError:
                continue
            held.append(conn)
            request = conn.recv(4096)
            if b"/stall" in request:
                conn.sendall(b"HTTP/1.0 200 OK\r\nContent-Length: 100000\r\n\r\n" + b"PK" * 10)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{listener.getsockname()[1]}"
    stop.set()
    thread.join(timeout=5)
    for conn in held:
        conn.close()
    listener.close()


@pytest.mark.parametrize("path", ["silent", "stall"])
def test_a_server_that_never_answers_times_out_in_one_line_and_leaves_no_partial_file(
    tmp_path, silent_server, path
):
    """A child process killed after 120 s: without a timeout the download waited forever."""
    url = f"{silent_server}/{path}/tiny-01234567.pt"
    done = subprocess.run(
        [sys.executable, "-m", "svbrdf_models", "show", url], capture_output=True, text=True, timeout=120,
        env={**os.environ, "TORCH_HOME": str(tmp_path / "torch"), "SVBRDF_DOWNLOAD_TIMEOUT": "1",
             "OMP_NUM_THREADS": "1"},
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"svbrdf-models: error: {url}: "), done.stderr
    assert "SVBRDF_DOWNLOAD_TIMEOUT=1 s" in lines[0]
    assert [p for p in (tmp_path / "torch").rglob("*") if p.is_file()] == []


def test_a_bad_timeout_setting_is_one_line(tmp_path, server, monkeypatch):
    base, sha = server
    monkeypatch.setenv("SVBRDF_DOWNLOAD_TIMEOUT", "soon")
    with pytest.raises(sm.ModelFileError) as e:
        load_model(f"{base}/{hash_name('tiny.pt', sha).name}", model_dir=tmp_path / "cache")
    assert _one_line(e).startswith("SVBRDF_DOWNLOAD_TIMEOUT='soon'")


@pytest.fixture(scope="module")
def hostile_server(tmp_path_factory, model_file):
    """Loopback HTTP: pickled code under its true hash, and the model under a name whose first
    ``-`` torch.hub reads as an empty hash."""
    root = tmp_path_factory.mktemp("hostile")
    evil = root / "evil.pt"
    torch.save({"format": "svbrdf-model", "code": functools.partial(print)}, evil)
    evil.rename(root / hash_name("evil.pt", file_sha256(evil)).name)
    (root / "x-.y-deadbeef.pt").write_bytes(model_file.read_bytes())
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(root))
    handler.log_message = lambda *a: None
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    names = {"evil": next(p.name for p in root.glob("evil-*.pt")), "dash": "x-.y-deadbeef.pt"}
    yield f"http://127.0.0.1:{httpd.server_address[1]}", names
    httpd.shutdown()


def test_a_refused_download_gives_no_unsafe_advice_and_is_not_kept(tmp_path, hostile_server):
    base, names = hostile_server
    with pytest.raises(sm.ModelFileError) as e:
        load_model(f"{base}/{names['evil']}", model_dir=tmp_path / "cache")
    text = _one_line(e)
    assert "never unpickled" in text and "weights_only" not in text
    assert list((tmp_path / "cache").iterdir()) == []


def test_a_name_torch_hub_reads_as_an_empty_hash_is_checked_here(tmp_path, hostile_server):
    base, names = hostile_server
    with pytest.raises(sm.ModelFileError) as e:
        load_model(f"{base}/{names['dash']}", model_dir=tmp_path / "cache")
    text = _one_line(e)
    assert "the download does not match the SHA-256 in its name" in text and "cached copy" not in text
    assert "deadbeef" in text
    assert list((tmp_path / "cache").iterdir()) == []


def test_a_good_download_leaves_only_the_model_in_the_cache(tmp_path, server):
    base, sha = server
    name = hash_name("tiny.pt", sha).name
    load_model(f"{base}/{name}", model_dir=tmp_path / "cache")
    assert [p.name for p in (tmp_path / "cache").iterdir()] == [name]
