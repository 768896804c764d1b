"""The one-line progress display of a fit: step, losses, samples/s, ETA.

On a terminal the line is redrawn in place (at most 10 times a second); into a file or a
pipe (CI logs, ``nohup``) a full line is printed every ``every_s`` seconds instead, so logs
stay readable. The drawing is :class:`svbrdf_render.plumbing.StatusLine`'s, the one the photo
tool's refinement bar uses too. :class:`Interrupt` turns Ctrl-C and SIGTERM into a request the
fit answers after its current step, on the same line.
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Mapping
from typing import Any, TextIO

from svbrdf_render.plumbing import StatusLine

__all__ = ["Progress", "Interrupt", "format_duration"]


def format_duration(seconds: float) -> str:
    """``75`` -> ``"1m15s"``; ``4000`` -> ``"1h06m"``."""
    s = max(0, int(round(seconds)))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{(s % 3600) // 60:02d}m"


class Progress:
    """Shows how far a fit is. ``update`` is cheap to call every step.

    Args:
        total: the step the fit stops at (its step budget).
        start: the step it starts from (non-zero after ``--resume``).
        budget_s: the training-time budget in seconds, if any: the ETA is the sooner of the two.
        enabled: False shows no progress line (``--quiet``).
        messages: False shows no messages either (ranks > 0).
    """

    def __init__(
        self,
        total: int,
        *,
        start: int = 0,
        budget_s: float | None = None,
        enabled: bool = True,
        messages: bool = True,
        stream: TextIO | None = None,
        every_s: float = 10.0,
    ):
        self.total, self.start, self.budget_s = total, start, budget_s
        self.status = StatusLine(stream, enabled=enabled, messages=messages, file_every_s=every_s)
        self.stream, self.tty, self.enabled = self.status.stream, self.status.tty, self.status.enabled

    def line(self, step: int, losses: Mapping[str, float], samples_per_s: float, train_s: float) -> str:
        pct = 100.0 * step / max(self.total, 1)
        parts = [f"step {step}/{self.total} {pct:3.0f}%"]
        if losses:
            parts.append(" ".join(f"{k} {v:.4g}" for k, v in losses.items()))
        parts.append(f"{samples_per_s:.1f} samples/s")
        done = step - self.start
        eta = None
        if done > 0 and train_s > 0:
            eta = (self.total - step) * train_s / done
        if self.budget_s is not None:
            left = max(0.0, self.budget_s - train_s)
            eta = left if eta is None else min(eta, left)
        if eta is not None:
            parts.append(f"ETA {format_duration(eta)}")
        return " | ".join(parts)

    def update(
        self,
        step: int,
        losses: Mapping[str, float],
        samples_per_s: float,
        train_s: float,
        *,
        force: bool = False,
    ) -> None:
        self.status.show(lambda: self.line(step, losses, samples_per_s, train_s), force=force)

    def message(self, text: str) -> None:
        """A line of its own, above the progress line."""
        self.status.message(text)

    def close(self) -> None:
        self.status.close()


class Interrupt:
    """Ctrl-C / SIGTERM: the first asks to stop after the current step, the second stops now."""

    def __init__(self, progress: Progress):
        self.requested: str | None = None
        self.progress = progress
        self._old: dict[int, Any] = {}

    def __enter__(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(ValueError):  # not the main thread: leave signals alone
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame):
        name = signal.Signals(signum).name
        if self.requested is not None:
            raise KeyboardInterrupt
        self.requested = name
        self.progress.message(f"{name}: saving a checkpoint after this step (again to stop at once)")

    def __exit__(self, *exc):
        for sig, old in self._old.items():
            signal.signal(sig, old)
