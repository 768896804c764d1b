#!/usr/bin/env python
"""How fast the renderer is on this machine: a benchmark, not a test.

Renders B materials x K light/view configurations (default 8 x 9 at 256 x 256, float32,
the shape of one training step's rendering loss) and prints Markdown tables:

1. Backends. The straightforward eager implementation (``render_reference``), the staged
   eager renderer (``render(..., backend="eager")``) and the fused one
   (``backend="compiled"``: ``torch.compile`` of the shading stages), on K point
   light/camera configurations shared by the B materials, Des18 effects, so that all
   three compute the same formulas. Then the staged renderer on the real
   ``training_scene`` (3 directional + 6 point configurations per material).
   Columns: forward ms, forward+backward ms, megapixel-renders per second
   (``B*K*H*W / time / 1e6``) and the forward+backward speed-up over the reference.
2. Per-effect cost of the staged eager renderer: the Des18 scene with each shading or
   light effect removed and with each image effect added, as the change in ms against
   the Des18 scene (``--effects both`` adds the compiled backend; each shading variant
   then compiles once more).
3. Sanity: max abs/rel difference of the staged and compiled renderings from the
   reference on the benchmark inputs, in float32 and against a float64 reference.

Timing: every measurement is warmed up first (the compiled path's first call compiles;
that time is reported separately), then the median of ``--repeats`` runs is taken. The
backends take turns (round robin) and each effect variant alternates with the Des18
scene, so that a burst of other work on the machine does not land on one row only.
``--order sequential`` times each backend in a block of its own instead. The eager paths
allocate ~1 GB of fresh tensors per forward+backward, so their time depends on the
allocator state (page faults) that the previous work left; the order changes it.
"forward" is the forward pass with autograd recording (the maps require grad), as in a
training step; "forward+backward" adds ``out.mean().backward()``. torch's thread count
is left at its default. Progress goes to stderr, the tables to stdout.

Usage::

    .venv/bin/python benchmarks/render_speed.py              # the full run (a few minutes)
    .venv/bin/python benchmarks/render_speed.py --quick      # a smoke run (64 x 64, 2 repeats)
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable

import torch

import svbrdf_render
from svbrdf_render import (
    DES18_EFFECTS,
    SVBRDF,
    Camera,
    PointLight,
    Scene,
    render,
    render_reference,
    training_scene,
)
from svbrdf_render.sampling import cosine_weighted_directions

SHADING_EFFECTS = ("diffuse", "specular", "fresnel", "masking", "cosine", "falloff")
IMAGE_EFFECTS = ("vignetting", "exposure", "noise", "clip", "gamma")
#: The issue's target: fused forward+backward at least this much faster than the reference.
TARGET_SPEEDUP = 3.0


# -- inputs -------------------------------------------------------------------------------


def random_materials(batch: int, size: int, seed: int) -> SVBRDF:
    """Random but valid maps (every value in range), each requiring grad.

    Normals tilted up to ~40 degrees, albedos and roughness uniform in [0, 1].
    """
    g = torch.Generator().manual_seed(seed)
    shape = (batch, 1, size, size)
    xy = 0.35 * torch.randn((batch, 2, size, size), generator=g)
    normal = torch.cat([xy, torch.ones(shape)], dim=1)
    normal = normal / normal.norm(dim=1, keepdim=True)
    maps = SVBRDF(
        normal,
        torch.rand((batch, 3, size, size), generator=g),
        torch.rand(shape, generator=g),
        torch.rand((batch, 3, size, size), generator=g),
    )
    for t in (maps.normal, maps.diffuse, maps.roughness, maps.specular):
        t.requires_grad_(True)
    return maps


def shared_point_configs(k: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``k`` point light/camera pairs, evaluation-scene style.

    Returns light and view positions ``(k, 3)`` and intensities ``(k,)``.

    Directions cosine-weighted within 45 degrees of the normal, distances uniform in
    [1.5, 3], intensity ``pi d^2`` (unit-``pi`` irradiance at the patch centre).
    """
    g = torch.Generator().manual_seed(seed)
    v_dir = cosine_weighted_directions((k,), g, high=0.5)
    l_dir = cosine_weighted_directions((k,), g, high=0.5)
    v_dist = 1.5 + 1.5 * torch.rand((k, 1), generator=g)
    l_dist = 1.5 + 1.5 * torch.rand((k, 1), generator=g)
    return l_dir * l_dist, v_dir * v_dist, math.pi * l_dist.squeeze(-1) ** 2


def point_scene(light, view, intensity, effects=DES18_EFFECTS) -> Scene:
    return Scene(Camera(view), (PointLight(light, intensity),), effects)


# -- timing -------------------------------------------------------------------------------


class Progress:
    def __init__(self, total: int):
        self.total, self.done, self.start = total, 0, time.perf_counter()

    def __call__(self, what: str) -> None:
        self.done += 1
        elapsed = time.perf_counter() - self.start
        print(f"[{self.done:>2}/{self.total} {elapsed:6.1f}s] {what}", file=sys.stderr, flush=True)


def _clear_grads(maps: SVBRDF) -> None:
    for t in (maps.normal, maps.diffuse, maps.roughness, maps.specular):
        t.grad = None


def _ms(fn: Callable[[], object]) -> float:
    t0 = time.perf_counter()
    fn()
    return 1e3 * (time.perf_counter() - t0)


def _fwd_bwd(forward: Callable[[], torch.Tensor], maps: SVBRDF) -> None:
    _clear_grads(maps)
    forward().mean().backward()


def measure_round_robin(
    runs: list[tuple[str, Callable[[], torch.Tensor]]],
    maps: SVBRDF,
    repeats: int,
    progress: Callable[[str], None],
) -> list[tuple[float, list[float], list[float]]]:
    """Per run: (first-call seconds, forward ms samples, forward+backward ms samples).

    Each run is warmed up (its first call, timed, compiles where it compiles), then the
    runs take turns, ``repeats`` rounds, so that a burst of other work on the machine
    slows every backend alike instead of one of them.
    """
    firsts = []
    for name, fn in runs:
        t0 = time.perf_counter()
        _fwd_bwd(fn, maps)
        firsts.append(time.perf_counter() - t0)
        _fwd_bwd(fn, maps)  # a second warm-up: allocator and caches settled
        progress(f"warm-up {name}: first call {firsts[-1]:.1f} s")
    fwd: list[list[float]] = [[] for _ in runs]
    both: list[list[float]] = [[] for _ in runs]
    for r in range(repeats):
        for i, (_, fn) in enumerate(runs):
            fwd[i].append(_ms(fn))
        for i, (_, fn) in enumerate(runs):
            both[i].append(_ms(lambda fn=fn: _fwd_bwd(fn, maps)))
        progress(f"round {r + 1}/{repeats}: forward+backward "
                 + ", ".join(f"{b[-1]:.0f}" for b in both) + " ms")
    _clear_grads(maps)
    return list(zip(firsts, fwd, both, strict=True))


def measure_paired(base: Callable[[], torch.Tensor], variant: Callable[[], torch.Tensor],
                   maps: SVBRDF, repeats: int) -> dict[str, list[float]]:
    """Interleaved timings (ms) of ``variant`` and ``base``, and their paired differences."""
    _fwd_bwd(variant, maps)  # warm-up (and the compile of a new variant)
    _fwd_bwd(base, maps)
    out: dict[str, list[float]] = {k: [] for k in ("fwd", "both", "base_fwd", "base_both",
                                                   "d_fwd", "d_both")}
    for _ in range(repeats):
        b, v = _ms(base), _ms(variant)
        out["base_fwd"].append(b)
        out["fwd"].append(v)
        out["d_fwd"].append(v - b)
        b = _ms(lambda: _fwd_bwd(base, maps))
        v = _ms(lambda: _fwd_bwd(variant, maps))
        out["base_both"].append(b)
        out["both"].append(v)
        out["d_both"].append(v - b)
    _clear_grads(maps)
    return out


# -- tables -------------------------------------------------------------------------------


def _table(header: list[str], rows: list[list[str]]) -> str:
    align = ["---"] + ["---:"] * (len(header) - 1)
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join(align) + " |"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _diff(a: torch.Tensor, ref: torch.Tensor) -> tuple[float, float]:
    """Max abs difference, and max relative difference ``|a-ref| / max(|ref|, 1e-4 max|ref|)``."""
    a, ref = a.double(), ref.double()
    d = (a - ref).abs()
    floor = 1e-4 * float(ref.abs().max())
    return float(d.max()), float((d / ref.abs().clamp_min(floor)).max())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="render_speed.py",
        description=(
            "Time the svbrdf renderer on this machine: reference eager vs staged eager vs "
            "compiled (torch.compile) forward and forward+backward, megapixel-renders per "
            "second, and the cost of each effect. Prints Markdown tables to stdout, progress "
            "to stderr. The default run takes a few minutes on 2 CPU cores."
        ),
        epilog=(
            "examples:\n"
            "  .venv/bin/python benchmarks/render_speed.py          # 8 x 9 x 256^2, 5 repeats\n"
            "  .venv/bin/python benchmarks/render_speed.py --quick  # smoke run\n"
            "  .venv/bin/python benchmarks/render_speed.py --effects both --repeats 3\n"
            "Set TORCHINDUCTOR_FORCE_DISABLE_CACHES=1 to time a cold compile."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--repeats", type=int, default=None,
                    help="timed runs per measurement (median reported); default 5, --quick 2")
    ap.add_argument("--size", type=int, default=None,
                    help="map size in pixels (square); default 256, --quick 64")
    ap.add_argument("--batch", type=int, default=8, help="materials per render (default 8)")
    ap.add_argument("--configs", type=int, default=9,
                    help="light/view configurations of the shared scene (default 9; the "
                         "training scene always has 3 directional + 6 point)")
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: --size 64 --repeats 2 (compiling still takes its time)")
    ap.add_argument("--effects", choices=("eager", "compiled", "both", "none"), default="eager",
                    help="backends for the per-effect table; 'compiled'/'both' compile every "
                         "shading variant (about 20 s each on 2 cores); default eager")
    ap.add_argument("--order", choices=("round-robin", "sequential"), default="round-robin",
                    help="round-robin (default): the backends take turns, each round; "
                         "sequential: each backend's runs in a block of their own (the eager "
                         "paths' page faults then depend on what ran just before)")
    ap.add_argument("--seed", type=int, default=0,
                    help="seed of the materials and configurations (default 0)")
    args = ap.parse_args(argv)
    size = args.size if args.size is not None else (64 if args.quick else 256)
    repeats = args.repeats if args.repeats is not None else (2 if args.quick else 5)
    if size < 1 or repeats < 1 or args.batch < 1 or args.configs < 1:
        ap.error("--size, --repeats, --batch and --configs must be positive")
    b, k = args.batch, args.configs

    effect_backends = {"eager": ["eager"], "compiled": ["compiled"], "both": ["eager", "compiled"],
                       "none": []}[args.effects]
    variants = [("Des18", DES18_EFFECTS)]  # the baseline, then one variant per effect
    for e in SHADING_EFFECTS:
        # fresnel and masking modify the lobe: without the specular lobe they go too.
        drop = {"specular", "fresnel", "masking"} if e == "specular" else {e}
        label = "- specular (whole lobe)" if e == "specular" else f"- {e}"
        variants.append((label, tuple(x for x in DES18_EFFECTS if x not in drop)))
    for e in IMAGE_EFFECTS:
        variants.append((f"+ {e}", DES18_EFFECTS + (e,)))
    n_backend_lines = 5 + (repeats if args.order == "round-robin" else 0)
    total = n_backend_lines + (len(variants) - 1) * len(effect_backends) + 1
    progress = Progress(total)

    maps = random_materials(b, size, args.seed)
    light, view, intensity = shared_point_configs(k, args.seed)
    scene = point_scene(light, view, intensity)
    train = training_scene(b, generator=torch.Generator().manual_seed(args.seed))
    mpix = b * k * size * size / 1e6
    mpix_train = b * int(train.config_shape[1]) * size * size / 1e6

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
    if load > 0.5 * (os.cpu_count() or 1):
        print(
            f"warning: 1-minute load average {load:.1f} on {os.cpu_count()} CPUs: other processes "
            "are running and the timings will be slower and noisier",
            file=sys.stderr,
            flush=True,
        )
    print(
        f"svbrdf render benchmark: {b} materials x {k} configurations at {size}x{size}, float32, "
        f"median of {repeats}; torch {torch.__version__}, {torch.get_num_threads()} threads, "
        f"{platform.processor() or platform.machine()}, svbrdf-render {svbrdf_render.__version__}",
        file=sys.stderr,
        flush=True,
    )

    # -- backends -----------------------------------------------------------------------
    runs = [
        ("reference eager (`render_reference`)", "shared",
         lambda: render_reference(maps, light, view, intensity)),
        ("staged eager (`backend=\"eager\"`)", "shared", lambda: render(maps, scene)),
        ("compiled, fused (`backend=\"compiled\"`)", "shared",
         lambda: render(maps, scene, backend="compiled")),
        ("staged eager, `training_scene`", "train", lambda: render(maps, train)),
        ("compiled, `training_scene`", "train", lambda: render(maps, train, backend="compiled")),
    ]
    if args.order == "round-robin":
        measured = measure_round_robin([(n, fn) for n, _, fn in runs], maps, repeats, progress)
    else:  # each backend in a block of its own
        measured = []
        for n, _, fn in runs:
            measured += measure_round_robin([(n, fn)], maps, repeats, lambda msg: None)
            progress(f"{n}: measured")
    results = []
    for (name, which, _), (first, fwd_s, both_s) in zip(runs, measured, strict=True):
        fwd, both = statistics.median(fwd_s), statistics.median(both_s)
        results.append((name, first, fwd, both, mpix if which == "shared" else mpix_train))
        note = f", first call {first:.1f} s" if "compiled" in name else ""
        print(f"  {name}: forward {fwd:.1f} ms, forward+backward {both:.1f} ms{note}",
              file=sys.stderr, flush=True)
    ref_both = results[0][3]
    rows = []
    for name, _first, fwd, both, mp in results:
        rows.append([name, f"{fwd:.1f}", f"{both:.1f}", f"{mp / (fwd / 1e3):.1f}",
                     f"{mp / (both / 1e3):.1f}", f"{ref_both / both:.2f}x"])
    compile_notes = [
        f"{name}: {first:.1f} s" for name, first, *_ in results if "compiled" in name
    ]

    # -- per-effect ---------------------------------------------------------------------
    # Each variant is timed interleaved with the Des18 scene (A B A B ...) and the delta is
    # the median of the paired differences, so that drift (other processes, allocator
    # state) cancels instead of showing up as an effect's cost.
    effect_rows = []
    des18 = scene.with_effects(DES18_EFFECTS)
    for backend in effect_backends:
        base_fn = lambda be=backend: render(maps, des18, backend=be)  # noqa: E731
        base_fwd, base_both = [], []
        rows_b = []
        for label, effects in variants[1:]:
            sc = scene.with_effects(effects)
            fn = lambda sc=sc, be=backend: render(maps, sc, backend=be)  # noqa: E731
            p = measure_paired(base_fn, fn, maps, repeats)
            base_fwd += p["base_fwd"]
            base_both += p["base_both"]
            fwd, both = statistics.median(p["fwd"]), statistics.median(p["both"])
            d_fwd, d_both = statistics.median(p["d_fwd"]), statistics.median(p["d_both"])
            progress(f"{backend} {label}: forward {fwd:.1f} ms ({d_fwd:+.1f}), "
                     f"forward+backward {both:.1f} ms ({d_both:+.1f})")
            rows_b.append([backend, label, f"{fwd:.1f}", f"{d_fwd:+.1f}", f"{both:.1f}",
                           f"{d_both:+.1f}"])
        effect_rows.append([backend, "Des18 (all runs)", f"{statistics.median(base_fwd):.1f}", "",
                            f"{statistics.median(base_both):.1f}", ""])
        effect_rows += rows_b

    # -- sanity -------------------------------------------------------------------------
    with torch.no_grad():
        ref32 = render_reference(maps, light, view, intensity)
        ref64 = render_reference(maps.to(torch.float64), light.double(), view.double(),
                                 intensity.double())
        outs = {
            "reference eager (float32)": ref32,
            "staged eager": render(maps, scene),
            "compiled": render(maps, scene, backend="compiled"),
        }
        sanity_rows = []
        for name, out in outs.items():
            a32, r32 = _diff(out, ref32)
            a64, r64 = _diff(out, ref64)
            sanity_rows.append([name, f"{a32:.3g}", f"{r32:.3g}", f"{a64:.3g}", f"{r64:.3g}"])
        peak = float(ref64.abs().max())
        del ref32, ref64, outs
    progress("sanity: differences from the reference")

    # -- print --------------------------------------------------------------------------
    print(
        f"### Render speed: {b} materials x {k} configurations, {size}x{size}, float32 "
        f"(torch {torch.__version__}, {torch.get_num_threads()} threads, {os.cpu_count()} CPUs, "
        f"median of {repeats}, {args.order})\n"
    )
    print(_table(["backend", "forward ms", "fwd+bwd ms", "Mpix-renders/s fwd",
                  "Mpix-renders/s fwd+bwd", "fwd+bwd speed-up vs reference"], rows))
    print(
        f"\nShared scene: {k} point light/camera pairs, Des18 effects (what `render_reference` "
        f"computes). `training_scene`: 3 directional + 6 point configurations per material. "
        f"On `training_scene` the compiled path is {results[3][3] / results[4][3]:.2f}x the "
        f"staged eager one (fwd+bwd). "
        f"Mpix-renders = {b}*{k}*{size}*{size}/1e6 = {mpix:.2f} per call. "
        f"First compiled call (compiles forward and backward; may come from Inductor's on-disk "
        f"cache): " + "; ".join(compile_notes) + "."
    )
    fused = ref_both / results[2][3]
    target = f"Target: fused fwd+bwd >= {TARGET_SPEEDUP:g}x the reference at 8 x 9 x 256 x 256"
    if (b, k, size) == (8, 9, 256):
        print(f"\n{target}: {'met' if fused >= TARGET_SPEEDUP else 'NOT met'} ({fused:.2f}x).")
    else:
        print(f"\n{target}: not evaluated at {b} x {k} x {size} x {size} ({fused:.2f}x here).")
    if load > 0.5 * (os.cpu_count() or 1):
        print(f"\nNote: the 1-minute load average was {load:.1f} before the run (other processes).")
    if effect_rows:
        print(f"\n### Per-effect cost ({size}x{size}, shared scene; delta against Des18)\n")
        print(_table(["backend", "scene", "forward ms", "delta fwd ms", "fwd+bwd ms",
                      "delta fwd+bwd ms"], effect_rows))
        print(
            "\n`- e`: the Des18 scene without effect e (a negative delta is what e costs); "
            "`+ e`: with image effect e added. Each delta is the median of paired differences "
            "against the Des18 scene timed alternately; a few ms is within timing noise."
        )
    print("\n### Sanity: difference from `render_reference` on the benchmark inputs\n")
    print(_table(["renderer", "max abs vs ref float32", "max rel vs ref float32",
                  "max abs vs ref float64", "max rel vs ref float64"], sanity_rows))
    print(
        f"\nrel = |x - ref| / max(|ref|, 1e-4 * max|ref|); peak radiance {peak:.4g}. The "
        "float32 reference forms cos^2 (alpha^2 - 1) + 1 by subtraction and loses digits in "
        "sharp highlights; the float64 reference shows which float32 result is closer."
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
