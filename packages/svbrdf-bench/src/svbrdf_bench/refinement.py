"""Refinement budgets as an axis of the benchmark (``svbrdf-bench run --refine 0,50,200``).

Each scored row (a trained model, a reference model file, the baselines ``mean`` and ``photo``)
gets one more row per budget ``N > 0``: its maps of each test photo refined by
:func:`svbrdf_render.refine_maps` for ``N`` Adam steps against that photo, then scored with the
same figures as every row. Budget 0 is the row as it always was. ``mean +refine N`` starts from
constant maps: it is the *pure-optimisation baseline*, what optimisation alone reaches in as many
steps, and the report holds every refined row against it.

Timing is per image, as a capture tool meets it: each test photo goes through the network and
the refinement alone (batch of one), with the device synchronised, after an untimed warm-up
(the compiled backend compiles on its first call). The seconds include finding the flash.

With refinement on, every row (budget 0 too) also gets :data:`~svbrdf_bench.layout.INPUT_RERENDER`:
the maps re-rendered under the flash the refinement used against the photo itself, what the
refinement optimises (the 6 evaluation views measure whether that helped the material).

With ``--real-data`` too, each refined row also gets the real-photo figure
(:data:`~svbrdf_bench.layout.REAL_RERENDER`, :func:`refine_real`): the row's maps of each real
photo refined alike against that photo, then re-rendered under the flash fitted to them. That
re-rendering of the photo's own view is what refinement optimises, so it is no evidence of accuracy.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np
import torch
from torch import Tensor

from svbrdf_render import BACKENDS
from svbrdf_render.plumbing import positive_number
from svbrdf_render.refinement.fit import FLASH_MODES

from .errors import BenchError
from .layout import (
    INPUT_RERENDER,
    NETWORK_SECONDS_PER_IMAGE,
    REFINE_SECONDS_PER_IMAGE,
    REFINE_STEPS_METRIC,
    REFINE_TAKEN_METRIC,
    SECONDS_PER_IMAGE,
)

__all__ = [
    "RefinePlan",
    "RefinedRow",
    "parse_budgets",
    "parse_flash",
    "refined_label",
    "refine_rows",
    "refine_real",
    "REFINE_BACKENDS",
    "REFINE_FLASH_MODES",
]

#: The renderer backends ``--refine-backend`` takes: the renderer's own list.
REFINE_BACKENDS = BACKENDS
#: How ``--refine-flash`` finds the flash of a photo when no intensity is given: the
#: refinement's own list.
REFINE_FLASH_MODES = FLASH_MODES
_EXAMPLE = "e.g. --refine 0,50,200"


def parse_budgets(text: str | None, flag: str = "--refine") -> tuple[int, ...]:
    """``"0,50,200"`` -> ``(0, 50, 200)``: sorted, without repeats, 0 always in (the row itself).

    Empty text or items, non-integers and negative numbers are one-line :class:`BenchError`.
    """
    raw = "" if text is None else str(text)
    if not raw.strip():
        raise BenchError(f"{flag} is empty; give refinement budgets in Adam steps, integers >= 0, {_EXAMPLE}")
    budgets = set()
    for item in raw.split(","):
        item = item.strip()
        if not item:
            raise BenchError(f"{flag} {raw!r}: an empty budget between commas; {_EXAMPLE}")
        try:
            value = int(item)
        except ValueError:
            raise BenchError(
                f"{flag} {raw!r}: {item!r} is not a whole number of steps; "
                f"budgets are integers >= 0, {_EXAMPLE}"
            ) from None
        if value < 0:
            raise BenchError(f"{flag} {raw!r}: {value} is negative; budgets are integers >= 0, {_EXAMPLE}")
        budgets.add(value)
    return tuple(sorted(budgets | {0}))


def parse_flash(text: str | None, flag: str = "--refine-flash") -> str | float:
    """``axis``, ``fit`` or the intensity of the on-axis Des18 flash (a number > 0)."""
    value = (text or "").strip()
    if value in REFINE_FLASH_MODES:
        return value
    intensity = positive_number(value)
    if intensity is None:
        raise BenchError(
            f"{flag} {text!r}: expected axis, fit or the intensity of the on-axis flash the test "
            "photos were taken with (a number > 0, e.g. 15)"
        )
    return intensity


@dataclass(frozen=True)
class RefinePlan:
    """The refinement budgets of a benchmark and how each refinement runs."""

    budgets: tuple[int, ...] = (0,)
    """Adam steps; 0 (always there) is the unrefined row."""
    backend: str = "compiled"
    """The renderer backend of :func:`svbrdf_render.refine_maps`."""
    flash: str | float = "axis"
    """``axis`` / ``fit`` (found from the maps being refined), or the on-axis flash's intensity."""
    settings: dict = field(default_factory=dict)
    """:class:`svbrdf_render.RefineSettings` fields other than the defaults (none: the defaults)."""

    def __post_init__(self):
        if self.backend not in REFINE_BACKENDS:
            raise BenchError(
                f"--refine-backend {self.backend!r}: expected one of {', '.join(REFINE_BACKENDS)}"
            )

    @property
    def refined(self) -> tuple[int, ...]:
        """The budgets that add rows (all but 0)."""
        return tuple(k for k in self.budgets if k > 0)

    @property
    def active(self) -> bool:
        return bool(self.refined)

    def flash_words(self) -> str:
        if isinstance(self.flash, str):
            return self.flash
        return f"on-axis flash of intensity {self.flash:g}"

    def refine_settings(self):
        from svbrdf_render import RefineSettings

        return RefineSettings(**self.settings)

    def params(self, steps: int) -> dict[str, str]:
        """The ``refine.*`` params of the child run of a row refined for ``steps``."""
        settings = {f"refine.{k}": str(v) for k, v in asdict(self.refine_settings()).items()}
        return {"refine.steps": str(steps), "refine.backend": self.backend,
                "refine.flash": self.flash_words(), **settings}  # fmt: skip

    def scene(self, device):
        """The scene given to :func:`refine_maps` (None: found from the maps, by ``flash``)."""
        if isinstance(self.flash, str):
            return None
        from svbrdf_render import Scene

        return Scene.flash(intensity=float(self.flash)).to(device)


def refined_label(label: str, steps: int, name: str | None = None) -> str:
    """The row label of ``label`` refined for ``steps``: ``ours +refine 200``; a reference
    label ``fold0 (reference: ...)`` with ``name="fold0"`` gives ``fold0 +refine 200 (reference: ...)``."""
    if name and label.startswith(name) and label != name:
        return f"{name} +refine {steps}{label[len(name) :]}"
    return f"{label} +refine {steps}"


@dataclass
class RefinedRow:
    """One budget of one row: per-sample figures, time figures, and maps for the comparison grid."""

    steps: int
    per_sample: dict[str, np.ndarray]
    figures: dict[str, float]
    shown: list = field(default_factory=list)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _input_rerender(maps, scene, photo: Tensor) -> np.ndarray:
    """``(B,)`` RMSE of ``maps`` rendered under ``scene`` against ``photo`` (display encoding)."""
    from svbrdf_render import linear_to_srgb, render
    from svbrdf_render.compare import per_sample_rmse

    with torch.no_grad():
        r = render(maps, scene)
        r = r[:, 0] if r.dim() == 5 else r
        err = per_sample_rmse(linear_to_srgb(r.clamp(0, 1)), linear_to_srgb(photo.clamp(0, 1)))
    return err.to("cpu", torch.float64).numpy()


def refine_rows(generator, test, device, lpips, plan: RefinePlan, shown: int = 0) -> dict[int, RefinedRow]:
    """Every budget of ``plan`` for one generator on every test image, one image at a time.

    Returns ``{steps: RefinedRow}``. Budget 0 holds the network's own maps: only its
    :data:`INPUT_RERENDER` and its seconds are new (its accuracy is the benchmark's usual row).
    """
    from svbrdf_render import SVBRDF, refine_maps

    from .metrics import evaluate

    device = torch.device(device)
    scene = plan.scene(device)
    settings = plan.refine_settings()
    options = {"scene": scene, "flash": plan.flash if scene is None else "axis", "settings": settings,
               "backend": plan.backend}  # fmt: skip
    parts: dict[int, dict[str, list[np.ndarray]]] = {k: {} for k in plan.budgets}
    seconds: dict[int, list[float]] = {k: [] for k in plan.budgets}
    taken: dict[int, list[int]] = {k: [] for k in plan.budgets}
    net_seconds: list[float] = []
    grids: dict[int, list] = {k: [] for k in plan.budgets}
    for i in range(len(test)):
        sample = test[i]
        photo = sample["input"][None].to(device)
        target = SVBRDF.unpack(sample["maps"][None].to(device), validate=False)
        if i == 0:  # warm-up, untimed: the first call of a network or a compiled render is slow
            with torch.no_grad():
                start = generator(photo)
            if plan.active:
                refine_maps(photo, start, steps=min(2, max(plan.budgets)), **options)
        _sync(device)
        t0 = time.perf_counter()
        with torch.no_grad():
            start = generator(photo)
        _sync(device)
        net = time.perf_counter() - t0
        net_seconds.append(net)
        for k in plan.budgets:
            t0 = time.perf_counter()
            result = refine_maps(photo, start, steps=k, **options)
            _sync(device)
            spent = time.perf_counter() - t0 if k > 0 else 0.0  # budget 0: the network's maps as they are
            seconds[k].append(net + spent)
            taken[k].append(result.steps)
            figures = evaluate(result.svbrdf, target, lpips=lpips) if k > 0 else {}
            figures[INPUT_RERENDER] = _input_rerender(result.svbrdf, result.scene, photo)
            for name, v in figures.items():
                parts[k].setdefault(name, []).append(np.asarray(v, dtype=np.float64))
            if len(grids[k]) < shown:
                grids[k].append((photo[0].cpu(), result.svbrdf.to("cpu"), target.to("cpu")))
    out = {}
    network = float(np.mean(net_seconds))
    for k in plan.budgets:
        total = float(np.mean(seconds[k]))
        figures = {SECONDS_PER_IMAGE: total, NETWORK_SECONDS_PER_IMAGE: network,
                   REFINE_SECONDS_PER_IMAGE: total - network}  # fmt: skip
        if k > 0:
            figures |= {REFINE_STEPS_METRIC: float(k), REFINE_TAKEN_METRIC: float(np.mean(taken[k]))}
        per_sample = {name: np.concatenate(v) for name, v in parts[k].items()}
        out[k] = RefinedRow(k, per_sample, figures, grids[k])
    return out


def refine_real(
    generator, photos, resolution: int, device, plan: RefinePlan, shown: int = 0
) -> dict[int, tuple]:
    """Every budget of ``plan`` for one generator on every real photo (no ground truth).

    Each photo's centre square at ``resolution`` (as the unrefined real-photo figure takes it) is
    predicted, its maps refined for each budget against it with the plan's backend, flash and
    settings, then re-rendered under the flash fitted to the refined maps
    (:func:`~svbrdf_models.capture.one.flash_consistency`, as for the unrefined row).

    Returns ``{steps: (per-photo RMSE, shown)}`` for every budget, 0 (the network's maps) too;
    ``shown``: up to ``shown`` ``(photo, maps, fitted re-rendering)`` on the CPU, for the sheet.
    """
    from svbrdf_render import refine_maps
    from svbrdf_models import square_photo
    from svbrdf_models.capture import flash_consistency

    device = torch.device(device)
    scene = plan.scene(device)
    options = {"scene": scene, "flash": plan.flash if scene is None else "axis",
               "settings": plan.refine_settings(), "backend": plan.backend}  # fmt: skip
    errors: dict[int, list[float]] = {k: [] for k in plan.budgets}
    grids: dict[int, list] = {k: [] for k in plan.budgets}
    for i in range(len(photos)):
        x = square_photo(photos[i]["input"], resolution).to(device)[None]
        with torch.no_grad():
            start = generator(x)
        for k in plan.budgets:
            maps = refine_maps(x, start, steps=k, **options).svbrdf if k > 0 else start
            fit = flash_consistency(maps, x)
            errors[k].append(float(fit.rmse[0]))
            if len(grids[k]) < shown:
                grids[k].append((x[0].cpu(), maps.detach().to("cpu"), fit.rendering[0].detach().cpu()))
    return {k: (np.asarray(errors[k], dtype=np.float64), grids[k]) for k in plan.budgets}
