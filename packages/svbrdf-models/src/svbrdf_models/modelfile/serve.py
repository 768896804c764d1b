"""``svbrdf-models serve``: a model behind an HTTP server that holds up against what a hostile or
careless client sends.

It speaks MLflow's scoring protocol (what ``mlflow models serve`` answers), so clients need no
change::

    svbrdf-models serve models:/svbrdf-ours/1 --port 5001      # or a model file, or pretrained
    curl 127.0.0.1:5001/invocations -H 'Content-Type: application/json' \\
         -d '{"inputs": [[[[0.5, 0.4, 0.3], ...]]], "params": {"refine": 0}}'
    # -> {"predictions": {"normal": [...], "diffuse": [...], "roughness": [...], "specular": [...]}}

``GET /ping`` (and ``/health``) answer 200 while the worker can take a request, ``GET /version``
the package's version. What it does that MLflow's own server does not (docs/serving.md has the
cases, measured against ``mlflow models serve``):

- every limit (:class:`ServeLimits`: body size, JSON nesting, pixels per request, refinement
  steps, time per request) is checked before any work, and a refusal is one line of text whose
  first words say what was wrong, never an echo of the input (413 for a body over the limit,
  400 for the rest, 415 for a body that is not JSON);
- a request's refinement stops at its deadline (:attr:`ServeLimits.timeout`, less a margin for
  the network and the answer) and answers with the maps it reached, so no request holds the
  worker past its time; the predictions run one at a time on one worker thread (torch already
  uses every core), and a request that waited in the queue past its deadline is answered 503;
- ``/ping`` answers 503 while one request has held the worker past its timeout (stuck), not a
  healthy 200 over a worker that takes nothing;
- it is one process: SIGTERM or Ctrl-C ends the server and its work (a running refinement
  stops at its next step), and frees the port.

Needs starlette and uvicorn (they come with ``svbrdf-models[mlflow]``: MLflow's own server is
built on them); mlflow itself only for ``models:/`` and ``runs:/`` sources.
"""

from __future__ import annotations

import asyncio
import json
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import DataError

__all__ = [
    "ServeLimits",
    "build_app",
    "serve",
    "check_photo_array",
    "refine_budget",
    "maps_arrays",
    "encode_answer",
]

#: What a photo array must be, as the refusals say it.
PHOTOS = "photos (linear RGB in [0, 1], shape (N, H, W, 3) or (H, W, 3))"


def check_photo_array(photos: Any, max_pixels: int, limit_name: str) -> np.ndarray:
    """``photos`` (nested lists or an array) as a float32 ``(N, H, W, 3)`` array of linear RGB in
    [0, 1] (an ``(H, W, 3)`` photo gets a batch axis), with at most ``max_pixels`` pixels in all
    (``limit_name``: the setting that changes it); a :class:`DataError` that says what is wrong."""
    try:
        array = np.asarray(photos)
    except Exception as e:  # ragged nested lists, objects numpy cannot hold in one array
        raise DataError(f"{PHOTOS}: not an array ({type(e).__name__})") from None
    if array.dtype.kind not in "fiu":
        raise DataError(f"{PHOTOS}: expected numbers, got {array.dtype} values ({type(photos).__name__})")
    if array.ndim == 3:
        array = array[None]
    if array.ndim != 4 or array.shape[-1] != 3 or 0 in array.shape:
        hint = "; channels go last" if array.ndim == 4 and array.shape[1] == 3 else ""
        raise DataError(f"{PHOTOS}: got shape {tuple(np.shape(photos))}{hint}")
    pixels = int(np.prod(array.shape[:3]))
    if pixels > max_pixels:
        raise DataError(f"{PHOTOS}: {pixels:,} pixels in one request, over this server's limit of "
                        f"{max_pixels:,} ({limit_name}); send fewer or smaller photos")  # fmt: skip
    array = array.astype(np.float32, copy=False)
    bad = int(np.count_nonzero(~np.isfinite(array)))
    if bad:
        raise DataError(f"{PHOTOS}: {bad} values are NaN or infinite; give finite pixel values")
    low, high = float(array.min()), float(array.max())
    if low < 0:
        raise DataError(f"{PHOTOS}: values down to {low:.4g}; linear radiance is never below 0")
    if high > 1:
        raise DataError(f"{PHOTOS}: values span [{low:.4g}, {high:.4g}]; scale 8-bit values by 1/255, and "
                        "decode sRGB to linear first")  # fmt: skip
    return array


def refine_budget(refine: Any, limit: int, limit_name: str) -> int:
    """A request's refinement steps (an integer >= 0; numpy integers too) at most ``limit``
    (``limit_name``: the setting that changes it); a :class:`DataError` otherwise."""
    from ..capture.refining import check_refine

    if isinstance(refine, np.integer):  # MLflow's parameter schema may hand numpy integers
        refine = int(refine)
    try:
        steps = check_refine(refine)
    except DataError as e:
        raise DataError(f"params: {e}") from None
    if steps > limit:
        raise DataError(
            f"params: refine {steps} is over this server's limit of {limit} steps ({limit_name}); "
            "ask for fewer"
        )
    return steps


def maps_arrays(svbrdf) -> dict[str, np.ndarray]:
    """The maps of an :class:`svbrdf_render.SVBRDF` as channels-last float32 arrays by name."""
    return {name: t.permute(0, 2, 3, 1).contiguous().cpu().numpy() for name, t in svbrdf.maps().items()}


@dataclass(frozen=True)
class ServeLimits:
    """What one request may ask of the server; each has a ``svbrdf-models serve`` option."""

    #: Request body, MiB (``--max-body-mb``): a 2048x2048 photo is 60-120 MB of JSON.
    body_mb: float = 128.0
    #: Pixels of all the photos of one request (``--max-pixels``): 2048x2048, about 2 GB refined.
    pixels: int = 4 * 1024 * 1024
    #: Refinement steps one request may ask (``--max-refine``).
    refine: int = 500
    #: Seconds a request may take, queue included (``--timeout``); refinement stops before it.
    timeout: float = 60.0
    #: Nesting of the JSON body: a batch of photos is 4 deep inside its object; 8 leaves room.
    depth: int = 8


class _Refused(Exception):
    """A request answered with ``status`` and one line, ``reason``."""

    def __init__(self, status: int, reason: str):
        super().__init__(reason)
        self.status, self.reason = status, reason


class _Stopped(Exception):
    """The server is shutting down: the refinement under way stops at its next step."""


def check_depth(body: bytes, limit: int) -> None:
    """Refuse a body whose brackets nest deeper than ``limit`` (read as bytes in 8 MiB chunks,
    before any parser recurses into it; brackets inside strings count too, which a photo has
    none of)."""
    depth, chunk = 0, 8 << 20
    for start in range(0, len(body), chunk):
        b = np.frombuffer(body, np.uint8, min(chunk, len(body) - start), start)
        step = np.isin(b, (91, 123)).astype(np.int32) - np.isin(b, (93, 125))  # [{ minus ]}
        levels = depth + np.cumsum(step)
        if levels.size and int(levels.max()) > limit:
            raise _Refused(400, f"body: JSON nested more than {limit} deep; a batch of photos is 4 deep")
        depth = int(levels[-1]) if levels.size else depth


def parse_request(body: bytes, limits: ServeLimits) -> tuple[np.ndarray, int]:
    """``(photos (N, H, W, 3) float32, refinement steps)`` from a request body, or :class:`_Refused`."""
    check_depth(body, limits.depth)
    try:
        doc = json.loads(body)
    except (ValueError, RecursionError) as e:  # JSONDecodeError, bad UTF-8: the position, not the text
        raise _Refused(400, f"body: not JSON ({type(e).__name__} {str(e)[:80]})") from None
    shape = 'expected {"inputs": photos, "params": {"refine": STEPS}}'
    if not isinstance(doc, dict) or not {"inputs", "instances"} & doc.keys():
        raise _Refused(400, f"body: {shape}")
    params = doc.get("params") or {}
    if not isinstance(params, dict) or set(params) - {"refine"}:
        raise _Refused(400, f"params: {shape}; refine is the only parameter")
    try:
        photos = check_photo_array(doc.get("inputs", doc.get("instances")), limits.pixels, "--max-pixels")
        steps = refine_budget(params.get("refine", 0), limits.refine, "--max-refine")
    except DataError as e:
        raise _Refused(400, str(e)) from None
    return photos, steps


class _Worker:
    """One prediction at a time on one thread; knows since when it has been busy."""

    def __init__(self, model, limits: ServeLimits):
        self.model, self.limits = model, limits
        self.pool = ThreadPoolExecutor(1, thread_name_prefix="svbrdf-serve")
        self.busy_since: float | None = None
        self.stopping = threading.Event()

    def stuck_for(self) -> float:
        """Seconds the request under way has held the worker past the timeout (0: not stuck)."""
        since = self.busy_since
        return 0.0 if since is None else max(0.0, time.monotonic() - since - self.limits.timeout)

    def run(self, photos: np.ndarray, steps: int, deadline: float) -> dict[str, np.ndarray]:
        """The maps of ``photos`` (:func:`maps_arrays`), refined until ``deadline`` at most."""
        import torch

        now = time.monotonic()
        if now > deadline:
            raise _Refused(503, "busy: this request waited in the queue past its timeout; try again")
        self.busy_since = now
        try:
            # the network and the answer's JSON take time too: refinement gets 80% of what is left
            seconds = max(0.5, 0.8 * (deadline - now)) if steps else None
            photo = torch.from_numpy(photos).permute(0, 3, 1, 2)
            maps = self.model.predict(photo, refine=steps, seconds=seconds, callback=self._stop_check)
            return maps_arrays(maps)
        finally:
            self.busy_since = None

    def _stop_check(self, step: int, total: int, loss: float) -> None:
        if self.stopping.is_set():
            raise _Stopped()

    def close(self) -> None:
        self.stopping.set()
        self.pool.shutdown(wait=True, cancel_futures=True)


def encode_answer(arrays: dict[str, np.ndarray]) -> bytes:
    """The answer's body, ``{"predictions": {name: nested lists}}``, values rounded to 6 decimals
    (a 4000th of an 8-bit step): half the bytes and time of every float32's 17 digits."""
    rounded = {k: np.round(v.astype(np.float64), 6).tolist() for k, v in arrays.items()}
    return json.dumps({"predictions": rounded}).encode()


def _line(status: int, reason: str):
    from starlette.responses import PlainTextResponse

    return PlainTextResponse(reason.splitlines()[0] + "\n", status_code=status)


#: Bytes of a body over the limit read and thrown away before the 413, so that a client that
#: sends its whole body before it reads (urllib, requests) sees the answer, not a broken pipe.
DRAIN_BYTES = 1 << 30


async def _read_body(request, limits: ServeLimits) -> bytes:
    """The body, refused (413) once it is known to exceed ``limits.body_mb``; what is over the
    limit is read and dropped (up to :data:`DRAIN_BYTES`), never kept."""
    cap = int(limits.body_mb * 2**20)
    over = f"over this server's limit of {limits.body_mb:g} MB (--max-body-mb); send fewer or smaller photos"
    length = request.headers.get("content-length", "")
    declared = int(length) if length.isdigit() else None
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size <= cap and (declared is None or declared <= cap):
            chunks.append(chunk)
        elif size > DRAIN_BYTES:
            break
    if size > cap or (declared or 0) > cap:
        chunks.clear()
        got = f"{max(size, declared or 0) / 2**20:.1f} MB" if size <= DRAIN_BYTES else "more than 1 GB"
        raise _Refused(413, f"body: {got}, {over}")
    return b"".join(chunks)


def build_app(model, limits: ServeLimits | None = None):
    """The Starlette app serving ``model`` (a :class:`svbrdf_models.TrainedModel`) within ``limits``;
    ``app.state.worker`` is its worker (``close()`` it when the server ends)."""
    from starlette.applications import Starlette
    from starlette.responses import Response
    from starlette.routing import Route

    from .. import __version__

    limits = limits or ServeLimits()
    worker = _Worker(model, limits)

    async def ping(request):
        stuck = worker.stuck_for()
        if stuck > 0:
            return _line(503, f"unhealthy: one request has held the worker {stuck:.0f} s past its "
                              f"{limits.timeout:g} s timeout")  # fmt: skip
        return Response("\n", media_type="application/json")

    async def version(request):
        return Response(__version__, media_type="application/json")

    async def invocations(request):
        deadline = time.monotonic() + limits.timeout
        try:
            kind = request.headers.get("content-type", "").split(";")[0].strip()
            if kind != "application/json":
                raise _Refused(415, f"body: Content-Type {kind or 'none'}; send application/json")
            photos, steps = parse_request(await _read_body(request, limits), limits)
            loop = asyncio.get_running_loop()
            future = loop.run_in_executor(worker.pool, worker.run, photos, steps, deadline)
            arrays = await asyncio.wait_for(asyncio.shield(future), limits.timeout * 1.5)
            body = await asyncio.to_thread(encode_answer, arrays)  # the worker goes on to the next photo
        except _Refused as e:
            return _line(e.status, e.reason)
        except DataError as e:  # what the model refuses once it has the photo (a refinement too large)
            return _line(400, str(e))
        except TimeoutError:
            return _line(504, f"timeout: no answer within {limits.timeout * 1.5:g} s; send a smaller photo")
        return Response(body, media_type="application/json")

    routes = [Route("/ping", ping), Route("/health", ping), Route("/version", version),
              Route("/invocations", invocations, methods=["POST"])]  # fmt: skip
    app = Starlette(routes=routes)
    app.state.worker = worker
    return app


def serve(model, host: str, port: int, limits: ServeLimits, say=print) -> None:
    """Serve ``model`` until SIGTERM or Ctrl-C; the worker ends with the server. A port taken, or
    starlette/uvicorn missing, is a :class:`DataError` before anything starts."""
    import socket

    try:
        import starlette  # noqa: F401
        import uvicorn
    except ImportError as e:
        raise DataError(f"svbrdf-models serve needs {e.name}: pip install 'svbrdf-models[mlflow]'") from None
    with socket.socket() as probe:  # uvicorn would log a traceback-like error and exit 1
        try:
            probe.bind((host, port))
        except OSError as e:
            raise DataError(f"--host {host} --port {port}: cannot listen there ({e.strerror}); "
                            "give another --port") from None  # fmt: skip
    app = build_app(model, limits)
    say(f"serving {model.describe()} at http://{host}:{port}/invocations "
        f"(limits: body {limits.body_mb:g} MB, {limits.pixels:,} pixels, refine {limits.refine} steps, "
        f"{limits.timeout:g} s); Ctrl-C stops")  # fmt: skip
    config = uvicorn.Config(app, host=host, port=port, log_level="warning", timeout_graceful_shutdown=5)
    try:
        uvicorn.Server(config).run()
    finally:
        app.state.worker.close()
