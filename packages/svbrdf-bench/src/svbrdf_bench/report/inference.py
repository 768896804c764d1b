"""The report's inference cost table: per row, its parameters, FLOPs per 256 px image and latency
at each point of the latency grid (:mod:`svbrdf_bench.inference` measures them), as logged in its
MLflow child run; and the results.json keys of those figures."""

from __future__ import annotations

import math

from ..inference import BASE_POINT, FLOPS_METRIC, FLOPS_SIZE, GridPoint, grid_points
from ..timing import CPU_WAIT_LIMIT
from .figures import Report
from .tables import Table

__all__ = ["inference_table"]


def _cell(figures: dict[str, float], point: GridPoint) -> tuple[str, bool]:
    """``12.6 [0.3]`` (ms, median [IQR]), with `` 850 MB`` on CUDA and ``*`` when the load made it
    unreliable; and whether it did. ``-``: not timed."""
    median = figures.get(f"{point.metric}_ms", math.nan)
    if math.isnan(median):
        return "-", False
    iqr = figures.get(f"{point.metric}_iqr_ms", math.nan)
    text = f"{median:.1f}" if math.isnan(iqr) else f"{median:.1f} [{iqr:.1f}]"
    memory = figures.get(point.memory_metric)
    if memory is not None and not math.isnan(memory):
        text += f" {memory:.0f} MB"
    busy = figures.get(f"{point.metric}_cpu_wait", 0.0) > CPU_WAIT_LIMIT
    return text + ("*" if busy else ""), busy


def inference_table(report: Report) -> Table | None:
    """Parameters, FLOPs and the latency grid per row that has them; None when no row has more
    than the time table's 256 px latency (older runs)."""
    rows_with = [e for e in report.models if FLOPS_METRIC in e.figures or "time/latency_ms" in e.figures]
    points = grid_points({k for e in rows_with for k in e.figures})
    if not any(FLOPS_METRIC in e.figures for e in rows_with) and len(points) < 2:
        return None
    rows, busy = [], False
    for e in rows_with:
        params, flops = e.figures.get("model/params", math.nan), e.figures.get(FLOPS_METRIC, math.nan)
        cells = [e.short, "-" if math.isnan(params) else f"{params / 1e6:.2f}",
                 "-" if math.isnan(flops) else f"{flops / 1e9:.3g}"]  # fmt: skip
        for p in points:
            text, slow = _cell(e.figures, p)
            cells.append(text)
            busy |= slow
        rows.append(cells)
    def runs(grid: list[GridPoint]) -> str:
        counts = sorted({int(e.figures[f"{p.metric}_runs"]) for e in rows_with for p in grid
                         if f"{p.metric}_runs" in e.figures})  # fmt: skip
        return "/".join(map(str, counts)) or "?"

    others = [p for p in points if p != BASE_POINT]
    how = f"{runs([BASE_POINT])} timed runs at 256x1" + (f", {runs(others)} at the others" if others else "")
    after = [
        "",
        f"FLOPs: one forward pass of one {FLOPS_SIZE}x{FLOPS_SIZE} image, counted by "
        "torch.utils.flop_counter (convolutions and matrix products, a multiply-add as 2 FLOPs; "
        "element-wise ops, norms and pooling not counted). The networks are fully convolutional: "
        "FLOPs grow with the pixel count, x4 at 512 px, x16 at 1024 px.",
        f"Latency SxB: ms per forward pass of B images of S px on the benchmark's device, median "
        f"[IQR] of {how}, after warm-up runs; torch.no_grad, one torch thread on a CPU; per image: "
        "divide by B. On CUDA each cell also gives the peak memory the allocator held.",
    ]
    if busy:
        after.append(f"* a timed thread waited for a CPU over {100 * CPU_WAIT_LIMIT:.0f}% of the time: "
                     "the machine was busy and that latency is unreliable.")  # fmt: skip
    head = ["model", "params (M)", f"GFLOP/image {FLOPS_SIZE}px"]
    head += [f"{p.size}px b{p.batch} ms [IQR]" for p in points]
    return Table("Inference cost", head, rows, after)
