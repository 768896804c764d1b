#!/usr/bin/env python
"""The flash the photo tools find, against the flash the photo was taken with.

A single photo cannot separate the albedo from the flash's power: the capture reads the flash
off the network's maps (:func:`svbrdf_render.axis_flash`: on the axis at distance 2.2, the
median log ratio of photo to rendering), so an error of the network on the albedo level is
an error of the flash, and the refinement then bends the albedo to match. This benchmark
shows how large that error is, per material of folders of Des18-layout strips with ground
truth:

- **true flash**: where the capture is known, give it as ``FOLDER:INTENSITY`` (unseen-dev's
  inputs were rendered on the axis at distance 2.2 with intensity 15: ``DATA/unseen-dev:15``);
  otherwise the flash fitted to the *true* maps (:func:`svbrdf_render.fit_flash`, position and
  intensity, camera at the light; des18-dev inputs come from the Des18 data set, whose flash
  varies, distance about 1.8-3.7, so the fit is the only reference there).
- **axis on the network's maps** (what ``predict`` uses) and **fit on the network's maps**
  (``flash="fit"``: position too);
- **axis on the true maps**: the estimator's own error when the maps are right.

Per estimator: the intensity ratio found / true (median and quartiles over the strips), its
median absolute log2 (1 = a factor 2), and the distance error (found - true, median of the
absolute value). The last column is the network's diffuse level against the truth (ratio of
mean luminances), which the ``axis`` ratio follows.

Usage::

    .venv/bin/python benchmarks/flash_estimate.py DATA/unseen-dev:15 DATA/des18-dev [--model pretrained]
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from pathlib import Path

import torch

ESTIMATORS = ("axis on the network's maps", "fit on the network's maps", "axis on the true maps")


def _lum_mean(x: torch.Tensor) -> float:
    return float((x.mean((0, 2, 3)) * x.new_tensor([0.2126, 0.7152, 0.0722])).sum())


def _one(photo, truth, net, known: float | None) -> dict[str, tuple[float, float]]:
    """(intensity, distance) of the true flash and of each estimator, for one strip."""
    from svbrdf_render import fit_flash
    from svbrdf_render.refinement.fit import axis_flash

    if known is None:
        true = fit_flash(truth, photo)
        out = {"true": (float(true.intensity[0]), float(true.position[0].norm()))}
    else:
        out = {"true": (known, 2.2)}
    for name, maps in (("axis on the network's maps", net), ("axis on the true maps", truth)):
        scene = axis_flash(maps, photo)
        out[name] = (float(torch.as_tensor(scene.lights[0].intensity).reshape(-1)[0]), 2.2)
    fit = fit_flash(net, photo)
    out["fit on the network's maps"] = (float(fit.intensity[0]), float(fit.position[0].norm()))
    return out


def run_folder(folder: Path, model, known: float | None) -> tuple[list[dict], list[float]]:
    from svbrdf_render import read_des18

    files = sorted(folder.glob("*.png"))
    if not files:
        sys.exit(f"flash_estimate: error: {folder}: no .png strips there")
    rows, levels = [], []
    for i, f in enumerate(files):
        sample = read_des18(f)
        photo, truth = sample.input, sample.svbrdf
        with torch.no_grad():
            net = model.predict(photo[0]).resize(*truth.size)
        rows.append(_one(photo, truth, net, known))
        levels.append(_lum_mean(net.diffuse) / max(_lum_mean(truth.diffuse), 1e-6))
        print(f"  {folder.name}: {i + 1}/{len(files)} {f.name}", file=sys.stderr, flush=True)
    return rows, levels


def _spread(values: list[float], fmt: str = ".2f") -> str:
    """``median [first quartile, third quartile]``."""
    q1, _, q3 = statistics.quantiles(values, n=4) if len(values) > 1 else (values[0],) * 3
    return f"{statistics.median(values):{fmt}} [{q1:{fmt}}, {q3:{fmt}}]"


def table(name: str, rows: list[dict], levels: list[float], known: float | None) -> str:
    true_i = [r["true"][0] for r in rows]
    true_d = [r["true"][1] for r in rows]
    how = (
        f"known, on the axis: intensity {known:g}, distance 2.2"
        if known is not None
        else (f"fitted to the true maps: intensity {_spread(true_i, '.1f')}, distance {_spread(true_d)}")
    )
    lines = [
        f"### {name}: {len(rows)} strips; true flash ({how})",
        "",
        "| estimator | intensity found / true, median [quartiles] | median abs log2 "
        "| distance error, median abs |",
        "| --- | ---: | ---: | ---: |",
    ]
    for est in ESTIMATORS:
        ratio = [r[est][0] / r["true"][0] for r in rows]
        log2 = statistics.median(abs(math.log2(max(x, 1e-6))) for x in ratio)
        dist = statistics.median(abs(r[est][1] - r["true"][1]) for r in rows)
        lines.append(f"| {est} | {_spread(ratio)} | {log2:.2f} | {dist:.2f} |")
    lines += [
        "",
        f"The network's diffuse level / the true one (mean luminance): {_spread(levels)}.",
        "",
    ]
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "folders",
        nargs="+",
        help="folders of Des18-layout strips with ground truth, each as "
        "FOLDER or FOLDER:INTENSITY where the on-axis capture at 2.2 is known",
    )
    ap.add_argument("--model", default="pretrained", help="model source (default: the shipped model)")
    args = ap.parse_args(argv)
    import svbrdf_models as sm

    torch.set_num_threads(1)
    model = sm.load_model(args.model)
    print(f"# The flash found against the true one\n\nModel: {model.describe()}.\n")
    for spec in args.folders:
        name, _, known = spec.partition(":")
        try:
            intensity = float(known) if known else None
        except ValueError:
            sys.exit(f"flash_estimate: error: {spec}: give FOLDER or FOLDER:INTENSITY (a number)")
        rows, levels = run_folder(Path(name), model, intensity)
        print(table(Path(name).name, rows, levels, intensity))


if __name__ == "__main__":
    main()
