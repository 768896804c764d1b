"""Published numbers set beside a benchmark's rows (``svbrdf-bench run --published FILE.yaml``).

The file holds figures a user copied from papers, on a named test set, under the protocol those
papers scored with::

    test_set: des18
    protocol: {crop: "centre 256 of 288 px", resolution: 256, values: "[0, 1]", rmse: per image then mean}
    rows:
      - {name: "Author et al. 2018", source: "venue, Table N", rmse: {normal: 0.05, diffuse: 0.02}}

Each row gives any of the RMSE of ``normal``, ``diffuse``, ``roughness``, ``specular`` and
``render`` (and the same under ``lpips``), and may carry a ``protocol`` of its own, laid over the
file's. :func:`read_published` reads and checks the file (every refusal one line, before anything
is trained); :func:`check_test_set` holds it against the run's test set; :func:`log_published`
keeps it, as written, in the parent run (:data:`~svbrdf_bench.layout.PUBLISHED`), from which
:mod:`svbrdf_bench.report` reads it back with :func:`parse_published`.

The rows are not rerun: the report shows them as ``NAME (published, not rerun)``, without an
interval, outside every verdict and the Pareto front, beside the protocol they were scored
under and the points where this benchmark scores otherwise (:mod:`svbrdf_bench.report.published`).
No numbers ship with the package: ``--published des18`` (a name) is refused, saying why.

Scoring as the papers scored
----------------------------

This benchmark's own figures (:mod:`svbrdf_bench.metrics`) resize each whole test tile to the
models' resolution, score renderings as well as maps and average per material. The papers that
report RMSE on Deschaintre et al. 2018's test set did otherwise, and not all alike
(docs/svbrdf-bench.md, "The Des18 protocols"). A ``--published`` file may therefore carry a
``scorer`` section that says how its rows were scored::

    scorer: {window: centre-crop, size: 256, values: "[0, 1]", rmse: per-image}

and every row of the run (fits, reference models, baselines; refined rows are not rescored) is
then scored a second time that way, by :func:`score_as_published`:

- ``window``: ``centre-crop`` cuts the centre ``size`` x ``size`` pixels out of each stored tile
  (on a 288 px Des18 tile at 256: the window [16, 272), no resampling); ``resize`` brings the
  whole tile to ``size`` px with the area filter (normals renormalised,
  :func:`svbrdf_train.resize_sample`). The model is run on that window at that size, whatever
  resolution it was trained at (the networks are fully convolutional).
- ``values``: the RMSE of each map on its stored encoding in [0, 1] (normals as (n + 1) / 2,
  roughness one channel, no gamma change); ``[-1, 1]`` reports it on the networks' [-1, 1]
  range, which doubles every figure.
- ``rmse``: ``per-image`` takes the RMSE of each image, then the mean over images; ``pooled``
  takes one square root over all images' squared errors (never below the per-image mean).
- Maps only: none of those papers' Des18 evaluations has a rendering metric.

The figures go into the row's MLflow child run as :data:`AS_PUBLISHED` metrics
(``as_published/rmse/normal`` ...), from which the report's "Scored as the published rows"
table is rebuilt (:mod:`svbrdf_bench.report.published`).
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from svbrdf_render import MAP_NAMES

from .errors import BenchError
from .layout import PUBLISHED

__all__ = ["PublishedRow", "Published", "read_published", "parse_published", "check_test_set",
           "log_published", "TEST_SETS", "FIGURE_NAMES", "MARK", "DOCS_SECTION", "PublishedScorer",
           "score_as_published", "parse_scorer", "check_tiles", "AS_PUBLISHED", "WINDOWS", "VALUES",
           "POOLING", "SCORER_KEYS", "MIN_SIZE"]  # fmt: skip

#: The test sets a file may name, and what a run's test set must be for each.
TEST_SETS = {"des18": "the synthetic test set of Deschaintre et al. 2018"}
#: The figures a row may give, under ``rmse`` and ``lpips``.
FIGURE_NAMES = (*MAP_NAMES, "render")
#: How the report marks a published row.
MARK = "published, not rerun"
#: Where the file format is documented.
DOCS_SECTION = 'docs/svbrdf-bench.md, "Published numbers"'
_TOP_KEYS = ("test_set", "protocol", "rows")
#: Keys a file may add: how to score this run's rows as the papers did (:func:`score_as_published`).
_OPTIONAL_KEYS = ("scorer",)
_ROW_KEYS = ("name", "source", "rmse", "lpips", "protocol")


@dataclass(frozen=True)
class PublishedRow:
    """One published result: who, where it was printed, its figures and the protocol behind them."""

    name: str
    source: str
    rmse: dict[str, float]
    lpips: dict[str, float] = field(default_factory=dict)
    #: The file's protocol with the row's own entries laid over it.
    protocol: dict[str, str] = field(default_factory=dict)

    @property
    def label(self) -> str:
        return f"{self.name} ({MARK})"


@dataclass(frozen=True)
class Published:
    """A checked ``--published`` file: its test set, protocol and rows, and its text as written."""

    test_set: str
    protocol: dict[str, str]
    rows: list[PublishedRow]
    #: The file's name (where it came from).
    origin: str
    #: The file's text, kept as written (logged in the parent run).
    text: str
    #: How to score this run's rows as the published ones were (the file's ``scorer``); None: not asked.
    scorer: PublishedScorer | None = None


def read_published(value: str) -> Published:
    """The ``--published`` file ``value``, read and checked; refuses, in one line, a test set's name
    (no numbers ship with svbrdf-bench), an unreadable path and a malformed file."""
    path = Path(value)
    if value in TEST_SETS and not path.is_file():
        raise BenchError(
            f"--published {value}: svbrdf-bench ships no published numbers for {value}: no paper's {value} "
            "table could be read and checked where it was built, and numbers written from memory would be "
            "guesses; copy them from the papers into a YAML file and pass --published FILE.yaml "
            f"({DOCS_SECTION})"
        )
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        why = e.strerror if isinstance(e, OSError) and e.strerror else type(e).__name__
        raise _fail(value, f"cannot read it ({why}); give a YAML file of published numbers") from None
    return parse_published(text, path.name)


def _fail(origin: str, what: str) -> BenchError:
    return BenchError(f"--published {origin}: {what} ({DOCS_SECTION})")


def _text(origin: str, where: str, value) -> str:
    """A non-empty one-line text (numbers are written as text)."""
    if isinstance(value, bool) or not isinstance(value, str | int | float) or not str(value).strip():
        raise _fail(origin, f"{where} must be a non-empty text, got {value!r}")
    return " ".join(str(value).split())


def _protocol(origin: str, where: str, value) -> dict[str, str]:
    if not isinstance(value, dict) or not value:
        raise _fail(origin, f"{where} must be a mapping of aspects (crop, resolution, values, ...) to texts")
    return {_text(origin, f"{where} key", k): _text(origin, f"{where}.{k}", v) for k, v in value.items()}


def _figures(origin: str, where: str, value) -> dict[str, float]:
    if not isinstance(value, dict):
        raise _fail(origin, f"{where} must be a mapping of {', '.join(FIGURE_NAMES)} to numbers")
    out = {}
    for name, number in value.items():
        if name not in FIGURE_NAMES:
            raise _fail(origin, f"{where}.{name}: unknown map; give {', '.join(FIGURE_NAMES)}")
        if isinstance(number, bool) or not isinstance(number, int | float):
            raise _fail(origin, f"{where}.{name} must be a number, got {number!r}")
        if not math.isfinite(number) or number < 0:
            raise _fail(origin, f"{where}.{name} is {number}; an RMSE or LPIPS is a finite number >= 0")
        out[name] = float(number)
    return out


def _row(origin: str, index: int, value, protocol: dict[str, str]) -> PublishedRow:
    where = f"rows[{index}]"
    if not isinstance(value, dict):
        raise _fail(origin, f"{where} must be a mapping with name, source and rmse")
    unknown = [k for k in value if k not in _ROW_KEYS]
    if unknown:
        raise _fail(origin, f"{where}: unknown key {unknown[0]!r}; a row has {', '.join(_ROW_KEYS)}")
    for key, why in (("name", "whose result it is"), ("source", "where it was printed")):
        if key not in value:
            raise _fail(origin, f"{where} has no {key}; every published row says {why}")
    name = _text(origin, f"{where}.name", value["name"])
    where = f"rows[{index}] ({name})"
    source = _text(origin, f"{where}.source", value["source"])
    rmse = _figures(origin, f"{where}.rmse", value.get("rmse", {}))
    lpips = _figures(origin, f"{where}.lpips", value.get("lpips", {}))
    if not rmse and not lpips:
        raise _fail(origin, f"{where} gives no figure; give rmse (or lpips) of at least one map")
    own = _protocol(origin, f"{where}.protocol", value["protocol"]) if "protocol" in value else {}
    return PublishedRow(name, source, rmse, lpips, protocol | own)


def parse_published(text: str, origin: str) -> Published:
    """A ``--published`` file's ``text`` (named ``origin`` in messages), checked: a known
    ``test_set``, a ``protocol``, and ``rows`` each with a name, a source and figures >= 0."""
    import yaml

    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or type(e).__name__
        raise _fail(origin, f"not valid YAML{at} ({problem})") from None
    if not isinstance(doc, dict):
        raise _fail(origin, "expected a mapping with test_set, protocol and rows")
    unknown = [k for k in doc if k not in (*_TOP_KEYS, *_OPTIONAL_KEYS)]
    if unknown:
        known = ", ".join(_TOP_KEYS) + " and optionally " + ", ".join(_OPTIONAL_KEYS)
        raise _fail(origin, f"unknown key {unknown[0]!r}; the file has {known}")
    for key in _TOP_KEYS:
        if key not in doc:
            raise _fail(origin, f"no {key}")
    test_set = _text(origin, "test_set", doc["test_set"])
    if test_set not in TEST_SETS:
        known = ", ".join(TEST_SETS)
        raise _fail(origin, f"test_set {test_set!r} is not one this benchmark can check; known: {known}")
    protocol = _protocol(origin, "protocol", doc["protocol"])
    rows = doc["rows"]
    if not isinstance(rows, list) or not rows:
        raise _fail(origin, "rows must be a non-empty list of published results")
    parsed = [_row(origin, i, r, protocol) for i, r in enumerate(rows)]
    names = [r.name for r in parsed]
    twice = next((n for n in names if names.count(n) > 1), None)
    if twice is not None:
        raise _fail(origin, f"two rows are named {twice!r}; name each row once")
    scorer = parse_scorer(doc["scorer"], lambda what: _fail(origin, what)) if "scorer" in doc else None
    return Published(test_set, protocol, parsed, origin, text, scorer)


def check_test_set(published: Published | None, test) -> None:
    """Refuse a file whose test set is not the run's: ``des18`` numbers need ``--test-data`` strips
    grouped as Des18 strips (``test``: a :class:`~svbrdf_bench.testset.TestSet`), and a ``scorer``
    needs tiles at least as large as its window."""
    if published is None:
        return
    if published.test_set == "des18" and test.group_by != "des18":
        what = "each image its own material" if test.group_by == "image" else f"grouped by {test.group_by}"
        raise _fail(
            published.origin,
            f"its numbers are on des18 ({TEST_SETS['des18']}), but this run tests on {test.description}, "
            f"{what}; give --test-data a folder of Des18 strips (names ID;MatAXMatB;varAXvarB.png) with "
            "--group-by des18 or auto",
        )
    if published.scorer is not None:
        check_tiles(published.scorer, test.sides, published.origin)


def log_published(parent, published: Published | None) -> None:
    """The file, as written, logged in the ``parent`` run (an :class:`svbrdf_train.MlflowTracker`)
    as :data:`~svbrdf_bench.layout.PUBLISHED`, for ``svbrdf-bench report`` to read back."""
    if published is None:
        return
    with tempfile.TemporaryDirectory(prefix="svbrdf-bench-published-") as tmp:
        target = Path(tmp) / Path(PUBLISHED).name
        target.write_text(published.text, encoding="utf-8")
        parent.log_artifact(target, str(Path(PUBLISHED).parent))


# -- scoring as the papers scored ------------------------------------------------------------


#: Prefix of the child-run metrics a row scored as published carries (then ``rmse/<map>``).
AS_PUBLISHED = "as_published/"
#: How the scored window is cut out of a stored tile.
WINDOWS = ("centre-crop", "resize")
#: The value range the RMSE is reported on.
VALUES = ("[0, 1]", "[-1, 1]")
#: How per-image errors are combined.
POOLING = ("per-image", "pooled")
#: The keys of a ``scorer`` section, each required.
SCORER_KEYS = ("window", "size", "values", "rmse")
#: The smallest window the scorer runs a model at.
MIN_SIZE = 8


@dataclass(frozen=True)
class PublishedScorer:
    """How the published rows were scored, as a scorer this benchmark can run (see the module doc)."""

    window: str
    size: int
    values: str
    rmse: str

    def words(self) -> dict[str, str]:
        """The protocol aspects (as :mod:`svbrdf_bench.report.published` names them) this scorer follows."""
        side = f"{self.size} px"
        resized = f"none: each whole tile resized to {side} (area filter, normals renormalised)"
        centre = f"centre {side} of each stored tile, not resampled"
        crop = centre if self.window == "centre-crop" else resized
        scale = "" if self.values == "[0, 1]" else ", reported on [-1, 1] (twice the [0, 1] figure)"
        per_image = "per image over all pixels and channels, then the mean over images"
        root = "pooled: one square root over every image's squared errors"
        pooled = per_image if self.rmse == "per-image" else root
        return {
            "resolution": f"{side} (the models run at it, whatever they were trained at)",
            "crop": crop,
            "values": f"each map on its stored encoding in [0, 1]{scale}; roughness as stored (no remap)",
            "normals": "unit normals encoded as (n + 1) / 2, 3 channels",
            "rmse": pooled,
            "renderings": "none: maps only",
        }

    def describe(self) -> str:
        """One line: how the rows are rescored."""
        w = self.words()
        return f"{w['crop']}; {self.values}; {self.rmse}; maps only"


def parse_scorer(value, fail: Callable[[str], Exception]) -> PublishedScorer:
    """A file's ``scorer`` section checked; ``fail(what)`` makes the one-line refusal."""
    if not isinstance(value, dict):
        raise fail(f"scorer must be a mapping of {', '.join(SCORER_KEYS)}")
    unknown = [k for k in value if k not in SCORER_KEYS]
    if unknown:
        raise fail(f"scorer: unknown key {unknown[0]!r}; a scorer has {', '.join(SCORER_KEYS)}")
    missing = [k for k in SCORER_KEYS if k not in value]
    if missing:
        raise fail(f"scorer has no {missing[0]}; give {', '.join(SCORER_KEYS)}")
    for key, allowed in (("window", WINDOWS), ("values", VALUES), ("rmse", POOLING)):
        if value[key] not in allowed:
            raise fail(f"scorer.{key} is {value[key]!r}; choose one of {', '.join(map(repr, allowed))}")
    size = value["size"]
    if isinstance(size, bool) or not isinstance(size, int) or not MIN_SIZE <= size <= 8192:
        raise fail(f"scorer.size is {size!r}; give the side in px the papers scored at, an integer "
                   f"from {MIN_SIZE} to 8192")  # fmt: skip
    return PublishedScorer(value["window"], size, value["values"], value["rmse"])


def check_tiles(scorer: PublishedScorer, sides: list[int], origin: str) -> None:
    """Refuse test tiles smaller than the scorer's window (``sides``: each tile's stored side)."""
    small = [s for s in sides if s < scorer.size]
    if small:
        raise BenchError(
            f"--published {origin}: its scorer works on {scorer.size} px windows, but {len(small)} of the "
            f"{len(sides)} test tiles are smaller (the smallest {min(small)} px); give --test-data tiles of "
            f"at least {scorer.size} px, or a smaller scorer.size"
        )


def _window(sample: dict, scorer: PublishedScorer) -> dict:
    h = sample["input"].shape[-1]
    if scorer.window == "resize":
        if h == scorer.size:
            return sample
        from svbrdf_train import resize_sample

        return resize_sample(sample, scorer.size)
    o = (h - scorer.size) // 2
    cut = slice(o, o + scorer.size)
    return {"input": sample["input"][..., cut, cut], "maps": sample["maps"][..., cut, cut]}


@torch.no_grad()
def score_as_published(generator, data, scorer: PublishedScorer, device: torch.device,
                       batch: int = 8) -> dict[str, float]:  # fmt: skip
    """``{AS_PUBLISHED + "rmse/<map>": figure}`` of ``generator`` on the stored tiles of ``data`` (a
    data set of samples with ``input`` and ``maps``, at their stored size), scored as ``scorer``
    says, and ``as_published/images``, the number of tiles."""
    from svbrdf_render import SVBRDF
    from svbrdf_render.compare import map_rmse

    errors: dict[str, list[np.ndarray]] = {name: [] for name in MAP_NAMES}
    for start in range(0, len(data), batch):
        windows = [_window(data[i], scorer) for i in range(start, min(start + batch, len(data)))]
        photo = torch.stack([w["input"] for w in windows]).float().to(device)
        target = SVBRDF.unpack(torch.stack([w["maps"] for w in windows]).float().to(device), validate=False)
        for name, v in map_rmse(generator(photo), target).items():
            errors[name].append(v.detach().to("cpu", torch.float64).numpy())
    scale = 2.0 if scorer.values == "[-1, 1]" else 1.0
    out = {f"{AS_PUBLISHED}images": float(len(data))}
    for name, parts in errors.items():
        rmse = np.concatenate(parts)
        figure = rmse.mean() if scorer.rmse == "per-image" else np.sqrt(np.mean(rmse**2))
        out[f"{AS_PUBLISHED}rmse/{name}"] = float(scale * figure)
    return out
