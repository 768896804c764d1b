"""``svbrdf-models serve``: a model behind an HTTP server that holds up against what a hostile or
careless client sends.

It speaks MLflow's scoring protocol (what ``mlflow models serve`` answers), so clients need no
change::

    svbrdf-models serve models:/svbrdf-ours/1 --port 5001      # or a model file, or pretrained
    curl 127.0.0.1:5001/invocations -H 'Content-Type: application/json' \\
         -d '{"inputs": [[[[0.5, 0.4, 0.3], ...]]], "params": {"refine": 0}}'
    # -> {"predictions": {"normal": [...], "diffuse": [...], "roughness": [...], "specular": [...]}}

``GET /ping`` (and ``/health``) answer 200 while the worker can take a request, ``GET /version``
the package's version. What it does that MLflow's own server does not (docs/svbrdf-models.md
has the cases, measured against ``mlflow models serve``):

- every limit (:class:`~svbrdf_models.modelfile.serve_limits.ServeLimits`: body size, JSON
  nesting, photos and pixels per request, refinement steps, the answer's size, memory, time) is
  checked before any work, and a refusal is one line of text whose first words say what was
  wrong, never an echo of the input (413 for a body over the limit, 400 for the rest, 415 for a
  body that is not JSON); the answer, memory and time are estimated from the photos' shape
  (:func:`~svbrdf_models.modelfile.serve_limits.estimate_request`);
- the deadline covers the whole request: upload, parsing, queue, network, refinement and
  answer; the model's time budget (the network, the refinement's start, its steps) is what the
  stages before it took leave, less the answer's estimate, and the refinement answers with the
  maps it reached, so no request holds the worker past its time; the predictions run one at a
  time on one worker thread (torch already uses every core); a request left too little time is
  answered 503 when the queue took it, 408 when its upload did; each answer's ``Server-Timing``
  header gives the seconds of each stage (``work``: the worker's);
- a large body is parsed in a child process (json's C code holds the GIL all through), and the
  answer is encoded by numpy on a thread (1.7 s for a 1024 px material, where json took 14-28 s),
  so ``/ping`` answers meanwhile;
- connections are bounded (503 beyond ``--max-connections``), an upload or a connection that
  sends nothing for ``--read-timeout`` seconds is ended (408 for an upload), a client that
  leaves mid-upload ends its request quietly, and the log holds one line per kind of failure
  every 10 s (:mod:`~svbrdf_models.modelfile.serve_log`), never a client's traceback;
- ``/ping`` answers 503 while one request has held the worker past its timeout (stuck), not a
  healthy 200 over a worker that takes nothing;
- SIGTERM or Ctrl-C ends the server, its child and its work (a running refinement stops at
  its next step), and frees the port; the port is bound with ``SO_REUSEADDR``, so the server
  starts again on it at once, even while a connection it closed waits in TIME_WAIT.

Needs starlette and uvicorn (they come with ``svbrdf-models[mlflow]``: MLflow's own server is
built on them); mlflow itself only for ``models:/`` and ``runs:/`` sources.
"""

from __future__ import annotations

import asyncio
import threading
import time
import traceback
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..errors import DataError
from .serve_json import CHILD_BYTES, JsonPool, encode_answer
from .serve_limits import Refused, RequestCost, ServeLimits, check_cost, estimate_request, parse_request
from .serve_log import FailureLog, quiet_logs

__all__ = ["build_app", "serve", "server_config", "maps_arrays"]

#: Of what the other stages' estimates leave, the share the refinement gets: the estimates are
#: an idle machine's, and a busy one is slower.
REFINE_SHARE = 0.9
#: The answer's encoding is estimated (``serve_limits.ANSWER_SECONDS_PER_VALUE``); a busier
#: machine takes longer (3.5 s for the 3.1 s estimated of a 1024 px material, up to twice on
#: a loaded one): the refinement leaves it this many times its estimate.
ANSWER_MARGIN = 1.5


def maps_arrays(svbrdf) -> dict[str, np.ndarray]:
    """The maps of an :class:`svbrdf_render.SVBRDF` as channels-last float32 arrays by name."""
    return {name: t.permute(0, 2, 3, 1).contiguous().cpu().numpy() for name, t in svbrdf.maps().items()}


class _Stopped(Exception):
    """The server is shutting down: the refinement under way stops at its next step."""


class _Worker:
    """One prediction at a time on one thread; knows since when it has been busy."""

    def __init__(self, model, limits: ServeLimits):
        self.model, self.limits = model, limits
        self.pool = ThreadPoolExecutor(1, thread_name_prefix="svbrdf-serve")
        self.json = JsonPool()
        self.busy_since: float | None = None
        self.stopping = threading.Event()

    def stuck_for(self) -> float:
        """Seconds the request under way has held the worker past the timeout (0: not stuck)."""
        since = self.busy_since
        return 0.0 if since is None else max(0.0, time.monotonic() - since - self.limits.timeout)

    def run(self, photos: np.ndarray, steps: int, deadline: float, cost: RequestCost, timing: dict) -> dict:
        """The maps of ``photos`` (:func:`maps_arrays`), the request queued at ``timing["queued"]``
        and due at ``deadline``. The model's time budget covers the network and the refinement,
        all of what is left but the answer's estimate; each stage's seconds go to ``timing``."""
        import torch

        now = time.monotonic()
        timing["queue"] = now - timing.pop("queued")
        if deadline - now < cost.least_s:
            raise self._too_late(deadline - now, cost, timing)
        self.busy_since = now
        try:
            # The refinement stops after the step that reaches its budget: one step short of it.
            left = REFINE_SHARE * (deadline - now - ANSWER_MARGIN * cost.answer_s) - cost.step_s
            seconds = max(0.0, left) if steps else None
            photo = torch.from_numpy(photos).permute(0, 3, 1, 2)
            maps = self.model.predict(
                photo, refine=steps, seconds=seconds, callback=self._stop_check, backend="eager"
            )
            return maps_arrays(maps)
        finally:
            self.busy_since = None
            timing["work"] = time.monotonic() - now

    def _too_late(self, left: float, cost: RequestCost, timing: dict) -> Refused:
        """The refusal of a request with ``left`` seconds to go when its work needs more: 503 when
        it waited in the queue for them, 408 when its upload and parsing took them."""
        need = (f"too little of the {self.limits.timeout:g} s timeout (--timeout) was left for this "
                f"request's work (about {cost.least_s:.0f} s)")  # fmt: skip
        waited = timing["queue"]
        if left + waited >= cost.least_s:
            return Refused(503, f"busy: this request waited {waited:.1f} s in the queue behind others "
                                f"and {need}; try again")  # fmt: skip
        return Refused(408, f"body: the upload took {timing.get('upload', 0.0):.1f} s and {need}; send it "
                            "faster, or fewer photos")  # fmt: skip

    def _stop_check(self, step: int, total: int, loss: float) -> None:
        if self.stopping.is_set():
            raise _Stopped()

    def close(self) -> None:
        self.stopping.set()
        self.json.close()
        self.pool.shutdown(wait=True, cancel_futures=True)


def _line(status: int, reason: str, *, close: bool = False):
    """One line of text; ``close``: the connection ends with it (a body left unread)."""
    from starlette.responses import PlainTextResponse

    headers = {"Connection": "close"} if close else None
    return PlainTextResponse(reason.splitlines()[0] + "\n", status_code=status, headers=headers)


#: Bytes of a body over the limit read and thrown away before the 413, so that a client that
#: sends its whole body before it reads (urllib, requests) sees the answer, not a broken pipe.
DRAIN_BYTES = 1 << 30


async def _chunks(request, limits: ServeLimits, deadline: float):
    """The body's chunks, each within ``limits.read_timeout`` of the last and all before
    ``deadline`` (else :class:`Refused` 408); starlette's ``ClientDisconnect`` when the client leaves."""
    stream = request.stream().__aiter__()
    while True:
        wait = min(limits.read_timeout, deadline - time.monotonic())
        try:
            chunk = await asyncio.wait_for(stream.__anext__(), max(wait, 0.0))
        except StopAsyncIteration:
            return
        except TimeoutError:
            why = (f"no byte for {limits.read_timeout:g} s (--read-timeout)" if wait == limits.read_timeout
                   else f"not all in within the {limits.timeout:g} s timeout (--timeout)")  # fmt: skip
            raise Refused(408, f"body: the upload stalled, {why}; send the whole body at once") from None
        yield chunk


async def _read_body(request, limits: ServeLimits, deadline: float) -> bytes:
    """The body, refused (413) once it is known to exceed ``limits.body_mb``; what is over the
    limit is read and dropped (up to :data:`DRAIN_BYTES`), never kept."""
    cap = int(limits.body_mb * 2**20)
    over = f"over this server's limit of {limits.body_mb:g} MB (--max-body-mb); send fewer or smaller photos"
    length = request.headers.get("content-length", "")
    declared = int(length) if length.isdigit() else None
    chunks, size = [], 0
    async for chunk in _chunks(request, limits, deadline):
        size += len(chunk)
        if size <= cap and (declared is None or declared <= cap):
            chunks.append(chunk)
        elif size > DRAIN_BYTES:
            break
    if size > cap or (declared or 0) > cap:
        chunks.clear()
        got = f"{max(size, declared or 0) / 2**20:.1f} MB" if size <= DRAIN_BYTES else "more than 1 GB"
        raise Refused(413, f"body: {got}, {over}")
    return b"".join(chunks)


async def _answer(request, worker: _Worker, limits: ServeLimits, start: float, timing: dict) -> bytes:
    """The answer's body to a request that arrived at ``start``, or :class:`Refused`; the seconds
    of each stage go to ``timing``."""
    from svbrdf_render.plumbing import machine

    deadline = start + limits.timeout
    kind = request.headers.get("content-type", "").split(";")[0].strip()
    if kind != "application/json":
        raise Refused(415, f"body: Content-Type {kind or 'none'}; send application/json")
    body = await _read_body(request, limits, deadline)
    timing["upload"] = time.monotonic() - start
    try:
        photos, steps = await worker.json.run(len(body) >= CHILD_BYTES, parse_request, body, limits)
    finally:
        del body
        timing["parse"] = time.monotonic() - start - timing["upload"]
    cost = estimate_request(photos.shape, steps, worker.model.resolution)
    spent = time.monotonic() - start
    check_cost(cost, steps, limits, spent=spent, free=machine.available_memory(), upload=timing["upload"])
    timing["queued"] = time.monotonic()
    loop = asyncio.get_running_loop()
    future = loop.run_in_executor(worker.pool, worker.run, photos, steps, deadline, cost, timing)
    late = start + 1.5 * limits.timeout  # should the estimates miss: 504 (the refinement keeps its budget)
    arrays = await asyncio.wait_for(asyncio.shield(future), max(late - time.monotonic(), 0.1))
    encoded = time.monotonic()  # the worker goes on to the next photo meanwhile
    body = await asyncio.to_thread(encode_answer, arrays)  # numpy's: the GIL let go for most of it
    timing["encode"] = time.monotonic() - encoded
    return body


def _timed(response, timing: dict):
    """``response`` with a ``Server-Timing`` header: the seconds of each stage the request went
    through (upload, parse, queue, work: the worker's, encode), in milliseconds as the header has them."""
    stages = ", ".join(f"{k};dur={v * 1000:.0f}" for k, v in timing.items() if k != "queued")
    if stages:
        response.headers["Server-Timing"] = stages
    return response


def build_app(model, limits: ServeLimits | None = None, log: FailureLog | None = None):
    """The Starlette app serving ``model`` (a :class:`svbrdf_models.TrainedModel`) within ``limits``,
    its failures written to ``log``; ``app.state.worker`` is its worker (``close()`` it when the
    server ends)."""
    from starlette.applications import Starlette
    from starlette.requests import ClientDisconnect
    from starlette.responses import Response
    from starlette.routing import Route

    from .. import __version__

    limits, log = limits or ServeLimits(), log or FailureLog()
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
        timing: dict = {}
        return _timed(await _invoke(request, timing), timing)

    async def _invoke(request, timing: dict):
        try:
            body = await _answer(request, worker, limits, time.monotonic(), timing)
        except Refused as e:
            log.note(f"{e.status} refused", e.reason)
            return _line(e.status, e.reason, close=e.status in (408, 415))
        except DataError as e:  # what the model refuses once it has the photo (a refinement too large)
            log.note("400 refused", str(e))
            return _line(400, str(e))
        except TimeoutError:
            log.note("504 late", f"no answer within {limits.timeout * 1.5:g} s")
            return _line(504, f"timeout: no answer within {limits.timeout * 1.5:g} s; send a smaller photo")
        except _Stopped:
            return _line(503, "stopping: the server is shutting down")
        except ClientDisconnect:  # nobody is left to answer
            log.note("client gone", "a client closed its connection mid-upload; its request ended")
            return _line(400, "body: the client closed the connection mid-upload", close=True)
        except Exception as e:  # the server's own fault: its traceback, once a window
            log.note("500 server error", "".join(traceback.format_exception(e)).rstrip())
            return _line(500, f"server error: {type(e).__name__}; the server's log has the details")
        return Response(body, media_type="application/json")

    routes = [Route("/ping", ping), Route("/health", ping), Route("/version", version),
              Route("/invocations", invocations, methods=["POST"])]  # fmt: skip
    app = Starlette(routes=routes)
    app.state.worker, app.state.log = worker, log
    return app


def _guarded_protocol(idle_seconds: float):
    """uvicorn's h11 protocol, closing a connection whose request line and headers have not all
    come within ``idle_seconds`` of its first byte (or of the connection): uvicorn waits for them
    without end, so 64 silent sockets would hold every connection. It uses the timer uvicorn
    keeps for idle keep-alive connections."""
    import h11
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class GuardedH11Protocol(H11Protocol):
        waiting_since: float | None = None  # when this connection began to owe a request

        def _arm(self) -> None:
            if self.conn.their_state is not h11.IDLE or self.transport.is_closing():
                self.waiting_since = None  # a request is under way, or the connection ends
                return
            now = self.loop.time()
            self.waiting_since = now if self.waiting_since is None else self.waiting_since
            if self.timeout_keep_alive_task is None:
                left = max(self.waiting_since + idle_seconds - now, 0.0)
                self.timeout_keep_alive_task = self.loop.call_later(left, self.timeout_keep_alive_handler)

        def connection_made(self, transport) -> None:
            super().connection_made(transport)
            self._arm()

        def data_received(self, data: bytes) -> None:
            super().data_received(data)  # cancels the timer; a request still incomplete re-arms it
            self._arm()

    return GuardedH11Protocol


def server_config(app, host: str, port: int, limits: ServeLimits):
    """The uvicorn configuration of ``app`` within ``limits``: ``limits.connections`` connections
    at once, a request on one more answered 503 (uvicorn counts the request's own connection),
    a connection that has not sent its request's headers within ``limits.read_timeout`` s closed."""
    import uvicorn

    return uvicorn.Config(
        app, host=host, port=port, log_level="warning", timeout_graceful_shutdown=5,
        limit_concurrency=limits.connections + 1, http=_guarded_protocol(limits.read_timeout),
    )  # fmt: skip


#: File descriptors a server needs besides its connections (the model, logs, torch's threads).
SPARE_FILES = 64


def check_open_files(limits: ServeLimits) -> None:
    """Refuse (:class:`DataError`) more connections than this process may open files: past
    the limit every accept fails, and /ping with it."""
    import resource

    soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    if soft != resource.RLIM_INFINITY and limits.connections + SPARE_FILES > soft:
        raise DataError(
            f"--max-connections {limits.connections}: this process may open {soft} files (ulimit -n); "
            f"give at most {max(soft - SPARE_FILES, 1)}, or raise ulimit -n"
        )


def listen(host: str, port: int):
    """The server's listening socket on ``host:port``, with ``SO_REUSEADDR``: started again
    within a minute of closing a connection (whose side then waits in TIME_WAIT), the server
    binds at once; a port another socket listens on is still a :class:`DataError` (uvicorn
    would log a traceback-like error and exit 1)."""
    import socket

    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        sock = socket.socket(family, kind, proto)
    except OSError as e:  # an unknown host included
        raise DataError(f"--host {host}: cannot listen there ({e.strerror or e}); give an address of "
                        "this machine") from None  # fmt: skip
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.listen(2048)
    except OSError as e:
        sock.close()
        raise DataError(f"--host {host} --port {port}: cannot listen there ({e.strerror}); "
                        "give another --port") from None  # fmt: skip
    return sock


def serve(model, host: str, port: int, limits: ServeLimits, say=print) -> None:
    """Serve ``model`` until SIGTERM or Ctrl-C; the worker ends with the server. A port taken,
    more connections than open files, or starlette/uvicorn missing, is a :class:`DataError`
    before anything starts."""
    try:
        import starlette  # noqa: F401
        import uvicorn
    except ImportError as e:
        raise DataError(f"svbrdf-models serve needs {e.name}: pip install 'svbrdf-models[mlflow]'") from None
    check_open_files(limits)
    sock = listen(host, port)
    log = FailureLog()
    app = build_app(model, limits, log)
    app.state.worker.json.start()  # the forkserver of the parse children, ready before the first large body
    say(f"serving {model.describe()} at http://{host}:{port}/invocations (limits: body "
        f"{limits.body_mb:g} MB, {limits.photos} photos, {limits.pixels:,} pixels, refine {limits.refine} "
        f"steps, answer {limits.answer_mb:g} MB, {limits.timeout:g} s, {limits.connections} connections, "
        f"{limits.read_timeout:g} s idle); Ctrl-C stops")  # fmt: skip
    config = server_config(app, host, port, limits)
    try:
        with quiet_logs(log):
            uvicorn.Server(config).run(sockets=[sock])
    finally:
        app.state.worker.close()
        sock.close()
