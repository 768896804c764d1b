"""What a model costs to run: FLOPs per image, and latency over a grid of image sizes and batches.

Every scored row (:class:`~svbrdf_bench.scoring.RowScorer`) gets, beside its parameters and its
256 px latency (``time/latency_ms``):

- :data:`FLOPS_METRIC` (``model/flops_per_image_256px``): the FLOPs of one forward pass of one
  256x256 image, counted once by ``torch.utils.flop_counter.FlopCounterMode``
  (:func:`svbrdf_train.count_flops`): convolutions (transposed ones too) and matrix products, a
  multiply-add counted as 2 FLOPs; element-wise ops, normalisation, pooling and resizing count
  nothing. The generators are fully convolutional, so their FLOPs grow with the pixel count:
  x4 at 512 px, x16 at 1024 px (measured 3.997 and 15.99; only the global track's fully
  connected layers do not grow, 0.1% of ``ours``' FLOPs at 256 px).
- per point ``SxB`` of the latency grid (:func:`parse_latency_grid`; the preset's, or
  ``--latency-grid``), ``time/latency_{S}px_b{B}_ms``: milliseconds per forward pass of a
  batch of B SxS images, the median of a few timed runs after warm-up runs, under
  ``torch.no_grad`` on the benchmark's device (on a CPU on one torch thread, as the 256 px
  latency: :func:`svbrdf_bench.timing.time_inference`), with ``_iqr_ms``, ``_runs`` and
  ``_cpu_wait`` (the share of the runs a thread waited for a CPU; over
  :data:`~svbrdf_bench.timing.CPU_WAIT_LIMIT` the figure is unreliable). The point 256x1 is
  ``time/latency_ms`` itself, timed with the preset's more numerous runs, not twice.
- on CUDA, per point, ``memory/inference_peak_cuda_mb_{S}px_b{B}``: the most memory the
  allocator held during those runs (on a CPU not measured: the process's peak resident size
  only grows, so it cannot be read per call).

A point whose size the network cannot take (a U-Net of depth d takes multiples of 2**d px) is
left out of that row, with a line saying so.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

from .errors import BenchError
from .timing import LATENCY_METRIC

__all__ = [
    "FLOPS_METRIC",
    "FLOPS_SIZE",
    "GRID_WARMUP",
    "GridPoint",
    "BASE_POINT",
    "parse_latency_grid",
    "grid_points",
    "forward_flops",
    "inference_cost",
]

#: Side of the image the FLOPs are counted on.
FLOPS_SIZE = 256
#: FLOPs of one forward pass of one ``FLOPS_SIZE`` image.
FLOPS_METRIC = f"model/flops_per_image_{FLOPS_SIZE}px"
#: Untimed runs before each grid point's timed ones (allocator, caches, cuDNN's choices).
GRID_WARMUP = 2
#: The bounds of a grid point: image side in px (the smallest tiny U-Net input, the largest map
#: size the tools make) and images per forward pass.
SIZE_RANGE = (16, 8192)
BATCH_RANGE = (1, 256)
#: Prefix of the CUDA memory figures of the grid points.
CUDA_MEMORY_PREFIX = "memory/inference_peak_cuda_mb"


@dataclass(frozen=True, order=True)
class GridPoint:
    """One point of the latency grid: a batch of ``batch`` images of ``size`` x ``size`` px."""

    size: int
    batch: int

    @property
    def name(self) -> str:
        """``512x8``, as ``--latency-grid`` writes it."""
        return f"{self.size}x{self.batch}"

    @property
    def metric(self) -> str:
        """The timing's metric name (:meth:`svbrdf_bench.timing.Timing.metrics` adds ``_ms``...):
        ``time/latency`` for 256x1, else ``time/latency_512px_b8``."""
        return LATENCY_METRIC if self == BASE_POINT else f"{LATENCY_METRIC}_{self.size}px_b{self.batch}"

    @property
    def memory_metric(self) -> str:
        """``memory/inference_peak_cuda_mb_512px_b8``."""
        return f"{CUDA_MEMORY_PREFIX}_{self.size}px_b{self.batch}"


#: The point every row is timed at anyway (``time/latency_ms``): always in a grid.
BASE_POINT = GridPoint(256, 1)

_ITEM = re.compile(r"(\d+)[xX](\d+)")


def parse_latency_grid(text: str, flag: str = "--latency-grid") -> tuple[GridPoint, ...]:
    """``"256x1,256x8,512x1"`` -> the grid points, sorted, 256x1 added when missing.

    Raises BenchError (one line, naming ``flag``) for an item that is not ``SIZExBATCH``, a size
    or batch out of range, or a point given twice."""
    usage = (
        f"give SIZExBATCH items, e.g. {flag} 256x1,256x8,512x1 (SIZE: image side in px, "
        f"{SIZE_RANGE[0]}-{SIZE_RANGE[1]}; BATCH: images per forward pass, {BATCH_RANGE[0]}-{BATCH_RANGE[1]})"
    )
    items = [x.strip() for x in text.split(",")]
    if not any(items):
        raise BenchError(f"{flag} is empty: {usage}")
    points: list[GridPoint] = []
    for item in items:
        m = _ITEM.fullmatch(item)
        if m is None:
            raise BenchError(f"{flag} {text!r}: {item!r} is not SIZExBATCH; {usage}")
        point = GridPoint(int(m[1]), int(m[2]))
        (lo, hi), (b_lo, b_hi) = SIZE_RANGE, BATCH_RANGE
        if not (lo <= point.size <= hi and b_lo <= point.batch <= b_hi):
            raise BenchError(f"{flag} {text!r}: {item!r} is out of range; {usage}")
        if point in points:
            raise BenchError(f"{flag} {text!r}: {item!r} is given twice; give each point once")
        points.append(point)
    return tuple(sorted({BASE_POINT, *points}))


def grid_points(figures) -> list[GridPoint]:
    """The grid points a row's figures (or any figure names) hold a latency of, sorted; 256x1
    when ``time/latency_ms`` is there."""
    pattern = re.compile(re.escape(LATENCY_METRIC) + r"_(\d+)px_b(\d+)_ms")
    found = {GridPoint(int(m[1]), int(m[2])) for k in figures if (m := pattern.fullmatch(k))}
    if f"{LATENCY_METRIC}_ms" in figures:
        found.add(BASE_POINT)
    return sorted(found)


def _takes(generator, size: int) -> bool:
    """Whether ``generator`` takes ``size`` x ``size`` photos (a config that says, else yes)."""
    check = getattr(getattr(generator, "config", None), "check_input_size", None)
    if check is None:
        return True
    try:
        check(size, size)
    except ValueError:
        return False
    return True


def forward_flops(generator, size: int, device) -> int:
    """FLOPs of one forward pass of ``generator`` on one ``size`` x ``size`` image on ``device``
    (:func:`svbrdf_train.count_flops`: convolutions and matrix products, a multiply-add as 2)."""
    import torch

    from svbrdf_train import count_flops

    x = torch.rand(1, 3, size, size, device=device)
    with torch.no_grad():
        return count_flops(lambda: generator(x))


def _point_figures(generator, point: GridPoint, device, runs: int) -> dict[str, float]:
    """The latency figures of one grid point (and its CUDA memory on a GPU)."""
    import torch

    from .timing import time_inference

    device = torch.device(device)
    x = torch.rand(point.batch, 3, point.size, point.size, device=device)
    cuda = device.type == "cuda"
    if cuda:
        torch.cuda.reset_peak_memory_stats(device)
    with torch.no_grad():
        timing = time_inference(lambda: generator(x), runs, device, warmup=GRID_WARMUP)
    keep = ("_ms", "_iqr_ms", "_runs", "_cpu_wait")
    figures = {k: v for k, v in timing.metrics(point.metric).items() if k[len(point.metric) :] in keep}
    if cuda:
        figures[point.memory_metric] = torch.cuda.max_memory_allocated(device) / 2**20
    return figures


def inference_cost(
    generator, device, grid: tuple[GridPoint, ...], runs: int, label: str, say: Callable[[str], None] = print
) -> dict[str, float]:
    """A row's FLOPs per 256 px image and its latency at each grid point but 256x1 (which the
    row's ``time/latency_ms`` is): ``runs`` timed runs each after :data:`GRID_WARMUP`; see the
    module docstring for the figures' names."""
    figures: dict[str, float] = {}
    if _takes(generator, FLOPS_SIZE):
        figures[FLOPS_METRIC] = float(forward_flops(generator, FLOPS_SIZE, device))
    points = [p for p in grid if p != BASE_POINT]
    skipped = [p.name for p in points if not _takes(generator, p.size)]
    points = [p for p in points if p.name not in skipped]
    if points:
        say(f"timing the inference of {label} at {', '.join(p.name for p in points)} (SIZExBATCH, "
            f"{runs} timed runs each)")  # fmt: skip
    if skipped:
        say(f"  {label} cannot take the image sizes of {', '.join(skipped)} (a U-Net takes multiples of "
            "2**depth px): no latency there")  # fmt: skip
    for point in points:
        figures |= _point_figures(generator, point, device, runs)
    return figures
