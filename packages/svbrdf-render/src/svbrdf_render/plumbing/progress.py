"""The toolkit's one progress display: a status line on a stream, and messages above it.

A fit's step line (``svbrdf_train.training.progress.Progress``) and the refinement bar the photo
tool draws (:class:`ProgressBar`, here) both draw through :class:`StatusLine`, so they behave
alike: on a terminal the line is redrawn in place with ``\\r`` (at most ``tty_every_s`` apart,
blanks over the end of a longer previous line); into a file or a pipe (CI logs, ``nohup``) a
whole line is printed every ``file_every_s`` seconds, or nothing when that is None, so logs hold
no control characters. A message is a line of its own, printed above the status line.

tqdm would draw the bar, but its estimate of the time left runs on the wall clock where a fit's
budget runs on its training clock, and into a file it writes ``\\r``-joined updates rather than
lines; this stays in the standard library.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO

__all__ = ["ProgressBar", "StatusLine"]


class StatusLine:
    """One status line on ``stream`` (stderr by default), redrawn in place on a terminal.

    Args:
        enabled: False draws no status line (messages still print).
        messages: False prints no messages either (and no status line).
        tty_every_s: on a terminal, the shortest time between two redraws.
        file_every_s: off a terminal, the time between two whole lines; None: none at all.
    """

    def __init__(
        self,
        stream: TextIO | None = None,
        *,
        enabled: bool = True,
        messages: bool = True,
        tty_every_s: float = 0.1,
        file_every_s: float | None = None,
    ):
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.messages = messages
        self.every_s = tty_every_s if self.tty else file_every_s
        self.enabled = enabled and messages and self.every_s is not None
        self._last: float | None = None
        self._width = 0  # characters of the status line now on the terminal (0: none)

    def due(self, *, force: bool = False) -> bool:
        """Whether :meth:`show` would draw now: enabled, and ``force`` or the interval passed."""
        if not self.enabled:
            return False
        return force or self._last is None or time.monotonic() - self._last >= self.every_s

    def show(self, text: str | Callable[[], str], *, force: bool = False) -> bool:
        """Draw ``text`` (or what the callable returns, built only when drawn) if :meth:`due`;
        returns whether it drew."""
        if not self.due(force=force):
            return False
        self._last = time.monotonic()
        line = text() if callable(text) else text
        if self.tty:
            self.stream.write("\r" + line + " " * max(0, self._width - len(line)))
            self._width = max(1, len(line))
        else:
            self.stream.write(line + "\n")
        self.stream.flush()
        return True

    def message(self, text: str) -> None:
        """A line of its own, above the status line (which the next :meth:`show` redraws)."""
        if not self.messages:
            return
        if self._width:
            self.stream.write("\r" + " " * self._width + "\r")
            self._width = 0
            self._last = None
        self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        """End the status line on a terminal (a newline after it); nothing when none is drawn."""
        if self._width:
            self.stream.write("\n")
            self.stream.flush()
            self._width = 0


class ProgressBar:
    """``callback(step, total, loss)`` drawing one line on ``stream`` with ``\\r`` updates:
    ``NAME: refining  37/100 [#######.............] 1.2 s loss 0.0812``.

    Silent when ``enabled`` is false (by default: when ``stream`` is not a terminal, so logs and
    pipes get no control characters; ``enabled=True`` there prints whole lines). :meth:`close`
    ends the line. At most ~10 redraws a second,
    and always the last step. Drawn by :class:`StatusLine`, the display a fit's progress
    uses too.
    """

    #: Said at the end of every progress line when the machine is busy (set by ``predict``
    #: from :func:`svbrdf_render.plumbing.machine.choose_threads`): why the refinement is slower.
    busy_note = ""

    def __init__(self, name: str, stream=None, enabled: bool | None = None, width: int = 20):
        # enabled=True off a terminal: a whole line per redraw (no \r in a file)
        self.line = StatusLine(stream, enabled=enabled is not False, file_every_s=0.1 if enabled else None)
        self.stream = self.line.stream
        self.enabled = self.line.enabled
        self.name = name
        self.width = width
        self.start = time.perf_counter()

    def __call__(self, step: int, total: int, loss: float) -> None:
        if not self.line.due(force=step >= total):
            return
        filled = round(self.width * step / max(total, 1))
        bar = "#" * filled + "." * (self.width - filled)
        digits = len(str(total))
        seconds = time.perf_counter() - self.start
        self.line.show(
            f"{self.name}: refining {step:>{digits}}/{total} [{bar}] {seconds:.1f} s loss {loss:.4f}"
            + self.busy_note,
            force=True,
        )

    def close(self) -> None:
        self.line.close()
