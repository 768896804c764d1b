"""How many torch threads a command computes with: the cores the machine has free.

torch starts one thread per core, and its threads spin while they wait for each other. When
other programs keep the cores busy, those threads wait for cores that never come free: on a
2-core machine with two CPU-bound processes beside it, the default refinement of a 256 px
photo took 15.8 s with 2 threads against 7.4 s with 1 (117 s against 11.5 s seen by a
user). :func:`choose_threads` therefore takes one thread per core that is *free*: the cores
this process may run on, less the load average of the last minute (the processes already
running), at least 1. A number given by the user (``--threads N``, or ``OMP_NUM_THREADS`` in
the environment) is taken as it is.

    from svbrdf_render.machine import choose_threads
    choice = choose_threads(None)        # sets torch's threads; choice.describe() for people
"""

from __future__ import annotations

import os
from dataclasses import dataclass

__all__ = ["THREADS_HELP", "ThreadChoice", "choose_threads", "usable_cores"]

#: The ``--threads`` help of every command that computes.
THREADS_HELP = (
    "torch threads on the CPU (default: one per free core, the cores less the load average, so "
    "that a busy machine is not slowed down further by threads waiting for cores; "
    "OMP_NUM_THREADS, when set, is taken)"
)


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity, else the machine's count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _load() -> float | None:
    try:
        return float(os.getloadavg()[0])
    except (AttributeError, OSError):  # pragma: no cover - Windows
        return None


@dataclass(frozen=True)
class ThreadChoice:
    """The threads chosen, and why."""

    threads: int
    cores: int
    #: The 1-minute load average seen (None where the system gives none, or when given).
    load: float | None
    #: ``"--threads"``, ``"OMP_NUM_THREADS"`` or ``"free cores"``.
    source: str

    @property
    def busy(self) -> bool:
        """Whether other programs keep cores busy (fewer threads than cores were chosen for it)."""
        return self.source == "free cores" and self.threads < self.cores

    def describe(self) -> str:
        """One line for people, e.g. ``1 torch thread (2 cores, load 2.9: the machine is busy)``."""
        plural = "s" if self.threads != 1 else ""
        if self.source != "free cores":
            return f"{self.threads} torch thread{plural} ({self.source})"
        load = f", load {self.load:.1f}" if self.load is not None else ""
        busy = ": the machine is busy, so fewer threads than cores" if self.busy else ""
        return f"{self.threads} torch thread{plural} ({self.cores} cores{load}{busy})"


def choose_threads(requested: int | None = None, *, apply: bool = True) -> ThreadChoice:
    """The torch threads to compute with (see the module); sets them unless ``apply`` is False.

    Raises:
        ValueError: ``requested`` below 1.
    """
    cores = usable_cores()
    if requested is not None:
        if isinstance(requested, bool) or int(requested) < 1:
            raise ValueError(f"threads must be at least 1, got {requested!r}")
        choice = ThreadChoice(int(requested), cores, None, "--threads")
    elif os.environ.get("OMP_NUM_THREADS", "").strip().isdigit() and int(os.environ["OMP_NUM_THREADS"]) >= 1:
        choice = ThreadChoice(int(os.environ["OMP_NUM_THREADS"]), cores, None, "OMP_NUM_THREADS")
    else:
        load = _load()
        free = cores - load if load is not None else cores
        choice = ThreadChoice(max(1, min(cores, int(free + 0.5))), cores, load, "free cores")
    if apply:
        import torch

        torch.set_num_threads(choice.threads)
    return choice
