"""The clock that training-time budgets (``max_minutes``) and the logged training time count.

Wall time is what a person waits, but on a shared machine it also counts the time other
programs take the cores away, so two models given "2 minutes" each get different amounts of
computation depending on what else ran. The ``cpu`` clock counts the process's CPU time
(all its threads) divided by its torch threads: on an idle machine it runs at the speed of
wall time, and a busy machine slows it down with the training instead of eating its budget.
DataLoader workers are other processes and are not counted. On a GPU the ``auto`` clock is
wall time with the device synchronised before each reading, i.e. the GPU time of the steps.

Clock names are recorded on each MLflow run as the tag :data:`CLOCK_TAG`.
"""

from __future__ import annotations

import time

import torch

__all__ = ["TrainClock", "Stopwatch", "CLOCK_TAG", "CLOCKS", "WARMUP_STEPS"]

#: MLflow tag naming the clock a fit's training time was counted on.
CLOCK_TAG = "svbrdf.clock"
#: Clock names as recorded: process CPU time over torch threads, wall time, wall time of a synchronised GPU.
CLOCKS = ("cpu", "wall", "cuda")
#: Steps left out of the throughput figure: the first ones pay for lazy initialisation.
WARMUP_STEPS = 3


class TrainClock:
    """``now()`` in seconds on the clock a recipe's ``train.clock`` chooses for ``device``."""

    def __init__(self, choice: str, device: torch.device):
        if choice not in ("auto", "cpu", "wall"):
            raise ValueError(f"train.clock must be auto, cpu or wall, got {choice!r}")
        self.device = torch.device(device)
        cuda = self.device.type == "cuda"
        if choice == "auto":
            choice = "cuda" if cuda else "cpu"
        elif choice == "wall" and cuda:
            choice = "cuda"  # wall time of queued GPU work means nothing without a sync
        self.name = choice

    def now(self) -> float:
        if self.name == "cpu":
            return time.process_time() / max(1, torch.get_num_threads())
        if self.name == "cuda":
            torch.cuda.synchronize(self.device)
        return time.perf_counter()

    def describe(self) -> str:
        return {
            "cpu": f"process CPU time / {torch.get_num_threads()} torch threads",
            "wall": "wall time",
            "cuda": "GPU time (wall time, device synchronised)",
        }[self.name]


class Stopwatch:
    """The training time of a fit's steps, on its clock and on the wall, and its throughput.

    ``start()`` before a step and ``lap(samples)`` after it count the step; what happens in
    between laps (validation, checkpoints) is not training time. ``seconds`` and
    ``wall_seconds`` carry on from a resumed fit's.
    """

    def __init__(self, clock: TrainClock, seconds: float = 0.0, wall_seconds: float = 0.0):
        self.clock, self.seconds, self.wall_seconds = clock, seconds, wall_seconds
        self.steps = 0  # laps of this session
        self.samples = 0
        self.steady: tuple[float, int] | None = None  # (seconds, samples) when warm-up ended
        self._tick = self._wall_tick = 0.0

    def start(self) -> None:
        self._tick, self._wall_tick = self.clock.now(), time.perf_counter()

    def lap(self, samples: int) -> None:
        self.seconds += self.clock.now() - self._tick
        self.wall_seconds += time.perf_counter() - self._wall_tick
        self.steps += 1
        self.samples += samples
        if self.steps == WARMUP_STEPS:
            self.steady = (self.seconds, self.samples)

    def steady_rate(self) -> float | None:
        """Samples per second of training time after the warm-up steps (None: too few steps)."""
        if self.steady is None or self.samples <= self.steady[1]:
            return None
        return (self.samples - self.steady[1]) / (self.seconds - self.steady[0])

    def pace(self) -> float | None:
        """Seconds per step since the warm-up, once :data:`WARMUP_STEPS` more steps are done."""
        if self.steady is None or self.steps < 2 * WARMUP_STEPS:
            return None
        return (self.seconds - self.steady[0]) / (self.steps - WARMUP_STEPS)
