"""Pictures of a benchmark: learning curves, accuracy against cost, side-by-side predictions.

Figures are drawn on :class:`matplotlib.figure.Figure` directly (no pyplot, no display, no
global backend state); matplotlib is imported on first use, not at import time.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Iterable, Mapping, Sequence
from pathlib import Path

from torch import Tensor

from .errors import BenchError

__all__ = [
    "learning_curves",
    "learning_curves_figure",
    "pareto",
    "pareto_front",
    "dominated_by",
    "comparison_grid",
    "accuracy_vs_capture_time",
    "accuracy_vs_training_time",
]

_DPI = 120


def _figure(size=(7.0, 4.5)):
    from matplotlib.figure import Figure

    return Figure(figsize=size, layout="constrained")


def _save(fig, path) -> Path:
    from svbrdf_render.plumbing import atomic_output

    path = Path(path)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=_DPI, format="png")
    return path


def _points(curves, what: str) -> dict[str, tuple[list[float], list[float]]]:
    drawn = {}
    for name, (xs, ys) in (curves or {}).items():
        xs, ys = [float(x) for x in xs], [float(y) for y in ys]
        if len(xs) != len(ys):
            raise BenchError(f"learning curves: {what} {name!r} has {len(xs)} times but {len(ys)} values")
        if xs:
            drawn[name] = (xs, ys)
    return drawn


def learning_curves(
    curves: Mapping[str, tuple[Sequence[float], Sequence[float]]],
    path,
    *,
    real: Mapping[str, tuple[Sequence[float], Sequence[float]]] | None = None,
    ylabel: str = "validation render RMSE",
    xlabel: str = "training time (s)",
) -> Path:
    """One line per model, ``{name: (training time in seconds, metric)}``, as a PNG at ``path``.

    ``real`` adds, per model, the same figure on a second validation set of real materials
    (the trainer's ``val_real/``): a dashed line in the model's colour, labelled "<name> (real)".
    Models with no points are left out; no points at all is a :class:`BenchError`.
    """
    return _save(learning_curves_figure(curves, real=real, ylabel=ylabel, xlabel=xlabel), path)


def learning_curves_figure(
    curves: Mapping[str, tuple[Sequence[float], Sequence[float]]],
    *,
    real: Mapping[str, tuple[Sequence[float], Sequence[float]]] | None = None,
    ylabel: str = "validation render RMSE",
    xlabel: str = "training time (s)",
):
    """The :class:`matplotlib.figure.Figure` that :func:`learning_curves` saves."""
    drawn = _points(curves, "model")
    dashed = _points(real, "real curve of model")
    if not drawn and not dashed:
        raise BenchError("learning curves: no points to draw (no model logged a validation figure)")
    fig = _figure()
    ax = fig.add_subplot()
    colours = {}
    for name, (xs, ys) in drawn.items():
        (line,) = ax.plot(xs, ys, marker="o", markersize=3.5, linewidth=1.5, label=name)
        colours[name] = line.get_color()
    for name, (xs, ys) in dashed.items():
        ax.plot(xs, ys, linestyle="--", marker="s", markersize=3, linewidth=1.3, label=f"{name} (real)",
                **({"color": colours[name]} if name in colours else {}))  # fmt: skip
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    # Two lines when the note is there: one line is wider than the figure.
    ax.set_title(f"{ylabel} against {xlabel}" + ("\n(dashed: real materials)" if dashed else ""))
    ax.grid(True, alpha=0.35)
    ax.legend(fontsize="small")
    return fig


def _check_points(points: Mapping[str, tuple[float, float, float, float]], what: str) -> None:
    if not points:
        raise BenchError(f"{what}: no models to place")
    for name, p in points.items():
        if len(p) != 4:
            raise BenchError(f"{what}: model {name!r} has {len(p)} values, expected (x, y, y_low, y_high)")
        if not (math.isfinite(p[0]) and math.isfinite(p[1])):
            raise BenchError(f"{what}: model {name!r} is at ({p[0]}, {p[1]}); expected finite x and y")


def _noise_pairs(within_noise: Iterable[Iterable[str]]) -> set[frozenset[str]]:
    pairs = set()
    for pair in within_noise:
        pair = frozenset(pair)
        if len(pair) != 2:
            raise BenchError(f"pareto: within_noise takes pairs of two model names, got {sorted(pair)}")
        pairs.add(pair)
    return pairs


def dominated_by(
    points: Mapping[str, tuple[float, float, float, float]], *, within_noise: Iterable[Iterable[str]] = ()
) -> dict[str, str | None]:
    """Each model -> a model that dominates it (the fastest such), or None: it is on the front.

    ``points`` maps a name to ``(x, y, y_low, y_high)``; lower is better on both axes. B dominates
    A when B is no slower (``x_B <= x_A``), no worse in y, and better in one: strictly faster, or
    lower in y where their y cannot be told apart is not lower. ``within_noise`` names the pairs
    whose y difference lies within noise (e.g. a paired bootstrap interval that contains 0): for
    them y counts as equal, so a faster model dominates a slower one whatever their means say,
    and a model is on the front only if it is faster than, or better beyond noise than, every
    model at least as fast. (Noise is not transitive: C may be better than A beyond noise yet
    dominated by B, faster than C and within noise of it.) Models at the same place, or at the
    same x within noise, do not dominate each other.
    """
    _check_points(points, "pareto_front")
    noise = _noise_pairs(within_noise)
    xy = {name: (float(p[0]), float(p[1])) for name, p in points.items()}

    def dominates(b: str, a: str) -> bool:
        (xa, ya), (xb, yb) = xy[a], xy[b]
        tied = frozenset((a, b)) in noise
        no_worse = tied or yb <= ya
        better_y = not tied and yb < ya
        return xb <= xa and no_worse and (xb < xa or better_y)

    out: dict[str, str | None] = {}
    for name in xy:
        by = [b for b in xy if b != name and dominates(b, name)]
        out[name] = min(by, key=lambda b: (xy[b][0], xy[b][1], b)) if by else None
    return out


def pareto_front(
    points: Mapping[str, tuple[float, float, float, float]], *, within_noise: Iterable[Iterable[str]] = ()
) -> list[str]:
    """Names of the models no other one dominates (:func:`dominated_by`), by x.

    ``points`` maps a name to ``(x, y, y_low, y_high)``; lower is better on both axes. Without
    ``within_noise`` a model is dominated by one with lower or equal x and y, one strictly
    lower; pairs named in ``within_noise`` count as equal in y. Models at the same place do
    not dominate each other: both are on the front. Ties in x are ordered by y, then name.
    """
    xy = {name: (float(p[0]), float(p[1])) for name, p in points.items()}
    by = dominated_by(points, within_noise=within_noise)
    return sorted((n for n in xy if by[n] is None), key=lambda n: (xy[n][0], xy[n][1], n))


def pareto(
    points: Mapping[str, tuple[float, float, float, float]],
    path,
    *,
    xlabel: str = "inference latency per image at 256x256 (ms)",
    ylabel: str = "render RMSE",
    logx: bool = False,
    within_noise: Iterable[Iterable[str]] = (),
) -> Path:
    """Accuracy against cost, ``{name: (x, y, y_low, y_high)}``, as a PNG at ``path``.

    Each model is a labelled point with its interval (e.g. the 95% bootstrap) as a vertical
    error bar; the Pareto front (:func:`pareto_front`, with ``within_noise``: the pairs whose y
    cannot be told apart) is drawn as a step line, the dominated points in grey. ``logx`` puts
    x on a log scale (for latencies spanning decades).
    """
    _check_points(points, "pareto")
    within_noise = _noise_pairs(within_noise)
    front = pareto_front(points, within_noise=within_noise)
    fig = _figure()
    ax = fig.add_subplot()
    for name, (x, y, lo, hi) in points.items():
        lo = y if not math.isfinite(lo) else lo
        hi = y if not math.isfinite(hi) else hi
        err = [[max(y - lo, 0.0)], [max(hi - y, 0.0)]]
        ax.errorbar(
            [x],
            [y],
            yerr=err,
            fmt="o",
            capsize=3,
            markersize=5,
            color="tab:blue" if name in front else "tab:gray",
        )
        ax.annotate(name, (x, y), xytext=(5, 4), textcoords="offset points", fontsize="small")
    fx = [float(points[n][0]) for n in front]
    fy = [float(points[n][1]) for n in front]
    ax.step(
        fx,
        fy,
        where="post",
        color="tab:red",
        linewidth=1.2,
        alpha=0.8,
        label="Pareto front: " + ", ".join(front),
    )
    if len(front) < len(points):
        noise = " within noise" if within_noise else ""
        label = f"dominated: a faster model is as good{noise}"
        ax.plot([], [], "o", color="tab:gray", markersize=5, label=label)
    if logx:
        ax.set_xscale("log")
    ax.margins(x=0.08, y=0.08)  # room for the labels of the outer points
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(f"{ylabel} against {xlabel}")
    ax.grid(True, alpha=0.35)
    ax.legend(fontsize="small")
    return _save(fig, path)


#: The panels of :func:`accuracy_vs_capture_time`: (column, axis label).
CAPTURE_PANELS = (("render", "render RMSE (6 evaluation views)"), ("diffuse", "diffuse RMSE"))


def accuracy_vs_capture_time(
    series: Mapping[str, Sequence[tuple[float, int, Mapping[str, tuple[float, float, float]]]]],
    path,
    *,
    baselines: Collection[str] = (),
    panels: Sequence[tuple[str, str]] = CAPTURE_PANELS,
    xlabel: str = "seconds per image (network + refinement)",
) -> Path:
    """Accuracy against capture time, one panel per ``panels`` column, as a PNG at ``path``.

    ``series`` maps a row to its points through the refinement budgets,
    ``[(seconds per image, refinement steps, {column: (mean, low, high)}), ...]``: one line per row,
    each point labelled with its steps and given its interval as an error bar. Rows named in
    ``baselines`` (constant-map baselines: refinement from them is optimisation alone) are drawn
    dashed, with square markers, beside the models. x is on a log scale (a network's
    milliseconds and a refinement's seconds on one axis).
    """
    drawn = {}
    for name, points in series.items():
        pts = sorted((float(t), int(k), dict(v)) for t, k, v in points)
        for t, k, v in pts:
            if not (math.isfinite(t) and t > 0):
                raise BenchError(f"capture time plot: {name!r} at {k} steps has {t} seconds per image")
            missing = [c for c, _ in panels if c not in v]
            if missing:
                raise BenchError(f"capture time plot: {name!r} at {k} steps has no {', '.join(missing)}")
        if pts:
            drawn[name] = pts
    if not drawn:
        raise BenchError("capture time plot: no rows to draw")
    fig = _figure((6.0 * len(panels), 4.5))
    axes = [fig.add_subplot(1, len(panels), i + 1) for i in range(len(panels))]
    for ax, (column, ylabel) in zip(axes, panels, strict=True):
        for name, pts in drawn.items():
            xs = [t for t, _, _ in pts]
            ys = [v[column][0] for _, _, v in pts]
            err = [[max(v[column][0] - v[column][1], 0.0) for _, _, v in pts],
                   [max(v[column][2] - v[column][0], 0.0) for _, _, v in pts]]  # fmt: skip
            style = {"linestyle": "--", "marker": "s", "alpha": 0.8} if name in baselines else {"marker": "o"}
            ax.errorbar(xs, ys, yerr=err, capsize=2.5, markersize=4.5, linewidth=1.4, label=name, **style)
            for t, k, v in pts:
                ax.annotate(str(k), (t, v[column][0]), xytext=(4, 3), textcoords="offset points",
                            fontsize="x-small")  # fmt: skip
        ax.set_xscale("log")
        ax.margins(x=0.1, y=0.08)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.set_title(f"{ylabel} against capture time\n(labels: refinement steps; dashed: baselines)",
                     fontsize="medium")  # fmt: skip
        ax.grid(True, alpha=0.35, which="both")
    axes[0].legend(fontsize="small")
    return _save(fig, path)


def accuracy_vs_training_time(
    series: Mapping[str, Sequence[tuple[float, str, tuple[float, float, float]]]],
    path,
    *,
    ylabel: str = "test render RMSE (6 evaluation views)",
    xlabel: str = "training time, budget clock (min)",
) -> Path:
    """Test accuracy against training time, one line per model through its budgets, as a PNG.

    ``series`` maps a model to ``[(training minutes, budget label, (mean, low, high)), ...]``: each
    point labelled with its budget (``8 min``, ``500 steps``) and given its interval (e.g. the
    95% bootstrap over seeds and materials) as an error bar. x is on a log scale (budgets such as
    2, 8, 32 minutes are evenly spaced there): what each minute of training buys, and where a
    model stops gaining.
    """
    drawn = {}
    for name, points in series.items():
        pts = sorted((float(t), str(k), tuple(v)) for t, k, v in points)
        for t, k, _ in pts:
            if not (math.isfinite(t) and t > 0):
                raise BenchError(f"training time plot: {name!r} at {k} has {t} training minutes")
        if pts:
            drawn[name] = pts
    if not drawn:
        raise BenchError("training time plot: no models to draw")
    fig = _figure()
    ax = fig.add_subplot()
    for name, pts in drawn.items():
        xs, ys = [t for t, _, _ in pts], [v[0] for _, _, v in pts]
        err = [[max(v[0] - v[1], 0.0) for _, _, v in pts], [max(v[2] - v[0], 0.0) for _, _, v in pts]]
        ax.errorbar(xs, ys, yerr=err, capsize=2.5, marker="o", markersize=4.5, linewidth=1.4, label=name)
        for t, k, v in pts:
            ax.annotate(k, (t, v[0]), xytext=(4, 3), textcoords="offset points", fontsize="x-small")
    ax.set_xscale("log")
    _plain_ticks(ax, [t for pts in drawn.values() for t, _, _ in pts])
    ax.margins(x=0.1, y=0.08)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(f"{ylabel} against training time\n(labels: budgets; bars: 95% interval over seeds "
                 "and materials)", fontsize="medium")  # fmt: skip
    ax.grid(True, alpha=0.35, which="both")
    ax.legend(fontsize="small")
    return _save(fig, path)


def _plain_ticks(ax, xs: Iterable[float]) -> None:
    """Ticks of a log x axis at the values drawn (two significant digits: 2, 8, 32 minutes), as
    plain numbers, instead of powers of ten."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullLocator

    ticks = sorted({float(f"{x:.2g}") for x in xs})
    ax.xaxis.set_major_locator(FixedLocator(ticks))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_locator(NullLocator())


def comparison_grid(
    rows: Sequence[tuple[str, Sequence[Tensor]]], columns: Sequence[str], path, *, min_tile: int = 0
) -> Path:
    """Side-by-side pictures: one labelled row per ``(label, tiles)``, under ``columns`` titles.

    Tiles are ``(3, H, W)`` (or grey ``(1, H, W)``) display images in [0, 1], all the same size,
    one per column; tiles narrower than ``min_tile`` are enlarged (nearest neighbour). Written
    as an 8-bit PNG at ``path``.
    """
    from svbrdf_render import write_image
    from svbrdf_models.capture.figures import image_grid

    if not rows:
        raise BenchError("comparison grid: no rows to draw")
    columns = list(columns)
    if not columns:
        raise BenchError("comparison grid: no columns to draw")
    size = None
    tiles_rows = []
    for label, tiles in rows:
        if len(tiles) != len(columns):
            raise BenchError(
                f"comparison grid: row {label!r} has {len(tiles)} pictures for {len(columns)} columns"
            )
        row = []
        for tile in tiles:
            if tile.dim() != 3 or tile.shape[0] not in (1, 3):
                raise BenchError(
                    f"comparison grid: row {label!r}: expected (3, H, W) pictures, got {tuple(tile.shape)}"
                )
            if size is None:
                size = tuple(tile.shape[-2:])
            elif tuple(tile.shape[-2:]) != size:
                raise BenchError(
                    f"comparison grid: row {label!r}: a {tuple(tile.shape[-2:])} picture among {size} ones"
                )
            row.append(tile.expand(3, -1, -1) if tile.shape[0] == 1 else tile)
        tiles_rows.append(row)
    image = image_grid(tiles_rows, columns, [label for label, _ in rows], min_tile=min_tile)
    return write_image(Path(path), image)
