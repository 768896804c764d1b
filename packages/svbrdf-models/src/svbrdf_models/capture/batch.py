"""The photo tool's command-line side, shared by ``svbrdf-models predict`` and ``svbrdf-train
predict``: photos captured one by one into their folders, progress, the summary table and the
exit status.

::

    status = capture_batch(model, ["a.jpg", "b.png"], Path("maps"), CaptureOptions(refine=100),
                           prog="svbrdf-models", summary={"model": model.source})

Messages go to stderr, one line each, starting with ``PROG: error:`` or ``PROG: note:``; the
folder of each photo captured goes to stdout. Exit status: 0 every photo captured; 1 some
failed; 2 all failed; 3 a file could not be written (the photos after it are not done); 130
interrupted by Ctrl-C or SIGTERM alike (the photo in progress is not written; summary.json lists
the photos done before it, marked ``"interrupted": true``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from svbrdf_render.plumbing import INTERRUPTED, ProgressBar, locked, write_text

__all__ = [
    "HELP_SECTIONS",
    "announce_model",
    "capture_batch",
    "check_material_folders",
    "set_threads",
    "rechoose_threads",
    "write_summary",
    "folder_name",
    "help_text",
    "folder_listing",
    "folder_table",
    "ALBEDO_NOTE",
]

#: The ``--help`` paragraphs both photo commands share (``{refine}``: the command's --refine
#: default; the limits are filled in by :func:`help_text`).
HELP_SECTIONS = (
    """Photos: JPEG or PNG, in colour, the flash roughly at the centre. The EXIF orientation is
applied, then the largest centred square (or --crop X,Y,SIZE, in pixels of the photo as
displayed) is resized to the model's resolution and decoded from sRGB (unless --linear).
With --tiles the square is kept at its own size (or --map-size) and predicted in tiles of
the model's resolution overlapping by half, blended with raised-cosine weights; each tile
sees the flash off its centre, which the model may not have been trained for: check the
re-rendering.""",
    """Refinement (--refine STEPS, default {refine}; 0: the network's maps only): the network's
maps are refined against the photo at the square's own resolution up to {map_size} px
(--map-size N, or full for all of it: a refinement holds about 1.4 KB a pixel, and what this
machine's memory cannot hold is refused before the work starts) through the differentiable
renderer, for at most STEPS steps (and --refine-seconds S), under a flash whose intensity
svbrdf_render.refine_maps finds from the network's maps (or a --reference card measures), and
which stands, when the lens is known (EXIF, --fov), where the fall-off of its light over the
photo puts it, else over the photo's highlight (or --scene FILE, a scene YAML as
`svbrdf-render scene` writes: one camera, one view). The maps written are the refined
ones. A progress bar is drawn on stderr when it is a terminal (nothing when it is not).
Squares or --map-size under {min_refine} px are refused. --backend auto (default) refines
photos from 512x512 up with the compiled renderer (it compiles first, seconds, and is then
about 30% faster per step there) and smaller ones eagerly.""",
    """Each photo gets a material folder DIR/NAME/, every image tagged with its encoding
(PNG cICP/sRGB/gAMA chunks) and listed in material.json; a file marked [OPTION] only with it:
{folder}
--tileable makes opposite edges match (material.json: seam error before and after). A
folder that holds another photo's material is refused before any work; the same photo's
is replaced. DIR/summary.json holds, per photo, the status, notes, the re-rendering RMSE
against the photo (linear) of the maps written and the flash, with refinement the budget,
steps, seconds and the RMSE of the network's and the refined maps; and the median RMSE.""",
    """Refused photos (each reported on its own line, the others still done): missing, folders,
not an image, neither JPEG nor PNG, under {min_side} px on the short side, over {megapixels} megapixels,
grey, translucent alpha, a crop that does not fit. Processed with a note: EXIF rotation,
16-bit PNG, opaque alpha, palette or CMYK, grey saved as RGB, clipped highlights, a square
smaller than the model's resolution.""",
    """stdout: the folder of each photo captured; stderr: progress, where each photo's flash was
taken to be (over its highlight, or assumed: none clear), notes, errors, a summary table.
Exit status: 0 every photo captured; 1 some photos failed, others were captured; 2 every
photo failed, or bad arguments (no model, unreadable model, bad option, -o not writable);
3 a file could not be written (disk full...): the photos after it are not done; 130
interrupted (Ctrl-C or SIGTERM): the photo in progress is not written; summary.json lists the
photos done before it.
Every file is written whole or not at all (summary.json too).""",
)


def help_text(refine: int, *, click: bool = False) -> str:
    """:data:`HELP_SECTIONS` filled in; ``click``: each paragraph kept as written (``\\b``)."""
    from svbrdf_render import MIN_REFINE_SIDE

    from .photos import MAX_PIXELS, MIN_SIDE
    from .refining import DEFAULT_MAP_SIZE

    limits = {"min_refine": MIN_REFINE_SIDE, "min_side": MIN_SIDE, "megapixels": MAX_PIXELS // 1_000_000,
              "map_size": DEFAULT_MAP_SIZE}  # fmt: skip
    parts = [p.format(refine=refine, folder=folder_listing(), **limits) for p in HELP_SECTIONS]
    return "\n\n".join(f"\b\n{p}" if click else p for p in parts)


# -- the material folder as people read it: made from its declaration (material.FOLDER) ----------

#: How the listings show an encoding; "albedo" is said under them (:data:`ALBEDO_NOTE`).
_SHOWN = {"srgb": "sRGB", "linear": "linear", "albedo": "sRGB*", "": ""}
ALBEDO_NOTE = "*sRGB unless --albedo-encoding linear (the default with --linear), as Des18 stores them"
_NORMAL_SHOWN = "opengl (y up; --normal dx: directx, green flipped)"


def _rows() -> list[tuple[str, str, str, str]]:
    """``(name, encoding, holds, when)`` of each file the folder may hold, as the listings show them."""
    from .material import FOLDER, WHEN

    return [(f.name, _SHOWN[f.encoding], f.holds.format(normal=_NORMAL_SHOWN), WHEN[f.when][0])
            for f in FOLDER]  # fmt: skip


def folder_listing() -> str:
    """The material folder in ``predict --help``: a line per file (wrapped), then the albedo note."""
    import textwrap

    lines = []
    for name, encoding, holds, when in _rows():
        text = f"{holds} [{when}]" if when != "always" else holds
        first = f"  {name:<22} {encoding:<7} "
        lines += textwrap.wrap(text, 92, initial_indent=first, subsequent_indent=" " * len(first))
    return "\n".join([*lines, f"  {ALBEDO_NOTE}"])


def folder_table() -> str:
    """The material folder as docs/capture.md shows it: a Markdown table, then the albedo note."""
    lines = ["| file | encoding | holds | written |", "| --- | --- | --- | --- |"]
    for name, encoding, holds, when in _rows():
        cell = holds.replace("|", "\\|")  # a bare bar would end the cell
        lines.append(f"| `{name}` | {encoding} | {cell} | {when} |")
    return "\n".join([*lines, "", ALBEDO_NOTE.replace("*", "\\*", 1)])


def announce_model(model, line: str, tile_size: int | None) -> None:
    """``line`` (the model, as the command loaded it) on stderr, and with --tiles --map-size what
    the tiles will cost; a --map-size under the model's resolution is refused first."""
    from ..errors import DataError

    if tile_size is not None and tile_size < model.resolution:
        raise DataError(f"--map-size {tile_size} is smaller than the model's resolution ({model.resolution})")
    print(line, file=sys.stderr)
    if tile_size is not None:
        from svbrdf_render.plumbing import machine

        from .tiles import tile_count, tiled_capture_bytes

        have = machine.available_memory()
        print(
            f"--tiles --map-size {tile_size}: {tile_count(tile_size, model.resolution)} tiles of "
            f"{model.resolution} px per photo, about {tiled_capture_bytes(tile_size) / 2**30:.1f} GiB "
            f"of memory" + (f" ({have / 2**30:.1f} GiB available)" if have is not None else ""),
            file=sys.stderr,
        )


def set_threads(requested: int | None):
    """Choose and set the torch threads (:func:`svbrdf_render.plumbing.choose_threads`: one per
    free core unless ``requested``); say so on stderr, and at the end of every progress line
    when the machine is busy. Returns the :class:`~svbrdf_render.plumbing.ThreadChoice`."""
    from svbrdf_render.plumbing import choose_threads

    global _CHOICE
    choice = _CHOICE = choose_threads(requested)
    print(choice.describe(), file=sys.stderr)
    _busy_note(choice)
    return choice


#: The thread choice of the command in progress (:func:`set_threads`), chosen again before
#: each photo of a batch when it was made from the free cores (:func:`rechoose_threads`).
_CHOICE = None


def _busy_note(choice) -> None:
    plural = "s" if choice.threads > 1 else ""
    ProgressBar.busy_note = f" (busy machine: {choice.threads} thread{plural})" if choice.busy else ""


def rechoose_threads(prog: str) -> None:
    """Before each photo after the first: the threads chosen again from the cores free now,
    when the command chose them so (not ``--threads`` nor ``OMP_NUM_THREADS``): a machine that
    gets busy half-way through a batch would otherwise keep threads spinning for cores that
    another program holds (a 3.5 s refinement took 42-181 s). A change is said in one line."""
    global _CHOICE
    from svbrdf_render.plumbing import choose_threads

    if _CHOICE is None or _CHOICE.source != "free cores":
        return
    choice = choose_threads(None)
    if choice.threads != _CHOICE.threads:
        print(f"{prog}: now {choice.describe()}", file=sys.stderr, flush=True)
    _CHOICE = choice
    _busy_note(choice)


def folder_name(path: Path, used: set[str]) -> str:
    """The photo's stem as the name of one folder inside ``-o``, numbered (``NAME-2``, ...) when
    an earlier photo of the batch took it. Leading dots and spaces go (``...png`` would name
    ``..``, the folder above ``-o``; ``..png`` would name ``.``, ``-o`` itself; ``.x.png`` a
    hidden folder), and a stem left empty becomes ``photo``: a folder made from a photo's name
    never leaves ``-o``."""
    stem = path.stem.lstrip(". ").rstrip(" ") or "photo"
    name, k = stem, 1
    while name in used:
        k += 1
        name = f"{stem}-{k}"
    return name


def check_material_folders(photos, out: Path) -> None:
    """Before any work: refuse (:class:`DataError`) when the folder a photo would be captured
    into holds another material (:func:`svbrdf_models.capture.material.check_material_folder`)."""
    from .material import check_material_folder

    used: set[str] = set()
    for path in map(Path, photos):
        if path.is_file():
            name = folder_name(path, used)
            used.add(name)
            check_material_folder(Path(out) / name, path)


def capture_batch(predictor, photos, out: Path, options, *, prog: str, summary: dict) -> int:
    """Capture each photo into ``out/NAME``, write ``out/summary.json`` (with ``summary``'s
    fields), print the table; the exit status (see the module). A photo whose folder holds
    another material fails at its writing (the commands refuse it before the model loads:
    :func:`check_material_folders`)."""
    from svbrdf_render.plumbing import sigterm_as_interrupt

    out = Path(out)
    with sigterm_as_interrupt():  # SIGTERM (kill, a scheduler) stops the batch as Ctrl-C does
        entries, stopped = _capture_all(predictor, photos, out, options, prog)
    if stopped == INTERRUPTED:
        if entries:  # the photos done before the stop keep their summary
            write_summary(out / "summary.json", entries, **summary, interrupted=True)
        return INTERRUPTED

    result = write_summary(out / "summary.json", entries, **summary)
    err = sys.stderr
    this_run = _figures(entries)  # the table and the exit status are this run's, not the folder's
    print(_table(entries, this_run), file=err, end="", flush=True)
    if result["photos"] != len(entries):
        print(f"{out / 'summary.json'}: {result['photos']} photo(s) of this and earlier runs, "
              f"{result['failed']} failed", file=err)  # fmt: skip
    if stopped is not None:
        left = len(photos) - len(entries)
        print(f"stopped: a file could not be written; {left} photo(s) after it not done", file=err)
        return stopped.exit_code
    failed = this_run["failed"]
    if failed:
        print(f"{failed} of {len(photos)} photo(s) failed", file=err)
        return 2 if failed == len(photos) else 1
    return 0


def _capture_all(predictor, photos, out: Path, options, prog: str):
    """Capture each photo into its own folder of ``out``; the summary entries, and what stopped the
    batch (None: every photo was tried; an OutputError; or INTERRUPTED). A photo that fails is
    reported and skipped; a file that cannot be written stops the photos after it. An interrupt
    (Ctrl-C, or SIGTERM under :func:`~svbrdf_render.plumbing.sigterm_as_interrupt`) is caught
    wherever it lands, between photos too: the entries of the photos done are kept."""
    entries: list[dict] = []
    now: dict = {}  # the photo in progress and its bar, for an interrupt wherever it lands
    try:
        return entries, _capture_each(predictor, photos, out, options, prog, entries, now)
    except KeyboardInterrupt:
        if "bar" in now:
            now["bar"].close()
        done = f"summary.json of the {len(entries)} before it" if entries else "no photo before it"
        what = f"{now['path']} not written" if "path" in now else "stopped"
        print(f"{prog}: interrupted: {what} ({done})", file=sys.stderr)
        return entries, INTERRUPTED


def _stoppable(bar: ProgressBar):
    """The refinement's ``callback(step, total, loss)``: ``bar`` drawn, and a stop that a signal
    asked for but whose interrupt was lost taken at the next step."""
    from svbrdf_render.plumbing import raise_if_interrupted

    def callback(step: int, total: int, loss: float) -> None:
        raise_if_interrupted()
        bar(step, total, loss)

    return callback


def _capture_each(predictor, photos, out: Path, options, prog: str, entries: list, now: dict):
    """The loop of :func:`_capture_all`: ``entries`` grows as photos are done, ``now`` names the
    photo in progress; what stopped the batch (None, or the OutputError of a failed write)."""
    from svbrdf_render import SVBRDFError
    from svbrdf_render.errors import OutputError
    from svbrdf_render.plumbing import raise_if_interrupted

    from .geometry import flash_line
    from .material import model_record
    from .one import capture_one

    used: set[str] = set()
    made = model_record(predictor)  # in each entry as SOURCE@SHA12: which model, briefly
    made_by = f"{made['source']}@{(made['sha256'] or '?')[:12]}"
    for k, path in enumerate(map(Path, photos)):
        raise_if_interrupted()  # a signal whose interrupt Python dropped (see sigterm_as_interrupt)
        if k:
            rechoose_threads(prog)
        now.clear()
        now["path"] = path
        name = folder_name(path, used)
        _announce_cost(path, options, prog)
        bar = now["bar"] = ProgressBar(path.name)
        try:
            entry = capture_one(predictor, path, out / name, options, progress=_stoppable(bar))
        except OutputError as e:  # the disk, not the photo: the photos after it would fail alike
            bar.close()
            print(f"{prog}: error: {e}", file=sys.stderr)
            entries.append(_failed(name, path, str(e), made_by))
            return e
        except (SVBRDFError, OSError, RuntimeError) as e:  # RuntimeError: out of memory, a broken model
            bar.close()
            what = str(e) if isinstance(e, (SVBRDFError, OSError)) else f"{type(e).__name__}: {e}"
            text = what if what.startswith(str(path)) else f"{path}: {what}"
            print(f"{prog}: error: {text}", file=sys.stderr)
            entries.append(_failed(name, path, text, made_by))
            continue
        bar.close()
        used.add(name)
        print(f"{prog}: {path}: {flash_line(entry['flash'])}", file=sys.stderr)  # found, or assumed
        for note in entry["notes"]:
            print(f"{prog}: note: {path}: {note}", file=sys.stderr)
        entries.append({"name": name, **entry, "model": made_by})
        print(str(out / name), flush=True)
    now.clear()
    return None


def _failed(name: str, path: Path, error: str, model: str) -> dict:
    """The summary entry of a photo that failed: the folder it would have had (so that its next
    capture replaces the entry), the photo, why, and the model that tried."""
    return {"name": name, "photo": str(path), "status": "failed", "error": error, "model": model}


def _announce_cost(path: Path, options, prog: str) -> None:
    """Before a long refinement: about how long and how much memory it takes (from the file's
    header; said when over 10 s or 1 GB): the steps (at most ``--refine-seconds``) and the maps
    and files written after them."""
    from .photos import square_side
    from .refining import AFTER_REFINE_SECONDS_PER_PIXEL, refine_cost, refine_map_size

    side = square_side(path, options.crop) if options.refine and not options.tiles else None
    if side is None:
        return
    size = refine_map_size(side, options.map_size)
    seconds, memory = refine_cost(size, options.refine)
    if options.refine_seconds is not None:
        seconds = min(seconds, options.refine_seconds)
    after = size * size * AFTER_REFINE_SECONDS_PER_PIXEL
    if seconds + after >= 10 or memory >= 2**30:
        print(
            f"{prog}: {path.name}: refining {size} px maps for {options.refine} steps: about "
            f"{seconds + after:.0f} s on 2 cores ({seconds:.0f} s of steps, {after:.0f} s for the maps "
            f"and files) and {memory / 2**30:.1f} GB",
            file=sys.stderr,
            flush=True,
        )


def _table(entries: list[dict], summary: dict) -> str:
    """The summary table: one line per photo, then the median. With refinement, the network's
    RMSE, the refined one (under the same scene) and the steps and seconds taken."""
    names = [Path(e["photo"]).name for e in entries]
    width = max(len("photo"), *(len(n) for n in names))
    refined = any(e.get("refine") for e in entries)
    extra = f"  {'network':>7}  {'steps':>5}  {'seconds':>7}" if refined else ""
    lines = [
        f"{'photo':<{width}}  status  {'rmse':>7}{extra}  {'flash x, y, z':>21}  {'intensity':>9}  notes"
    ]
    for name, e in zip(names, entries, strict=True):
        if e["status"] != "ok":
            dash = f"  {'-':>7}  {'-':>5}  {'-':>7}" if refined else ""
            lines.append(f"{name:<{width}}  failed  {'-':>7}{dash}  {'-':>21}  {'-':>9}")
            continue
        rmse = _number(e["rmse"], ".4f")
        more = ""
        if refined:
            r = e.get("refine") or {}
            more = (
                f"  {_number(r.get('rmse_network'), '.4f'):>7}  {r.get('steps', 0):>5}  "
                f"{_number(r.get('seconds'), '.1f'):>7}"
            )
        pos = ", ".join(_number(v, "+.2f") for v in e["flash"]["position"])
        k = _number(e["flash"]["intensity"], "9.3g")
        lines.append(f"{name:<{width}}  ok      {rmse:>7}{more}  {pos:>21}  {k:>9}  {len(e['notes'])}")
    median = summary["median_rmse"]
    lines.append(
        f"median re-rendering RMSE over {summary['captured']} photo(s): "
        + ("-" if median is None else f"{median:.4f}")
        + " (how well the maps explain these photos, not how right they are)"
    )
    return "\n".join(lines) + "\n"


def _number(value, spec: str) -> str:
    return "nan" if value is None else format(value, spec)


def write_summary(path, entries: list[dict], **extra) -> dict:
    """``summary.json``: the entries, the median RMSE over the photos captured, and ``extra``.

    An earlier ``summary.json`` in the folder (another run into the same ``-o``, or a run
    stopped by Ctrl-C) keeps its entries of other photos: entries are merged by material folder
    (by photo for failed ones), this run's replacing the earlier run's of the same photo. The
    read and the write are one step under a lock of the folder, so two runs lose no entry."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with locked(path.parent):
        return _write_summary(path, _merged(_earlier_entries(path), entries), extra)


def _photo_key(entry: dict) -> str:
    return str(Path(str(entry.get("photo"))).expanduser().resolve())


def _replaced(earlier: dict, new: dict) -> bool:
    """Whether entry ``new`` of this run replaces ``earlier``: the same photo (captured or failed
    again), or a capture into the folder ``earlier`` names (what the folder now holds)."""
    if _photo_key(earlier) == _photo_key(new):
        return True
    return new.get("status") == "ok" and bool(earlier.get("name")) and earlier.get("name") == new.get("name")


def _earlier_entries(path: Path) -> list[dict]:
    """The entries of an earlier summary.json at ``path`` (none when missing or unreadable)."""
    try:
        earlier = json.loads(path.read_text())
    except (OSError, ValueError):
        return []
    entries = earlier.get("entries") if isinstance(earlier, dict) else None
    return [e for e in entries if isinstance(e, dict)] if isinstance(entries, list) else []


def _merged(earlier: list[dict], entries: list[dict]) -> list[dict]:
    return [e for e in earlier if not any(_replaced(e, n) for n in entries)] + list(entries)


#: What the re-rendering RMSE of summary.json and of the printed table says, and what not.
RMSE_MEANS = (
    "how well the maps explain this one photo under the flash found for it, not how right they "
    "are: maps that bake the photo into the diffuse score near 0 and look wrong under any other "
    "light; a highlight stamped into the maps is measured by benchmarks/real_photos.py"
)


def _figures(entries: list[dict]) -> dict:
    """The counts and the median re-rendering RMSE of ``entries``."""
    import statistics

    values = [e["rmse"] for e in entries if e.get("status") == "ok" and e.get("rmse") is not None]
    return {
        "photos": len(entries),
        "captured": sum(e.get("status") == "ok" for e in entries),
        "failed": sum(e.get("status") != "ok" for e in entries),
        "median_rmse": statistics.median(values) if values else None,
    }


def _write_summary(path: Path, entries: list[dict], extra: dict) -> dict:
    summary = {**extra, **_figures(entries), "rmse_means": RMSE_MEANS, "entries": entries}
    write_text(path, json.dumps(summary, indent=2) + "\n")  # atomic: never a 0-byte summary
    return summary
