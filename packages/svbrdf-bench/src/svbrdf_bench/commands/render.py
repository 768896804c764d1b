"""``svbrdf-bench render``: the renderer's accuracy against its time, one table."""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import click

from svbrdf_render.renderer import BACKENDS
from svbrdf_train import experiment_option

EPILOG = """\b
Examples:
  svbrdf-bench render                       # the full table: 8 x 9 renders of 256x256 (minutes)
  svbrdf-bench render --quick --no-track    # seconds: 2 materials at 32x32, eager only
  svbrdf-bench render --backend eager --repeats 3 --out /tmp/bench-render
  svbrdf-bench render --effects none        # only the dtype x backend rows

\b
Rows: float64, float32 and bfloat16 maps x the eager and compiled (torch.compile, fused
backward) backends on the Des18 effects ("des18"); then, in float32 for each backend, the
Des18 scene with one effect removed ("-fresnel"; "-specular" removes the whole lobe) or one
image effect added ("+noise"). bfloat16 maps are upcast to float32 inside the renderer: that
row measures what quantising the inputs costs.

\b
Columns:
  fwd ms        median time of a forward render (maps require grad, as in training)
  fwd+bwd ms    median time of forward + out.mean().backward()
  first call s  the first forward+backward; on the compiled backend it includes compiling,
                unless an earlier row compiled the same kernels (bfloat16 reuses float32's)
                or Inductor's on-disk cache has them (TORCHINDUCTOR_FORCE_DISABLE_CACHES=1
                times a cold compile)
  max abs err   max |x - ref|, ref = the eager float64 render of the same maps and scene
  max rel err   max |x - ref| / max(|ref|, 1e-4 max|ref|)
  grad err      max |grad - ref grad| / max |ref grad| of out.mean() w.r.t. the four maps
  note          why a value is missing (a failed compile, noise drawn per dtype)
"-" marks a value not measured. The eager float64 row is the reference itself: error 0.

\b
Writes DIR/render.md (header and table), render.csv (one line per row) and render.json
(the settings and every timing sample). Runs go to MLflow (MLFLOW_TRACKING_URI, else
./mlflow.db): one run tagged kind=render with metrics such as fwd_ms/float32/eager/des18
and the three files; --no-track skips it. Progress goes to stderr, the table to stdout.
"""

LEGEND = (
    "fwd / fwd+bwd ms: median time of a forward render and of forward + out.mean().backward() "
    "(maps require grad); first call s: the first forward+backward (compiles on the compiled "
    "backend, unless cached); max abs / rel err: the rendering against the eager float64 "
    "rendering of the same maps and scene, rel = |x - ref| / max(|ref|, 1e-4 max|ref|); grad err: "
    "max |grad - ref grad| / max |ref grad| over the four maps; -: not measured (see note). "
    '"-e": the Des18 scene without effect e ("-specular" drops the whole lobe); "+e": with image '
    "effect e added."
)
CSV_COLUMNS = (
    "dtype",
    "backend",
    "effects",
    "forward_ms",
    "forward_backward_ms",
    "first_call_s",
    "max_abs_error",
    "max_rel_error",
    "grad_error",
    "note",
)
METRICS = (
    ("forward_ms", "fwd_ms"),
    ("forward_backward_ms", "fwd_bwd_ms"),
    ("first_call_s", "first_call_s"),
    ("max_abs_error", "max_abs_err"),
    ("max_rel_error", "max_rel_err"),
    ("grad_error", "grad_err"),
)


def _device_name(device: str) -> str:
    import torch

    dev = torch.device(device)
    if dev.type == "cuda" and torch.cuda.is_available():
        return f"{dev.type} ({torch.cuda.get_device_name(dev)})"
    return f"{dev.type} ({platform.processor() or platform.machine()}, {os.cpu_count()} CPUs)"


class _Progress:
    def __init__(self):
        self.start = time.perf_counter()

    def __call__(self, msg: str) -> None:
        click.echo(f"[{time.perf_counter() - self.start:6.1f} s] {msg}", err=True)


def _write(out: Path, header: str, table: str, records: list[dict], meta: dict) -> list[Path]:
    from svbrdf_render.plumbing import write_text

    from ..report import csv_text

    md, csv_path, js = out / "render.md", out / "render.csv", out / "render.json"
    write_text(md, f"{header}\n\n{table}\n\n{LEGEND}\n")
    write_text(csv_path, csv_text(records, CSV_COLUMNS))
    write_text(js, json.dumps({"meta": meta, "rows": records}, indent=2) + "\n")
    return [md, csv_path, js]


@click.command("render", epilog=EPILOG)
@click.option("--size", type=int, help="Map size in pixels, square.  [default: 256; --quick 32]")
@click.option(
    "--materials", type=int, help="Materials per render, 9 configurations each.  [default: 8; --quick 2]"
)
@click.option(
    "--repeats", type=int, help="Timed calls per row; the median is shown.  [default: 5; --quick 1]"
)
@click.option(
    "--backend",
    type=click.Choice([*BACKENDS, "both"]),
    help="Backends to time; compiling takes seconds per effect set.  [default: both; --quick eager]",
)
@click.option(
    "--effects",
    type=click.Choice(["each", "none"]),
    default="each",
    show_default=True,
    help="each: also the float32 rows with each effect toggled; none: only dtype x backend.",
)
@click.option(
    "--quick", is_flag=True, help="A smoke run in seconds: --size 32 --materials 2 --repeats 1, eager."
)
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("bench-render"),
    show_default=True,
    help="Folder for render.md, render.csv and render.json.",
)
@click.option(
    "--device", default="cpu", show_default=True, help="Torch device to render on (cpu, cuda, cuda:1)."
)
@click.option(
    "--seed", type=int, default=0, show_default=True, help="Seed of the random materials and scene."
)
@click.option("--no-track", is_flag=True, help="Do not log the run to MLflow.")
@experiment_option("svbrdf-bench")
def render(size, materials, repeats, backend, effects, quick, out, device, seed, no_track, experiment):
    """Time the renderer in float64, float32 and bfloat16, eager and compiled, with each
    effect on and off, and show how far each result is from the float64 reference.

    Renders MATERIALS materials x 9 configurations (the training scene: 3 directional, 6 point
    lights) at SIZE x SIZE and prints a Markdown table, one row per way of rendering.
    """
    from ..render_rows import format_table, to_records
    from ..render_table import measure

    settings = _settings(size, materials, repeats, backend, quick)
    header, meta = _describe(settings, effects, seed, device)
    tracker = None if no_track else _tracker(settings, effects, seed, experiment, meta)
    status = "FAILED"
    try:
        click.echo(header, err=True)
        start = time.perf_counter()
        rows = measure(**settings, effects=effects, seed=seed, device=device, progress=_Progress())
        total = time.perf_counter() - start
        meta["total_s"] = round(total, 1)
        table = format_table(rows)
        click.echo(f"{header}\n\n{table}")
        files = _write(out, header, table, to_records(rows), meta)
        click.echo(f"wrote {', '.join(str(f) for f in files)} ({total:.0f} s in all)", err=True)
        if tracker is not None:
            _log(tracker, rows, files, total)
        status = "FINISHED"
    except KeyboardInterrupt:
        status = "KILLED"
        raise
    finally:
        if tracker is not None:
            tracker.finish(status)


def _settings(size, materials, repeats, backend, quick) -> dict:
    """The sizes and backends to measure: the flags, else the defaults (``--quick``'s when given);
    as :func:`~svbrdf_bench.render_table.measure`'s arguments."""
    from ..errors import BenchError

    size = size if size is not None else (32 if quick else 256)
    materials = materials if materials is not None else (2 if quick else 8)
    repeats = repeats if repeats is not None else (1 if quick else 5)
    backend = backend or ("eager" if quick else "both")
    for name, value in (("--size", size), ("--materials", materials), ("--repeats", repeats)):
        if value < 1:
            raise BenchError(f"{name} must be at least 1, got {value}")
    backends = list(BACKENDS) if backend == "both" else [backend]
    return {"size": size, "materials": materials, "repeats": repeats, "backends": backends}


def _describe(settings: dict, effects: str, seed: int, device: str) -> tuple[str, dict]:
    """The table's header (with a warning when other processes load the machine) and the
    settings as render.json's ``meta``."""
    import torch

    from svbrdf_render import __version__ as render_version

    from ..errors import BenchError

    try:
        device_name = _device_name(device)
    except (RuntimeError, ValueError) as e:
        raise BenchError(f"--device {device!r}: {str(e).splitlines()[0]}") from None
    size, materials, repeats = settings["size"], settings["materials"], settings["repeats"]
    threads = torch.get_num_threads()
    header = (
        f"svbrdf-bench render: {materials} materials x 9 configurations at {size}x{size}, "
        f"median of {repeats}; torch {torch.__version__}, {threads} threads, device {device_name}, "
        f"svbrdf-render {render_version}"
    )
    meta = {"size": size, "materials": materials, "configurations": 9, "repeats": repeats,
            "backends": settings["backends"], "effects": effects, "seed": seed, "torch": torch.__version__,
            "threads": threads, "device": device_name, "svbrdf_render": render_version}  # fmt: skip
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
    meta["load_average"] = round(load, 2)
    if load > 0.5 * (os.cpu_count() or 1):
        note = (
            f"warning: 1-minute load average {load:.1f} on {os.cpu_count()} CPUs: other processes are "
            "running; the times will be slower and noisier"
        )
        header += f"\n\n{note}"
    return header, meta


def _tracker(settings: dict, effects: str, seed: int, experiment: str, meta: dict):
    """The MLflow run of this table (tagged kind=render)."""
    from svbrdf_render import __version__ as render_version
    from svbrdf_train import MlflowTracker, git_revision

    sha, dirty = git_revision()
    return MlflowTracker(
        experiment=experiment,
        run_name=f"render-{settings['size']}px",
        tags={"kind": "render", "torch": meta["torch"], "device": meta["device"],
              "threads": str(meta["threads"]), "version.svbrdf-render": render_version, "git_sha": sha,
              "git_dirty": str(dirty).lower()},
        params={"size": str(settings["size"]), "materials": str(settings["materials"]),
                "repeats": str(settings["repeats"]), "backends": ",".join(settings["backends"]),
                "effects": effects, "seed": str(seed)},
    )  # fmt: skip


def _log(tracker, rows, files: list[Path], total: float) -> None:
    """Every measured figure as a metric (``fwd_ms/float32/eager/des18``...), and the files."""
    from ..render_rows import metric_key

    metrics = {"total_s": total}
    for row in rows:
        for attr, name in METRICS:
            value = getattr(row, attr)
            if value == value:  # not NaN
                metrics[metric_key(row, name)] = value
    tracker.log_metrics(metrics, step=0)
    for f in files:
        tracker.log_artifact(f)
    click.echo(tracker.describe(), err=True)


COMMANDS = [render]
