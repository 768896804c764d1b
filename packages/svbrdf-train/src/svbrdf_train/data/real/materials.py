"""Which source materials a strip shows, folds that keep them apart, and per-material averages.

A Des18 strip is named ``ID;MatAXMatB;varAXvarB.png`` (e.g.
``0000004;PolishedMarbleFloor_01Xmetal_bumpy_squares;4X2.png``): it blends two source
materials, and other strips of the same folder blend the same ones. A model trained on some
strips of such a folder and judged on others has seen what it is judged on, and a mean over
strips weighs a material by how many strips happen to show it. Three tools undo both:

- :func:`material_groups`: the materials of a strip: the Des18 pair (both, sorted, once each)
  when the name parses, else the file stem as one material of its own (a folder like
  ``unseen-dev``, one material per file). ``strict=True`` refuses a name that does not parse.
- :func:`material_folds` / :func:`fold_from_spec`: train/judge splits in which no judged strip
  shares a source material with any training strip. For a held-out set of materials ``H``: judge
  = the strips whose materials all lie in ``H``, train = the strips with no material in ``H``
  (strips that mix the two are left out of both). The standard list takes every ``H`` of half
  the materials; with Des18's 4 that is the 3 two-versus-two partitions in both directions, 6
  folds, under which every strip of two materials is judged exactly once.
- :func:`per_material`: per-strip scores averaged per material (a strip counts for each of its
  materials), and the mean over materials, which weighs every material alike.

Example::

    from svbrdf_train.data.real.materials import material_folds, per_material
    for fold in material_folds(sorted(Path("des18-dev").glob("*.png"))):
        print(fold.name, len(fold.train), len(fold.judge))
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path, PurePath

from svbrdf_models.errors import DataError

__all__ = [
    "GROUP_BY",
    "DES18_PATTERN",
    "Fold",
    "PerMaterial",
    "des18_materials",
    "material_groups",
    "group_samples",
    "materials_of",
    "material_folds",
    "fold_from_spec",
    "per_material",
    "strip_files",
]

#: How the samples of a test folder are grouped into materials: ``des18`` (by the pair in the
#: name; a name that does not parse is an error), ``file`` (each file a material of its own),
#: ``auto`` (``des18`` when every name parses, else ``file``).
GROUP_BY = ("auto", "des18", "file")
#: The layout of a Des18 strip's name, in words and by example.
DES18_PATTERN = (
    "ID;MaterialAXMaterialB;variantAXvariantB.png "
    "(e.g. 0000004;PolishedMarbleFloor_01Xmetal_bumpy_squares;4X2.png)"
)
#: Prefix of the folds' names.
FOLD_PREFIX = "hold-out:"


def _stem(name_or_path) -> str:
    name = PurePath(str(name_or_path)).name
    return name[: -len(".png")] if name.lower().endswith(".png") else PurePath(name).stem or name


def des18_materials(name_or_path) -> tuple[str, ...] | None:
    """The source materials in a Des18 strip's name (sorted, each once), or None if it does not
    parse as ``ID;MatAXMatB;varAXvarB``."""
    parts = _stem(name_or_path).split(";")
    if len(parts) != 3 or not parts[0]:
        return None
    pair, variants = parts[1].split("X"), parts[2].split("X")
    if len(pair) != 2 or len(variants) != 2 or not all(pair) or not all(variants):
        return None
    return tuple(sorted(set(pair)))


def material_groups(name_or_path, *, strict: bool = False, remedy: str | None = None) -> tuple[str, ...]:
    """The source materials a strip shows: both of a Des18 name's pair, else the file stem.

    Args:
        name_or_path: a file name or path (``.png`` or not).
        strict: refuse a name that is not a Des18 strip's (``--group-by des18``).
        remedy: what the error tells the user to do (default: rename, or group by file).

    Raises:
        DataError: with ``strict``, a name that does not parse; the message names the file.
    """
    found = des18_materials(name_or_path)
    if found is not None:
        return found
    if strict:
        raise DataError(
            f"{name_or_path}: not a Des18 strip name, whose source materials are read from "
            f"{DES18_PATTERN}; {remedy or 'rename the file, or group one material per file'}"
        )
    return (_stem(name_or_path),)


def group_samples(names: Sequence, group_by: str = "auto") -> tuple[str, list[tuple[str, ...]]]:
    """``(mode, groups)``: the materials of each name under ``group_by`` (one of :data:`GROUP_BY`);
    ``mode`` is ``des18`` or ``file`` (what ``auto`` chose)."""
    if group_by not in GROUP_BY:
        raise DataError(f"group by {group_by!r}: choose one of {', '.join(GROUP_BY)}")
    if group_by == "file":
        return "file", [(_stem(n),) for n in names]
    if group_by == "des18":
        return "des18", [material_groups(n, strict=True) for n in names]
    parsed = [des18_materials(n) for n in names]
    if names and all(p is not None for p in parsed):
        return "des18", parsed  # type: ignore[return-value]
    return "file", [(_stem(n),) for n in names]


def materials_of(files: Iterable, remedy: str | None = None) -> list[str]:
    """Every source material of Des18 strips ``files``, sorted (a name that does not parse: DataError)."""
    return sorted({m for f in files for m in material_groups(f, strict=True, remedy=remedy)})


@dataclass(frozen=True)
class Fold:
    """A train/judge split of strips; no judged strip shares a source material with a training one."""

    #: ``hold-out:MatA+MatB``: the held-out materials (those of the judged strips).
    name: str
    held_out: tuple[str, ...]
    #: Strips with no held-out material (what a model of this fold may train on).
    train: list = field(default_factory=list)
    #: Strips whose materials are all held out (what it is judged on).
    judge: list = field(default_factory=list)

    def materials(self, which: str) -> list[str]:
        """The source materials of the ``train`` or ``judge`` strips, sorted."""
        return materials_of(getattr(self, which))


def _fold(files: Sequence, held: Iterable[str]) -> Fold:
    held = tuple(sorted(set(held)))
    h = set(held)
    groups = [(f, set(material_groups(f, strict=True))) for f in files]
    return Fold(
        name=FOLD_PREFIX + "+".join(held),
        held_out=held,
        train=[f for f, g in groups if not g & h],
        judge=[f for f, g in groups if g <= h],
    )


def material_folds(files: Sequence) -> list[Fold]:
    """The standard material folds of Des18 strips ``files``: one per held-out set ``H`` of half the
    materials (judge: strips all in ``H``; train: strips with none in ``H``).

    With 4 materials: the 3 two-versus-two partitions in both directions, 6 folds, in which every
    strip of two materials is judged exactly once. Folds that would judge or train on nothing are
    left out.

    Raises:
        DataError: no files, a name that is not a Des18 strip's, fewer than 2 or an odd number of
            materials (no halves: pick the held-out ones with :func:`fold_from_spec`).
    """
    files = list(files)
    if not files:
        raise DataError("material folds: no strips given; give the .png strips of a Des18 folder")
    materials = materials_of(files)
    n = len(materials)
    if n < 2 or n % 2:
        raise DataError(
            f"material folds: the strips show {n} source material{'s' if n != 1 else ''} "
            f"({', '.join(materials)}); the standard folds hold out half of an even number of "
            "materials; name the held-out materials instead (--hold-out A,B)"
        )
    folds = [_fold(files, held) for held in itertools.combinations(materials, n // 2)]
    return [f for f in folds if f.train and f.judge]


def fold_from_spec(files: Sequence, spec: str, *, where=None) -> Fold:
    """The fold holding out the materials of ``spec``: comma-separated names, each an exact name or an
    unambiguous prefix, case-insensitive (``brick,leather``).

    Raises:
        DataError: a name matching no material or several, or a fold with nothing to train on or
            nothing to judge; the message names the spec and the input and lists the materials.
    """
    files = list(files)
    materials = materials_of(files)
    source = f" in {where}" if where is not None else ""
    known = f"materials{source}: {', '.join(materials)}"
    head = f"--hold-out {spec!r}"
    wanted = [w.strip() for w in str(spec).split(",") if w.strip()]
    if not wanted:
        raise DataError(f"{head}: names no material; give comma-separated {known}")
    held = []
    for w in wanted:
        exact = [m for m in materials if m.lower() == w.lower()]
        hits = exact or [m for m in materials if m.lower().startswith(w.lower())]
        if not hits:
            raise DataError(f"{head}: {w!r} is no known material; {known}")
        if len(hits) > 1:
            raise DataError(f"{head}: {w!r} could be {' or '.join(hits)}; write more of the name ({known})")
        held.append(hits[0])
    fold = _fold(files, held)
    if not fold.judge:
        raise DataError(
            f"{head}: leaves nothing to judge{source}: no strip shows only {'+'.join(fold.held_out)}; "
            f"hold out more materials (a strip is judged when all its materials are held out); {known}"
        )
    if not fold.train:
        raise DataError(
            f"{head}: leaves nothing to train on{source}: every strip shows a held-out material; "
            f"hold out fewer materials; {known}"
        )
    return fold


@dataclass(frozen=True)
class PerMaterial:
    """Per-strip scores averaged per material."""

    #: ``{material: {key: mean over the strips that show it}}``, materials sorted.
    materials: dict[str, dict[str, float]]
    #: ``{material: number of strips that show it}``.
    counts: dict[str, int]
    #: ``{key: mean over materials}``: every material weighs alike, however many strips show it.
    mean: dict[str, float]
    #: Number of strips (rows) averaged.
    strips: int

    def values(self, key: str) -> list[float]:
        """``key``'s per-material means, in the order of :attr:`materials` (for bootstraps)."""
        return [d[key] for d in self.materials.values() if key in d]


def per_material(rows: Iterable[tuple[object, Mapping[str, float]]], *, strict: bool = False) -> PerMaterial:
    """Average per-strip scores per material: ``rows`` of ``(groups, {key: value})``, where ``groups``
    is a strip's materials (a tuple or list) or its name/path (read by :func:`material_groups`).
    A strip counts, whole, for each of its materials.
    """
    acc: dict[str, dict[str, list[float]]] = {}
    counts: dict[str, int] = {}
    strips = 0
    for groups, figures in rows:
        strips += 1
        if isinstance(groups, (str, PurePath)):
            groups = material_groups(groups, strict=strict)
        for g in dict.fromkeys(groups):
            counts[g] = counts.get(g, 0) + 1
            for k, v in figures.items():
                acc.setdefault(g, {}).setdefault(k, []).append(float(v))
    materials = {g: {k: sum(v) / len(v) for k, v in acc.get(g, {}).items()} for g in sorted(counts)}
    keys = dict.fromkeys(k for d in materials.values() for k in d)
    mean = {}
    for k in keys:
        values = [d[k] for d in materials.values() if k in d]
        mean[k] = sum(values) / len(values)
    return PerMaterial(materials, {g: counts[g] for g in sorted(counts)}, mean, strips)


def strip_files(folder) -> list[Path]:
    """The ``.png`` strips of a folder (hidden files left out), sorted."""
    folder = Path(folder)
    return sorted(
        p
        for p in folder.iterdir()
        if p.suffix.lower() == ".png" and not p.name.startswith(".") and p.is_file()
    )
