"""What this machine has for a command: the device to compute on (:func:`pick_device`), cores
(how many torch threads to compute with) and memory (:func:`available_memory`, which the photo
tool checks a refinement or a tiled capture against before it starts).

torch starts one thread per core, and its threads spin while they wait for each other. When
other programs keep the cores busy, those threads wait for cores that never come free: on a
2-core machine with two CPU-bound processes beside it, the default refinement of a 256 px
photo took 15.8 s with 2 threads against 7.4 s with 1 (117 s against 11.5 s seen by a
user). :func:`choose_threads` therefore takes one thread per core that is *free*: the cores
this process may run on, less the other tasks running *now* (Linux: the running count of
``/proc/loadavg``, less this process, the median of a few readings over 40 ms; elsewhere the
load average of the last minute), at least 1. The load average alone lags: a minute after a
benchmark ends it still reads 1.6 on an idle machine, and a command started then took 1
thread where 2 were free. A number given by the user (``--threads N``, or ``OMP_NUM_THREADS``
in the environment) is taken as it is, up to :data:`MAX_THREADS` (4096: more than the cores of
any machine torch runs on; above it, ``--threads`` is refused and ``OMP_NUM_THREADS`` ignored,
as torch's own setter would fail with an overflow past 2**31 and start that many threads below
it).

    from svbrdf_render.plumbing import choose_threads, pick_device
    choice = choose_threads(None)        # sets torch's threads; choice.describe() for people
    device = pick_device("auto")         # CUDA when there is one
"""

from __future__ import annotations

import os
import re
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from ..errors import SVBRDFError

__all__ = [
    "MAX_THREADS",
    "THREADS_HELP",
    "ThreadChoice",
    "available_memory",
    "choose_threads",
    "pick_device",
    "usable_cores",
]

#: The most torch threads a command takes (``--threads``): more than any machine's cores.
MAX_THREADS = 4096

#: The ``--threads`` help of every command that computes.
THREADS_HELP = (
    "torch threads on the CPU, 1 to 4096 (default: one per free core, the cores less the load "
    "average, so that a busy machine is not slowed down further by threads waiting for cores; "
    "OMP_NUM_THREADS, when set, is taken)"
)


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity, else the machine's count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


#: Linux's load file: its fourth field is ``running/total`` tasks at this instant.
_LOADAVG = "/proc/loadavg"


def _running_now() -> float | None:
    """Tasks running or ready to run now besides this one (median of 5 readings 10 ms apart);
    None where the system has no :data:`_LOADAVG`."""
    counts = []
    for i in range(5):
        try:
            with open(_LOADAVG) as f:
                counts.append(int(f.read().split()[3].split("/")[0]) - 1)  # less this process
        except (OSError, IndexError, ValueError):
            return None
        if i < 4:
            time.sleep(0.01)
    return float(max(0.0, statistics.median(counts)))


def _load() -> float | None:
    """How many cores other programs keep busy: :func:`_running_now`, else the 1-minute load
    average; None where the system gives neither."""
    now = _running_now()
    if now is not None:
        return now
    try:
        return float(os.getloadavg()[0])
    except (AttributeError, OSError):  # pragma: no cover - Windows
        return None


def _omp_threads() -> int | None:
    """``OMP_NUM_THREADS`` when it is a whole number from 1 to :data:`MAX_THREADS`; None otherwise
    (unset, or a value torch could not take: the free cores are counted instead)."""
    text = os.environ.get("OMP_NUM_THREADS", "").strip()
    return int(text) if text.isdigit() and 1 <= int(text) <= MAX_THREADS else None


@dataclass(frozen=True)
class ThreadChoice:
    """The threads chosen, and why."""

    threads: int
    cores: int
    #: The other tasks seen running (:func:`_load`; None where the system gives none, or when given).
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
        load = f", {self.load:g} other tasks running" if self.load is not None else ""
        busy = ": the machine is busy, so fewer threads than cores" if self.busy else ""
        return f"{self.threads} torch thread{plural} ({self.cores} cores{load}{busy})"


def choose_threads(requested: int | None = None, *, apply: bool = True) -> ThreadChoice:
    """The torch threads to compute with (see the module); sets them unless ``apply`` is False.

    Raises:
        SVBRDFError: ``requested`` below 1 or above :data:`MAX_THREADS` (a ``ValueError``).
    """
    cores = usable_cores()
    if requested is not None:
        if isinstance(requested, bool) or not 1 <= int(requested) <= MAX_THREADS:
            raise SVBRDFError(f"threads must be from 1 to {MAX_THREADS}, got {requested!r}")
        choice = ThreadChoice(int(requested), cores, None, "--threads")
    elif _omp_threads() is not None:
        choice = ThreadChoice(_omp_threads(), cores, None, "OMP_NUM_THREADS")
    else:
        load = _load()
        free = cores - load if load is not None else cores
        choice = ThreadChoice(max(1, min(cores, int(free + 0.5))), cores, load, "free cores")
    if apply:
        torch.set_num_threads(choice.threads)
    return choice


def pick_device(name: str, local_rank: int = 0) -> torch.device:
    """``auto`` (CUDA when there is one), ``cpu``, ``cuda`` or ``cuda:K``; ``cuda`` takes the GPU
    of ``local_rank`` (under torchrun). A device this machine lacks, or a name that is none, is
    an :class:`~svbrdf_render.errors.SVBRDFError` naming ``--device``."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" or re.fullmatch(r"cuda:[0-9]+", name):
        if not torch.cuda.is_available():
            raise SVBRDFError(f"--device {name}: this torch sees no CUDA GPU; use --device cpu")
        count = torch.cuda.device_count()
        if name == "cuda":
            name = f"cuda:{local_rank % count}"
        elif int(name[5:]) >= count:
            raise SVBRDFError(f"--device {name}: this machine has {count} GPU(s), cuda:0 to cuda:{count - 1}")
    elif name != "cpu":
        raise SVBRDFError(f"--device {name!r}: expected auto, cpu, cuda or cuda:K")
    return torch.device(name)


#: Where Linux says how much memory is available, and the cgroup (v2) this process runs in.
_MEMINFO = "/proc/meminfo"
_CGROUP = Path("/sys/fs/cgroup")


def available_memory() -> int | None:
    """Bytes of memory this process may still take: the kernel's ``MemAvailable`` (what can be
    had without swapping), lowered to a cgroup's limit when the process runs under one; None
    where neither can be read."""
    found = []
    try:
        with open(_MEMINFO) as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    found.append(int(line.split()[1]) * 1024)
                    break
    except (OSError, ValueError, IndexError):
        pass
    if not found:
        try:
            found.append(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (OSError, ValueError, AttributeError):
            pass
    try:  # cgroup v2: the limit minus what the group uses
        limit = (_CGROUP / "memory.max").read_text().strip()
        if limit.isdigit():
            used = int((_CGROUP / "memory.current").read_text().strip())
            found.append(max(0, int(limit) - used))
    except (OSError, ValueError):
        pass
    return min(found) if found else None
