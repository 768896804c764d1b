"""The log of ``svbrdf-models serve`` (:mod:`svbrdf_models.modelfile.serve`): one line per kind of
failure, at most one per kind every :data:`WINDOW` seconds, with the count of those left out.

A flood (1100 half-sent uploads, a client that drops mid-upload a thousand times) used to write
a traceback each: 647 MB of log in 90 s. Here each kind (an idle upload, a client gone, a
refusal by status, uvicorn's "Exceeded concurrency limit", asyncio's "out of system resource")
is one line, the first of its window; the next line of that kind, or the end of the server,
says how many were left out. No traceback is written for what a client did; the server's own
faults (an error in its code) keep theirs, once a window::

    log = FailureLog()
    log.note("408 idle upload", "no byte for 10 s")      # printed
    log.note("408 idle upload", "no byte for 10 s")      # counted, printed with the next one
    with quiet_logs(log):                                 # uvicorn's and asyncio's loggers too
        ...
"""

from __future__ import annotations

import contextlib
import logging
import sys
import threading
import time
from collections.abc import Callable, Iterator

__all__ = ["WINDOW", "FailureLog", "quiet_logs"]

#: Seconds between two lines of the same kind.
WINDOW = 10.0
#: The loggers whose records go through :class:`FailureLog`: uvicorn's errors and warnings
#: (invalid requests, the connection limit), asyncio's (a file limit reached on accept).
LOGGERS = ("uvicorn.error", "asyncio")


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


class FailureLog:
    """One line per kind per ``window`` seconds (``write``: where lines go, stderr by default;
    ``clock``: seconds, monotonic). Thread-safe: the worker thread and the event loop both log."""

    def __init__(self, window: float = WINDOW, write: Callable[[str], None] = _stderr, clock=time.monotonic):
        self.window, self.write, self.clock = window, write, clock
        self._printed: dict[str, float] = {}  # kind -> when its last line was written
        self._left_out: dict[str, int] = {}  # kind -> lines not written since
        self._lock = threading.Lock()

    def admit(self, kind: str) -> str | None:
        """None when a line of ``kind`` was written less than a window ago (it is counted), else
        what to append to the line: the count left out since the last one ("" when none)."""
        with self._lock:
            now = self.clock()
            last = self._printed.get(kind)
            if last is not None and now - last < self.window:
                self._left_out[kind] = self._left_out.get(kind, 0) + 1
                return None
            self._printed[kind] = now
            skipped = self._left_out.pop(kind, 0)
            overdue = self._overdue(now)
        for line in overdue:
            self.write(line)
        return f" (and {skipped} more like it in the {now - last:.0f} s before)" if skipped else ""

    def note(self, kind: str, detail: str = "") -> bool:
        """Write ``kind: detail`` unless one of ``kind`` was written less than a window ago;
        whether it was written."""
        suffix = self.admit(kind)
        if suffix is not None:
            self.write(f"{kind}: {detail}{suffix}" if detail else f"{kind}{suffix}")
        return suffix is not None

    def _overdue(self, now: float) -> list[str]:
        """Lines for the kinds whose window ended with lines left out (caller holds the lock)."""
        lines = []
        for kind, count in list(self._left_out.items()):
            if now - self._printed[kind] >= self.window:
                lines.append(f"{kind}: {count} more in the last {now - self._printed[kind]:.0f} s")
                self._printed[kind] = now
                del self._left_out[kind]
        return lines

    def close(self) -> None:
        """Write the counts still left out (the server ends)."""
        with self._lock:
            lines = [f"{kind}: {n} more before the server ended" for kind, n in self._left_out.items()]
            self._left_out.clear()
        for line in lines:
            self.write(line)


class _OneLine(logging.Filter):
    """Lets the first record of a kind (its logger and message template) through a
    :class:`FailureLog`, as one line: an exception becomes ``(Type: message)``, no traceback."""

    def __init__(self, log: FailureLog):
        super().__init__()
        self.log = log

    def filter(self, record: logging.LogRecord) -> bool:
        kind = f"{record.name}: {str(record.msg).splitlines()[0][:80] if str(record.msg) else ''}"
        suffix = self.log.admit(kind)
        if suffix is None:
            return False
        text = record.getMessage().splitlines()[0] if record.getMessage() else ""
        if record.exc_info and record.exc_info[1] is not None:
            error = record.exc_info[1]
            text += f" ({type(error).__name__}: {str(error)[:120]})"
        record.msg, record.args = text + suffix, ()
        record.exc_info = record.exc_text = record.stack_info = None
        return True


@contextlib.contextmanager
def quiet_logs(log: FailureLog) -> Iterator[FailureLog]:
    """Route :data:`LOGGERS` through ``log`` while the block runs; ``log.close()`` at its end."""
    one_line = _OneLine(log)
    loggers = [logging.getLogger(name) for name in LOGGERS]
    for logger in loggers:
        logger.addFilter(one_line)
    try:
        yield log
    finally:
        for logger in loggers:
            logger.removeFilter(one_line)
        log.close()
