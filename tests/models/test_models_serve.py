"""``svbrdf-models serve`` on loopback, against what a hostile tester sent ``mlflow models serve``
(issue 36): huge refinement budgets that held the worker for good, bodies far over any photo,
junk echoed back in 50-98 line answers, deep nesting answered 500, channels-first and negative
photos given the wrong hint, a ``/ping`` that said healthy over a stuck worker, and a worker that
outlived the server. Each case is checked through a real server; the stuck worker through the
app itself, with a model that never returns."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request

import numpy as np
import pytest
import torch

import svbrdf_models as sm
from conftest import free_port, load_benchmark, serving

pytest.importorskip("starlette")
pytest.importorskip("uvicorn")
from svbrdf_models.modelfile.serve import build_app  # noqa: E402
from svbrdf_models.modelfile.serve_limits import ServeLimits, check_depth, parse_request  # noqa: E402

LIMITS = ["--max-body-mb", "1", "--max-pixels", "20000", "--max-refine", "100000", "--timeout", "4"]


def _command(port: int, *extra: str) -> list[str]:
    exe = os.path.join(os.path.dirname(sys.executable), "svbrdf-models")
    return [exe, "serve", "pretrained", "--port", str(port), "--threads", "1", *extra]


def _photos(n: int, h: int, w: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.02, 0.9, (n, h, w, 3)).astype(np.float32)


def _post(url: str, body: bytes | dict, kind: str = "application/json") -> tuple[int, bytes]:
    data = body if isinstance(body, bytes) else json.dumps(body).encode()
    request = urllib.request.Request(url + "/invocations", data=data, headers={"Content-Type": kind})
    try:
        with urllib.request.urlopen(request, timeout=60) as response:
            return response.status, response.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def _get(url: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=10) as response:
            return response.status, response.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """The server (shipped model, small limits) and its process."""
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    with serving(
        _command(port, *LIMITS), f"{url}/ping", tmp_path_factory.mktemp("serve") / "serve.log"
    ) as proc:
        yield url, proc


@pytest.fixture
def server(served):
    return served[0]


def test_a_posted_photo_gets_the_maps_load_model_gives(server):
    photos = _photos(1, 24, 20, seed=3)
    status, body = _post(server, {"inputs": photos.tolist(), "params": {"refine": 0}})
    assert status == 200, body
    got = json.loads(body)["predictions"]
    want = sm.load_model("pretrained").predict(torch.from_numpy(photos).permute(0, 3, 1, 2))
    for name, t in want.maps().items():
        assert np.abs(np.asarray(got[name], np.float32) - t.permute(0, 2, 3, 1).numpy()).max() <= 1e-5, name


def test_a_huge_refinement_stops_at_its_deadline_and_the_worker_takes_the_next(server):
    # mlflow models serve: six of these 504ed and disabled the server for good.
    status, body = _post(server, {"inputs": _photos(1, 64, 64).tolist(), "params": {"refine": 100000}})
    assert status == 200, body  # the maps it reached before the 4 s deadline, not a 504
    assert np.asarray(json.loads(body)["predictions"]["diffuse"]).shape == (1, 64, 64, 3)
    assert _get(f"{server}/ping")[0] == 200
    assert _post(server, {"inputs": _photos(1, 16, 16).tolist()})[0] == 200


def _refusal(status: int, body: bytes, want_status: int, *needles: str) -> str:
    text = body.decode()
    assert status == want_status, text[:300]
    assert text.count("\n") == 1 and len(text) < 400, text[:300]  # one short line, no input echoed
    for needle in needles:
        assert needle in text, text
    return text


@pytest.mark.parametrize(
    ("params", "needles"),
    [
        ({"refine": 1000000000}, ["refine 1000000000 is over this server's limit of 100000", "--max-refine"]),
        ({"refine": 1e30}, ["whole number of refinement steps"]),
        ({"refine": 2**63}, ["over this server's limit"]),
        ({"refine": -1}, ["whole number"]),
        ({"refine": 1, "seed": 3}, ["refine is the only parameter"]),
    ],
)
def test_bad_parameters_are_one_line_400s(server, params, needles):
    _refusal(*_post(server, {"inputs": _photos(1, 16, 16).tolist(), "params": params}), 400, *needles)


@pytest.mark.parametrize(
    ("inputs", "needles"),
    [
        (_photos(1, 16, 16).transpose(0, 3, 1, 2), ["channels go last"]),
        (-_photos(1, 16, 16), ["never below 0"]),
        (_photos(1, 16, 16) * 255, ["scale 8-bit values by 1/255"]),
        (
            np.full((1, 150, 150, 3), 0.5),
            ["22,500 pixels in one request, over this server's limit of 20,000", "--max-pixels"],
        ),  # fmt: skip
        (np.zeros((0, 16, 16, 3)), ["got shape (0,)"]),
        (_photos(1, 1, 1), ["the photo is 1x1 px, under 8 px"]),
        ([[[0.5, 0.5]]], ["got shape"]),
        ("a photo", ["expected numbers"]),
    ],
)
def test_bad_photos_are_one_line_400s_with_the_right_hint(server, inputs, needles):
    data = inputs.tolist() if isinstance(inputs, np.ndarray) else inputs
    _refusal(*_post(server, {"inputs": data}), 400, *needles)


def test_a_body_over_the_limit_is_refused_and_never_echoed(server):
    junk = b"x" * (1 << 20) + b"y" * 4096  # just over --max-body-mb 1
    text = _refusal(
        *_post(server, junk), 413, "body: 1.0 MB", "over this server's limit of 1 MB", "--max-body-mb"
    )
    assert "xxxx" not in text
    assert _post(server, {"inputs": _photos(1, 16, 16).tolist()})[0] == 200  # and the next request is served


def test_junk_deep_nesting_and_other_types_are_one_line_answers(server):
    text = _refusal(*_post(server, b"not json " * 5000), 400, "body: not JSON")
    assert "not json" not in text
    _refusal(*_post(server, b"[" * 100_000 + b"]" * 100_000), 400, "nested more than 8 deep")
    _refusal(*_post(server, {"photos": [1]}), 400, 'expected {"inputs": photos')
    _refusal(*_post(server, b"a,b\n1,2\n", kind="text/csv"), 415, "send application/json")
    assert _get(f"{server}/ping")[0] == 200  # none of it hurt the server


def test_the_nesting_check_counts_across_chunks():
    check_depth(b"[" * 8 + b"]" * 8, 8)
    with pytest.raises(Exception, match="nested more than 8 deep"):
        check_depth(b"[" * 9, 8)
    photos, steps = parse_request(json.dumps({"inputs": _photos(2, 8, 8).tolist()}).encode(), ServeLimits())
    assert photos.shape == (2, 8, 8, 3) and photos.dtype == np.float32 and steps == 0


class _Stuck:
    """A model whose prediction never returns until released: a stuck worker."""

    resolution = 128

    def __init__(self):
        self.release = threading.Event()

    def predict(self, photo, refine=0, seconds=None, callback=None, backend=None):
        self.release.wait(60)
        return sm.load_model("pretrained").predict(photo)

    def describe(self) -> str:
        return "stuck"


def test_ping_says_unhealthy_while_a_request_holds_the_worker_past_its_timeout():
    import uvicorn

    model, port = _Stuck(), free_port()
    app = build_app(model, ServeLimits(timeout=1.0))
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    url = f"http://127.0.0.1:{port}"
    try:
        while not server.started:
            time.sleep(0.05)
        assert _get(f"{url}/ping")[0] == 200
        answer = {}
        client = threading.Thread(
            target=lambda: answer.setdefault("r", _post(url, {"inputs": _photos(1, 16, 16).tolist()}))
        )
        client.start()
        time.sleep(2.5)  # past the 1 s timeout: the request is answered 504, its work still holds the worker
        status, body = _get(f"{url}/ping")
        assert status == 503 and body.decode().startswith("unhealthy: one request has held the worker"), body
        client.join(10)
        assert answer["r"][0] == 504 and answer["r"][1].decode().startswith("timeout:")
        model.release.set()
        deadline = time.monotonic() + 10
        while _get(f"{url}/ping")[0] != 200 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert _get(f"{url}/ping")[0] == 200  # healthy again once the worker is free
    finally:
        model.release.set()
        server.should_exit = True
        thread.join(15)
        app.state.worker.close()


def _listened(port: int) -> bool:
    """Whether a process still listens on ``port`` (a connection is accepted, not refused)."""
    with socket.socket() as sock:
        return sock.connect_ex(("127.0.0.1", port)) == 0


def test_sigterm_during_a_refinement_ends_the_server_and_frees_its_port(tmp_path):
    # mlflow models serve: SIGTERM left its uvicorn worker holding the port.
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    with serving(_command(port, "--timeout", "120"), f"{url}/ping", tmp_path / "serve.log") as proc:
        body = {"inputs": _photos(1, 64, 64).tolist(), "params": {"refine": 100000}}
        client = threading.Thread(target=lambda: _post(url, body), daemon=True)
        client.start()
        time.sleep(2)  # the refinement is under way
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) is not None
    assert not _listened(port)


def test_a_taken_port_is_one_line_and_exit_2():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = subprocess.run(_command(port), capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and f"--port {port}: cannot listen there" in result.stderr


def test_a_bounded_load_test_reports_latency_and_memory(served):
    bench = load_benchmark("serve_load")
    url, proc = served
    figures = bench.load_test(url, clients=2, requests=6, size=32, pid=proc.pid)
    print(bench.table([("2 clients, 32 px, refine 0", figures)]))
    assert figures["errors"] == 0 and figures["requests"] == 6
    assert 0 < figures["p50_s"] <= figures["p95_s"] and figures["peak_mb"] > 0


def test_a_single_request_case_reports_the_workers_busy_time_and_sampled_memory(served):
    bench = load_benchmark("serve_load")
    url, proc = served
    assert bench.server_timing("upload;dur=12, parse;dur=3") == {"upload": 0.012, "parse": 0.003}
    figures = bench.single_request(url, photos=1, side=16, refine=2, pid=proc.pid)
    print(bench.cases_table([("one 16x16 photo at refine 2", figures)]))
    assert figures["status"] == 200 and figures["answer"] == "maps"
    assert set(figures["stages"]) == {"upload", "parse", "queue", "work", "encode"}
    assert figures["busy_s"] == figures["stages"]["work"] > 0  # the Server-Timing header's work stage
    assert figures["server_mb"] > 0 and figures["tree_mb"] > 0
    refused = bench.single_request(url, photos=3, side=100, refine=0, pid=proc.pid)  # over --max-pixels
    assert refused["status"] == 400 and refused["busy_s"] == 0  # refused before any work


def test_serve_starts_again_on_its_port_at_once_after_closing_an_idle_keep_alive_connection(tmp_path):
    # issue 47: "Address already in use" for a minute once the server had closed an idle keep-alive
    # connection (its side of it waits in TIME_WAIT), though nothing listened on the port
    import http.client

    port = free_port()
    url = f"http://127.0.0.1:{port}"
    with serving(_command(port), f"{url}/ping", tmp_path / "first.log"):
        kept = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
        kept.request("GET", "/ping")
        assert kept.getresponse().read() == b"\n"  # the connection stays open, idle
    try:
        with serving(_command(port), f"{url}/ping", tmp_path / "second.log", timeout=60):
            assert _get(f"{url}/ping")[0] == 200
    finally:
        kept.close()
