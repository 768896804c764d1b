"""The specular albedo the networks learn from, against real materials'.

Most real dielectrics reflect about 4% at normal incidence (F0 = 0.04); metals reflect far
more, in colour. This script pools the per-pixel specular level (mean of R, G, B) of

- procedural materials (svbrdf-train's generator, ``--count`` of them),
- the map-only real materials of a strip folder (REAL_TRAIN, e.g. DATA/real-train),
- the materials with ground truth of a Des18-style folder (UNSEEN, e.g. DATA/unseen-dev),
- the training mixture of a recipe that draws real strips with probability ``--weight`` and
  procedural materials otherwise (a weighted sum of the first two histograms),

prints the share of pixels near 0.04, of metal-like pixels (> 0.2), the 10th/50th/90th
percentiles and the earth mover's distance (W1, on log10 of the level) to real-train and to
unseen-dev, and draws the four histograms (``-o FILE.png``).

Usage:
    python benchmarks/specular_prior.py DATA/real-train DATA/unseen-dev --weight 0.5 -o docs/specular-prior.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

#: Histogram bins of the specular level, log-spaced (levels below the first bin are counted in it).
BINS = np.logspace(np.log10(0.005), 0.0, 61)
SIZE = 64


def _levels_procedural(count: int) -> np.ndarray:
    from svbrdf_train.data.procedural import ProceduralMaterials
    from svbrdf_train.data.simulated_photo import PhotoSettings

    data = ProceduralMaterials(count, SIZE, seed=0, photo=PhotoSettings.preset("phone"))
    parts = [data.batch(range(i, min(i + 16, count)))["maps"][:, 7:10] for i in range(0, count, 16)]
    return torch.cat(parts).mean(dim=1).flatten().numpy()


def _levels_strips(folder: Path) -> np.ndarray:
    from svbrdf_train.data.real.strip_bank import MaterialBank, resize_bank, strip_tensor

    bank = resize_bank(MaterialBank.open(folder), SIZE)
    return np.concatenate([strip_tensor(m)[7:10].mean(dim=0).flatten().numpy() for m in bank.maps])


def _levels_des18(folder: Path) -> np.ndarray:
    from svbrdf_render import read_des18

    out = []
    for p in sorted(folder.glob("*.png")):
        s = read_des18(p).svbrdf.resize(SIZE, mode="area")
        out.append(s.specular.mean(dim=1).flatten().numpy())
    return np.concatenate(out)


def _histogram(levels: np.ndarray) -> np.ndarray:
    h, _ = np.histogram(np.clip(levels, BINS[0], BINS[-1]), bins=BINS)
    return h / h.sum()


def _quantile(h: np.ndarray, q: float) -> float:
    cdf = np.cumsum(h)
    return float(BINS[1:][np.searchsorted(cdf, q)])


def _w1(a: np.ndarray, b: np.ndarray) -> float:
    """Earth mover's distance between two histograms over log10 of the level."""
    width = np.diff(np.log10(BINS))
    return float(np.sum(np.abs(np.cumsum(a) - np.cumsum(b))[:-1] * width[1:]))


def _row(name: str, h: np.ndarray, real: np.ndarray, unseen: np.ndarray) -> str:
    centres = np.sqrt(BINS[1:] * BINS[:-1])
    near = float(h[(centres > 0.03) & (centres < 0.055)].sum())
    metal = float(h[centres > 0.2].sum())
    q = [_quantile(h, p) for p in (0.1, 0.5, 0.9)]
    return (
        f"| {name} | {near:.0%} | {metal:.1%} | {q[0]:.3f} / {q[1]:.3f} / {q[2]:.3f} "
        f"| {_w1(h, real):.3f} | {_w1(h, unseen):.3f} |"
    )


def _plot(hists: dict[str, np.ndarray], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.6), dpi=110)
    for name, h in hists.items():
        ax.stairs(h, BINS, label=name, linewidth=1.6)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.axvline(0.04, color="grey", linestyle=":", linewidth=1)
    ax.set_xlabel("specular albedo (mean of R, G, B), per pixel")
    ax.set_ylabel("share of pixels")
    ax.set_title("Specular albedo: training data against real materials")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out)
    print(f"wrote {out}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("real_train", type=Path, help="folder of map-only strips (DATA/real-train)")
    ap.add_argument("unseen", type=Path, help="Des18-style folder with ground truth (DATA/unseen-dev)")
    ap.add_argument("--count", type=int, default=256, help="procedural materials (default 256)")
    ap.add_argument("--weight", type=float, default=0.5, help="share of real strips in the mixture")
    ap.add_argument("-o", "--out", type=Path, help="histogram figure (.png)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    proc = _histogram(_levels_procedural(args.count))
    real = _histogram(_levels_strips(args.real_train))
    unseen = _histogram(_levels_des18(args.unseen))
    mix = args.weight * real + (1 - args.weight) * proc
    hists = {
        f"procedural ({args.count})": proc,
        f"training mixture ({args.weight:.0%} real strips)": mix,
        "real-train (70)": real,
        "unseen-dev (9)": unseen,
    }
    print(
        "| data | pixels in 0.03-0.055 | pixels > 0.2 | p10 / p50 / p90 | W1 to real-train | W1 to unseen-dev |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for name, h in hists.items():
        print(_row(name, h, real, unseen))
    if args.out:
        _plot(hists, args.out)


if __name__ == "__main__":
    main()
