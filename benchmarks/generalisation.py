#!/usr/bin/env python
"""How the training recipe for materials it has never seen was chosen (recipe ``ours-general``):
short pilot fits of each change, judged per material on materials none of them trained on.

Each variant is a fit of ``ours`` at ``--size`` (default ``cpu``) for ``--minutes`` on the fit's
clock (process CPU time), one torch thread per fit, ``--jobs`` fits at a time; every variant adds
one change to the one before it:

=========================  ==================================================================
``paper``                  ``ours``: transposed convs, raw (log) input, Des18 capture
``resize``                 + nearest x2 and 3x3 conv instead of transposed convs
                           (``generator.config.upsample=resize``)
``resize+norm``            + photo scaled to a fixed median, its level fed to the global track
                           (``input_norm=median``, ``input_level=true``)
``resize+norm+phone``      + procedural photos under the phone capture (``data.capture=phone``):
                           recipe ``ours-general`` itself
``real`` (one per fold)    ``ours-general`` on a mix: 70% procedural, 30% the fold's training
                           strips (``data.source=mix``, ``--data FOLD/train``)
=========================  ==================================================================

Folds (``--folds``, specs separated by ``;``) hold materials of the Des18 folder out
(:func:`svbrdf_train.data.real.materials.fold_from_spec`): ``hold-out:A+B`` judges the strips that
show only A and B and trains on the strips that show neither, as ``svbrdf-train data folds``
splits them (link folders in ``OUT/folds/<fold>/train`` and ``judge``).

Every fit is exported (``OUT/NAME.pt``) and its network maps (no refinement), brought to the
strip's full resolution, are scored against the ground truth: RMSE of each map (stored encodings)
and of renderings under the 6 evaluation views, with the ``mean`` baseline (constant maps) on the
same photos. Test folders: UNSEEN (every model; one material per file), DES18 (only the variants
that trained on no real strip) and each fold's judge strips (the procedural-only variants and that
fold's ``real`` variant). Scores are averaged per material
(:func:`svbrdf_train.data.real.materials.per_material`: a Des18 strip counts for both of its
materials) and compared over materials with 95% bootstrap intervals: each variant against the one
before it, each against ``mean``, and each ``real`` variant against ``resize+norm+phone``.

A fold's judge strips hold only the fold's own two materials, so its per-material figures are
one pair counted twice: the tables say so and print no interval there.

Usage::

    .venv/bin/python benchmarks/generalisation.py DATA/unseen-dev DATA/des18-dev -o generalisation
    .venv/bin/python benchmarks/generalisation.py U D -o g --minutes 0.05 --variants paper,resize,real \\
        --folds 'hold-out:brick_uneven_stones+leather_tiles'             # the pipeline, in minutes
    .venv/bin/python benchmarks/generalisation.py U D -o generalisation --skip-fit   # score again
    .venv/bin/python benchmarks/generalisation.py U D --print                        # commands only

Writes ``OUT/generalisation.md`` (tables) and ``OUT/generalisation.json`` (every per-material
figure, the fits' commands and the procedural generator version the installed code makes, which
the procedural-data variants trained on). Fits log to ``OUT/NAME.log`` and are not tracked in
MLflow. Exit status: 0 done; 1 a fit or export failed (its log named); 2 bad arguments (a missing
folder, an unknown variant, a fold spec that names no material, a missing fit with --skip-fit).
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path


def _sibling(name: str):
    """Another script of benchmarks/ as a module: refine_curve (``score``, the RMSE of each map
    and of the renderings, and ``MAPS``, the columns) and real_mix (its job runner)."""
    here = str(Path(__file__).resolve().parent)
    if here not in sys.path:
        sys.path.insert(0, here)
    return importlib.import_module(name)

PROG = "generalisation"
#: The chain of changes, each variant one change on the one before it.
CHAIN = ("paper", "resize", "resize+norm", "resize+norm+phone")
REAL = "real"
VARIANT_NAMES = (*CHAIN, REAL)
#: ``name: (recipe, --set overrides)`` of the procedural-only variants.
RECIPES: dict[str, tuple[str, tuple[str, ...]]] = {
    "paper": ("ours", ()),
    "resize": ("ours", ("generator.config.upsample=resize",)),
    "resize+norm": (
        "ours",
        (
            "generator.config.upsample=resize",
            "generator.config.input_norm=median",
            "generator.config.input_level=true",
        ),
    ),
    "resize+norm+phone": ("ours-general", ()),  # = ours + the three above + data.capture=phone
}
#: The fold variants: ours-general on a 70/30 mix of procedural materials and the fold's strips.
#: ``data.source=mix`` is needed: ours-general's source is procedural, and a ``data.mix`` without
#: it is refused; ``--data`` then gives the path of the des18 entry.
REAL_SHARE = 0.3
REAL_RECIPE = "ours-general"
REAL_SETS = (
    "data.source=mix",
    f"data.mix=[{{source: procedural, weight: {1 - REAL_SHARE:g}}}, "
    f"{{source: des18, weight: {REAL_SHARE:g}, validation: 0}}]",
)
#: Every pilot fit: one epoch of 200k samples (the budget ends it), no validation on the way.
COMMON_SETS = (
    "data.count=200000",
    "train.epochs=1",
    "train.validate_every=100000",
    "train.checkpoint_every=500",
)
DEFAULT_FOLDS = (
    "hold-out:PolishedMarbleFloor_01+metal_bumpy_squares;hold-out:brick_uneven_stones+leather_tiles"
)
REFERENCE = "resize+norm+phone"


class UsageError(Exception):
    """Bad arguments or input: one line, exit status 2."""


@dataclass
class Fit:
    name: str  # OUT/NAME: its folder; OUT/NAME.pt: its model; OUT/NAME.log: its log
    label: str  # its row in the tables
    recipe: str
    sets: tuple[str, ...]
    data: Path | None = None  # the fold's training strips (real variants)
    fold: str | None = None  # the fold's name (real variants)
    args: list[str] = field(default_factory=list)

    @property
    def procedural_only(self) -> bool:
        return self.data is None


# -- plan -----------------------------------------------------------------------------------------


def parse_variants(text: str) -> list[str]:
    wanted = [v.strip() for v in text.split(",") if v.strip()]
    unknown = [v for v in wanted if v not in VARIANT_NAMES]
    if unknown or not wanted:
        raise UsageError(
            f"--variants {text!r}: {'unknown variant ' + repr(unknown[0]) if unknown else 'names none'}; "
            f"choose from {', '.join(VARIANT_NAMES)} (comma-separated)"
        )
    return [v for v in VARIANT_NAMES if v in wanted]


def parse_folds(text: str, des18: Path):
    """The folds of ``--folds``: ``hold-out:A+B`` specs (or ``A,B`` as ``data folds --hold-out``
    takes them) separated by ``;``."""
    from svbrdf_models.errors import DataError
    from svbrdf_train.data.real.materials import FOLD_PREFIX, fold_from_spec, strip_files

    files = strip_files(des18)
    folds = []
    for raw in text.split(";"):
        spec = raw.strip()
        if not spec:
            continue
        names = spec[len(FOLD_PREFIX):] if spec.startswith(FOLD_PREFIX) else spec
        try:
            fold = fold_from_spec(files, names.replace("+", ","), where=des18)
        except DataError as e:
            raise UsageError(f"--folds {spec!r}: {e}") from None
        if fold.name not in [f.name for f in folds]:
            folds.append(fold)
    if not folds:
        raise UsageError(f"--folds {text!r}: names no fold; give hold-out:MatA+MatB specs separated by ';'")
    return folds


def plan(variants: list[str], folds, out: Path, minutes: float, size: str) -> list[Fit]:
    fits = [Fit(v, v, *RECIPES[v]) for v in variants if v in RECIPES]
    if REAL in variants:
        for fold in folds:
            fits.append(
                Fit(
                    f"real{round(100 * REAL_SHARE)}@{fold.name}",
                    f"{REFERENCE}+real {round(100 * REAL_SHARE)}% [{fold.name}]",
                    REAL_RECIPE,
                    REAL_SETS,
                    data=out / "folds" / fold.name / "train",
                    fold=fold.name,
                )
            )
    for fit in fits:
        fit.args = [
            sys.executable, "-m", "svbrdf_train", "fit", "--recipe", fit.recipe, "--size", size,
            "--max-minutes", f"{minutes:g}", "--no-track", "-q", "--out", str(out / fit.name), "--force",
            *(x for s in (*COMMON_SETS, *fit.sets) for x in ("--set", s)),
            *(("--data", str(fit.data)) if fit.data else ()),
        ]  # fmt: skip
    return fits


def write_folds(des18: Path, folds, out: Path, env: dict) -> None:
    """``OUT/folds/<fold>/train`` and ``judge``: link folders, as ``svbrdf-train data folds`` writes them."""
    for fold in folds:
        spec = ",".join(fold.held_out)
        cmd = [sys.executable, "-m", "svbrdf_train", "data", "folds", str(des18), "--out", str(out / "folds"),
               "--hold-out", spec]  # fmt: skip
        done = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if done.returncode != 0:
            why = (done.stderr or done.stdout).strip()
            sys.exit(f"{PROG}: error: `svbrdf-train data folds` failed: {why}")


# -- fits -----------------------------------------------------------------------------------------


def say(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", flush=True)


def run_fits(fits: list[Fit], jobs: int, env: dict) -> None:
    """Run the fits, ``jobs`` at a time (real_mix.py's job runner); a failed fit ends the
    program (exit 1) naming its log."""
    real_mix = _sibling("real_mix")
    for fit in fits:
        say(f"fit {fit.name}: svbrdf-train {shlex.join(fit.args[3:])}")
    real_mix.run_jobs([real_mix.Job(f.name, f.args) for f in fits], lambda: None, jobs, env, prog=PROG)


def export(fit: Fit, out: Path, env: dict) -> Path:
    model = out / f"{fit.name}.pt"
    cmd = [sys.executable, "-m", "svbrdf_train", "export", str(out / fit.name / "last.pt"), "-o", str(model)]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"{PROG}: error: export of {fit.name} failed: {(done.stderr or done.stdout).strip()}")
    return model


# -- scoring --------------------------------------------------------------------------------------


@dataclass
class TestSet:
    name: str
    files: list[Path]
    groups: list[tuple[str, ...]]  # the materials of each file
    models: list[str]  # labels of the models scored on it (mean last)
    results: dict = field(default_factory=dict)  # label -> PerMaterial

    @property
    def one_set(self) -> bool:
        """Every strip shows the same materials: per-material figures are one set counted again."""
        return len(set(self.groups)) == 1


def score_tests(tests: list[TestSet], models: dict) -> None:
    """Network maps (no refinement) of each model, at the strip's resolution, against the truth."""
    import torch

    from svbrdf_render import read_des18, refine_start
    from svbrdf_train.data.real.materials import per_material

    score = _sibling("refine_curve").score
    cache: dict[Path, list] = {}
    for test in tests:
        rows: dict[str, list] = {label: [] for label in test.models}
        for i, (f, groups) in enumerate(zip(test.files, test.groups, strict=True)):
            sample = read_des18(f)
            photo, truth = sample.input, sample.svbrdf
            size = tuple(photo.shape[-2:])
            for label in test.models:
                key = (f.resolve(), label)
                if key not in cache:  # a strip scored in two test sets is predicted once
                    with torch.no_grad():
                        pred = models[label](photo) if label == "mean" else models[label].predict(photo[0])
                    cache[key] = score(refine_start(pred, size), truth)
                rows[label].append((groups, cache[key]))
            print(f"  {test.name}: {i + 1}/{len(test.files)} {f.name}", file=sys.stderr, flush=True)
        test.results = {label: per_material(r) for label, r in rows.items()}


# -- report ---------------------------------------------------------------------------------------


def comparisons(test: TestSet, fits: list[Fit]) -> list[tuple[str, str]]:
    """``(row, reference)`` pairs scored on ``test``: the chain, each against ``mean``, real against
    resize+norm+phone."""
    have = set(test.models)
    pairs = [(b, a) for a, b in zip(CHAIN, CHAIN[1:]) if a in have and b in have]
    pairs += [(f.label, "mean") for f in fits if f.label in have]
    if REFERENCE in have:
        pairs += [(f.label, REFERENCE) for f in fits if not f.procedural_only and f.label in have]
    return pairs


def table(test: TestSet, fits: list[Fit]) -> str:
    from svbrdf_bench.metrics import bootstrap_ci, paired_difference

    MAPS = _sibling("refine_curve").MAPS
    first = next(iter(test.results.values()))
    materials = list(first.materials)
    one = test.one_set
    head = "| model | " + " | ".join(MAPS) + " |\n|---|" + "---|" * len(MAPS)
    if one:
        what = (
            f"{len(test.files)} strips, all of the same {len(materials)} material"
            f"{'s' if len(materials) > 1 else ''} ({' + '.join(materials)}): the per-material means "
            "coincide, so the figures are means over these strips and there is no interval over "
            "materials (one pair is one sample)"
        )
    else:
        what = (
            f"{len(test.files)} strips, {len(materials)} materials (RMSE, mean over materials "
            "[95% bootstrap over materials])"
        )
    lines = [f"### {test.name}: {what}", "", head]
    for label in test.models:
        cells = []
        for k in MAPS:
            m, lo, hi = bootstrap_ci(test.results[label].values(k))
            cells.append(f"{m:.4f}" if one else f"{m:.4f} [{lo:.4f}, {hi:.4f}]")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    pairs = comparisons(test, fits)
    if pairs:
        how = (
            "change in % of the reference (one pair of materials: no interval, no verdict)"
            if one
            else "paired over materials, change in % of the reference [95% bootstrap]; better / worse: "
            "the interval excludes 0"
        )
        lines += ["", f"Changes ({how}):", "", "| model | against | " + " | ".join(MAPS) + " |",
                  "|---|---|" + "---|" * len(MAPS)]  # fmt: skip
        for label, ref in pairs:
            cells = []
            for k in MAPS:
                a, b = test.results[label].values(k), test.results[ref].values(k)
                base = sum(b) / len(b)
                if one:
                    cells.append(f"{100 * (sum(a) / len(a) - base) / base:+.0f}%")
                else:
                    cells.append(paired_difference(a, b).percent_of(base, "better"))
            lines.append(f"| {label} | {ref} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def report(tests: list[TestSet], fits: list[Fit], args, generator_version: str, models: dict) -> dict:
    data = {
        "procedural_generator_version": generator_version,
        "minutes": args.minutes,
        "size": args.size,
        "fits": {
            f.label: {
                "name": f.name,
                "recipe": f.recipe,
                "sets": [*COMMON_SETS, *f.sets],
                "data": str(f.data) if f.data else "procedural",
                "fold": f.fold,
                "model": models[f.label].describe(),
                "command": f.args[2:],
            }
            for f in fits
        },
        "tests": {
            t.name: {
                "files": [p.name for p in t.files],
                "one_material_set": t.one_set,
                "models": {
                    label: {"materials": r.materials, "strips_per_material": r.counts, "mean": r.mean,
                            "strips": r.strips}
                    for label, r in t.results.items()
                },
            }
            for t in tests
        },
    }  # fmt: skip
    return data


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="generalisation.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("unseen", type=Path, help="folder of strips of unseen materials, one material per file "
                   "(e.g. unseen-dev)")  # fmt: skip
    p.add_argument("des18", type=Path, help="Des18 folder of strips with ground truth (e.g. des18-dev): "
                   "judged whole, and split into the --folds")  # fmt: skip
    p.add_argument("-o", "--out", type=Path, default=Path("generalisation"),
                   help="fits, models, folds and the report (default: generalisation)")  # fmt: skip
    p.add_argument("--variants", default=",".join(VARIANT_NAMES),
                   help=f"comma-separated subset of {', '.join(VARIANT_NAMES)} (default: all); "
                   "real: one fit per fold")  # fmt: skip
    p.add_argument("--folds", default=DEFAULT_FOLDS,
                   help="held-out material sets, ';'-separated hold-out:MatA+MatB specs (names or "
                   f"unambiguous prefixes; default: {DEFAULT_FOLDS})")  # fmt: skip
    p.add_argument("--minutes", type=float, default=15.0,
                   help="training budget per fit, CPU minutes (default 15)")  # fmt: skip
    p.add_argument("--jobs", type=int, default=2, help="fits at a time (default 2)")
    p.add_argument("--size", default="cpu", choices=("cpu", "smoke", "paper"),
                   help="recipe size (default cpu)")  # fmt: skip
    p.add_argument("--threads", type=int, default=1, help="torch threads per fit and for scoring (default 1: "
                   "on a shared 2-core machine more threads per process slow every process "
                   "down)")  # fmt: skip
    p.add_argument("--skip-fit", action="store_true",
                   help="reuse OUT/NAME/last.pt of earlier fits: export and score again")  # fmt: skip
    p.add_argument("--print", dest="show", action="store_true", help="print the fits' commands, run nothing")
    args = p.parse_args(argv)
    try:
        for name, folder in (("unseen", args.unseen), ("des18", args.des18)):
            if not folder.is_dir():
                raise UsageError(f"{folder}: no such folder; give the {name} folder of strips")
        if not args.minutes > 0 or args.jobs < 1 or args.threads < 1:
            raise UsageError("--minutes must be > 0, --jobs and --threads at least 1")
        from svbrdf_models.errors import DataError
        from svbrdf_train.data.real.materials import group_samples, strip_files

        variants = parse_variants(args.variants)
        folds = parse_folds(args.folds, args.des18)
        unseen_files, des18_files = strip_files(args.unseen), strip_files(args.des18)
        if not unseen_files:
            raise UsageError(f"{args.unseen}: no .png strips there")
        try:
            des18_groups = group_samples(des18_files, "des18")[1]
        except DataError as e:
            raise UsageError(str(e)) from None
        fits = plan(variants, folds, args.out, args.minutes, args.size)
        if args.skip_fit:
            missing = [f.name for f in fits if not (args.out / f.name / "last.pt").is_file()]
            if missing:
                raise UsageError(
                    f"--skip-fit: no {args.out / missing[0] / 'last.pt'}"
                    f"{f' (nor for {len(missing) - 1} more)' if len(missing) > 1 else ''}; "
                    "fit first (no --skip-fit)"
                )
    except UsageError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    if args.show:
        for f in fits:
            print(f"OMP_NUM_THREADS={args.threads} svbrdf-train {shlex.join(f.args[3:])}")
        return 0

    env = {**os.environ, "OMP_NUM_THREADS": str(args.threads), "MKL_NUM_THREADS": str(args.threads)}
    args.out.mkdir(parents=True, exist_ok=True)
    write_folds(args.des18, folds, args.out, env)
    if not args.skip_fit:
        run_fits(fits, args.jobs, env)

    import torch

    import svbrdf_models as sm
    from svbrdf_train.data.procedural import GENERATOR_VERSION

    torch.set_num_threads(args.threads)
    models = {f.label: sm.load_model(export(f, args.out, env)) for f in fits}
    models["mean"] = sm.create_generator("mean", {})
    procedural = [f.label for f in fits if f.procedural_only]
    tests = [TestSet(args.unseen.name, unseen_files, group_samples(unseen_files, "file")[1],
                     [*(f.label for f in fits), "mean"])]  # fmt: skip
    if procedural:
        tests.append(TestSet(args.des18.name, des18_files, des18_groups, [*procedural, "mean"]))
    for fold in folds:
        real = [f.label for f in fits if f.fold == fold.name]
        if procedural or real:
            judge = sorted(fold.judge)
            tests.append(TestSet(f"{fold.name} judge", judge, group_samples(judge, "des18")[1],
                                 [*procedural, *real, "mean"]))  # fmt: skip
    score_tests(tests, models)

    lines = [
        "# Generalisation: pilot fits judged per material",
        "",
        f"Fits: recipe size {args.size}, {args.minutes:g} CPU minutes each, {args.threads} thread(s); "
        f"procedural data: generator version {GENERATOR_VERSION} (the installed code's). Scores: "
        "network maps (no refinement) at the strip's resolution; RMSE of the stored maps and of "
        "renderings under the 6 evaluation views.",
        "",
        "| model | recipe | overrides | data | model file |",
        "|---|---|---|---|---|",
        *(
            f"| {f.label} | {f.recipe} | {', '.join(f'`{s}`' for s in f.sets) or '-'} | "
            f"{f.data or 'procedural'} | {models[f.label].describe()} |"
            for f in fits
        ),
        "",
    ]
    text = "\n".join(lines) + "\n" + "\n".join(table(t, fits) for t in tests)
    (args.out / "generalisation.md").write_text(text)
    data = report(tests, fits, args, GENERATOR_VERSION, models)
    (args.out / "generalisation.json").write_text(json.dumps(data, indent=1) + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
