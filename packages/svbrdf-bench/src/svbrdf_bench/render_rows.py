"""The rows of ``svbrdf-bench render``'s table (:class:`Row`: one way of rendering, timed and
compared with the float64 reference, as :func:`svbrdf_bench.render_table.measure` fills it) and
how they are shown: a Markdown table (:func:`format_table`), plain records for CSV and JSON
(:func:`to_records`), MLflow metric names (:func:`metric_key`), and a warning in words when the
machine's load made the times unreliable (:func:`timing_warning`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

from .timing import CPU_WAIT_LIMIT, Load

__all__ = ["Row", "COLUMNS", "format_table", "timing_warning", "to_records", "metric_key"]


@dataclass
class Row:
    """One way of rendering, timed and compared with the float64 reference.

    Times in ms (``first_call_s`` in s): medians, and interquartile ranges (``*_iqr_ms``);
    errors are NaN where not measured (see ``note``).
    """

    dtype: str
    backend: str
    effects: str  # "des18", "-fresnel", "+noise", ...
    forward_ms: float = math.nan
    forward_backward_ms: float = math.nan
    forward_iqr_ms: float = math.nan
    forward_backward_iqr_ms: float = math.nan
    first_call_s: float = math.nan
    max_abs_error: float = math.nan
    max_rel_error: float = math.nan
    grad_error: float = math.nan
    note: str = ""
    forward_samples: list[float] = field(default_factory=list, repr=False)
    forward_backward_samples: list[float] = field(default_factory=list, repr=False)
    load: Load | None = field(default=None, repr=False)
    """The machine's load over the timed rounds (the same for every row of one table)."""


# -- output ---------------------------------------------------------------------------------
COLUMNS = (
    ("dtype", "dtype"),
    ("backend", "backend"),
    ("effects", "effects"),
    ("forward_ms", "fwd ms"),
    ("forward_backward_ms", "fwd+bwd ms"),
    ("forward_iqr_ms", "fwd IQR ms"),
    ("forward_backward_iqr_ms", "fwd+bwd IQR ms"),
    ("first_call_s", "first call s"),
    ("max_abs_error", "max abs err"),
    ("max_rel_error", "max rel err"),
    ("grad_error", "grad err"),
    ("note", "note"),
)


def _fmt(key: str, value) -> str:
    if isinstance(value, str):
        return value.replace("|", "/")
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if key.endswith("_ms"):
        return f"{value:.1f}" if value >= 10 else f"{value:.2f}"
    if key == "first_call_s":
        return f"{value:.2f}"
    if value == 0:
        return "0"
    return f"{value:.2e}"


def format_table(rows: Sequence[Row]) -> str:
    """A Markdown table, one line per row; ``-`` where a value was not measured."""
    keep = [c for c in COLUMNS if c[0] != "note" or any(r.note for r in rows)]
    head = [title for _, title in keep]
    align = ["---" if key in ("dtype", "backend", "effects", "note") else "---:" for key, _ in keep]
    lines = ["| " + " | ".join(head) + " |", "| " + " | ".join(align) + " |"]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(key, getattr(r, key)) for key, _ in keep) + " |")
    return "\n".join(lines)


def timing_warning(rows: Sequence[Row]) -> str | None:
    """A sentence when the load over the timed rounds makes the times unreliable, else None."""
    load = next((r.load for r in rows if r.load is not None), None)
    if load is None or not load.unreliable:
        return None
    return (
        f"warning: the times are unreliable: the machine was busy while they were measured ({load.words()}); "
        f"above {100 * CPU_WAIT_LIMIT:.0f}% of the time waiting for a CPU a time is inflated by more than "
        "the spread expected on an idle machine, by an amount that depends on what else ran"
    )


def to_records(rows: Sequence[Row]) -> list[dict]:
    """Plain dicts (CSV/JSON): the table's columns, NaN as None, the timing samples, and the load
    over the timed rounds (``load_cpu_wait``, ``load_other_cpus``, ``load_average``,
    ``load_unreliable``; None where not read)."""
    out = []
    for r in rows:
        d = asdict(r)
        d.pop("load")
        load = r.load
        d |= {
            "load_cpu_wait": load.cpu_wait if load else None,
            "load_other_cpus": load.other_cpus if load else None,
            "load_average": load.load_average if load else None,
            "load_unreliable": load.unreliable if load else None,
        }
        for k, v in d.items():
            if isinstance(v, float) and math.isnan(v):
                d[k] = None
        out.append(d)
    return out


def metric_key(row: Row, name: str) -> str:
    """``name/dtype/backend/effects`` with MLflow-safe effects (``no-fresnel``, ``with-noise``)."""
    label = row.effects
    if label.startswith("-"):
        label = "no-" + label[1:]
    elif label.startswith("+"):
        label = "with-" + label[1:]
    return f"{name}/{row.dtype}/{row.backend}/{label}"
