"""Shared fixtures: seeded random materials, the reference data folder, an op counter."""

from __future__ import annotations

import collections
import contextlib
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

from svbrdf_render import SVBRDF

REPO = Path(__file__).resolve().parents[1]
#: The reference data (README, "Reference data"): $SVBRDF_DATA, else shared/data beside the checkout.
SHARED_DATA = Path(os.environ.get("SVBRDF_DATA") or REPO.parent / "shared" / "data")

# No test may write to the user's MLflow store (./mlflow.db by default): every run of the suite
# gets a store of its own, in a temporary folder, before anything imports mlflow.
_MLFLOW_DIR = tempfile.mkdtemp(prefix="svbrdf-tests-mlflow-")
os.environ["MLFLOW_TRACKING_URI"] = f"sqlite:///{_MLFLOW_DIR}/mlflow.db"
# Nor may a user's MLFLOW_EXPERIMENT_NAME move the runs the tests look for (tests set it themselves).
os.environ.pop("MLFLOW_EXPERIMENT_NAME", None)
# A suite started in the background by a script (`setsid nohup ... &`) inherits Ctrl-C ignored,
# so Python installs no handler of its own and every command it starts ignores Ctrl-C too; the
# tests of what Ctrl-C does would then fail for the way the suite was started. Put Python's own
# handler in place, as in a terminal (the commands it starts then get the default disposition).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def random_svbrdf(
    batch: int = 2,
    size: int = 16,
    *,
    seed: int = 0,
    dtype: torch.dtype = torch.float32,
    tilt: float = 0.5,
    roughness: tuple[float, float] = (0.1, 0.9),
) -> SVBRDF:
    """Valid random maps: tilted unit normals, albedos in (0.05, 0.95)."""
    g = torch.Generator().manual_seed(seed)
    shape = (batch, 1, size, size)
    nxy = (torch.rand(batch, 2, size, size, generator=g) * 2 - 1) * tilt
    n = torch.cat([nxy, torch.ones(shape)], dim=1)
    n = n / n.norm(dim=1, keepdim=True)
    lo, hi = roughness
    return SVBRDF(
        n.to(dtype),
        (0.05 + 0.9 * torch.rand(batch, 3, size, size, generator=g)).to(dtype),
        (lo + (hi - lo) * torch.rand(shape, generator=g)).to(dtype),
        (0.02 + 0.9 * torch.rand(batch, 3, size, size, generator=g)).to(dtype),
    )


def des18_strips(folder: Path, count: int = 3, size: int = 64) -> Path:
    """A folder of ``count`` Des18 strips of ``size``-pixel random materials and photos."""
    from svbrdf_render import write_des18

    folder.mkdir(parents=True, exist_ok=True)
    for i in range(count):
        maps = random_svbrdf(1, size, seed=i, roughness=(0.3, 0.9))
        photo = torch.rand(1, 3, size, size, generator=torch.Generator().manual_seed(100 + i))
        write_des18(folder / f"{i:07d};MatAXMatB;0X1.png", photo, maps)
    return folder


@pytest.fixture(autouse=True, scope="module")
def _threads_for_the_free_cores():
    """Each module computes with one thread per free core, as the commands do
    (:func:`svbrdf_render.plumbing.choose_threads`; ``OMP_NUM_THREADS`` when set), in torch and
    in numpy's BLAS: their threads spin while they wait for each other, and on a 2-core machine
    that another program keeps busy the suite's own threads waited for cores that never came
    free (test_physics's albedo quadrature took 73 s of CPU with 2 threads there, 4 s with 1).
    An idle machine keeps every core; a test that sets its own threads puts them back itself."""
    from svbrdf_render.plumbing import choose_threads

    threads = choose_threads().threads
    with contextlib.suppress(ImportError):  # threadpoolctl comes with scikit-learn
        from threadpoolctl import threadpool_limits

        threadpool_limits(threads, user_api="blas")


@pytest.fixture
def material() -> SVBRDF:
    return random_svbrdf()


@pytest.fixture
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"reference data not found at {SHARED_DATA} (set SVBRDF_DATA to your copy)")
    return SHARED_DATA


class OpCounter(TorchDispatchMode):
    """Counts every aten op that runs (forward, and backward when it runs inside)."""

    def __init__(self):
        super().__init__()
        self.counts: collections.Counter[str] = collections.Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.counts[str(func.overloadpacket)] += 1
        return func(*args, **(kwargs or {}))

    @property
    def total(self) -> int:
        return sum(self.counts.values())


@pytest.fixture
def op_counter():
    return OpCounter


def run_cli(*args: str, cwd=None, env=None, timeout: float = 300) -> subprocess.CompletedProcess:
    """``python -m svbrdf_train ARGS`` in a fresh process (the suite's MLflow store by default)."""
    return subprocess.run(
        [sys.executable, "-m", "svbrdf_train", *args],
        cwd=cwd,
        env={**os.environ, **(env or {})},
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def run_cli_here(
    *args: str, cwd=None, env=None, program: str = "svbrdf_train"
) -> subprocess.CompletedProcess[str]:
    """:func:`run_cli` in this process (``program``: ``svbrdf_train`` or ``svbrdf_bench``): the
    command's ``main`` with ``env`` set and ``cwd`` entered, its exit status and what it printed.
    A fresh interpreter spends about 2.5 s of CPU importing torch and MLflow before a refusal
    that takes milliseconds; a test that checks many refusals runs one of them with
    :func:`run_cli` and the others here. The environment, the working folder and torch's thread
    count (``--threads`` sets it) are put back afterwards."""
    import importlib
    import io

    main = importlib.import_module(f"{program}.cli").main
    out, err = io.StringIO(), io.StringIO()
    saved = {k: os.environ.get(k) for k in env or {}}
    threads, here = torch.get_num_threads(), os.getcwd()
    try:
        os.environ.update(env or {})
        if cwd is not None:
            os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main([str(a) for a in args])
    finally:
        os.chdir(here)
        torch.set_num_threads(threads)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return subprocess.CompletedProcess([program, *args], code, out.getvalue(), err.getvalue())


# -- the validators and the browser that the README's set-up installs ------------------------------

#: The repository's glTF validator (tools/gltf-validate: the Khronos validator under Node.js).
GLTF_VALIDATOR = REPO / "tools" / "gltf-validate"
CHROMIUM = Path("/usr/bin/chromium")


def missing_tool(reason: str):
    """Skip a test that needs a tool the set-up installs, or fail it when CI is set: a CI run
    that skipped it would prove nothing."""
    if os.environ.get("CI"):
        pytest.fail(f"{reason} (CI is set: the set-up must install it)")
    pytest.skip(reason)


def validate_gltf(path: Path) -> dict:
    """The Khronos glTF validator's report on ``path``: ``{"issues": ..., "info": ...,
    "returncode": ...}`` (see tools/gltf-validate/validate.mjs)."""
    import json
    import shutil

    node = shutil.which("node")
    if node is None:
        missing_tool("node is not installed: the glTF validator runs under Node.js")
    if not (GLTF_VALIDATOR / "node_modules" / "gltf-validator").is_dir():
        missing_tool(f"the glTF validator is not installed: run `npm ci` in {GLTF_VALIDATOR}")
    r = subprocess.run(
        [node, str(GLTF_VALIDATOR / "validate.mjs"), str(path)], capture_output=True, text=True, timeout=120
    )
    if r.returncode not in (0, 1):  # 2: it could not validate the file at all
        pytest.fail(f"the glTF validator failed on {path}: {r.stderr.strip()}")
    (report,) = json.loads(r.stdout)
    report["returncode"] = r.returncode
    return report


def require_materialx():
    """The MaterialX module (see :func:`missing_tool`)."""
    try:
        import MaterialX
    except ImportError:
        missing_tool("the materialx package is not installed: pip install materialx")
    return MaterialX


def require_chromium() -> Path:
    """Debian's Chromium (see :func:`missing_tool`)."""
    if not CHROMIUM.is_file():
        missing_tool(f"{CHROMIUM} not found: install it with apt-get install -y chromium")
    return CHROMIUM


def load_benchmark(name: str):
    """The script ``benchmarks/NAME.py`` imported as a module (its functions tested without
    running it)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, REPO / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def free_port() -> int:
    """A TCP port free on loopback now."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _answers(url: str) -> bool:
    import urllib.request

    try:
        with urllib.request.urlopen(url, timeout=5) as response:
            return response.status == 200
    except OSError:
        return False


def stop_process_group(proc: subprocess.Popen) -> None:
    """End a server started with ``start_new_session=True`` and the workers it started."""
    import signal

    if proc.poll() is not None:
        return
    os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)


@contextlib.contextmanager
def serving(command: list[str], ready_url: str, log_path: Path, *, env=None, cwd=None, timeout: float = 120,
            on_failure=pytest.fail):  # fmt: skip
    """Run a server (``command``, in its own process group, output to ``log_path``) until
    ``ready_url`` answers 200, yield the process, and stop the whole group afterwards. A server
    that exits or stays silent for ``timeout`` s is ``on_failure(message with its log's tail)``
    (pytest.fail, or pytest.skip where the test's subject is not the server)."""
    with open(log_path, "w") as log:
        proc = subprocess.Popen(command, cwd=cwd, env=env, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)  # fmt: skip
    try:
        deadline = time.monotonic() + timeout
        while not _answers(ready_url):
            if proc.poll() is not None or time.monotonic() > deadline:
                why = f"exited with code {proc.returncode}" if proc.poll() is not None else f"silent {timeout:g} s"
                on_failure(f"{command[:4]} {why}:\n{Path(log_path).read_text()[-2000:]}")
            time.sleep(0.5)
        yield proc
    finally:
        stop_process_group(proc)


@pytest.fixture
def refine_calls(monkeypatch) -> list:
    """Each refinement the photo tool's one-photo capture runs, recorded as ``(photo, start,
    steps, keywords, result)`` (the photo cloned), the call itself made as usual: a test can
    make the same call again and compare the maps bit for bit."""
    from svbrdf_models.capture import one
    from svbrdf_models.capture.refining import refine_prediction

    calls = []

    def spy(photo, start, steps, **kw):
        result = refine_prediction(photo, start, steps, **kw)
        calls.append((photo.clone(), start, steps, kw, result))
        return result

    monkeypatch.setattr(one, "refine_prediction", spy)
    return calls
