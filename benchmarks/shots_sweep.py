#!/usr/bin/env python
"""Refinement settings of several shots tried side by side (issue 44): the frame rows of
``benchmarks/shots.py`` (its simulator, seeds and scoring), each material simulated once (or
its photos read back from an earlier run's ``OUT``), then ``svbrdf-models predict --shots``
run in this process once per setting and K. A research tool for choosing what the capture
should do; the figures a user gets are ``benchmarks/shots.py``'s.

A setting is ``NAME:KEY=VALUE,...``. With no keys it is the shipped capture
(:func:`svbrdf_models.capture.shots.refine_settings`, the clipped pixels as lower bounds, the
normals pulled towards :data:`~svbrdf_models.capture.shots.SHOTS_PRIOR_RELIEF` of the network's
relief).
Keys:

- ``steps``: ``--refine`` (default 100);
- ``prior``: a factor on a single photo's prior weights (default ``1/K``, the shipped rule);
  ``prior_normal``, ``prior_diffuse``, ``prior_roughness``, ``prior_specular``: one map's;
- ``coarse`` (0: roughness and specular per pixel, the shipped rule), ``lr``,
  ``normal_lr_scale``: :class:`svbrdf_render.RefineSettings`'s;
- ``floor``: 1 keeps a shot's clipped pixels as lower bounds, 0 leaves them out
  (:data:`svbrdf_models.capture.shots.CLIPPED_FLOOR`);
- ``relief``: the share of the network's relief the normals are pulled towards (0 a flat
  surface, 1 the network's normals; :data:`svbrdf_models.capture.shots.SHOTS_PRIOR_RELIEF`);
- ``true_offset``: 1 passes the simulated phone's lens-to-flash offset (``--flash-offset``),
  as a user who measured it.

Settings run in the order given, all materials each, so a run stopped by ``--minutes`` holds
whole settings. Before them each material's ``today`` photo is captured (100 steps, a single
photo's weights; kept in ``OUT/today.json`` and reused), the row the issue's targets pair
against, with ``mean (window)``, the constant maps.

Usage::

    .venv/bin/python benchmarks/shots_sweep.py DATA/unseen-dev --out out/sweep \\
        --set kept --set long:steps=300 --set free:prior=0 [--device cuda] [--minutes 8]

Each setting's per-material figures go to ``OUT/<setting>.json`` as it finishes; the means
(per K and map) and each setting's paired difference against the first are printed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import shots as bench  # noqa: E402

MAPS = ("normal", "diffuse", "roughness", "specular")
KEYS = {"steps": int, "prior": float, **{f"prior_{m}": float for m in MAPS}, "coarse": int, "lr": float,
        "normal_lr_scale": float, "floor": int, "relief": float, "true_offset": int}  # fmt: skip
SHOWN = ("normal", "diffuse", "roughness", "specular", "render", "relight", "seconds")


def parse_setting(text: str) -> tuple[str, dict]:
    """``name:key=value,...`` as (name, {key: value}); ArgumentTypeError naming what is wrong."""
    name, _, rest = text.partition(":")
    if not name.strip():
        raise argparse.ArgumentTypeError(f"a setting needs a name before ':', got {text!r}")
    values: dict = {}
    for part in filter(None, (p.strip() for p in rest.split(","))):
        key, _, value = part.partition("=")
        if key not in KEYS:
            raise argparse.ArgumentTypeError(f"{text!r}: unknown key {key!r}; keys: {', '.join(KEYS)}")
        try:
            values[key] = KEYS[key](value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: {key} must be a number, got {value!r}") from None
    return name.strip(), values


def settings_for(values: dict):
    """A replacement for ``refine_settings``: the shipped K shots' settings
    (:func:`svbrdf_models.capture.shots.refine_settings`) with what ``values`` changes."""
    from svbrdf_models.capture.shots import refine_settings as shipped
    from svbrdf_render import RefineSettings

    def refine_settings(shots: int):
        base = shipped(shots)
        if base is None:
            return None
        single = RefineSettings().prior  # the factors of ``prior`` are on a single photo's weights
        prior = dict(base.prior)
        for name in prior:
            factor = values.get(f"prior_{name}", values.get("prior"))
            if factor is not None:
                prior[name] = single[name] * factor
        changes = {k: v for k, v in values.items() if k in ("coarse", "lr", "normal_lr_scale")}
        return dataclasses.replace(base, prior=prior, **changes)

    return refine_settings


def in_process(device: str, options: dict):
    """``bench.run_command``'s stand-in: the command run by ``svbrdf_models.cli.main`` here,
    on ``device``; peak memory is the device's (CUDA) or not measured. ``options["true_offset"]``:
    shots are captured with the simulated phone's own lens-to-flash offset (``--flash-offset``,
    as a user who measured it), else the default's."""
    from svbrdf_models import cli

    def run_command(cmd: list[str], log: Path) -> dict:
        argv = cmd[1:] + ["--device", device]
        if options.get("true_offset") and "--shots" in argv:
            first = next(Path(a) for a in argv if a.endswith(".jpg"))
            phone = json.loads((first.parent / "phone.json").read_text())
            argv += ["--flash-offset", ",".join(f"{v:.4f}" for v in phone["flash_offset_cm"])]
        if torch.cuda.is_available():
            torch.cuda.reset_peak_memory_stats()
        t0 = time.perf_counter()
        rc = cli.main(argv)
        seconds = time.perf_counter() - t0
        peak = torch.cuda.max_memory_allocated() / 1024**3 if device.startswith("cuda") else float("nan")
        log.write_text(" ".join(argv) + f"\nexit {rc}\n")
        why = "" if rc == 0 else f"exit {rc}"
        return {"ok": rc == 0, "rc": rc, "seconds": seconds, "peak_gb": peak, "why": why}

    return run_command


def cached(simulate):
    """``bench.simulate`` once per material folder: the photos and their draws reused, and
    photos an earlier run wrote (the same seed and size) read, not made again: every draw of
    a shot comes before the first photo is made, so skipping the photos changes no draw."""
    memo: dict = {}
    sim = bench.sim

    def once(truth, folder, seed, short, n_frame):
        key = (str(folder), seed, short, n_frame)
        names = ["today.jpg", "card.jpg", *(f"shot{k}.jpg" for k in range(1, n_frame + 1))]
        if key not in memo and all((Path(folder) / n).is_file() for n in names):
            make, save = sim.make_photo, sim.save_jpeg
            sim.make_photo, sim.save_jpeg = (lambda *a, **k: None), (lambda *a, **k: None)
            try:
                memo[key] = simulate(truth, folder, seed, short, n_frame)
            finally:
                sim.make_photo, sim.save_jpeg = make, save
        if key not in memo:
            memo[key] = simulate(truth, folder, seed, short, n_frame)
        return memo[key]

    return once


def _counts(text: str) -> list[int]:
    try:
        counts = sorted({int(k) for k in text.split(",") if k.strip()})
    except ValueError:
        counts = []
    if not counts or counts[0] < 1:
        raise argparse.ArgumentTypeError(f"expected shot counts K,K,... (1 or more), got {text!r}")
    return counts


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folders", nargs="+", type=Path, help="folders of Des18-layout strips with ground truth")
    ap.add_argument("--set", dest="settings", action="append", type=parse_setting, required=True,
                    metavar="NAME:KEY=V,...", help="a setting to try (repeat); the first is the reference")
    ap.add_argument("--shots", default=[3, 5], type=_counts, help="K shots per capture (default 3,5)")
    ap.add_argument("--size", type=int, default=512, help="the photos' shorter side (default 512)")
    ap.add_argument("--out", type=Path, default=Path("out/sweep"), help="photos, captures, figures")
    ap.add_argument("--limit", type=int, default=None, help="at most N files per folder")
    ap.add_argument("--device", default="cpu", help="predict's --device (default cpu)")
    ap.add_argument("--minutes", type=float, default=None, help="start no setting after this many minutes")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    for folder in args.folders:
        if not folder.is_dir() or not any(folder.glob("*.png")):
            ap.error(f"{folder}: no Des18-layout strips (*.png) there; give a folder such as DATA/unseen-dev")
    import svbrdf_models.capture.shotcapture as shotcapture
    import svbrdf_models.capture.shots as shots_module

    args.out.mkdir(parents=True, exist_ok=True)
    current: dict = {}
    bench.run_command = in_process(args.device, current)
    bench.simulate = cached(bench.simulate)
    floor, relief = shots_module.CLIPPED_FLOOR, shots_module.SHOTS_PRIOR_RELIEF
    files = [f for folder in args.folders for f in sorted(folder.glob("*.png"))[: args.limit]]
    began = time.monotonic()
    today = _today(files, args)
    table: dict[str, object] = {}
    for name, values in args.settings:
        if args.minutes is not None and time.monotonic() - began > 60 * args.minutes:
            print(f"stopped before {name}: --minutes {args.minutes} passed", flush=True)
            break
        shotcapture.refine_settings = settings_for(values)
        shots_module.SHOTS_PRIOR_RELIEF = float(values.get("relief", relief))
        shots_module.CLIPPED_FLOOR = bool(values.get("floor", floor))
        current.clear()
        current.update(values)
        t0 = time.monotonic()
        skip = ("today", "today, known flash", "grey card")
        table[name] = _capture_all(files, args, values.get("steps", 100), skip, args.out / f"{name}.json",
                                   {"values": values})  # fmt: skip
        print(f"setting {name} {values}: {time.monotonic() - t0:.0f} s", flush=True)
    print_sweep(table, today, args.shots)


def _capture_all(files: list[Path], args, steps: int, skip, record: Path, head: dict):
    """``bench.capture_material`` over ``files`` at ``steps`` with the rows of ``skip`` left
    out; the per-material means, written to ``record`` (after ``head``)."""
    from svbrdf_train.data.real.materials import material_groups, per_material

    run = argparse.Namespace(shots=args.shots, size=args.size, refine=steps, model=None, threads=None,
                             seed=args.seed, rescore=False)  # fmt: skip
    results = []
    for f in files:
        index = sorted(f.parent.glob("*.png")).index(f)  # shots.py's seed: the file's place in its folder
        fig = bench.capture_material(f, index, run, args.out / f.parent.name, dict.fromkeys(skip, "-"), {})
        results.append((material_groups(f), fig))
    pm = per_material(results)
    record.write_text(json.dumps({**head, "materials": pm.materials}, indent=1))
    return pm


def _today(files: list[Path], args):
    """Each material's single photo captured as a user would (100 steps, a single photo's
    weights), and the constant maps: read back from ``OUT/today.json`` when it has them."""
    from svbrdf_train.data.real.materials import material_groups, per_material

    kept = args.out / "today.json"
    if kept.is_file():  # the single photo depends on no setting
        materials = json.loads(kept.read_text())["materials"]
        if {g for f in files for g in material_groups(f)} <= set(materials):
            return per_material([((g,), d) for g, d in materials.items()])
    skip = ("today, known flash", "grey card", *(bench._frame_row(k) for k in args.shots))
    return _capture_all(files, args, 100, skip, kept, {})


def print_sweep(table: dict, today, shots: list[int]) -> None:
    """The means of ``today``'s rows and of every setting's frame rows, as a markdown table;
    then each setting against the first, paired over materials."""
    from svbrdf_bench.metrics import paired_difference

    if not table:
        return
    print("\n| setting | K | " + " | ".join(SHOWN) + " |")
    print("| --- | ---: |" + " ---: |" * len(SHOWN))
    lines = [(row, 1, today, row) for row in ("today", "mean (window)")]
    lines += [(name, k, pm, bench._frame_row(k)) for name, pm in table.items() for k in shots]
    for name, k, pm, row in lines:
        cells = [f"{pm.mean.get(f'{row}|{m}', float('nan')):.4f}" for m in SHOWN]
        print(f"| {name} | {k} | {' | '.join(cells)} |")
    first, ref = next(iter(table.items()))
    print(f"\npaired over materials against {first} (percent of {first}'s mean [95%]):")
    for name, pm in list(table.items())[1:]:
        for k in shots:
            parts = []
            for m in SHOWN[:-1]:
                key = f"{bench._frame_row(k)}|{m}"
                both = [(d[key], ref.materials[g][key]) for g, d in pm.materials.items()
                        if key in d and key in ref.materials.get(g, {})]  # fmt: skip
                if both:
                    x, y = zip(*both, strict=True)
                    parts.append(f"{m} {paired_difference(list(x), list(y)).percent_of(ref.mean[key])}")
            print(f"  {name}, {k} shots: " + "; ".join(parts))


if __name__ == "__main__":
    main()
