"""The recipe's sections: their fields, each field's range, and what each section builds.

A :class:`Recipe` is six sections (``generator``, ``discriminator``, ``loss``, ``optim``,
``data``, ``train``), each a frozen dataclass whose fields carry their default and their help
(``svbrdf_models.param``) and whose ``__post_init__`` refuses a value out of range with one
line naming the field. Settings that are each in range but cannot work together are refused
by :func:`svbrdf_train.recipe.checks.check_recipe`.

What they describe is built by the rooms that use them, which import the recipe (never the
other way): :func:`svbrdf_train.training.schedule.optimiser_of` and ``LrSchedule(optim, ...)``
for ``optim``, :func:`svbrdf_train.training.losses.loss_of` for ``loss``, ``data.setup(resolution)``
-> ``(train, validation)`` data sets (:func:`svbrdf_train.data.fitdata.section_datasets`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from svbrdf_models import param
from svbrdf_render.renderer import BACKENDS

from .paper_weights import MAP_WEIGHTS
from .datasection import DataSection
from .values import MAX_RESOLUTION, MIN_RESOLUTION, _check, _finite, _int_at_least, _number, _seed

__all__ = [
    "BATCH_RULES",
    "KEEP_BEST_METRICS",
    "NetworkSection",
    "LossSection",
    "OptimSection",
    "TrainSection",
    "Recipe",
    "SECTIONS",
    "TOP_LEVEL",
]


@dataclass(frozen=True)
class NetworkSection:
    name: str = param("ours", "registered name (svbrdf-models list)")
    config: dict = param({}, "config dict of that network; may hold 'preset'")


@dataclass(frozen=True)
class LossSection:
    adv: float = param(0.1, "lambda1: weight of the adversarial loss (0: no discriminator is trained)")
    render: float = param(0.5, "lambda2: weight of the log rendering loss")
    svbrdf: float = param(0.5, "lambda3: weight of the L1 map loss")
    gan: str = param(
        "bce", "adversarial objective: bce (eq. 3, non-saturating) or lsgan", choices=("bce", "lsgan")
    )
    maps: dict = param(
        dict(MAP_WEIGHTS),
        "per-map weights of the L1 map loss (the paper's: normal, diffuse 1; roughness, specular 0.5)",
    )
    eps: float = param(0.01, "offset of the log in the rendering loss")

    def __post_init__(self):
        for name in ("adv", "render", "svbrdf"):
            _finite(getattr(self, name), name)
        _finite(self.eps, "eps", positive=True)  # log(0) of a black rendering is -inf
        if self.adv + self.render + self.svbrdf <= 0:
            raise ValueError(
                f"at least one of adv, render and svbrdf must be positive, got {self.adv}, "
                f"{self.render} and {self.svbrdf}"
            )
        unknown = set(self.maps) - set(MAP_WEIGHTS)
        if unknown:
            raise ValueError(
                f"maps: unknown map {sorted(unknown)}; maps are normal, diffuse, roughness, specular"
            )
        for name, weight in self.maps.items():
            _finite(weight, f"maps.{name}")
        if self.svbrdf > 0 and not any(w > 0 for w in self.maps.values()):
            raise ValueError(
                f"svbrdf is {self.svbrdf} but every weight of maps is 0 ({self.maps}), so the map loss "
                "is always 0; give a map a weight, or set svbrdf to 0"
            )


#: How the rates follow the batch (``optim.batch_rule``).
BATCH_RULES = ("none", "sqrt", "linear")


@dataclass(frozen=True)
class OptimSection:
    lr: float = param(2e-5, "Adam learning rate of the generator")
    d_lr: float = param(2e-5, "Adam learning rate of the discriminator")
    betas: tuple[float, float] = param((0.5, 0.999), "Adam betas")
    g_steps_per_d: int = param(5, "generator steps per discriminator step (paper: 5)")
    decay_every_samples: int | None = param(
        400_000,
        "step decay period in samples seen, whatever the data set size (paper: 2 epochs of 200k "
        "= 400000); None: no decay",
    )
    decay_every_epochs: int | None = param(
        None,
        "the period in epochs instead (set decay_every_samples to null): the same as the paper only "
        "on its 200k samples; on a small data set an epoch is a few steps",
    )
    decay: float = param(0.5, "learning-rate factor at each decay step (paper: halved)")
    warmup_samples: int = param(0, "linear warm-up of both rates over this many samples (0: none)")
    batch_rule: str = param(
        "none",
        "lr and d_lr times 1 (none), sqrt(r) (sqrt) or r (linear), r = batch x processes / batch_reference",
        choices=BATCH_RULES,
    )
    batch_reference: int = param(8, "the batch lr and d_lr are set for (the paper's 8), for batch_rule")

    def __post_init__(self):
        _finite(self.lr, "lr", positive=True)
        _finite(self.d_lr, "d_lr", positive=True)
        for i, beta in enumerate(self.betas):
            _check(_number(beta) and 0 <= beta < 1, f"betas[{i}]", beta, "in [0, 1) (Adam's)")
        _int_at_least(self.g_steps_per_d, "g_steps_per_d", 1)
        for name in ("decay_every_samples", "decay_every_epochs"):
            _int_at_least(getattr(self, name), name, 1, none="no decay")
        if self.decay_every_samples is not None and self.decay_every_epochs is not None:
            raise ValueError(
                f"decay_every_samples={self.decay_every_samples} and decay_every_epochs="
                f"{self.decay_every_epochs} are both set; keep one (--set optim.decay_every_samples=null "
                "to count in epochs)"
            )
        _check(0 < self.decay <= 1, "decay", self.decay, "in (0, 1] (1: no decay)")
        _int_at_least(self.warmup_samples, "warmup_samples", 0)
        _check(
            self.batch_rule in BATCH_RULES, "batch_rule", self.batch_rule, f"one of {', '.join(BATCH_RULES)}"
        )
        _int_at_least(self.batch_reference, "batch_reference", 1)

    def batch_factor(self, per_step: int) -> float:
        """The factor ``batch_rule`` puts on both rates for ``per_step`` samples a step."""
        ratio = per_step / self.batch_reference
        return {"none": 1.0, "sqrt": math.sqrt(ratio), "linear": ratio}[self.batch_rule]


#: What ``train.keep_best`` may choose on (lower is better); never the watched real set, val_real.
KEEP_BEST_METRICS = tuple(f"{p}/rmse/{m}" for p in ("val_fold", "val") for m in (*MAP_WEIGHTS, "render"))


@dataclass(frozen=True)
class TrainSection:
    resolution: int = param(256, "training crop size in pixels")
    batch: int = param(8, "samples per step")
    epochs: int = param(20, "passes over the data")
    max_steps: int | None = param(None, "stop after this many generator steps (None: no limit)")
    max_minutes: float | None = param(None, "stop after this much training time (None: no limit)")
    renderings: int = param(9, "light/view configurations per sample for the rendering loss and D")
    seed: int = param(0, "seed of initialisation, sampling and dropout")
    log_every: int = param(10, "log losses every this many steps")
    validate_every: int = param(500, "validate every this many steps (and at the end)")
    checkpoint_every: int | None = param(
        None,
        "write the full checkpoint (OUT/last.pt) every this many steps, and at the end (None: "
        "by time only, checkpoint_minutes)",
    )
    checkpoint_minutes: float | None = param(
        10.0,
        "write the full checkpoint when this many minutes of wall time have passed since the "
        "last one (None: by steps only); a paper-size one is about 1.2 GB",
    )
    upload_minutes: float | None = param(
        60.0,
        "upload the weights (OUT/weights.pt, no optimiser state) to the MLflow run at most this "
        "often, and always at the end (None: only at the end)",
    )
    render_backend: str = param(
        "compiled",
        "renderer of the loss and discriminator renderings: compiled (torch.compile, 2-3x faster "
        "forward+backward after a compile of seconds) or eager",
        choices=tuple(sorted(BACKENDS)),  # the renderer's backends (svbrdf_render), named once
    )
    clock: str = param(
        "auto",
        "what max_minutes and the logged training time count: cpu (the process's CPU time over its "
        "torch threads, which other programs on the machine cannot tilt), wall, or auto (cpu on a "
        "CPU; on a GPU wall time with the GPU synchronised, i.e. GPU time)",
        choices=("auto", "cpu", "wall"),
    )
    compile: bool = param(
        False,
        "torch.compile the generator and the discriminator (a compile of tens of seconds to "
        "minutes when the fit starts)",
    )
    keep_best: str | None = param(None, "keep the best validation's weights in OUT/best.pt, by this metric: "
                                  "val_fold/rmse/render (the held-out fold) or another of KEEP_BEST_METRICS")
    snapshot_minutes: tuple[float, ...] | None = param(
        None,
        "save the weights when the training time (train.clock) first reaches each of these minutes, "
        "to OUT/snapshots/minutes-M.pt and the MLflow run: one fit gives its model at several "
        "training budgets (svbrdf-bench run --minutes 2,8,32); None: none",
    )
    snapshot_steps: tuple[int, ...] | None = param(
        None, "the same at these step counts (OUT/snapshots/steps-N.pt); None: none"
    )
    channels_last: bool = param(False, "keep the networks' images in NHWC memory layout for the convolutions")
    precision: str = param(
        "fp32",
        "fp32, or bf16: the networks under bfloat16 autocast (the renderer and losses stay float32)",
        choices=("fp32", "bf16"),
    )

    def __post_init__(self):
        _check(
            MIN_RESOLUTION <= self.resolution <= MAX_RESOLUTION,
            "resolution",
            self.resolution,
            f"in [{MIN_RESOLUTION}, {MAX_RESOLUTION}] pixels (and what the generator takes)",
        )
        for name in ("batch", "epochs", "renderings", "log_every", "validate_every"):
            _int_at_least(getattr(self, name), name, 1)
        _int_at_least(self.checkpoint_every, "checkpoint_every", 1, none="by time only")
        for name in ("checkpoint_minutes", "upload_minutes"):
            if getattr(self, name) is not None:
                _finite(getattr(self, name), name, positive=True)
        for name in ("compile", "channels_last"):
            _check(isinstance(getattr(self, name), bool), name, getattr(self, name), "true or false")
        _int_at_least(self.max_steps, "max_steps", 1, none="no limit")
        ok = self.keep_best is None or self.keep_best in KEEP_BEST_METRICS
        _check(ok, "keep_best", self.keep_best, "null or one of " + ", ".join(KEEP_BEST_METRICS) + " (never val_real)")
        if self.max_minutes is not None:
            _finite(self.max_minutes, "max_minutes")  # 0: stop after the first step
        _seed(self.seed, "seed")
        for name, whole in (("snapshot_minutes", False), ("snapshot_steps", True)):
            marks = getattr(self, name)
            ok = marks is None or (
                isinstance(marks, (list, tuple)) and len(marks) > 0
                and all(_number(m) and math.isfinite(m) and m > 0 and (not whole or int(m) == m) for m in marks)
            )  # fmt: skip
            what = "whole numbers of steps > 0" if whole else "minutes > 0"
            _check(ok, name, marks, f"null or a list of {what}")


#: The sections of a recipe and their classes.
SECTIONS: dict[str, type] = {
    "generator": NetworkSection,
    "discriminator": NetworkSection,
    "loss": LossSection,
    "optim": OptimSection,
    "data": DataSection,
    "train": TrainSection,
}
#: The keys a recipe file may hold at its top level.
TOP_LEVEL = {*SECTIONS, "description", "base", "sizes"}


@dataclass(frozen=True)
class Recipe:
    """A resolved recipe: every field known, nothing left to defaults elsewhere."""

    name: str
    size: str
    description: str
    generator: NetworkSection
    discriminator: NetworkSection | None
    loss: LossSection
    optim: OptimSection
    data: DataSection
    train: TrainSection
    source: str

    def to_dict(self) -> dict[str, Any]:
        """Plain data (for MLflow params and the YAML artifact); tuples become lists."""

        def plain(v):
            if dataclasses.is_dataclass(v):
                return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
            if isinstance(v, (tuple, list)):
                return [plain(x) for x in v]
            if isinstance(v, Mapping):
                return {k: plain(x) for k, x in v.items()}
            return v

        return plain(self)

    @property
    def checked(self) -> bool:
        """Whether :func:`~svbrdf_train.recipe.checks.check_recipe` passed this very object."""
        return self.__dict__.get("_checked", False)

    def with_meta(self, *, name: str, size: str, description: str, source: str) -> Recipe:
        """This recipe under another name, size, description and source file; the checks read
        none of these, so a checked recipe stays checked."""
        out = dataclasses.replace(self, name=name, size=size, description=description, source=source)
        if self.checked:
            object.__setattr__(out, "_checked", True)
        return out
