"""Times that say how far they can be trusted: repeated timed runs, their median and spread,
and how busy the machine was while they ran.

One timed figure (a latency, a step time) is :func:`time_call`: a fixed number of timed runs
after untimed warm-up runs, each run read on the clock of ``torch.utils.benchmark`` (which
synchronises the accelerator before reading ``timeit``'s clock) through the standard library's
``timeit`` (garbage collection off during the runs). It is summarised as the median and the
interquartile range (IQR: 75th minus 25th percentile, linear interpolation) of the runs.

Why a fixed number of runs rather than ``Timer.blocked_autorange`` or ``adaptive_autorange``:
a fixed count gives every model the same number of samples, so their IQRs are comparable and
the cost is known (runs x latency); ``blocked_autorange`` fixes the time instead, so a slow (or
slowed-down) model gets a handful of samples, and it batches fast calls into blocks whose
averages hide the per-call spread a user sees; ``adaptive_autorange`` stops as soon as the IQR
looks small, which biases the very spread reported here downwards.

The load (:class:`Load`, read by :class:`LoadProbe` around the runs) tells a busy machine from
an idle one. On Linux the deciding figure is the share ``w`` of the measurement during which a
thread of this process was ready to run but waited for a CPU (the run-queue delay of
``/proc/self/task/*/schedstat``; the most delayed thread, since a parallel op waits for its
slowest thread): a time on that thread's path is inflated by about ``w / (1 - w)``, by an
amount that depends on what else happened to run. A thread asleep (in ``time.sleep``, or
waiting for a GPU) is not waiting for a CPU, so a GPU timing reads low unless its launches were
held up. Above :data:`CPU_WAIT_LIMIT` (10%: an inflation over 11%, more than the spread
expected on an idle machine, an IQR under 10% of the median, and more than separates models of
similar cost) the figure is unreliable. (Checked on a 2-CPU machine: one generator timed at
waits of 48% and 86% read 122 and 513 ms; ``median * (1 - w)`` gives 63 and 72 ms.) Beside it,
for the reader: the CPUs' worth of time other processes used (``/proc/stat`` minus this
process's own CPU time) and the 1-minute load average. Elsewhere (no ``/proc``) the load
average decides (unreliable above one runnable task per usable CPU; it lags by a minute);
without it the load is not measured and :attr:`Load.unreliable` is None.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from .errors import BenchError

__all__ = [
    "CPU_WAIT_LIMIT",
    "LATENCY_METRIC",
    "SPREAD_LIMIT",
    "Load",
    "LoadProbe",
    "Timing",
    "summarize",
    "time_call",
    "time_inference",
    "time_once",
]

#: Above this share of the measurement spent by a thread waiting for a CPU, a timing is unreliable.
CPU_WAIT_LIMIT = 0.10
#: The benchmark's latency metrics: ``time/latency_ms`` (the median, as before the spread was
#: logged), ``time/latency_iqr_ms``, ``time/latency_runs`` and the load's (``time/latency_cpu_wait``...).
LATENCY_METRIC = "time/latency"
#: An IQR above this share of the median is called wide (a noisy figure, whatever the load read).
SPREAD_LIMIT = 0.10


# -- the load -------------------------------------------------------------------------------


def _usable_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        return os.cpu_count() or 1


def _schedstat() -> dict[str, tuple[int, int]] | None:
    """Per thread of this process: (ns on a CPU, ns ready but waiting on a run queue)."""
    try:
        tasks = os.listdir("/proc/self/task")
    except OSError:
        return None
    out = {}
    for tid in tasks:
        try:
            with open(f"/proc/self/task/{tid}/schedstat") as f:
                on_cpu, waiting = f.read().split()[:2]
            out[tid] = (int(on_cpu), int(waiting))
        except (OSError, ValueError):  # the thread ended, or no schedstat in this kernel
            continue
    return out or None


def _busy_seconds() -> float | None:
    """CPU seconds all CPUs spent busy since boot (``/proc/stat``: user, nice, system, irq,
    softirq and steal, the time a hypervisor gave to others)."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
        ticks = os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, AttributeError):
        return None
    if not fields or fields[0] != "cpu" or len(fields) < 9:
        return None
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(v) for v in fields[1:9])
    return (user + nice + system + irq + softirq + steal) / ticks


def _load_average() -> float | None:
    try:
        return os.getloadavg()[0]
    except (AttributeError, OSError):  # Windows
        return None


@dataclass(frozen=True)
class Load:
    """How busy the machine was during a measurement (None: not measurable on this system)."""

    wall_s: float
    """Length of the measurement."""
    cpus: int
    """CPUs this process may run on."""
    threads: int | None = None
    """Torch threads of the timed work (None: not recorded)."""
    cpu_wait: float | None = None
    """Share of the measurement the most delayed thread of this process spent ready to run but
    waiting for a CPU, in [0, 1] (Linux)."""
    other_cpus: float | None = None
    """CPUs' worth of time other processes used during the measurement (Linux)."""
    load_average: float | None = None
    """1-minute load average, the larger of the readings before and after."""

    @property
    def unreliable(self) -> bool | None:
        """True when the load inflates a time beyond trust (see the module docstring); None when
        nothing could be read."""
        if self.cpu_wait is not None:
            return self.cpu_wait > CPU_WAIT_LIMIT
        if self.load_average is not None:
            return self.load_average > self.cpus
        return None

    def words(self) -> str:
        """The readings in words, e.g. ``a timed thread waited for a CPU 34% of the time;
        other processes used 1.5 of 2 CPUs; 1-minute load average 3.5 on 2 CPUs``."""
        parts = []
        if self.cpu_wait is not None:
            parts.append(f"a timed thread waited for a CPU {100 * self.cpu_wait:.0f}% of the time")
        if self.other_cpus is not None:
            parts.append(f"other processes used {self.other_cpus:.1f} of {self.cpus} CPUs")
        if self.load_average is not None:
            parts.append(f"1-minute load average {self.load_average:.1f} on {self.cpus} CPUs")
        return "; ".join(parts) or "load not measured on this system"

    def metrics(self, prefix: str) -> dict[str, float]:
        """MLflow metrics ``{prefix}_cpu_wait``, ``_other_cpus``, ``_load_avg``, ``_cpus``, ``_threads``
        (the readings taken)."""
        values = {
            "cpus": float(self.cpus),
            "threads": self.threads,
            "cpu_wait": self.cpu_wait,
            "other_cpus": self.other_cpus,
            "load_avg": self.load_average,
        }
        return {f"{prefix}_{k}": float(v) for k, v in values.items() if v is not None}

    @classmethod
    def from_metrics(cls, figures: Mapping[str, float], prefix: str) -> Load | None:
        """The reading :meth:`metrics` logged under ``prefix``; None when none was (older runs)."""
        cpus = figures.get(f"{prefix}_cpus")
        if cpus is None or math.isnan(cpus):
            return None

        def get(key: str) -> float | None:
            v = figures.get(f"{prefix}_{key}")
            return None if v is None or math.isnan(v) else float(v)

        threads = get("threads")
        return cls(
            wall_s=math.nan,
            cpus=int(cpus),
            threads=None if threads is None else int(threads),
            cpu_wait=get("cpu_wait"),
            other_cpus=get("other_cpus"),
            load_average=get("load_avg"),
        )


class LoadProbe:
    """Reads the machine's counters when made; :meth:`read` gives the :class:`Load` since then.

    ``threads``: the torch threads of the timed work, recorded with the reading.
    """

    def __init__(self, threads: int | None = None):
        self.threads = threads
        self._load = _load_average()
        self._sched = _schedstat()
        self._busy = _busy_seconds()
        self._own = time.process_time()
        self._wall = time.perf_counter()

    def read(self) -> Load:
        wall = time.perf_counter() - self._wall
        own = time.process_time() - self._own
        cpu_wait = other = None
        sched = _schedstat()
        if self._sched is not None and sched is not None:
            # Threads born during the measurement count from zero; ended ones are lost.
            waiting = max(v[1] - self._sched.get(t, (0, 0))[1] for t, v in sched.items())
            cpu_wait = min(max(waiting / (1e9 * wall), 0.0), 1.0) if wall > 0 else None
        busy = _busy_seconds()
        if self._busy is not None and busy is not None and wall > 0:
            other = max(busy - self._busy - own, 0.0) / wall
        loads = [v for v in (self._load, _load_average()) if v is not None]
        return Load(
            wall_s=wall,
            cpus=_usable_cpus(),
            threads=self.threads,
            cpu_wait=cpu_wait,
            other_cpus=other,
            load_average=max(loads) if loads else None,
        )


# -- timed runs -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Timing:
    """Repeated timed runs of one call: their times and the load while they ran."""

    samples_ms: tuple[float, ...]
    load: Load | None = None

    def _quantile(self, q: float) -> float:
        return float(np.quantile(np.asarray(self.samples_ms, dtype=np.float64), q))

    @property
    def median_ms(self) -> float:
        return self._quantile(0.5)

    @property
    def iqr_ms(self) -> float:
        """Interquartile range: the 75th minus the 25th percentile (linear interpolation)."""
        return self._quantile(0.75) - self._quantile(0.25)

    @property
    def runs(self) -> int:
        return len(self.samples_ms)

    def words(self) -> str:
        """``19.3 ms [IQR 0.8] over 20 runs``."""
        return f"{self.median_ms:.3g} ms [IQR {self.iqr_ms:.2g}] over {self.runs} runs"

    def metrics(self, name: str) -> dict[str, float]:
        """MLflow metrics: ``{name}_ms`` (the median), ``{name}_iqr_ms``, ``{name}_runs`` and the
        load's (:meth:`Load.metrics`), e.g. ``time/latency_ms``, ``time/latency_iqr_ms``."""
        out = {f"{name}_ms": self.median_ms, f"{name}_iqr_ms": self.iqr_ms, f"{name}_runs": float(self.runs)}
        return out | (self.load.metrics(name) if self.load is not None else {})


def summarize(samples_ms, load: Load | None = None) -> Timing:
    """A :class:`Timing` of times measured elsewhere (ms, at least one, finite)."""
    values = tuple(float(v) for v in samples_ms)
    if not values or not all(math.isfinite(v) for v in values):
        raise BenchError(f"timing: expected at least one finite time in ms, got {values[:5]}")
    return Timing(values, load)


def _clock() -> Callable[[], float]:
    """``torch.utils.benchmark``'s clock: synchronises the accelerator, then reads ``timeit``'s."""
    from torch.utils.benchmark.utils.timer import timer

    return timer


def time_once(fn: Callable[[], object]) -> float:
    """Milliseconds of one call of ``fn``, on the clock of :func:`time_call`."""
    import timeit

    return 1e3 * timeit.Timer(fn, timer=_clock()).timeit(number=1)


def time_call(fn: Callable[[], object], runs: int, *, warmup: int = 3, threads: int | None = None) -> Timing:
    """Time ``runs`` calls of ``fn`` one by one, after ``warmup`` untimed calls, and read the load.

    Args:
        fn: the work, called with no arguments; whatever it returns is dropped.
        runs: timed calls (at least 1; quartiles want 8 or more).
        warmup: untimed calls first (lazy initialisation, allocator, caches).
        threads: the torch threads the work uses, recorded with the load (default: torch's).

    Returns the times in ms with their median and IQR, and the :class:`Load` of the timed part.
    """
    import timeit

    import torch

    if runs < 1 or warmup < 0:
        raise BenchError(f"timing: runs must be >= 1 and warmup >= 0, got {runs} and {warmup}")
    for _ in range(warmup):
        fn()
    clock = timeit.Timer(fn, timer=_clock())
    probe = LoadProbe(threads if threads is not None else torch.get_num_threads())
    seconds = clock.repeat(repeat=runs, number=1)
    return Timing(tuple(1e3 * s for s in seconds), probe.read())


def time_inference(fn: Callable[[], object], runs: int, device, *, warmup: int = 3) -> Timing:
    """:func:`time_call` for a network's inference on ``device``: on a CPU on one torch thread
    (torch's thread count restored after), elsewhere as it is.

    One thread, as the fits train: on an idle 2-core machine two threads spread the runs by
    5-14% of the median against 4-6% with one (50 runs of the cpu-size generators), and a
    second thread is the first to wait when anything else runs."""
    import torch

    if torch.device(device).type != "cpu":
        return time_call(fn, runs, warmup=warmup)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return time_call(fn, runs, warmup=warmup, threads=1)
    finally:
        torch.set_num_threads(threads)
