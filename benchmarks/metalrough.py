#!/usr/bin/env python
"""What converting the project's maps to glTF metal/rough maps and back costs, per material.

The project's maps (diffuse ``d``, specular ``s``, roughness, normal; the Deschaintre 2018
convention) become the base colour and metallic maps that Blender, Substance, game engines and
web viewers read with :func:`svbrdf_render.to_metal_rough`, and come back with
:func:`svbrdf_render.from_metal_rough` (the equations, and what cannot survive, are in
``svbrdf_render/metalrough.py``). For every strip of each folder, the ground-truth maps are
brought to ``--size`` (whole tiles, area filter, normals renormalised: the benchmark's way) and
sent there and back; the table gives, per material:

- ``round trip render``: RMSE of renderings of the returned maps against renderings of the
  original ones under the 6 evaluation light/view pairs (clipped to [0, 1], sRGB: how the
  benchmark compares renderings), with the diffuse and specular map RMSEs beside it (roughness
  and normal pass through untouched: 0 by construction);
- ``naive render``: the same for what an artist gets by dropping the diffuse map into the base
  colour slot and leaving metallic at 0 (specular 0.04 everywhere): what the conversion buys;
- ``mean baseline render``: for scale, the render RMSE of the ``mean`` baseline (constant maps
  from the photo's statistics) against the same ground truth: the bar every model must clear;
- ``metallic``: the mean metallic value the conversion gives, and ``s < 0.04``: the share of
  pixels whose specular luminance is below glTF's dielectric floor by more than the 8-bit
  rounding of the files (0.04 itself is stored as 10/255 = 0.039); they come back at 0.04.

Scores are averaged per material (:mod:`svbrdf_train.data.real.materials`): a Des18 strip blends two
source materials, named in its file name, and counts for both; a file of ``unseen-dev`` is a
material of its own. Means over materials come with 95% bootstrap intervals.

``unseen-dev`` was made *from* metal/rough maps with the same equations, so its round trip
measures only the 8-bit rounding of its strips; ``des18-dev`` holds maps made in the des18
convention and shows what the conversion loses on them.

Usage::

    .venv/bin/python benchmarks/metalrough.py DATA/des18-dev DATA/unseen-dev
    .venv/bin/python benchmarks/metalrough.py DATA/des18-dev --size 128 -o metalrough.md

Exit status: 0 done; 2 a folder is missing, holds no strips, or its strips are smaller than
``--size`` (one line on stderr, nothing computed).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

PROG = "metalrough"
#: Specular luminance below 0.04 by more than half an 8-bit step.
FLOOR = 0.04 - 0.5 / 255


def score_strip(path: Path, size: int, mean) -> dict[str, float]:
    """The round trip's figures and the ``mean`` baseline's render RMSE for one strip."""
    from svbrdf_render import MetalRough, from_metal_rough, read_des18, roundtrip_error, to_metal_rough
    from svbrdf_render.compare import render_rmse
    from svbrdf_render.metalrough import LUMINANCE
    from svbrdf_train.data.fov import resize_maps, resize_photo

    sample = read_des18(path)
    photo, truth = resize_photo(sample.input, size), resize_maps(sample.svbrdf, size)
    err = roundtrip_error(truth)
    mr = to_metal_rough(truth)
    lum = (truth.specular * torch.tensor(LUMINANCE).view(1, 3, 1, 1)).sum(1)
    naive = from_metal_rough(
        MetalRough(truth.diffuse, torch.zeros_like(truth.roughness), truth.roughness, truth.normal)
    )
    with torch.no_grad():
        baseline = float(render_rmse(mean(photo), truth)[0])
        naive_render = float(render_rmse(naive, truth)[0])
    return {
        "render": float(err["render"][0]),
        "diffuse": float(err["diffuse"][0]),
        "specular": float(err["specular"][0]),
        "naive render": naive_render,
        "mean render": baseline,
        "metallic": float(mr.metallic.mean()),
        "s < 0.04": 100 * float((lum < FLOOR).float().mean()),
    }


def run_folder(folder: Path, size: int, mean):
    from svbrdf_train.data.real.materials import material_groups, per_material, strip_files

    rows = []
    files = strip_files(folder)
    for i, f in enumerate(files):
        rows.append((material_groups(f), score_strip(f, size, mean)))
        print(f"  {folder.name}: {i + 1}/{len(files)} {f.name}", file=sys.stderr, flush=True)
    return per_material(rows)


def table(name: str, result, size: int) -> str:
    from svbrdf_bench.metrics import bootstrap_ci

    n = len(result.materials)
    lines = [
        f"### {name}: {result.strips} strips, {n} materials, {size} px (RMSE; mean over materials "
        "[95% bootstrap])",
        "",
        "| material | strips | round trip render | diffuse | specular | naive render "
        "| mean baseline render | round trip / mean | metallic | s < 0.04 (%) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for material, fig in result.materials.items():
        lines.append(
            f"| {material} | {result.counts[material]} | {fig['render']:.4f} | {fig['diffuse']:.4f} "
            f"| {fig['specular']:.4f} | {fig['naive render']:.4f} | {fig['mean render']:.4f} | "
            f"{fig['render'] / fig['mean render']:.0%} | {fig['metallic']:.2f} | {fig['s < 0.04']:.0f} |"
        )
    cells = []
    for key in ("render", "diffuse", "specular", "naive render", "mean render"):
        m, lo, hi = bootstrap_ci(result.values(key))
        cells.append(f"{m:.4f} [{lo:.4f}, {hi:.4f}]")
    ratio = result.mean["render"] / result.mean["mean render"]
    lines.append(
        f"| **mean over materials** | {result.strips} | " + " | ".join(cells)
        + f" | {ratio:.0%} | {result.mean['metallic']:.2f} | {result.mean['s < 0.04']:.0f} |"
    )
    return "\n".join(lines) + "\n"


def check_folder(folder: Path, size: int) -> str | None:
    """One line saying what is wrong with ``folder``, or None."""
    from svbrdf_train.data.real.materials import strip_files

    if not folder.is_dir():
        return f"{folder}: no such folder; give folders of Des18-layout strips (des18-dev, unseen-dev)"
    files = strip_files(folder)
    if not files:
        return f"{folder}: holds no .png strips; give folders of Des18-layout strips"
    from PIL import Image

    with Image.open(files[0]) as im:
        tile = im.height
    if tile < size:
        return f"{files[0]}: {tile} px tiles, smaller than --size {size}; give --size {tile} or less"
    return None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "folders", nargs="+", type=Path,
        help="folders of Des18-layout strips with ground truth (input | normal | diffuse | roughness "
        "| specular), e.g. DATA/des18-dev DATA/unseen-dev",
    )
    ap.add_argument("--size", type=int, default=256,
                    help="pixels per side the maps are resized to before converting (default 256)")
    ap.add_argument("--threads", type=int, default=1,
                    help="torch threads (default 1: a shared machine runs slower with more)")
    ap.add_argument("-o", "--out", type=Path, help="also write the tables to this markdown file")
    a = ap.parse_args(argv)
    if a.size < 8:
        print(f"{PROG}: error: --size {a.size}: give at least 8 pixels", file=sys.stderr)
        return 2
    for folder in a.folders:
        problem = check_folder(folder, a.size)
        if problem:
            print(f"{PROG}: error: {problem}", file=sys.stderr)
            return 2
    import svbrdf_models as sm

    torch.set_num_threads(max(1, a.threads))
    torch.set_grad_enabled(False)
    mean = sm.create_generator("mean", {}).eval()
    from svbrdf_render import SVBRDFError
    from svbrdf_render.plumbing import write_text

    try:
        text = "## des18 -> glTF metal/rough -> des18, per material\n\n" + "\n".join(
            table(f.name, run_folder(f, a.size, mean), a.size) for f in a.folders
        )
        if a.out is not None:
            write_text(a.out, text)
    except SVBRDFError as e:  # a damaged strip, an output that cannot be written: one line
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return e.exit_code
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
