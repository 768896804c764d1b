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
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from svbrdf_render import MAP_NAMES

from .errors import BenchError
from .layout import PUBLISHED

__all__ = ["PublishedRow", "Published", "read_published", "parse_published", "check_test_set",
           "log_published", "TEST_SETS", "FIGURE_NAMES", "MARK", "DOCS_SECTION"]  # fmt: skip

#: The test sets a file may name, and what a run's test set must be for each.
TEST_SETS = {"des18": "the synthetic test set of Deschaintre et al. 2018"}
#: The figures a row may give, under ``rmse`` and ``lpips``.
FIGURE_NAMES = (*MAP_NAMES, "render")
#: How the report marks a published row.
MARK = "published, not rerun"
#: Where the file format is documented.
DOCS_SECTION = 'docs/svbrdf-bench.md, "Published numbers"'
_TOP_KEYS = ("test_set", "protocol", "rows")
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
    unknown = [k for k in doc if k not in _TOP_KEYS]
    if unknown:
        raise _fail(origin, f"unknown key {unknown[0]!r}; the file has {', '.join(_TOP_KEYS)}")
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
    return Published(test_set, protocol, parsed, origin, text)


def check_test_set(published: Published | None, test) -> None:
    """Refuse a file whose test set is not the run's: ``des18`` numbers need ``--test-data`` strips
    grouped as Des18 strips (``test``: a :class:`~svbrdf_bench.testset.TestSet`)."""
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


def log_published(parent, published: Published | None) -> None:
    """The file, as written, logged in the ``parent`` run (an :class:`svbrdf_train.MlflowTracker`)
    as :data:`~svbrdf_bench.layout.PUBLISHED`, for ``svbrdf-bench report`` to read back."""
    if published is None:
        return
    with tempfile.TemporaryDirectory(prefix="svbrdf-bench-published-") as tmp:
        target = Path(tmp) / Path(PUBLISHED).name
        target.write_text(published.text, encoding="utf-8")
        parent.log_artifact(target, str(Path(PUBLISHED).parent))
