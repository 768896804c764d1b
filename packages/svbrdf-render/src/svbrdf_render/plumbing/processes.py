"""Working beside other processes: the one lock between them, and their signals to stop.

:func:`locked` is the project's one inter-process lock (``flock`` on POSIX, ``filelock`` on
Windows; :class:`LockHeld` when it is asked not to wait and another process holds it).
:func:`sigterm_as_interrupt` makes SIGTERM raise ``KeyboardInterrupt`` within a block, as
Ctrl-C does, so that :func:`~svbrdf_render.plumbing.atomic.atomic_output` removes its temporary
file and the command says what was left and exits :data:`INTERRUPTED`;
:func:`raise_if_interrupted` takes a stop whose interrupt Python dropped on the way.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

__all__ = ["INTERRUPTED", "sigterm_as_interrupt", "raise_if_interrupted", "locked", "LockHeld"]

#: The exit status of a command stopped by Ctrl-C or SIGTERM (128 + SIGINT).
INTERRUPTED = 130

#: The signal that asked the innermost :func:`sigterm_as_interrupt` block to stop (None: none did).
_STOP: dict[str, str | None] = {"signal": None}


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises ``KeyboardInterrupt`` as Ctrl-C does, so that a command
    stopped by ``kill``, a job scheduler or a container's stop takes the same way out as one
    stopped by Ctrl-C: :func:`~svbrdf_render.plumbing.atomic.atomic_output` removes its temporary
    file, and the command says what was left and exits :data:`INTERRUPTED`. The previous handlers
    are restored on exit.
    Outside the main thread (where Python cannot set handlers) it does nothing.

    Both signals are also remembered. Python drops an exception raised where it cannot travel
    (a weakref callback or a ``__del__`` that runs when the signal lands: "Exception ignored
    in ..."), and the command would then go on to its end; a long loop calls
    :func:`raise_if_interrupted` between its steps, which raises the lost interrupt again (and
    the dropped one is not printed as an error). Ctrl-C is handled so only where Python's own
    handler is in place (a fit's handler is left alone).
    """
    import signal
    import sys
    import threading

    def _raise(signum, frame):
        _STOP["signal"] = signal.Signals(signum).name
        raise KeyboardInterrupt(_STOP["signal"])

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    def _unraisable(unraisable):
        if not (isinstance(unraisable.exc_value, KeyboardInterrupt) and _STOP["signal"]):
            hook(unraisable)  # anything else is printed as Python would

    outer, hook = _STOP["signal"], sys.unraisablehook
    previous = {signal.SIGTERM: signal.signal(signal.SIGTERM, _raise)}
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, _raise)
    sys.unraisablehook = _unraisable
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        sys.unraisablehook = hook
        _STOP["signal"] = outer


def raise_if_interrupted() -> None:
    """Raise ``KeyboardInterrupt`` when a signal asked the enclosing :func:`sigterm_as_interrupt`
    block to stop and its interrupt was lost on the way (see there); else nothing. Cheap: call it
    once per step of a long loop."""
    if _STOP["signal"] is not None:
        raise KeyboardInterrupt(_STOP["signal"])


class LockHeld(Exception):
    """:func:`locked` without waiting found the lock held by another process. ``holder`` is what
    the holder wrote in the lock file (its PID, with ``pid=True``; ``""`` when it wrote nothing
    yet), None where it cannot be read (``pid=False``, or Windows). The caller words the refusal.
    """

    def __init__(self, path: Path, holder: str | None):
        super().__init__(f"{path}: locked by {f'PID {holder}' if holder else 'another process'}")
        self.path, self.holder = path, holder


@contextlib.contextmanager
def locked(path: str | os.PathLike, *, wait: bool = True, pid: bool = False) -> Iterator[None]:
    """Hold an exclusive lock on ``path`` for the block: the project's one inter-process lock.

    ``path`` is where the lock lives: a folder (locked as it is: nothing is written in it) or a
    lock file (created if missing, its folder too). ``wait``: wait for another holder to leave;
    False raises :class:`LockHeld` at once instead. ``pid``: write this process's PID in the lock
    file while holding it, so that a refused process can name the holder (``LockHeld.holder``),
    and remove the file on release (a file naming a PID never outlives its holder but by
    SIGKILL); without it the file stays in place, so that every process locks the same file.

    The lock is the operating system's (``flock`` on POSIX; ``filelock``, which torch installs,
    on Windows, without the PID): a process that dies, even by SIGKILL, drops it, so a lock file
    left behind is simply taken over. Used where a check and the write it guards must be one step
    across processes: two captures into one folder (waiting), two fits on one ``--out``
    (refused, naming the PID), two processes creating one new SQLite MLflow store (waiting).
    """
    path = Path(path)
    if not path.is_dir():
        path.parent.mkdir(parents=True, exist_ok=True)
    elif pid:
        raise ValueError(f"locked({path}, pid=True): the PID is written in a lock file, not a folder")
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        with _filelock(path, wait):
            yield
        return
    fd = _flock(fcntl, path, wait, pid)
    try:
        if pid:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        yield
    finally:
        if pid:
            with contextlib.suppress(OSError):
                path.unlink()
        os.close(fd)  # closing the descriptor drops the lock


def _flock(fcntl, path: Path, wait: bool, pid: bool) -> int:
    """A descriptor of ``path`` that holds its exclusive ``flock`` (see :func:`locked`).

    A holder that removes the lock file on release leaves a process that waited on it holding
    a removed file: it then opens and locks the file now at ``path`` (or the new one) instead.
    """
    while True:
        fd = os.open(path, os.O_RDONLY) if path.is_dir() else os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            holder = os.read(fd, 32).decode("ascii", "replace").strip() if pid else None
            os.close(fd)
            raise LockHeld(path, holder) from None
        except BaseException:  # interrupted while waiting
            os.close(fd)
            raise
        try:
            now = os.stat(path)
            held = os.fstat(fd)
            same = (now.st_dev, now.st_ino) == (held.st_dev, held.st_ino)
        except FileNotFoundError:  # removed by the holder that just released it
            same = False
        if same:
            return fd
        os.close(fd)


@contextlib.contextmanager
def _filelock(path: Path, wait: bool) -> Iterator[None]:  # pragma: no cover - Windows
    """:func:`locked` where there is no ``flock``: ``filelock`` on the file (a folder's
    ``.lock``), without a PID."""
    from filelock import FileLock, Timeout

    lock = FileLock(str(path / ".lock" if path.is_dir() else path), timeout=-1 if wait else 0)
    try:
        lock.acquire()
    except Timeout:
        raise LockHeld(path, None) from None
    try:
        yield
    finally:
        lock.release()
