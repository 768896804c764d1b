"""``svbrdf-train data folds``: train/judge folders in which no judged strip shares a source material
with a training strip (:mod:`svbrdf_train.data.real.materials`)."""

from __future__ import annotations

from pathlib import Path

import click

__all__ = ["COMMANDS", "folds"]

_EPILOG = """\b
Examples:
  svbrdf-train data folds DATA/des18-dev --out folds/
  svbrdf-train data folds DATA/des18-dev --out folds/ --hold-out brick,leather
  svbrdf-train fit --recipe ours --data 'folds/hold-out:brick_uneven_stones+leather_tiles/train'
  svbrdf-bench run --models ours --test-data 'folds/hold-out:brick_uneven_stones+leather_tiles/judge'

\b
Why: a Des18 strip (ID;MatAXMatB;varAXvarB.png) blends two source materials, and the other
strips of its folder blend the same ones. Split by strip, a model is judged on materials it
trained on. Here the split is by material: for a set H of held-out materials,
  judge = the strips whose materials all lie in H,
  train = the strips that show no material of H;
strips mixing the two sides are left out of both.

\b
Folds: without --hold-out, every H of half the materials. With Des18's 4 materials that is
the 3 two-versus-two partitions in both directions, 6 folds, and every strip is judged in
exactly one of them. Each fold is named hold-out:MatA+MatB after its held-out materials.
--hold-out A,B picks one fold: comma-separated materials, each its full name or an unambiguous
prefix, case-insensitive.

\b
Output: OUT/<fold>/train/ and OUT/<fold>/judge/, folders of symbolic links to the strips (no
copies), which `fit --data` and `svbrdf-bench run --test-data` read like any Des18 folder;
links left there by an earlier run are replaced. Then a table of the folds: strips and
materials on each side.
"""


def _clear(folder: Path) -> None:
    """Make ``folder`` an empty folder, removing only the links an earlier run left there."""
    from svbrdf_models.errors import DataError

    folder.mkdir(parents=True, exist_ok=True)
    others = [p for p in folder.iterdir() if not p.is_symlink()]
    if others:
        raise DataError(
            f"{folder}: holds {others[0].name} and {len(others) - 1} more files that are not links "
            "made by `data folds`; give another --out or empty that folder"
            if len(others) > 1
            else f"{folder}: holds {others[0].name}, which is not a link made by `data folds`; "
            "give another --out or remove it"
        )
    for p in folder.iterdir():
        p.unlink()


def _link(files: list[Path], folder: Path) -> None:
    _clear(folder)
    for f in files:
        (folder / f.name).symlink_to(f.resolve())


@click.command("folds", epilog=_EPILOG)
@click.argument("des18_folder", type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--out",
    required=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="Folder to write the folds into, one subfolder per fold (created if missing).",
)
@click.option(
    "--hold-out",
    "spec",
    default=None,
    metavar="A,B,...",
    help="Write only the fold holding out these materials (names or unambiguous prefixes, "
    "case-insensitive), e.g. --hold-out brick,leather. Default: every standard fold.",
)
def folds(des18_folder, out, spec):
    """Split the strips of DES18_FOLDER into material folds: folders of links to train on and
    to judge on, such that no judged strip shares a source material with a training strip."""
    from svbrdf_models.errors import DataError

    from ..data.real.des18 import Des18Folder
    from ..data.real.materials import fold_from_spec, material_folds, materials_of

    try:
        files = Des18Folder(des18_folder, "test", crop=None).files
    except DataError as e:
        raise DataError(f"data folds {e}") from None
    # A name that is not a Des18 strip's fails here, naming the file.
    materials = materials_of(files, "folds split Des18 strips, whose names give their two source materials")
    chosen = [fold_from_spec(files, spec, where=des18_folder)] if spec else material_folds(files)
    rows = []
    for fold in chosen:
        _link(fold.train, out / fold.name / "train")
        _link(fold.judge, out / fold.name / "judge")
        rows.append(
            [
                fold.name,
                str(len(fold.train)),
                ", ".join(fold.materials("train")),
                str(len(fold.judge)),
                ", ".join(fold.materials("judge")),
            ]
        )
    click.echo(f"{len(files)} strips of {len(materials)} materials in {des18_folder}: {', '.join(materials)}")
    head = ["fold", "train strips", "train materials", "judge strips", "judge materials"]
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    click.echo(fmt.format(*head))
    click.echo(fmt.format(*("-" * w for w in widths)))
    for r in rows:
        click.echo(fmt.format(*r))
    judged = sum(int(r[3]) for r in rows)
    click.echo(
        f"wrote {len(rows)} fold{'s' if len(rows) != 1 else ''} to {out}/<fold>/train and judge "
        f"(links to the strips); {judged} judged strips in all"
    )


COMMANDS = [folds]
