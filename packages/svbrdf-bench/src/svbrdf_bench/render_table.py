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
:func:`~svbrdf_bench.render_rows.timing_warning` says in words when it makes the times unreliable.

:func:`measure` reads as its steps: the rows (``_cases``), their warm-up, the timed rounds, then
the accuracy against the reference. The rows, and how they are shown (Markdown, records, metric
names), are :mod:`svbrdf_bench.render_rows`'s.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from svbrdf_render import (
    BACKENDS,
    DES18_EFFECTS,
    EFFECTS,
    SVBRDF,
    render,
    training_scene,
)
from svbrdf_render.examples import EXAMPLES, example_material

from .errors import BenchError
from .render_rows import Row
from .timing import LoadProbe, summarize, time_once

__all__ = ["DTYPES", "bench_materials", "effect_variants", "measure"]

DTYPES: dict[str, torch.dtype] = {
    "float64": torch.float64,
    "float32": torch.float32,
    "bfloat16": torch.bfloat16,
}
#: The dtype of the effect-toggle rows (what training renders in).
EFFECT_DTYPE = "float32"
BASELINE = "des18"
_REL_FLOOR = 1e-4


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
        # an effect that requires another (fresnel, masking: the specular lobe) goes with it
        drop = {e} | {x for x in DES18_EFFECTS if e in EFFECTS[x].requires}
        variants.append((f"-{e}", tuple(x for x in DES18_EFFECTS if x not in drop)))
    for e in (name for name, spec in EFFECTS.items() if spec.phase == "image"):
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
    """One row to measure: its effects, the maps it renders (shared by the rows of one dtype) and
    how it renders them."""

    row: Row
    effects: tuple[str, ...]
    run: Callable[[], torch.Tensor]
    maps: SVBRDF
    ok: bool = True

    def forward(self, device: torch.device) -> torch.Tensor:
        _clear(self.maps)
        out = self.run()
        _sync(device)
        return out

    def forward_backward(self, device: torch.device) -> torch.Tensor:
        out = self.forward(device)
        out.mean().backward()
        _sync(device)
        return out


def measure(
    size: int = 256,
    materials: int = 8,
    repeats: int = 5,
    backends: Sequence[str] = BACKENDS,
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
    backends, dtypes = _checked(backends, BACKENDS, "backend"), _checked(dtypes, DTYPES, "dtype")
    if not backends or not dtypes:
        raise BenchError("at least one backend and one dtype are needed")
    variants = dict(effect_variants())
    toggles = _toggles(effects, variants)
    try:
        dev = torch.device(device)
        torch.empty(0, device=dev)
    except (RuntimeError, ValueError) as e:
        raise BenchError(f"device {device!r} is not usable here ({_reason(e)})") from None

    base = bench_materials(materials, size, seed).to(dev)
    scene = training_scene(materials, generator=torch.Generator().manual_seed(seed)).to(dev)
    cases = _cases(base, scene, variants, dtypes, backends, toggles)
    _warm_up(cases, dev, say)
    _time_rounds([c for c in cases if c.ok], repeats, dev, say)
    _accuracy([c for c in cases if c.ok], base, scene, variants, dev, say)
    return [c.row for c in cases]


def _checked(values: Sequence[str], known, what: str) -> list[str]:
    """``values`` without repeats, each one of ``known``."""
    values = list(dict.fromkeys(values))
    for v in values:
        if v not in known:
            raise BenchError(f"unknown {what} {v!r}; choose from {', '.join(known)}")
    return values


def _toggles(effects: str | Sequence[str], variants: dict[str, tuple[str, ...]]) -> list[str]:
    """The effect-toggle rows asked for: every one (``"each"``), none (``"none"``) or those listed."""
    if isinstance(effects, str):
        if effects not in ("each", "none"):
            raise BenchError(f"effects must be 'each', 'none' or a list of labels, got {effects!r}")
        return [k for k in variants if k != BASELINE] if effects == "each" else []
    toggles = list(dict.fromkeys(effects))
    unknown = [t for t in toggles if t not in variants]
    if unknown:
        raise BenchError(f"unknown effect toggle(s) {unknown}; choose from {', '.join(variants)}")
    return [t for t in toggles if t != BASELINE]


def _cases(
    base: SVBRDF, scene, variants, dtypes: list[str], backends: list[str], toggles: list[str]
) -> list[_Case]:
    """The rows in table order: Des18 for every dtype x backend, then per backend the float32
    effect toggles (after a float32 Des18 row, their baseline, when float32 is not among dtypes)."""
    maps_by_dtype: dict[str, SVBRDF] = {}
    cases: list[_Case] = []

    def add(dtype: str, backend: str, label: str) -> None:
        fx = variants[label]
        sc = scene.with_effects(fx)
        if dtype not in maps_by_dtype:
            maps_by_dtype[dtype] = _trainable(base, DTYPES[dtype])
        maps = maps_by_dtype[dtype]

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
    return cases


def _warm_up(cases: list[_Case], dev: torch.device, say: Callable[[str], None]) -> None:
    """Two forward+backward calls per row, the first timed (``first_call_s``: it compiles on the
    compiled backend); a row that fails is noted and left out of what follows."""
    compile_failed = False
    for i, case in enumerate(cases, 1):
        row = case.row
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                t0 = time.perf_counter()
                case.forward_backward(dev)
                row.first_call_s = time.perf_counter() - t0
                case.forward_backward(dev)  # allocator and caches settled
            except Exception as e:  # a compiler missing, out of memory: note it, go on
                case.ok = False
                row.note = f"failed: {_reason(e)}"
        failures = _compile_failures(caught)
        if failures:
            compile_failed = True
            row.note = f"{failures[0][:160]} (timed eager)"
        elif compile_failed and row.backend == "compiled" and case.ok and not row.note:
            row.note = "torch.compile failed on an earlier row: this one may run eager"
        _clear(case.maps)
        name = f"{row.dtype}/{row.backend}/{row.effects}"
        note = f" ({row.note})" if row.note else ""
        say(f"warm-up {i}/{len(cases)} {name}: first call {row.first_call_s:.2f} s{note}")


def _compile_failures(caught: list[warnings.WarningMessage]) -> list[str]:
    """The renderer's own words when it falls back to eager (svbrdf_render.renderer); the other
    warnings are issued again, as if not caught."""
    failures = [
        str(w.message)
        for w in caught
        if str(w.message).startswith(("torch.compile failed", "torch.compile unavailable"))
    ]
    for w in caught:
        if str(w.message) not in failures:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return failures


def _time_rounds(live: list[_Case], repeats: int, dev: torch.device, say: Callable[[str], None]) -> None:
    """``repeats`` rounds, the rows taking turns (every forward, then every forward+backward);
    each row's medians and IQRs, and the machine's load over the rounds."""

    def timed(fn: Callable[[], object]) -> float:
        _sync(dev)
        return time_once(fn)

    probe = LoadProbe(torch.get_num_threads())
    for r in range(repeats):
        for case in live:
            case.row.forward_samples.append(timed(lambda case=case: case.forward(dev)))
        for case in live:
            case.row.forward_backward_samples.append(timed(lambda case=case: case.forward_backward(dev)))
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


def _accuracy(live: list[_Case], base: SVBRDF, scene, variants, dev: torch.device, say) -> None:
    """Each row's rendering and gradients against the eager float64 rendering of the same maps,
    one reference per effect set."""
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
            out = case.forward_backward(dev).detach()
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


# -- output ---------------------------------------------------------------------------------
