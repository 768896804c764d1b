"""Published numbers in the report (``--published FILE.yaml``, :mod:`svbrdf_bench.published`): their
rows in the accuracy tables, the table that sets the protocol they were scored under against this
benchmark's own scoring, their part of results.json and of the exported table.

A published row is copied, not rerun: it has no per-material values, so it gets no interval, no
verdict, no place in the Holm family, the costs or the Pareto front; it is never a
:class:`~svbrdf_bench.report.rows.ModelEntry`. Whether a protocol aspect matches this benchmark's
is read from the words of the file (crop, resize, [-1, 1], remap, pooled, per image...) and said
as ``same``, ``differs`` or ``check by hand`` where the words do not settle it.
"""

from __future__ import annotations

import re

from svbrdf_render import MAP_NAMES

from ..published import AS_PUBLISHED, MARK, PublishedRow
from .figures import Report
from .rows import COLUMNS
from .tables import Table

__all__ = ["this_run", "protocol_check", "published_rows", "with_published", "published_note",
           "protocol_table", "rescored", "rescored_table", "published_json", "export_rows", "export_rescored",
           "export_words", "RESCORED_MARK"]  # fmt: skip

#: How the report marks this run's rows scored again as the published rows were.
RESCORED_MARK = "scored as published"

#: The aspects of a protocol the report compares, in order (a file may name others too).
ASPECTS = ("test strips", "resolution", "crop", "values", "normals", "rmse", "renderings")
SAME, DIFFERS, CHECK = "same", "differs", "check by hand"


def this_run(report: Report) -> dict[str, str]:
    """How this benchmark scores, aspect by aspect (:mod:`svbrdf_bench.metrics`,
    :mod:`svbrdf_bench.testset`)."""
    side = f"{report.resolution} px" if report.resolution else "the models' resolution"
    return {
        "test strips": f"this run's own: {report.test_set}",
        "resolution": f"{side} (the models' training resolution)",
        "crop": f"none: each whole tile resized to {side} (area filter, normals renormalised)",
        "values": "each map on its stored encoding in [0, 1]; diffuse and specular as the strips store "
        "them, roughness as stored (no remap, one channel)",
        "normals": "unit normals encoded as (n + 1) / 2, 3 channels",
        "rmse": "per strip over all pixels and channels, then per material (a Des18 strip counts for both "
        "its materials), then the mean over materials",
        "renderings": "6 fixed light/view pairs, clipped to [0, 1] and sRGB-encoded",
        "gamma": "none: maps compared as stored; only the renderings are sRGB-encoded",
        "lpips": "AlexNet LPIPS on each map and rendering, when its weights are on disk",
    }


#: Words that say a protocol does not crop.
_NO_CROP = ("no crop", "not crop", "uncropped", "without crop")


def _crop(text: str, _side: int | None) -> str:
    cropped = "crop" in text and not any(w in text for w in _NO_CROP)
    return DIFFERS if cropped else SAME if "resiz" in text or "whole" in text else CHECK


def _resolution(text: str, side: int | None) -> str:
    number = re.search(r"\d+", text)
    return CHECK if number is None or side is None else SAME if int(number.group()) == side else DIFFERS


def _values(text: str, _side: int | None) -> str:
    if "-1" in text or "remap" in text:
        return DIFFERS
    return SAME if any(w in text.replace(" ", "") for w in ("[0,1]", "0-1", "0to1")) else CHECK


def _normals(text: str, _side: int | None) -> str:
    if "n+1" in text.replace(" ", ""):
        return SAME
    return DIFFERS if "-1" in text or "vector" in text else CHECK


def _rmse(text: str, _side: int | None) -> str:
    if "pool" in text or "image" in text:  # over all pixels at once, or a mean over images, not materials
        return DIFFERS
    return SAME if "material" in text else CHECK


_RULES = {"resolution": _resolution, "crop": _crop, "values": _values, "normals": _normals, "rmse": _rmse}


def protocol_check(report: Report, protocol: dict[str, str]) -> list[dict[str, str]]:
    """Per aspect (:data:`ASPECTS`, then any other the file names): the published protocol's words,
    this run's, and whether they match (``same``, ``differs``, ``check by hand``)."""
    ours = this_run(report)
    theirs = {"test strips": f"the strips their source tested on ({report.published.test_set})"} | protocol
    out = []
    for aspect in dict.fromkeys([*ASPECTS, *protocol]):
        text = theirs.get(aspect)
        rule = _RULES.get(aspect)
        verdict = CHECK if text is None or rule is None else rule(text.lower(), report.resolution)
        out.append({"aspect": aspect, "published": text or "not given", "this_run": ours.get(aspect, "-"),
                    "verdict": verdict})  # fmt: skip
    return out


def _groups(report: Report) -> dict[tuple, list[PublishedRow]]:
    """The published rows by the protocol they were scored under, in the file's order."""
    out: dict[tuple, list[PublishedRow]] = {}
    for row in report.published.rows if report.published else []:
        out.setdefault(tuple(row.protocol.items()), []).append(row)
    return out


def published_rows(report: Report, metric: str) -> list[list[str]]:
    """The cells of the published rows in the accuracy table of ``metric`` (``rmse``, ``lpips``):
    each figure as printed, ``-`` where the row gives none; no interval. Rows with no figure of
    ``metric`` are left out."""
    out = []
    for row in report.published.rows if report.published else []:
        figures = row.rmse if metric == "rmse" else row.lpips if metric == "lpips" else {}
        if figures:
            out.append([row.label, *(f"{figures[c]:.4f}" if c in figures else "-" for c in COLUMNS)])
    return out


def with_published(table: Table, report: Report, metric: str) -> Table:
    """The accuracy ``table`` of ``metric`` with the published rows under its own, and the note
    on what they are; as it was when no published row gives ``metric``."""
    rows = published_rows(report, metric)
    if rows:
        table.rows += rows
        table.after += published_note(report)
    return table


def published_note(report: Report) -> list[str]:
    """The lines under an accuracy table that holds published rows."""
    if report.published is None:
        return []
    sources = "; ".join(f"{r.name}: {r.source}" for r in report.published.rows)
    return [
        "",
        f"Rows marked ({MARK}): figures copied from {report.published.origin} ({sources}), on "
        f"{report.published.test_set} under their own protocol (\"Published numbers\" below); not computed "
        "here, so they have no interval and take no part in any verdict, the Holm correction, the costs or "
        "the Pareto front.",
    ]


def protocol_table(report: Report) -> Table | None:
    """The protocol behind the published rows against this run's scoring, aspect by aspect; one
    column per protocol (rows may carry their own). None without published numbers."""
    groups = _groups(report)
    if not groups:
        return None
    checks = [protocol_check(report, dict(key)) for key in groups]
    head = ["aspect", "this run", *(f"published: {', '.join(r.name for r in g)}" for g in groups.values())]
    rows = [[c["aspect"], c["this_run"], *(f"{k[i]['published']} ({k[i]['verdict']})" for k in checks)]
            for i, c in enumerate(checks[0])]  # fmt: skip
    scorer = report.published.scorer
    if scorer is not None:  # the rows scored again as the file says the papers scored
        again = scorer.words() | {"test strips": "this run's own"}
        head.insert(2, f"this run, {RESCORED_MARK}")
        for row in rows:
            row.insert(2, again.get(row[0], "-"))
    lpips = [r.name for r in report.published.rows if r.lpips]
    after = [
        "",
        "same / differs: read from the words of the file; check by hand where they do not settle it. A "
        "published figure and this run's are comparable only where every aspect is the same.",
    ]
    if lpips and not any(m[0] == "lpips" for m in report.metrics_present()):
        after.append(f"LPIPS of {', '.join(lpips)}: in results.json; this run computed no LPIPS to set "
                     "them beside.")  # fmt: skip
    return Table(f"Published numbers ({report.published.origin}): their protocol against this run's", head,
                 rows, after)  # fmt: skip


def rescored(report: Report) -> dict[str, dict[str, float]]:
    """Row label -> its map RMSE scored as the published rows were (the file's ``scorer``), for
    every unrefined row that has them; empty without a scorer."""
    if report.published is None or report.published.scorer is None:
        return {}
    out = {}
    for e in report.models:
        figures = {m: e.figures.get(f"{AS_PUBLISHED}rmse/{m}") for m in MAP_NAMES}
        if not e.refine_steps and all(v is not None for v in figures.values()):
            out[e.label] = figures
    return out


def rescored_table(report: Report) -> Table | None:
    """This run's rows scored as the published ones were, with the published rows under them, on
    the maps; None without a ``scorer`` in the file."""
    rows = rescored(report)
    if not rows:
        return None
    scorer = report.published.scorer
    images = next((e.figures.get(f"{AS_PUBLISHED}images") for e in report.models if e.label in rows), None)
    body = [[label, *(f"{v[m]:.4f}" for m in MAP_NAMES)] for label, v in rows.items()]
    body += [[r.label, *(f"{r.rmse[m]:.4f}" if m in r.rmse else "-" for m in MAP_NAMES)]
             for r in report.published.rows if r.rmse]  # fmt: skip
    count = f"{images:.0f} test tiles" if images is not None else "the test tiles"
    after = [
        "",
        f"This run's rows scored again on {count} as the file's scorer says ({scorer.describe()}); the "
        f"published rows copied. One figure per row, over images as the papers take them: no interval, no "
        "verdict. That the papers scored this way is the file's claim; refined rows are not rescored.",
    ]
    title = f"Scored as the published rows ({report.published.origin}): RMSE of the maps, lower is better"
    return Table(title, ["model", *MAP_NAMES], body, after)


def published_json(report: Report) -> dict | None:
    """results.json's ``published``: the file, its test set and rows, each with its protocol and how
    that protocol compares with this run's; None without published numbers."""
    if report.published is None:
        return None
    p = report.published
    rows = [{"name": r.name, "label": r.label, "source": r.source, "rmse": r.rmse, "lpips": r.lpips,
             "protocol": r.protocol, "protocol_check": protocol_check(report, r.protocol)}
            for r in p.rows]  # fmt: skip
    scorer = None if p.scorer is None else {
        "window": p.scorer.window, "size": p.scorer.size, "values": p.scorer.values, "rmse": p.scorer.rmse,
        "words": p.scorer.words(), "rows": rescored(report)}  # fmt: skip
    return {"file": p.origin, "test_set": p.test_set, "marked": MARK, "protocol": p.protocol,
            "this_run": this_run(report), "rows": rows, "scorer": scorer,
            "note": f"copied from {p.origin}, not rerun: no interval, no verdict, outside the Holm family, "
            "the costs and the Pareto front"}  # fmt: skip


def export_rows(report: Report) -> dict[str, list[float | None]]:
    """Row label -> its RMSE per column (None where not given), for the exported table."""
    rows = report.published.rows if report.published else []
    return {r.label: [r.rmse.get(c) for c in COLUMNS] for r in rows if r.rmse}


def export_rescored(report: Report) -> dict[str, list[float | None]]:
    """This run's rows scored as published (a ``scorer``), marked, with their RMSE per column (None:
    renderings, which the scorer does not score), for the exported table."""
    rows = rescored(report)
    return {f"{label} ({RESCORED_MARK})": [v.get(c) for c in COLUMNS] for label, v in rows.items()}


def export_words(report: Report) -> str:
    """The caption's sentences on the published rows and on this run's rows scored as they were
    ('' without either): what they are, and where the published protocol differs from this table's."""
    again = ""
    if rescored(report):
        again = (f"Rows marked {RESCORED_MARK}: this table's models scored again under the file's scorer "
                 f"({report.published.scorer.describe()}). ")  # fmt: skip
    if not any(r.rmse for r in (report.published.rows if report.published else [])):
        return again
    checks = [c for r in report.published.rows for c in protocol_check(report, r.protocol)]
    differs = list(dict.fromkeys(c["aspect"] for c in checks if c["verdict"] == DIFFERS))
    unsure = [a for a in dict.fromkeys(c["aspect"] for c in checks if c["verdict"] == CHECK)
              if a not in differs]  # fmt: skip
    return (
        f"Rows marked {MARK}: RMSE copied from their sources ({report.published.origin}), scored under "
        "their own protocol, which differs from this table's in "
        + (", ".join(differs) or "no aspect the file's words settle")
        + (f" and may differ in {', '.join(unsure)}" if unsure else "")
        + "; shown without interval, never in bold. "
        + again
    )
