"""The JSON of ``svbrdf-models serve`` (:mod:`svbrdf_models.modelfile.serve`) kept off its event
loop: a large request body parsed in a child process (:class:`JsonPool`: json's C code holds the
GIL all through, 7.8 s for a 2048 px photo's body, so on a thread it held ``/ping`` as long), and
the answer written by numpy (:func:`encode_answer`: fixed-width text, 0.2 us a value where
json's took 1-2.7 us, and the GIL let go for most of it).
"""

from __future__ import annotations

import asyncio
import json
import signal
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .serve_limits import Refused

__all__ = ["CHILD_BYTES", "JsonPool", "encode_answer"]


#: Bodies of at least this many bytes are parsed in a child process (:class:`JsonPool`): json's
#: C code and numpy's reading of nested lists hold the GIL all through (7.8 s for a 2048 px
#: photo's body), so on a thread they would hold the event loop, and /ping, as long. Below,
#: parsing takes about 0.1 s at most and runs on a thread.
CHILD_BYTES = 2 << 20


def _call_and_send(send, fn, args) -> None:
    """In a child process: ``fn(*args)``, its result or its exception sent on ``send``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the server's to handle
    try:
        outcome = ("ok", fn(*args))
    except BaseException as e:  # noqa: BLE001 - the server raises it
        outcome = ("error", e)
    try:
        send.send(outcome)
    except OSError:  # the server is gone (stopped mid-parse): nobody to tell
        pass
    send.close()


class JsonPool:
    """Large bodies parsed in a child process, one at a time, each in a fresh child forked from a
    process that imported this module once (multiprocessing's forkserver: no import to wait for):
    the event loop goes on meanwhile, and the parse's memory, about 12 times the body, leaves with
    the child. No child waits idle, so none outlives the server, however it ends."""

    def __init__(self):
        self._context = None
        # One parse at a time (each holds 12 times its body), waited for on a thread of its own:
        # bodies waiting their turn take none of the threads small bodies and answers use.
        self._one = ThreadPoolExecutor(1, thread_name_prefix="svbrdf-serve-parse")
        self._running: set = set()

    def start(self):
        """The forkserver started (it imports this module and the main script once), so that the
        first large body has nothing to wait for; the multiprocessing context."""
        if self._context is None:
            import multiprocessing
            from multiprocessing import forkserver

            context = multiprocessing.get_context("forkserver")
            # The main script too: unless it is preloaded, every child runs it again.
            context.set_forkserver_preload(["__main__", __name__, "svbrdf_models.modelfile.serve_limits"])
            forkserver.ensure_running()
            self._context = context
        return self._context

    async def run(self, child: bool, fn, *args):
        """``fn(*args)`` in a child process when ``child``, else on a thread."""
        if child:
            return await asyncio.get_running_loop().run_in_executor(self._one, self._in_child, fn, args)
        return await asyncio.to_thread(fn, *args)

    def _in_child(self, fn, args):
        context = self.start()
        receive, send = context.Pipe(duplex=False)
        process = context.Process(target=_call_and_send, args=(send, fn, args), daemon=True)
        process.start()
        send.close()
        self._running.add(process)
        try:
            status, value = receive.recv()
        except EOFError:  # killed: the machine out of memory, or the server stopping
            raise Refused(503, "busy: the process that parses large bodies ended (out of memory?); try "
                               "again or send a smaller body") from None  # fmt: skip
        finally:
            receive.close()
            process.join(5)
            self._running.discard(process)
        if status == "error":
            raise value
        return value

    def close(self) -> None:
        self._one.shutdown(wait=False, cancel_futures=True)
        for process in list(self._running):
            process.terminate()  # a parse under way would otherwise hold the server's exit


def encode_answer(arrays: dict[str, np.ndarray]) -> bytes:
    """The answer's body, ``{"predictions": {name: nested lists}}``, values rounded to 6 decimals
    (a 4000th of an 8-bit step): half the bytes and time of every float32's 17 digits. Maps in
    (-10, 10) (all of them: normals, albedos, roughness) are written by numpy, each value 9
    characters wide (`` 0.123456``, ``-0.123456``): 0.1 us a value where json's were 1-2.7 us
    (28 s for a 1024 px material on a busy machine, past the timeout); others through json."""
    parts = []
    for name, v in arrays.items():
        v = np.asarray(v)
        if v.ndim and v.size and np.isfinite(v).all() and float(np.abs(v).max()) < 9.9999995:
            text = _nested(_fixed(v)).tobytes()
        else:
            text = json.dumps(np.round(v.astype(np.float64), 6).tolist()).encode()
        parts.append(json.dumps(name).encode() + b": " + text)
    return b'{"predictions": {' + b", ".join(parts) + b"}}"


def _fixed(values: np.ndarray) -> np.ndarray:
    """``(..., 9)`` uint8: each value of ``values`` (under 10 in size) as JSON text, rounded to 6
    decimals, a space or a minus sign first."""
    q = np.rint(np.abs(values.astype(np.float64)) * 1e6).astype(np.int64)
    out = np.empty((*values.shape, 9), np.uint8)
    out[..., 0] = np.where((values < 0) & (q > 0), ord("-"), ord(" "))
    out[..., 1] = ord("0") + q // 10**6
    out[..., 2] = ord(".")
    for k in range(6):
        out[..., 3 + k] = ord("0") + (q // 10 ** (5 - k)) % 10
    return out


def _nested(tokens: np.ndarray) -> np.ndarray:
    """The JSON text of nested lists from ``tokens`` ``(*shape, width)`` uint8, one value's text
    each, all of one width: each axis from the last joined by commas within brackets (every
    list of an axis is as wide as the others, so a whole axis is one array operation)."""
    while tokens.ndim > 1:
        *lead, n, width = tokens.shape
        joined = np.empty((*lead, n, width + 1), np.uint8)
        joined[..., :width], joined[..., width] = tokens, ord(",")
        joined = joined.reshape(*lead, n * (width + 1))
        joined[..., -1] = ord("]")  # in place of the last comma
        tokens = np.concatenate([np.full((*lead, 1), ord("["), np.uint8), joined], axis=-1)
    return tokens
