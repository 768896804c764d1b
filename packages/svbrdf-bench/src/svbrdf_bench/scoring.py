"""Scoring one row of the benchmark: every row (a fit, a reference model file, a baseline) is
scored alike by :class:`RowScorer`: its figures on the test images, its latency and size (and
its FLOPs and latency grid: :mod:`svbrdf_bench.inference`), its self-consistency on real
photos, its figures as published papers scored (with a ``--published`` file's ``scorer``:
:func:`svbrdf_bench.published.score_as_published`), and the rows of its refinement budgets; a
fit's row adds its training figures (:func:`training_figures`). The scorer keeps what the
comparison sheets show (:func:`comparison_grid`, :func:`real_grid`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from svbrdf_render import MAP_NAMES

from .inference import inference_cost
from .layout import FIT_WALL_METRIC, REAL_PREFIX, REAL_RERENDER, STEPS_METRIC, STEPS_WALL_METRIC, TEST_PREFIX
from .published import PublishedScorer, score_as_published
from .refinement import RefinedRow, RefinePlan, refine_real, refine_rows, refined_label
from .testset import TestSet

__all__ = ["RowScorer", "training_figures", "test_means", "comparison_grid", "real_grid", "LATENCY_SIZE"]

#: Test samples shown in the visual comparison grid.
GRID_SAMPLES = 3
#: Tiles of the comparison grid smaller than this many pixels are enlarged.
GRID_MIN_SIZE = 96
#: Side of the input of the latency measurement.
LATENCY_SIZE = 256


@torch.no_grad()
def _evaluate(generator, test: TestSet, device: torch.device, lpips) -> tuple[dict[str, np.ndarray], list]:
    from torch.utils.data import DataLoader

    from svbrdf_render import SVBRDF

    from .metrics import evaluate

    parts: dict[str, list[np.ndarray]] = {}
    shown = []
    for batch in DataLoader(test, batch_size=8):
        photo = batch["input"].to(device)
        target = SVBRDF.unpack(batch["maps"].to(device), validate=False)
        pred = generator(photo)
        for k, v in evaluate(pred, target, lpips=lpips).items():
            parts.setdefault(k, []).append(np.asarray(v, dtype=np.float64))
        if len(shown) < GRID_SAMPLES:
            shown += [(photo[i].cpu(), pred[i : i + 1].to("cpu"), target[i : i + 1].to("cpu"))
                      for i in range(min(GRID_SAMPLES - len(shown), photo.shape[0]))]  # fmt: skip
    return {k: np.concatenate(v) for k, v in parts.items()}, shown


def _self_consistency(generator, photos, resolution: int, device: torch.device) -> np.ndarray:
    """Per photo: RMSE of the predicted maps re-rendered under the flash fitted to the photo.

    The photo's centre square at the model's resolution is predicted, then the capture tool's
    :func:`~svbrdf_models.capture.one.flash_consistency` finds the flash that re-renders those maps
    closest to the photo; its RMSE (clipped re-rendering against the photo) is the figure.
    """
    from svbrdf_models import square_photo
    from svbrdf_models.capture import flash_consistency

    out = []
    for i in range(len(photos)):
        x = square_photo(photos[i]["input"], resolution).to(device)[None]
        with torch.no_grad():
            maps = generator(x)
        out.append(float(flash_consistency(maps, x).rmse[0]))
    return np.asarray(out, dtype=np.float64)


@torch.no_grad()
def _latency(generator, device: torch.device, repeats: int) -> dict[str, float]:
    """Inference time of one image of ``LATENCY_SIZE``: ``repeats`` timed runs after 3 warm-up
    runs (:func:`svbrdf_bench.timing.time_inference`: on the CPU one torch thread, as the fits
    train), as metrics ``time/latency_ms`` (the median), ``time/latency_iqr_ms``,
    ``time/latency_runs`` and the machine's load while they ran."""
    from .timing import LATENCY_METRIC, time_inference

    x = torch.rand(1, 3, LATENCY_SIZE, LATENCY_SIZE, device=device)
    return time_inference(lambda: generator(x), repeats, device, warmup=3).metrics(LATENCY_METRIC)


def _step_spread(client, run_id: str, batch: int) -> dict[str, float]:
    """Median and IQR of the fit's training time per step over its logging windows (its
    ``train/samples_per_s`` history, the first window left out: it pays for warm-up), as
    ``time/train_ms_per_step_median`` and ``time/train_ms_per_step_iqr``; empty under 4 windows."""
    from .timing import summarize

    history = sorted(client.get_metric_history(run_id, "train/samples_per_s"), key=lambda m: m.step)
    rates = [m.value for m in history[1:] if m.value > 0 and np.isfinite(m.value)]
    if len(rates) < 4:
        return {}
    t = summarize([1000 * batch / r for r in rates])
    return {"time/train_ms_per_step_median": t.median_ms, "time/train_ms_per_step_iqr": t.iqr_ms}


@dataclass
class RowScorer:
    """Scores rows on one test set, the same way for every row; keeps, per row label, the test
    samples the comparison grid shows (``shown``) and, with real photos and refinement, what the
    real-photo sheet shows (``real_shown``)."""

    test: TestSet
    device: torch.device
    #: The LPIPS network (:func:`svbrdf_bench.metrics.load_lpips`), or None.
    lpips: object
    #: A :class:`svbrdf_train.PhotoFolder` of real photos (``--real-data``), or None.
    photos: object
    refine: RefinePlan
    latency_repeats: int
    say: Callable[[str], None] = print
    #: Where the latency is timed beyond 256x1 (:func:`svbrdf_bench.inference.parse_latency_grid`),
    #: and the timed runs per point there; FLOPs are counted whatever the grid.
    latency_grid: tuple = ()
    grid_repeats: int = 5
    #: Each row scored a second time as published papers scored (``--published`` with a ``scorer``:
    #: :func:`svbrdf_bench.published.score_as_published`), or None.
    as_published: PublishedScorer | None = None
    shown: dict[str, list] = field(default_factory=dict)
    real_shown: dict[str, list] = field(default_factory=dict)

    def score(
        self, label: str, generator, shown_as: str | None = None
    ) -> tuple[dict[str, float], dict[str, np.ndarray], dict[int, RefinedRow]]:
        """Test images, latency, parameters and real photos: the same for every row; and the
        rows of its refinement budgets (``{steps: RefinedRow}``, empty without --refine).
        ``shown_as``: the row's name in the sheets (default: ``label``)."""
        test, device = self.test, self.device
        self.say(f"evaluating {label} on {len(test)} test images")
        per_sample, shown = _evaluate(generator, test, device, self.lpips)
        figures = {
            **_latency(generator, device, self.latency_repeats),
            **inference_cost(generator, device, self.latency_grid, self.grid_repeats, label, self.say),
            "model/params": float(sum(q.numel() for q in generator.parameters())),
        }
        if self.photos is not None:
            self.say(f"fitting the flash to {len(self.photos)} real photos with {label}'s maps")
            real = _self_consistency(generator, self.photos, test.resolution, device)
            per_sample[REAL_RERENDER] = real
            figures[f"{REAL_RERENDER}_median"] = float(np.median(real))
        if self.as_published is not None:
            self.say(f"scoring {label} as the published rows were: {self.as_published.describe()}")
            figures |= score_as_published(generator, test.data, self.as_published, device)
        self.shown[shown_as or label] = shown
        refined: dict[int, RefinedRow] = {}
        if self.refine.active:
            refined = self._refine(label, shown_as or label, generator, per_sample, figures)
        figures |= test_means(per_sample)
        return figures, per_sample, refined

    def _refine(self, label: str, shown_label: str, generator, per_sample: dict, figures: dict) -> dict:
        """The refined rows of one row; the row's own re-rendering of the photo and its time go
        into ``per_sample`` and ``figures``."""
        budgets = ", ".join(map(str, self.refine.refined))
        self.say(f"refining {label}'s maps of {len(self.test)} test images for {budgets} steps")
        refined = refine_rows(generator, self.test, self.device, self.lpips, self.refine, GRID_SAMPLES)
        unrefined = refined.pop(0)  # the row itself: its re-rendering of the photo, its time
        per_sample |= unrefined.per_sample
        figures |= unrefined.figures
        top = max(refined)
        self.shown[refined_label(shown_label, top, shown_label.split(" (")[0])] = refined[top].shown
        if self.photos is not None:
            self.say(f"refining {label}'s maps of {len(self.photos)} real photos for {budgets} steps")
            self._refine_real(shown_label, generator, refined)
        return refined

    def _refine_real(self, shown_label: str, generator, refined: dict[int, RefinedRow]) -> None:
        """Each refined row's maps of the real photos, refined too: their figure, and the sheet."""
        real_rows = refine_real(generator, self.photos, self.test.resolution, self.device, self.refine,
                                GRID_SAMPLES)  # fmt: skip
        for k, row in refined.items():
            values = real_rows[k][0]
            row.per_sample[REAL_RERENDER] = values
            row.figures[f"{REAL_RERENDER}_median"] = float(np.median(values))
        name = shown_label.split(" (")[0]
        self.real_shown[shown_label] = real_rows[0][1]
        for k in sorted(refined):
            self.real_shown[refined_label(shown_label, k, name)] = real_rows[k][1]


def training_figures(client, run_id: str, wall: float | None, batch: int, steps: int) -> dict[str, float]:
    """A fit's training figures from its MLflow run ``run_id``: training time on the budget clock
    and wall time (``wall``: measured here; None: the run's own span), throughput, time per step
    (median and IQR too), peak memory and steps done (``steps``: its checkpoint's)."""
    train_run = client.get_run(run_id)
    m = train_run.data.metrics
    if wall is None and train_run.info.end_time and train_run.info.start_time:
        wall = (train_run.info.end_time - train_run.info.start_time) / 1000
    rate = m.get("train/steady_samples_per_s")
    figures = {
        "time/train_wall_s": wall or float("nan"),
        "time/train_s": m.get("train/total_seconds", float("nan")),
        "time/train_samples_per_s": rate if rate is not None else float("nan"),
        "time/train_ms_per_step": 1000 * batch / rate if rate else float("nan"),
        **_step_spread(client, run_id, batch),
        "memory/peak_rss_mb": m.get("train/peak_rss_mb", float("nan")),
        STEPS_METRIC: float(steps),
    }
    if FIT_WALL_METRIC in m:
        figures[STEPS_WALL_METRIC] = m[FIT_WALL_METRIC]
    if "train/peak_cuda_mb" in m:
        figures["memory/peak_cuda_mb"] = m["train/peak_cuda_mb"]
    return figures


def test_means(per_sample: dict[str, np.ndarray]) -> dict[str, float]:
    """The ``test/`` metrics: the mean of each per-sample figure on the test images."""
    return {
        f"{TEST_PREFIX}{k}": float(v.mean()) for k, v in per_sample.items() if not k.startswith(REAL_PREFIX)
    }


def comparison_grid(shown: dict[str, list], path: Path) -> Path:
    """Per test sample: the input and true maps, then each model's maps; flash re-renderings."""
    from svbrdf_render import linear_to_srgb
    from svbrdf_render.compare import display_rendering
    from svbrdf_train import map_tiles, preview_flash

    from .plots import comparison_grid as sheet

    flash = preview_flash()
    rows = []
    first = next(iter(shown.values()))
    for k, (photo, _, target) in enumerate(first):
        rows.append((f"#{k} truth", [linear_to_srgb(photo), *map_tiles(target.pack()[0]),
                                     display_rendering(target, flash)[0]]))  # fmt: skip
        for label, items in shown.items():
            pred = items[k][1]
            rows.append((f"#{k} {label}", [linear_to_srgb(photo), *map_tiles(pred.pack()[0]),
                                          display_rendering(pred, flash)[0]]))  # fmt: skip
    columns = ["input", *MAP_NAMES, "flash"]
    return sheet(rows, columns, path, min_tile=GRID_MIN_SIZE)


def real_grid(shown: dict[str, list], path: Path) -> Path:
    """Per real photo: each model's maps and their re-rendering under the flash fitted to them,
    each refined version in the row under its model's (``--real-data`` with ``--refine``)."""
    from svbrdf_render import linear_to_srgb
    from svbrdf_train import map_tiles

    from .plots import comparison_grid as sheet

    rows = []
    count = min(len(items) for items in shown.values())
    for k in range(count):
        for label, items in shown.items():
            photo, maps, rendering = items[k]
            rows.append((f"#{k} {label}", [linear_to_srgb(photo), *map_tiles(maps.pack()[0]),
                                          linear_to_srgb(rendering.clamp(0, 1))]))  # fmt: skip
    columns = ["photo", *MAP_NAMES, "fitted flash"]
    return sheet(rows, columns, path, min_tile=GRID_MIN_SIZE)
