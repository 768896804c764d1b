"""The renderer's accuracy against its time: one table, one row per way of rendering.

Every row renders the same B materials (built-in examples, then seeded random maps) under
the same ``training_scene`` (9 configurations per material: 3 directional, 6 point), so the
render is what one training step's rendering loss computes, ``B x 9`` images of ``S x S``.

Rows:

* ``des18`` for every dtype x backend: float64, float32 and bfloat16 maps, ``eager`` (plain
  torch ops) and ``compiled`` (``torch.compile`` of the shading, with the hand-derived
  fused backward). bfloat16 maps are upcast to float32 inside the renderer, so that row
  measures what quantising the *inputs* to bfloat16 costs.
* float32, for every backend: the Des18 scene with one effect toggled: ``-e`` removes a
  Des18 effect (``-specular`` removes the whole lobe: fresnel and masking go with it),
  ``+e`` adds an image effect (vignetting, exposure, noise, clip, gamma).

Columns: median ``forward`` and ``forward+backward`` time (ms, ``loss = out.mean()``; the
maps require grad in both, as in training) over ``repeats`` timed calls after two warm-up
calls, and their interquartile ranges (``*_iqr_ms``, :mod:`svbrdf_bench.timing`);
``first_call_s``, the first warm-up call (forward+backward; it compiles on the compiled
backend); the max abs and max relative difference of the rendering from a
reference, the eager float64 rendering of the same maps (cast from the float32 ones)
under the same scene and effects; and the max difference of the gradients of
``out.mean()`` with respect to the four maps, relative to the largest reference gradient.
Relative difference: ``|x - ref| / max(|ref|, 1e-4 max|ref|)`` (the floor keeps black
pixels from dividing by zero), as in ``benchmarks/render_speed.py``.

The noise effect draws different numbers in float32 and float64 from one seed, so a
``+noise`` row has no rendering error unless its dtype is float64 (its gradient error is
still measured: the noise is additive).

Timing: the rows take turns, ``repeats`` rounds (each round times every row's forward, then
every row's forward+backward), so that a burst of other work slows every row alike. Each call
is read on the clock of ``torch.utils.benchmark`` (:func:`svbrdf_bench.timing.time_once`), and
the machine's load over the rounds is read once and kept on every row (``Row.load``);
:func:`timing_warning` says in words when it makes the times unreliable.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

import torch

from svbrdf_render import (
    BACKENDS,
    DES18_EFFECTS,
    EFFECTS,
    PHOTO_EFFECTS,
    SVBRDF,
    render,
    training_scene,
)
from svbrdf_render.examples import EXAMPLES, example_material

from .errors import BenchError
from .timing import CPU_WAIT_LIMIT, Load, LoadProbe, summarize, time_once

__all__ = [
    "DTYPES",
    "Row",
    "bench_materials",
    "effect_variants",
    "format_table",
    "measure",
    "metric_key",
    "timing_warning",
    "to_records",
]

DTYPES: dict[str, torch.dtype] = {
    "float64": torch.float64,
    "float32": torch.float32,
    "bfloat16": torch.bfloat16,
}
#: The dtype of the effect-toggle rows (what training renders in).
EFFECT_DTYPE = "float32"
BASELINE = "des18"
_REL_FLOOR = 1e-4


@dataclass
class Row:
    """One way of rendering, timed and compared with the float64 reference.

    Times in ms (``first_call_s`` in s): medians, and interquartile ranges (``*_iqr_ms``);
    errors are NaN where not measured (see ``note``).
    """

    dtype: str
    backend: str
    effects: str  # "des18", "-fresnel", "+noise", ...
    forward_ms: float = math.nan
    forward_backward_ms: float = math.nan
    forward_iqr_ms: float = math.nan
    forward_backward_iqr_ms: float = math.nan
    first_call_s: float = math.nan
    max_abs_error: float = math.nan
    max_rel_error: float = math.nan
    grad_error: float = math.nan
    note: str = ""
    forward_samples: list[float] = field(default_factory=list, repr=False)
    forward_backward_samples: list[float] = field(default_factory=list, repr=False)
    load: Load | None = field(default=None, repr=False)
    """The machine's load over the timed rounds (the same for every row of one table)."""


# -- inputs ---------------------------------------------------------------------------------


def bench_materials(count: int, size: int, seed: int = 0) -> SVBRDF:
    """``count`` float32 materials of ``size x size``: the built-in examples first (tiles,
    brushed metal, leather), then random maps (normals tilted up to ~40 degrees, albedos and
    roughness uniform in [0, 1], so some highlights are as sharp as the renderer allows)."""
    names = list(EXAMPLES)[:count]
    parts = [example_material(name, size) for name in names]
    rest = count - len(parts)
    if rest > 0:
        g = torch.Generator().manual_seed(seed)
        shape = (rest, 1, size, size)
        xy = 0.35 * torch.randn((rest, 2, size, size), generator=g)
        normal = torch.cat([xy, torch.ones(shape)], dim=1)
        normal = normal / normal.norm(dim=1, keepdim=True)
        parts.append(
            SVBRDF(
                normal,
                torch.rand((rest, 3, size, size), generator=g),
                torch.rand(shape, generator=g),
                torch.rand((rest, 3, size, size), generator=g),
            )
        )
    return SVBRDF.cat(parts)


def effect_variants() -> list[tuple[str, tuple[str, ...]]]:
    """``(label, effects)``: the Des18 set, then each Des18 effect off, each image effect on."""
    variants = [(BASELINE, tuple(DES18_EFFECTS))]
    for e in DES18_EFFECTS:
        # fresnel and masking modify the lobe: without the specular lobe they go too.
        drop = {"specular", "fresnel", "masking"} if e == "specular" else {e}
        variants.append((f"-{e}", tuple(x for x in DES18_EFFECTS if x not in drop)))
    extra = [e for e in PHOTO_EFFECTS if e not in DES18_EFFECTS]
    extra += [e for e in ("gamma",) if e in EFFECTS and e not in extra]
    for e in extra:
        variants.append((f"+{e}", tuple(DES18_EFFECTS) + (e,)))
    return variants


# -- measuring ------------------------------------------------------------------------------


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _leaves(maps: SVBRDF) -> list[torch.Tensor]:
    return [maps.normal, maps.diffuse, maps.roughness, maps.specular]


def _trainable(maps: SVBRDF, dtype: torch.dtype) -> SVBRDF:
    """Detached copies in ``dtype`` that require grad (leaves, as a network's output is not,
    but the backward then reaches them)."""
    out = maps.detach().to(dtype)
    out = SVBRDF(*(t.detach().clone().requires_grad_(True) for t in _leaves(out)), validate=False)
    return out


def _clear(maps: SVBRDF) -> None:
    for t in _leaves(maps):
        t.grad = None


def _diff(x: torch.Tensor, ref: torch.Tensor) -> tuple[float, float]:
    """Max abs difference and max ``|x - ref| / max(|ref|, 1e-4 max|ref|)``."""
    d = (x.double() - ref).abs()
    floor = max(_REL_FLOOR * float(ref.abs().max()), 1e-300)
    return float(d.max()), float((d / ref.abs().clamp_min(floor)).max())


def _grad_error(grads: Sequence[torch.Tensor | None], ref: Sequence[torch.Tensor | None]) -> float:
    """Max over the four maps of ``max |g - g_ref| / max |g_ref|``; a map that no declared
    effect reads (the diffuse map without ``diffuse``) gets no gradient: zero."""
    worst = 0.0
    for g, r in zip(grads, ref, strict=True):
        if g is None and r is None:
            continue
        g = torch.zeros_like(r) if g is None else g
        r = torch.zeros_like(g, dtype=torch.float64) if r is None else r
        scale = float(r.abs().max())
        d = float((g.double() - r).abs().max())
        worst = max(worst, d / scale if scale > 0 else d)
    return worst


def _reason(exc: BaseException) -> str:
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    return f"{type(exc).__name__}: {lines[0][:160]}" if lines else type(exc).__name__


@dataclass
class _Case:
    row: Row
    effects: tuple[str, ...]
    run: Callable[[], torch.Tensor]
    maps: SVBRDF
    ok: bool = True


def measure(
    size: int = 256,
    materials: int = 8,
    repeats: int = 5,
    backends: Sequence[str] = ("eager", "compiled"),
    dtypes: Sequence[str] = ("float64", "float32", "bfloat16"),
    effects: str | Sequence[str] = "each",
    *,
    seed: int = 0,
    device: str | torch.device = "cpu",
    progress: Callable[[str], None] | None = None,
) -> list[Row]:
    """Time and compare every row (see the module docstring); returns them in table order.

    Args:
        size, materials: maps of ``materials x size x size``; 9 configurations each.
        repeats: timed calls per row (the median is reported), after two warm-up calls.
        backends: among ``"eager"``, ``"compiled"``.
        dtypes: among ``"float64"``, ``"float32"``, ``"bfloat16"`` (Des18 rows).
        effects: ``"each"`` for every effect toggle (float32, every backend), ``"none"``
            for none, or a list of labels such as ``["-fresnel", "+noise"]``.
        progress: called with one line per step (warm-ups, rounds, references).

    A row that fails (a compiler missing, say) keeps NaN times and says why in ``note``;
    a compile failure that the renderer survives by running eager is noted too.
    """
    say = progress or (lambda msg: None)
    if size < 1 or materials < 1 or repeats < 1:
        raise BenchError(f"size, materials and repeats must be >= 1, got {size}, {materials} and {repeats}")
    backends = list(dict.fromkeys(backends))
    dtypes = list(dict.fromkeys(dtypes))
    for b in backends:
        if b not in BACKENDS:
            raise BenchError(f"unknown backend {b!r}; choose from {', '.join(BACKENDS)}")
    for d in dtypes:
        if d not in DTYPES:
            raise BenchError(f"unknown dtype {d!r}; choose from {', '.join(DTYPES)}")
    if not backends or not dtypes:
        raise BenchError("at least one backend and one dtype are needed")
    variants = dict(effect_variants())
    if isinstance(effects, str):
        if effects not in ("each", "none"):
            raise BenchError(f"effects must be 'each', 'none' or a list of labels, got {effects!r}")
        toggles = [k for k in variants if k != BASELINE] if effects == "each" else []
    else:
        toggles = list(dict.fromkeys(effects))
        unknown = [t for t in toggles if t not in variants]
        if unknown:
            raise BenchError(f"unknown effect toggle(s) {unknown}; choose from {', '.join(variants)}")
        toggles = [t for t in toggles if t != BASELINE]
    try:
        dev = torch.device(device)
        torch.empty(0, device=dev)
    except (RuntimeError, ValueError) as e:
        raise BenchError(f"device {device!r} is not usable here ({_reason(e)})") from None

    base = bench_materials(materials, size, seed).to(dev)
    scene = training_scene(materials, generator=torch.Generator().manual_seed(seed)).to(dev)
    maps_by_dtype: dict[str, SVBRDF] = {}

    def maps_for(dtype: str) -> SVBRDF:
        if dtype not in maps_by_dtype:
            maps_by_dtype[dtype] = _trainable(base, DTYPES[dtype])
        return maps_by_dtype[dtype]

    cases: list[_Case] = []

    def add(dtype: str, backend: str, label: str) -> None:
        fx = variants[label]
        sc = scene.with_effects(fx)
        maps = maps_for(dtype)

        def run(maps=maps, sc=sc, backend=backend) -> torch.Tensor:
            return render(maps, sc, backend=backend)

        cases.append(_Case(Row(dtype, backend, label), fx, run, maps))

    for dtype in dtypes:
        for backend in backends:
            add(dtype, backend, BASELINE)
    for backend in backends:
        if toggles and EFFECT_DTYPE not in dtypes:
            add(EFFECT_DTYPE, backend, BASELINE)
        for label in toggles:
            add(EFFECT_DTYPE, backend, label)

    def forward(case: _Case) -> torch.Tensor:
        _clear(case.maps)
        out = case.run()
        _sync(dev)
        return out

    def forward_backward(case: _Case) -> torch.Tensor:
        out = forward(case)
        out.mean().backward()
        _sync(dev)
        return out

    def timed(fn: Callable[[], object]) -> float:
        _sync(dev)
        return time_once(fn)

    # -- warm-up: the first call compiles (compiled backend) --------------------------------
    compile_failed = False
    for i, case in enumerate(cases, 1):
        row = case.row
        name = f"{row.dtype}/{row.backend}/{row.effects}"
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                t0 = time.perf_counter()
                forward_backward(case)
                row.first_call_s = time.perf_counter() - t0
                forward_backward(case)  # allocator and caches settled
            except Exception as e:  # a compiler missing, out of memory: note it, go on
                case.ok = False
                row.note = f"failed: {_reason(e)}"
        # The renderer's own words when it falls back to eager (svbrdf_render.renderer).
        failures = [
            str(w.message)
            for w in caught
            if str(w.message).startswith(("torch.compile failed", "torch.compile unavailable"))
        ]
        for w in caught:  # the others, as if not caught
            if str(w.message) not in failures:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        if failures:
            compile_failed = True
            row.note = f"{failures[0][:160]} (timed eager)"
        elif compile_failed and row.backend == "compiled" and case.ok and not row.note:
            row.note = "torch.compile failed on an earlier row: this one may run eager"
        _clear(case.maps)
        say(
            f"warm-up {i}/{len(cases)} {name}: first call {row.first_call_s:.2f} s"
            + (f" ({row.note})" if row.note else "")
        )

    # -- timing: the rows take turns -------------------------------------------------------
    live = [c for c in cases if c.ok]
    probe = LoadProbe(torch.get_num_threads())
    for r in range(repeats):
        for case in live:
            case.row.forward_samples.append(timed(lambda case=case: forward(case)))
        for case in live:
            case.row.forward_backward_samples.append(timed(lambda case=case: forward_backward(case)))
        for case in live:
            _clear(case.maps)
        say(f"round {r + 1}/{repeats} timed ({len(live)} rows)")
    load = probe.read()
    for case in live:
        fwd, both = summarize(case.row.forward_samples), summarize(case.row.forward_backward_samples)
        case.row.forward_ms, case.row.forward_iqr_ms = fwd.median_ms, fwd.iqr_ms
        case.row.forward_backward_ms, case.row.forward_backward_iqr_ms = both.median_ms, both.iqr_ms
        case.row.load = load
    if live:
        say(f"load while timing: {load.words()}")

    # -- accuracy: against the eager float64 rendering, one reference per effect set -------
    by_effects: dict[str, list[_Case]] = {}
    for case in live:
        by_effects.setdefault(case.row.effects, []).append(case)
    for j, (label, group) in enumerate(by_effects.items(), 1):
        ref_maps = _trainable(base, torch.float64)
        ref = render(ref_maps, scene.with_effects(variants[label]))
        ref.mean().backward()
        ref = ref.detach()
        ref_grads = [t.grad for t in _leaves(ref_maps)]
        for case in group:
            out = forward_backward(case).detach()
            row = case.row
            if "noise" not in case.effects or row.dtype == "float64":
                row.max_abs_error, row.max_rel_error = _diff(out, ref)
            elif not row.note:
                row.note = "noise draws differ between dtypes: no rendering error"
            row.grad_error = _grad_error([t.grad for t in _leaves(case.maps)], ref_grads)
            _clear(case.maps)
            del out
        del ref, ref_grads, ref_maps
        say(f"accuracy {j}/{len(by_effects)}: {label} against float64")
    return [c.row for c in cases]


# -- output ---------------------------------------------------------------------------------

COLUMNS = (
    ("dtype", "dtype"),
    ("backend", "backend"),
    ("effects", "effects"),
    ("forward_ms", "fwd ms"),
    ("forward_backward_ms", "fwd+bwd ms"),
    ("forward_iqr_ms", "fwd IQR ms"),
    ("forward_backward_iqr_ms", "fwd+bwd IQR ms"),
    ("first_call_s", "first call s"),
    ("max_abs_error", "max abs err"),
    ("max_rel_error", "max rel err"),
    ("grad_error", "grad err"),
    ("note", "note"),
)


def _fmt(key: str, value) -> str:
    if isinstance(value, str):
        return value.replace("|", "/")
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if key.endswith("_ms"):
        return f"{value:.1f}" if value >= 10 else f"{value:.2f}"
    if key == "first_call_s":
        return f"{value:.2f}"
    if value == 0:
        return "0"
    return f"{value:.2e}"


def format_table(rows: Sequence[Row]) -> str:
    """A Markdown table, one line per row; ``-`` where a value was not measured."""
    keep = [c for c in COLUMNS if c[0] != "note" or any(r.note for r in rows)]
    head = [title for _, title in keep]
    align = ["---" if key in ("dtype", "backend", "effects", "note") else "---:" for key, _ in keep]
    lines = ["| " + " | ".join(head) + " |", "| " + " | ".join(align) + " |"]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(key, getattr(r, key)) for key, _ in keep) + " |")
    return "\n".join(lines)


def timing_warning(rows: Sequence[Row]) -> str | None:
    """A sentence when the load over the timed rounds makes the times unreliable, else None."""
    load = next((r.load for r in rows if r.load is not None), None)
    if load is None or not load.unreliable:
        return None
    return (
        f"warning: the times are unreliable: the machine was busy while they were measured ({load.words()}); "
        f"above {100 * CPU_WAIT_LIMIT:.0f}% of the time waiting for a CPU a time is inflated by more than "
        "the spread expected on an idle machine, by an amount that depends on what else ran"
    )


def to_records(rows: Sequence[Row]) -> list[dict]:
    """Plain dicts (CSV/JSON): the table's columns, NaN as None, the timing samples, and the load
    over the timed rounds (``load_cpu_wait``, ``load_other_cpus``, ``load_average``,
    ``load_unreliable``; None where not read)."""
    out = []
    for r in rows:
        d = asdict(r)
        d.pop("load")
        load = r.load
        d |= {
            "load_cpu_wait": load.cpu_wait if load else None,
            "load_other_cpus": load.other_cpus if load else None,
            "load_average": load.load_average if load else None,
            "load_unreliable": load.unreliable if load else None,
        }
        for k, v in d.items():
            if isinstance(v, float) and math.isnan(v):
                d[k] = None
        out.append(d)
    return out


def metric_key(row: Row, name: str) -> str:
    """``name/dtype/backend/effects`` with MLflow-safe effects (``no-fresnel``, ``with-noise``)."""
    label = row.effects
    if label.startswith("-"):
        label = "no-" + label[1:]
    elif label.startswith("+"):
        label = "with-" + label[1:]
    return f"{name}/{row.dtype}/{row.backend}/{label}"
