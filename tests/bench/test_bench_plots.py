"""Benchmark pictures: learning curves, the Pareto plot and front, the comparison grid."""

from __future__ import annotations

import pytest
import torch

from svbrdf_bench.errors import BenchError
from svbrdf_bench.plots import comparison_grid, learning_curves, learning_curves_figure, pareto, pareto_front
from svbrdf_render import read_image


def _is_png(path, min_size=(100, 100)):
    image = read_image(path)
    assert image.dim() == 3 and image.shape[0] == 3
    assert image.shape[1] >= min_size[0] and image.shape[2] >= min_size[1]
    assert float(image.std()) > 0  # something was drawn
    return image


def test_learning_curves_writes_a_png(tmp_path):
    curves = {
        "unet": ([1.0, 2.0, 4.0, 8.0], [0.3, 0.2, 0.15, 0.12]),
        "des18": ([2.0, 5.0, 9.0], [0.35, 0.22, 0.18]),
        "never validated": ([], []),
    }
    path = learning_curves(curves, tmp_path / "plots" / "curves.png")
    assert path == tmp_path / "plots" / "curves.png"
    image = _is_png(path)
    assert image.shape[1:] == (int(4.5 * 120), int(7 * 120))  # 7 x 4.5 inches at 120 dpi


def test_learning_curves_draw_the_real_validation_dashed_in_the_model_colour(tmp_path):
    curves = {"unet": ([1.0, 2.0, 4.0], [0.3, 0.2, 0.15]), "des18": ([2.0, 5.0], [0.35, 0.22])}
    real = {"unet": ([1.0, 2.0, 4.0], [0.4, 0.38, 0.37]), "des18": ([], [])}
    fig = learning_curves_figure(curves, real=real)
    lines = {line.get_label(): line for line in fig.axes[0].get_lines()}
    assert set(lines) == {"unet", "des18", "unet (real)"}  # a model without real points gets no line
    assert lines["unet (real)"].get_linestyle() == "--" and lines["unet"].get_linestyle() == "-"
    assert lines["unet (real)"].get_color() == lines["unet"].get_color() != lines["des18"].get_color()
    assert list(lines["unet (real)"].get_ydata()) == [0.4, 0.38, 0.37]
    _is_png(learning_curves(curves, tmp_path / "both.png", real=real))
    # Without `real`, as before; real points alone are enough to draw.
    assert [x.get_label() for x in learning_curves_figure(curves).axes[0].get_lines()] == ["unet", "des18"]
    assert (
        learning_curves_figure({}, real={"unet": real["unet"]}).axes[0].get_lines()[0].get_label()
        == "unet (real)"
    )
    with pytest.raises(BenchError, match="3 times but 1 values"):
        learning_curves_figure(curves, real={"unet": ([1, 2, 3], [0.1])})


def test_learning_curves_needs_points(tmp_path):
    with pytest.raises(BenchError, match="no points"):
        learning_curves({}, tmp_path / "a.png")
    with pytest.raises(BenchError, match="no points"):
        learning_curves({"unet": ([], [])}, tmp_path / "a.png")
    with pytest.raises(BenchError, match="3 times but 2 values"):
        learning_curves({"unet": ([1, 2, 3], [0.1, 0.2])}, tmp_path / "a.png")
    assert not (tmp_path / "a.png").exists()


def test_pareto_front_leaves_out_dominated_models():
    points = {
        "fast": (1.0, 0.30, 0.28, 0.32),
        "slow accurate": (10.0, 0.10, 0.09, 0.11),
        "middle": (4.0, 0.20, 0.18, 0.22),
        "dominated": (5.0, 0.25, 0.2, 0.3),  # "middle" is faster and more accurate
        "same x, worse": (4.0, 0.22, 0.2, 0.24),  # ties "middle" on x, worse y
        "same y, slower": (12.0, 0.10, 0.09, 0.11),  # ties "slow accurate" on y, slower
    }
    assert pareto_front(points) == ["fast", "middle", "slow accurate"]


def test_pareto_front_keeps_both_of_two_equal_models():
    points = {"b": (2.0, 0.1, 0.1, 0.1), "a": (2.0, 0.1, 0.1, 0.1), "c": (3.0, 0.2, 0.1, 0.3)}
    assert pareto_front(points) == ["a", "b"]
    assert pareto_front({"only": (1.0, 1.0, 1.0, 1.0)}) == ["only"]


def test_pareto_front_rejects_bad_points():
    with pytest.raises(BenchError, match="no models"):
        pareto_front({})
    with pytest.raises(BenchError, match="finite"):
        pareto_front({"a": (float("nan"), 0.1, 0.1, 0.1)})


def test_pareto_plot_writes_a_png(tmp_path):
    points = {
        "fast": (1.0, 0.30, 0.28, 0.32),
        "slow": (10.0, 0.10, 0.09, 0.11),
        "dominated": (5.0, 0.35, 0.3, 0.4),
        "no interval": (3.0, 0.2, float("nan"), float("nan")),
    }
    _is_png(pareto(points, tmp_path / "pareto.png"))
    _is_png(pareto(points, tmp_path / "pareto-log.png", logx=True, xlabel="ms", ylabel="SSIM loss"))
    with pytest.raises(BenchError, match="no models"):
        pareto({}, tmp_path / "empty.png")


def test_comparison_grid_writes_the_image_grid(tmp_path):
    g = torch.Generator().manual_seed(0)
    tiles = [torch.rand(3, 16, 16, generator=g) for _ in range(3)]
    grey = torch.rand(1, 16, 16, generator=g)
    rows = [("ground truth", tiles), ("unet", [tiles[0], grey, tiles[2]])]
    path = comparison_grid(rows, ["render", "roughness", "diffuse"], tmp_path / "grid.png")
    image = _is_png(path, min_size=(2 * 16, 3 * 16))
    q = (tiles[2] * 255).round() / 255
    found = any(
        torch.equal(image[:, top : top + 16, left : left + 16], q)
        for top in range(image.shape[1] - 15)
        for left in range(image.shape[2] - 15)
    )
    assert found


def test_comparison_grid_rejects_bad_rows(tmp_path):
    t = torch.rand(3, 8, 8)
    with pytest.raises(BenchError, match="no rows"):
        comparison_grid([], ["a"], tmp_path / "g.png")
    with pytest.raises(BenchError, match="2 pictures for 3 columns"):
        comparison_grid([("x", [t, t])], ["a", "b", "c"], tmp_path / "g.png")
    with pytest.raises(BenchError, match="among"):
        comparison_grid([("x", [t]), ("y", [torch.rand(3, 4, 4)])], ["a"], tmp_path / "g.png")


def test_training_time_ticks_are_the_budgets_in_plain_numbers(tmp_path):
    """The log axis of accuracy against training time is ticked at the minutes drawn (measured
    2.01 and 2.0 are one tick), written 2, 8, 32: not 2 x 10^0."""
    from matplotlib.figure import Figure

    from svbrdf_bench.plots import _plain_ticks, accuracy_vs_training_time

    ax = Figure().add_subplot()
    ax.set_xscale("log")
    ax.plot([2.0, 2.01, 8.003, 32.01], [1, 2, 3, 4])
    _plain_ticks(ax, [2.0, 2.01, 8.003, 32.01])
    assert list(ax.get_xticks()) == [2.0, 8.0, 32.0]
    assert [ax.xaxis.get_major_formatter()(t, 0) for t in ax.get_xticks()] == ["2", "8", "32"]
    series = {"a": [(2.0, "2 min", (0.1, 0.09, 0.11)), (8.0, "8 min", (0.08, 0.07, 0.09))]}
    assert accuracy_vs_training_time(series, tmp_path / "t.png").is_file()
