#!/usr/bin/env python
"""Do the ``handheld`` capture's simulated photos look more like real phone flash photos, effect
by effect? The project keeps a capture effect only when it measures on real photos, and no fit per
effect is affordable, so this compares PHOTO statistics (no network) of real flash photos
(DATA/real-dev; ``deschaintre*`` photos are read as linear, the others as sRGB, as its README
says) with those of simulated photos of real materials (``--strips``, e.g. DATA/real-train) under
the captures ``des18``, ``phone``, ``handheld`` and ``handheld`` with one effect removed at a time.

Statistics of one photo (linear, resized to ``--size``; "blurred" is the luminance, the mean of
the channels, under the box blur ``benchmarks/real_photos.py`` finds the flash with; distances in
half-widths of the photo):

- ``highlight``: distance of the flash's highlight (``real_photos.flash_point``, the brightest
  point of the blurred photo) from the photo's centre (camera shift, flash offset);
- ``fall 0.5`` and ``fall 1.0``: the median of the blurred luminance on a ring (width 0.1) at
  0.5 and 1.0 from the highlight, over its median on the ring 0.1-0.2 from it (just outside the
  blur's own reach of the peak; a median, so a rough material's broad lobe or a few clipped
  pixels barely move it); only the ring's pixels inside the photo count (distance, beam,
  vignetting, tone);
- ``corners``: the median of the blurred luminance in the four corner squares (an eighth of the
  side) over its median in the central square (a quarter of the side) (vignetting, beam);
- ``clipped``: share of pixels with a channel >= 0.98 (exposure, tone shoulder);
- ``R/G`` and ``B/G``: medians over the pixels with G >= 0.02 and no channel clipped (white
  balance; the materials' own colours weigh in as much, so read it beside the real materials);
- ``level``: median luminance (exposure, tone);
- ``peak``: the blurred highlight over the 0.1-0.2 ring's median: how far the specular peak
  stands out (tone shoulder, clip);
- ``blocks``: mean absolute step across the 8-pixel grid over the mean step elsewhere (1: no
  JPEG blocks at this size; JPEG at the photo's own size raises it; a real photo, saved as JPEG
  at full size and then cropped and resized, has none).

Each statistic is printed as median [10th-90th percentile] per capture, then the two-sample
Kolmogorov-Smirnov statistic between the capture's and real-dev's distributions (0: alike, 1:
disjoint). Per effect, the KS statistics of the figures it moves are summed with and without it:
removing an effect that moves them farther from real-dev says keep; closer says drop or retune.
The simulated photos of one seed are paired (the same windows and draws, but for the effect), so
the change is the effect's; the support is the share of bootstrap resamples (of the real photos
and of the simulated ones, paired) that agree with the sign, and below 80% (``SUPPORT``) the
verdict is "within noise" (21 real photos carry little).

Usage::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/phone_capture.py DATA/real-dev \\
        --strips DATA/real-train --count 64 -o phone-capture.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_photos import _load, _luminance, flash_point  # noqa: E402

PROG = "phone_capture"
SIZE, COUNT, SEED = 256, 64, 0
CLIP = 0.98
#: Rings, in half-widths from the highlight: the reference ring, and the fall-off rings
#: (centre, half-width of the ring).
NEAR = (0.1, 0.2)
FALL = {"fall 0.5": (0.5, 0.05), "fall 1.0": (1.0, 0.05)}
STATS = ("highlight", "fall 0.5", "fall 1.0", "corners", "clipped", "R/G", "B/G", "level", "peak", "blocks")
#: Bootstrap resamples, and the share of them that must agree with a verdict's sign.
RESAMPLES, SUPPORT = 500, 0.8
BASE = "handheld"
#: effect -> (fields of the ``handheld`` preset replaced to remove it, statistics it moves)
EFFECTS: dict[str, tuple[dict, tuple[str, ...]]] = {
    "beam": ({"beam_exponent": None}, ("fall 0.5", "fall 1.0", "corners")),
    "vignetting": ({"vignetting": None}, ("fall 0.5", "fall 1.0", "corners")),
    "tone": ({"tone_power": None}, ("fall 0.5", "fall 1.0", "clipped", "level", "peak")),
    "off-centre": ({"camera_shift": (0.03, 0.3)}, ("highlight",)),
    "LED ring": ({"flash_offset": 0.2, "flash_offset_min": 0.0}, ("highlight",)),
    "white balance": ({"white_balance": 0.08}, ("R/G", "B/G")),
    "exposure": ({"exposure_ev": (0.0, 0.5)}, ("clipped", "level", "peak")),
    "JPEG": ({"jpeg_probability": 0.5, "jpeg_quality": (75, 95)}, ("blocks",)),
}


# -- statistics of one photo ------------------------------------------------------------------


def blurred(photo: torch.Tensor) -> np.ndarray:
    """The luminance of ``photo`` ``(3, H, W)`` under the box blur of ``flash_point``."""
    y = _luminance(photo.float())[None, None]
    k = max(3, y.shape[-1] // 16) | 1
    return F.avg_pool2d(y, k, stride=1, padding=k // 2, count_include_pad=False)[0, 0].numpy()


def _ring(values: np.ndarray, r: np.ndarray, low: float, high: float) -> float:
    inside = values[(r >= low) & (r < high)]
    return float(np.median(inside)) if inside.size else float("nan")


def _ratio(a: float, b: float) -> float:
    return a / b if b > 1e-6 else float("nan")


def blockiness(y: np.ndarray, block: int = 8) -> float:
    """Mean absolute step across the ``block`` grid over the mean step elsewhere (rows and
    columns together) of a luminance image ``y``: near 1 without JPEG blocks aligned to it."""
    steps = [np.abs(np.diff(y, axis=1)), np.abs(np.diff(y, axis=0)).T]
    on = np.concatenate([s[:, block - 1 :: block].ravel() for s in steps])
    grid = np.zeros(steps[0].shape[1], bool)
    grid[block - 1 :: block] = True
    off = np.concatenate([s[:, ~grid].ravel() for s in steps])
    return _ratio(float(on.mean()), float(off.mean()))


def photo_stats(photo: torch.Tensor) -> dict[str, float]:
    """The statistics of one linear photo ``(3, R, R)`` (see the module doc), by name."""
    x = photo.float().clamp(0, 1)
    size = x.shape[-1]
    half = size / 2
    blur = blurred(x)
    row, col = flash_point(x)
    centre = (size - 1) / 2
    rows, cols = np.mgrid[0:size, 0:size].astype(np.float64)
    r = np.hypot(rows - row, cols - col) / half
    near = _ring(blur, r, *NEAR)
    out = {"highlight": float(np.hypot(row - centre, col - centre) / half)}
    for name, (at, width) in FALL.items():
        out[name] = _ratio(_ring(blur, r, at - width, at + width), near)
    c, m = max(1, size // 8), size // 8 * 3
    corners = np.concatenate([blur[:c, :c], blur[:c, -c:], blur[-c:, :c], blur[-c:, -c:]], axis=None)
    out["corners"] = _ratio(float(np.median(corners)), float(np.median(blur[m:-m, m:-m])))
    rgb = x.numpy()
    clipped = rgb.max(axis=0) >= CLIP
    out["clipped"] = float(clipped.mean())
    lit = (rgb[1] >= 0.02) & ~clipped
    for name, k in (("R/G", 0), ("B/G", 2)):
        out[name] = float(np.median(rgb[k][lit] / rgb[1][lit])) if lit.any() else float("nan")
    y = _luminance(x).numpy()
    out["level"] = float(np.median(y))
    out["peak"] = _ratio(float(blur[row, col]), near)
    out["blocks"] = blockiness(y)
    return out


def table(photos) -> np.ndarray:
    """``(N, len(STATS))`` statistics of the photos, one row a photo."""
    rows = [[photo_stats(p)[s] for s in STATS] for p in photos]
    return np.array(rows, dtype=np.float64).reshape(-1, len(STATS))


# -- distances --------------------------------------------------------------------------------


def ks_distance(a: np.ndarray, b: np.ndarray) -> float:
    """The two-sample Kolmogorov-Smirnov statistic: the largest gap between the empirical
    distribution functions of ``a`` and ``b`` (NaNs left out; NaN when either is empty)."""
    a, b = np.sort(a[np.isfinite(a)]), np.sort(b[np.isfinite(b)])
    if not a.size or not b.size:
        return float("nan")
    x = np.concatenate([a, b])
    gap = np.searchsorted(a, x, side="right") / a.size - np.searchsorted(b, x, side="right") / b.size
    return float(np.abs(gap).max())


def effect_change(
    real: np.ndarray, base: np.ndarray, without: np.ndarray, stats, rng=None
) -> tuple[float, float]:
    """How much farther from ``real`` the statistics ``stats`` move when the effect goes: the
    summed KS statistic of ``without`` minus that of ``base`` (paired rows), and the share of
    bootstrap resamples (rows of ``real``, and paired rows of the two simulated tables) whose
    change has the same sign (1.0 with ``rng`` None: no bootstrap; NaN when nothing changes)."""
    cols = [STATS.index(s) for s in stats]

    def change(r, b, w):
        return sum(ks_distance(w[:, k], r[:, k]) - ks_distance(b[:, k], r[:, k]) for k in cols)

    delta = change(real, base, without)
    if delta == 0:
        return delta, float("nan")
    if rng is None:
        return delta, 1.0
    agree = 0
    for _ in range(RESAMPLES):
        ri, si = rng.integers(0, len(real), len(real)), rng.integers(0, len(base), len(base))
        agree += np.sign(change(real[ri], base[si], without[si])) == np.sign(delta)
    return delta, agree / RESAMPLES


def verdict(delta: float, support: float) -> str:
    if delta == 0:
        return "no change on these statistics"
    if support < SUPPORT:
        return "within noise"
    return "keep (removing it moves away from real-dev)" if delta > 0 else "drop/retune (better without it)"


# -- the photos -------------------------------------------------------------------------------


def captures() -> dict[str, dict]:
    """The captures compared: name -> PhotoSettings fields."""
    from svbrdf_train.data.simulated_photo import CAPTURE_PRESETS

    out = {name: dict(CAPTURE_PRESETS[name]) for name in ("des18", "phone", BASE)}
    for effect, (fields, _) in EFFECTS.items():
        out[f"{BASE} - {effect}"] = {**CAPTURE_PRESETS[BASE], **fields}
    return out


def simulated(bank, fields: dict, count: int, size: int, seed: int) -> np.ndarray:
    """Statistics of ``count`` photos of ``bank``'s materials under the capture ``fields``."""
    from svbrdf_train.data.real.strips import MaterialStrips
    from svbrdf_train.data.simulated_photo import PhotoSettings

    data = MaterialStrips(bank, count, size, seed=seed, photo=PhotoSettings(**fields))
    rows = []
    for start in range(0, count, 16):
        samples = data.__getitems__(list(range(start, min(count, start + 16))))
        rows.append(table(s["input"] for s in samples))
    return np.concatenate(rows)


def real_photos(folder: Path, size: int) -> tuple[list[str], np.ndarray]:
    """The names and statistics of the photos of ``folder``."""
    if not folder.is_dir():
        raise ValueError(f"{folder}: no such folder; give a folder of real flash photos (DATA/real-dev)")
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    if not paths:
        raise ValueError(f"{folder}: no photos (*.png, *.jpg) there; give a folder of real flash photos")
    return [p.stem for p in paths], table(_load(p, size) for p in paths)


# -- output -----------------------------------------------------------------------------------


def _fmt(v: float) -> str:
    return "-" if not np.isfinite(v) else f"{v:.3f}" if abs(v) < 10 else f"{v:.1f}"


def summary(values: np.ndarray) -> str:
    v = values[np.isfinite(values)]
    if not v.size:
        return "-"
    p10, p50, p90 = np.percentile(v, [10, 50, 90])
    return f"{_fmt(p50)} [{_fmt(p10)}-{_fmt(p90)}]"


def print_tables(real: np.ndarray, sims: dict[str, np.ndarray], rng) -> list[tuple]:
    """Print the distributions, the KS distances and the verdicts; return the verdict rows."""
    print("Median [10th-90th percentile] of each statistic\n")
    print("| capture | " + " | ".join(STATS) + " |")
    print("| --- |" + " ---: |" * len(STATS))
    for name, t in {"real-dev": real, **sims}.items():
        print(f"| {name} | " + " | ".join(summary(t[:, k]) for k in range(len(STATS))) + " |")
    print("\nKolmogorov-Smirnov statistic against real-dev (0: alike, 1: disjoint)\n")
    print("| capture | " + " | ".join(STATS) + " | sum |")
    print("| --- |" + " ---: |" * (len(STATS) + 1))
    for name, t in sims.items():
        ks = [ks_distance(t[:, k], real[:, k]) for k in range(len(STATS))]
        print(f"| {name} | " + " | ".join(_fmt(v) for v in ks) + f" | {_fmt(float(np.nansum(ks)))} |")
    print(f"\nPer effect: summed KS of the statistics it moves, {BASE} without it minus {BASE}"
          f" (> 0: removing it moves away from real-dev); support over {RESAMPLES} bootstrap resamples\n")
    print("| effect | statistics | KS with | KS without | change | support | verdict |")
    print("| --- | --- | ---: | ---: | ---: | ---: | --- |")
    rows = []
    for effect, (_, stats) in EFFECTS.items():
        base, without = sims[BASE], sims[f"{BASE} - {effect}"]
        ks = [sum(ks_distance(t[:, STATS.index(s)], real[:, STATS.index(s)]) for s in stats)
              for t in (base, without)]  # fmt: skip
        delta, support = effect_change(real, base, without, stats, rng)
        rows.append((effect, delta, support, verdict(delta, support)))
        print(f"| {effect} | {', '.join(stats)} | {_fmt(ks[0])} | {_fmt(ks[1])} | {delta:+.3f} | "
              f"{'-' if delta == 0 else f'{support:.0%}'} | {rows[-1][3]} |")  # fmt: skip
    return rows


def plot(real: np.ndarray, sims: dict[str, np.ndarray], out: Path) -> None:
    """One panel per statistic: each capture's 10th-90th percentile (line) and median (dot),
    real-dev on top with its range shaded across the panel."""
    from matplotlib.figure import Figure

    from svbrdf_render.plumbing import atomic_output

    named = {"real-dev": real, **sims}
    fig = Figure(figsize=(15, 6.5), layout="constrained")
    axes = fig.subplots(2, (len(STATS) + 1) // 2, sharey=True).ravel()
    for k, (ax, stat) in enumerate(zip(axes, STATS, strict=False)):
        for j, (name, t) in enumerate(named.items()):
            v = t[:, k][np.isfinite(t[:, k])]
            if not v.size:
                continue
            p10, p50, p90 = np.percentile(v, [10, 50, 90])
            colour = "black" if j == 0 else "tab:blue" if name == BASE else "tab:gray"
            if j == 0:
                ax.axvspan(p10, p90, color="tab:orange", alpha=0.15)
            ax.plot([p10, p90], [j, j], color=colour, lw=2)
            ax.plot([p50], [j], "o", color=colour, ms=4)
        ax.set_title(stat, fontsize=9)
        ax.tick_params(labelsize=7)
    axes[0].set_yticks(range(len(named)), list(named), fontsize=7)
    axes[0].invert_yaxis()
    fig.suptitle("Photo statistics, real-dev against the simulated captures (median, 10th-90th percentile)")
    with atomic_output(out) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    print(f"\nwrote {out}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(
        prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("folder", type=Path, help="folder of real flash photos (DATA/real-dev)")
    ap.add_argument(
        "--strips", type=Path, required=True,
        help="folder of material strips (or a strip shard) to photograph (DATA/real-train)",
    )  # fmt: skip
    ap.add_argument("--count", type=int, default=COUNT, help=f"photos per capture (default {COUNT})")
    ap.add_argument("--size", type=int, default=SIZE, help=f"side of the photos in pixels (default {SIZE})")
    ap.add_argument("--seed", type=int, default=SEED, help=f"seed of windows and draws (default {SEED})")
    ap.add_argument("-o", "--out", type=Path, help="also draw the distributions into this PNG")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    from svbrdf_models.errors import DataError
    from svbrdf_train.data.real.strip_bank import MaterialBank

    try:
        if args.count < 2 or args.size < 32:
            raise ValueError(f"expected --count >= 2 and --size >= 32, got {args.count} and {args.size}")
        names, real = real_photos(args.folder, args.size)
        bank = MaterialBank.open(args.strips)
        sims = {}
        for name, fields in captures().items():
            print(f"  photographing {args.count} materials under {name}", file=sys.stderr, flush=True)
            sims[name] = simulated(bank, fields, args.count, args.size, args.seed)
    except (ValueError, DataError, OSError) as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        sys.exit(2)
    print(f"{len(names)} real photos of {args.folder.name}; {args.count} simulated photos per capture of the "
          f"{len(bank)} materials of {args.strips.name}, {args.size} px, seed {args.seed}\n")  # fmt: skip
    print_tables(real, sims, np.random.default_rng(args.seed))
    if args.out:
        plot(real, sims, args.out)


if __name__ == "__main__":
    main()
