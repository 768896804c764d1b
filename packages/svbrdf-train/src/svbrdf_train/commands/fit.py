"""``svbrdf-train fit``: train a recipe, tracked in MLflow, resumable."""

from __future__ import annotations

import contextlib
import re
import sys
from pathlib import Path

import click

from ..recipe import KEEP_BEST_METRICS, SIZES
from .options import FiniteFloatRange, experiment_option, explicit, threads_option

#: What ``--init`` takes for an MLflow run id (anything else is a checkpoint or a fit's folder).
_RUN_ID = re.compile(r"[0-9a-f]{32}")

EPILOG = """\b
Examples:
  svbrdf-train fit --recipe ours --size smoke          # seconds: check the setup
  svbrdf-train fit --recipe ours --size cpu            # minutes on a laptop CPU
  svbrdf-train fit --recipe ours --data train.h5 --max-minutes 60
  svbrdf-train fit --recipe no-adv --size cpu --set optim.lr=1e-4 --set train.batch=4
  svbrdf-train fit --recipe ours --size cpu --set data.real_validation=des18-dev/   # + val_real/
  svbrdf-train fit --out runs/ours-cpu --resume        # continue after Ctrl-C or a crash
  svbrdf-train fit --recipe ours-finetune --size cpu --init runs/ours-cpu --data des18/  # fine-tune
  svbrdf-train fit --recipe ours-mix --size cpu --data des18/   # procedural and real, half and half
  svbrdf-train fit --recipe ours-materials --size cpu --init pretrained --data real-train/  # real maps
  torchrun --nproc_per_node=2 -m svbrdf_train fit --recipe ours --size cpu   # data parallel

\b
Recipes: svbrdf-train recipes. Runs go to MLflow: MLFLOW_TRACKING_URI, else ./mlflow.db;
look at them with `mlflow ui --backend-store-uri sqlite:///mlflow.db`.
Exit status: 0 finished (or stopped by its time budget); 1 stopped by a non-finite loss or
gradient (the last good checkpoint is kept); 2 bad arguments or input, refused before training;
3 a file could not be written (disk full, read-only...: the message names it; the last good
checkpoint is kept, no temporary file is left); 130 interrupted (a checkpoint was saved).
"""


def _data_overrides(items: tuple[str, ...]) -> dict:
    """``--data`` values -> recipe overrides: ``procedural``, shard files/folders, or one Des18 folder."""
    from svbrdf_models.errors import DataError

    if not items:
        return {}
    if items == ("procedural",):
        return {"data.source": "procedural", "data.path": None}  # a shards recipe's path goes too
    paths = [Path(p).expanduser() for p in items]
    for p in paths:
        if not p.exists():
            raise DataError(
                f"--data {p}: no such file or folder; give shard files (.h5), a folder of them, "
                "a Des18 folder, or 'procedural'"
            )
    shards = all(p.suffix == ".h5" or (p.is_dir() and any(p.glob("*.h5"))) for p in paths)
    if shards:
        return {"data.source": "shards", "data.path": [str(p) for p in paths]}
    if len(paths) == 1 and paths[0].is_dir():
        return {"data.source": "des18", "data.path": str(paths[0])}
    raise DataError(
        f"--data {' '.join(items)}: not shards (.h5 files or a folder of them) nor one Des18 folder "
        "(PNG strips, or trainBlended/ and testBlended/)"
    )


def system_metrics_option():
    """``--system-metrics``: MLflow's system metrics on the runs this command makes (off by default).

    The flag sets MLflow's own switch (``MLFLOW_ENABLE_SYSTEM_METRICS_LOGGING=true``, see
    :func:`svbrdf_train.tracking.enable_system_metrics`) while the options are read, so the
    command's function takes no argument for it, and the processes it starts inherit it.
    """

    def turn_on(ctx, param, value):
        if value:
            from ..tracking import enable_system_metrics

            enable_system_metrics()

    return click.option(
        "--system-metrics",
        is_flag=True,
        expose_value=False,
        callback=turn_on,
        help="Log the machine's CPU, memory, disk, network (and GPU) use every 10 s as system/... "
        "metrics of the MLflow runs this command makes (MLflow's system metrics; same as "
        "MLFLOW_ENABLE_SYSTEM_METRICS_LOGGING=true).",
    )


@click.command("fit", epilog=EPILOG)
@click.option(
    "--recipe",
    "recipe_name",
    metavar="NAME|FILE",
    help="Recipe name or YAML file (not needed with --resume).",
)
@click.option(
    "--size",
    type=click.Choice(SIZES),
    default="paper",
    show_default=True,
    help="paper: the paper's setup (GPU days); cpu: minutes on a CPU; smoke: seconds, for tests.",
)
@click.option(
    "--data",
    "data",
    multiple=True,
    metavar="procedural|PATH",
    help="Training data: 'procedural' (generated, the default), .h5 shards (repeat for several) "
    "or a Des18 folder. Overrides the recipe's data source; for a mix recipe (ours-mix), the "
    "path of its real entries.",
)
@click.option(
    "--max-minutes",
    type=FiniteFloatRange(min=0),
    help="Stop after this much training time, validation excluded, on the recipe's train.clock: "
    "by default the process's CPU time over its threads on a CPU (a busy machine cannot shorten "
    "it), GPU time on a GPU. 0: after the first step.",
)
@click.option("--max-steps", type=click.IntRange(min=1), help="Stop after this many generator steps.")
@click.option(
    "--keep-best",
    metavar="METRIC",
    type=click.Choice(KEEP_BEST_METRICS),
    help="Keep the weights of the best validation so far in OUT/best.pt, by this metric (lower is "
    "better): val_fold/rmse/render chooses on the held-out fold of real materials, which a fit that "
    "overfits needs; val_real is never chosen on. Sets train.keep_best.",
)
@click.option(
    "--set",
    "sets",
    multiple=True,
    metavar="SECTION.FIELD=VALUE",
    help="Override any recipe field, e.g. --set loss.adv=0 --set generator.config.preset=small.",
)
@click.option(
    "--out",
    type=click.Path(path_type=Path, file_okay=False),
    help="Folder of the checkpoint (last.pt), the weights alone (weights.pt: for predict and --init), "
    "the resolved recipe and sample grids [default: runs/RECIPE-SIZE].",
)
@click.option(
    "--resume", is_flag=True, help="Continue the fit in --out from its checkpoint, in the same MLflow run."
)
@click.option(
    "--force", is_flag=True, help="Start afresh even though --out holds a checkpoint (it is replaced)."
)
@click.option("--device", default="auto", show_default=True, help="auto, cpu, cuda or cuda:K.")
@threads_option()
@experiment_option("svbrdf")
@click.option("--run-name", help="MLflow run name [default: RECIPE-SIZE].")
@click.option(
    "--parent-run", metavar="RUN_ID", help="Make the MLflow run a child of this one (benchmarks do)."
)
@click.option(
    "--init",
    metavar="CHECKPOINT|MODEL|RUN_ID",
    help="Start from trained weights (a checkpoint, a fit's --out folder, a model file such as "
    "pretrained or pretrained:NAME, or an MLflow run id) in a new fit and run: the generator's, "
    "and the discriminator's if it is the same. To fine-tune.",
)
@click.option("--no-track", is_flag=True, help="Do not log to MLflow (local files only).")
@system_metrics_option()
@click.option("-q", "--quiet", is_flag=True, help="No progress line.")
@click.pass_context
def fit(
    ctx,
    recipe_name,
    size,
    data,
    max_minutes,
    max_steps,
    keep_best,
    sets,
    out,
    resume,
    force,
    device,
    experiment,
    run_name,
    parent_run,
    init,
    no_track,
    quiet,
):
    """Train a generator (and its discriminator) from a recipe.

    Shows step, losses, samples/s and ETA; logs every loss term, validation RMSE per map, sample
    grids and checkpoints to one MLflow run. Ctrl-C saves a checkpoint first; --resume goes on.
    """
    from ..errors import RecipeError
    from ..training.trainer import FitOptions
    from ..training.trainer import fit as run_fit

    if init and resume:
        raise RecipeError(
            "--init starts a new fit from trained weights and --resume continues one; give one of them"
        )
    if recipe_name is None and resume and explicit(ctx, "size"):
        raise RecipeError(
            f"--size {size} goes with --recipe; --resume without --recipe continues the checkpoint's "
            "recipe at the size it was started with"
        )
    _check_init_run(init)
    overrides, read = _overrides(recipe_name, size, data, sets, max_minutes, max_steps, keep_best)
    recipe, out = _recipe_and_out(recipe_name, size, overrides, out, resume, read)
    options = FitOptions(
        out=out,
        resume=resume,
        force=force,
        device=device,
        experiment=experiment,
        run_name=run_name,
        parent_run=parent_run,
        init=init,
        progress=not quiet,
        track=not no_track,
        overrides=overrides if recipe is None else {},  # --resume alone: the trainer applies them
    )
    with _output_lock(out) if _is_main() else contextlib.nullcontext():
        result = run_fit(recipe, options)
    if _is_main():
        click.echo("\n".join(_summary(result)), err=result.status != "FINISHED")
    sys.exit(result.exit_code)


def _check_init_run(init: str | None) -> None:
    """Refuse ``--init RUN_ID`` of a deleted MLflow run before anything is read or built."""
    if init and not Path(init).expanduser().exists() and _RUN_ID.fullmatch(init):
        from ..training.checkpoint import check_run_kept

        hint = f"restore it (mlflow runs restore --run-id {init}) or give another run"
        check_run_kept(init, "--init", hint)


def _overrides(recipe_name, size, data, sets, max_minutes, max_steps, keep_best=None):
    """The recipe overrides of the command line (``--set`` items, then ``--data``, then the
    budgets), and the recipe file when reading them needed it (else None)."""
    from ..recipe import parse_overrides, read_recipe

    overrides = parse_overrides(sets)
    data_overrides = _data_overrides(data)
    read = None
    if recipe_name is not None and data_overrides.get("data.source") not in (None, "procedural"):
        # a mix keeps its entries: --data gives the path of those that name none
        read = read_recipe(recipe_name)
        if (read.settings(size, overrides).get("data") or {}).get("source") == "mix":
            del data_overrides["data.source"]
    clash = sorted(set(data_overrides) & set(overrides)) if data else []
    if clash:  # --data would win without a word
        from ..errors import RecipeError

        raise RecipeError(f"--data and --set {clash[0]}={overrides[clash[0]]} both set {clash[0]}; give one")
    overrides.update(data_overrides)
    for flag, key, value in (
        ("--max-minutes", "train.max_minutes", max_minutes),
        ("--max-steps", "train.max_steps", max_steps),
        ("--keep-best", "train.keep_best", keep_best),
    ):
        if value is None:
            continue
        if key in overrides:  # one of the two would win without a word
            from ..errors import RecipeError

            shown = f"{value:g}" if isinstance(value, int | float) else value
            raise RecipeError(f"{flag} {shown} and --set {key}={overrides[key]} both set {key}; give one")
        overrides[key] = value
    return overrides, read


def _recipe_and_out(recipe_name, size, overrides: dict, out: Path | None, resume: bool, read=None):
    """The recipe to fit and its output folder: the named recipe (``runs/RECIPE-SIZE`` by default;
    ``read``: its file, when already read), or with ``--resume`` alone None: the fit reads the
    recipe saved in ``out``'s checkpoint, and applies ``overrides`` (budget changes) to it."""
    from ..errors import RecipeError
    from ..recipe import read_recipe

    if recipe_name is None and not resume:
        raise RecipeError(
            "--recipe is required (a name from `svbrdf-train recipes`, or a YAML file); "
            "or pass --resume with --out to continue a fit"
        )
    if out is None:
        if recipe_name is None:
            raise RecipeError("--resume needs --out: the folder of the fit to continue")
        out = Path("runs") / f"{Path(recipe_name).stem}-{size}"
    if recipe_name is not None:
        return (read or read_recipe(recipe_name)).recipe(size, overrides), out
    return None, out


def _summary(result) -> list[str]:
    """What a finished fit prints: its status, throughput, last validation, checkpoint and run."""
    lines = [f"{result.status.lower()}: {result.message}"]
    if result.samples_per_s is not None:
        lines.append(f"  throughput: {result.samples_per_s:.1f} samples/s after warm-up")
    for prefix, title in (
        ("val/", "validation RMSE"),
        ("val_real/", "real validation RMSE"),
        ("val_fold/", "held-out fold RMSE"),
    ):
        shown = {k: v for k, v in result.metrics.items() if k.startswith(prefix + "rmse/")}
        if shown:
            lines.append(
                f"  {title}: " + ", ".join(f"{k.rsplit('/', 1)[-1]} {v:.4f}" for k, v in shown.items())
            )
    if result.checkpoint is not None:
        lines.append(f"  checkpoint: {result.checkpoint} (step {_saved_step(result.checkpoint)})")
        if result.best:
            b = result.best
            lines.append(
                f"  best: {result.checkpoint.parent / 'best.pt'} (step {b['step']}, {b['metric']} {b['value']:.4f}; "
                "ship it: svbrdf-train export that file)"
            )
    if result.run_id is not None:
        lines.append(f"  MLflow run: {result.run_id}")
    return lines


def _saved_step(path: Path) -> str:
    import json

    try:
        return str(json.loads(path.with_suffix(".json").read_text())["step"])
    except (OSError, ValueError, KeyError):
        return "?"


#: The lock file a fit holds in its output folder while it runs; it holds the fit's PID.
LOCK_NAME = ".fit.lock"


@contextlib.contextmanager
def _output_lock(out: Path):
    """Hold ``out/.fit.lock`` for the fit's lifetime: a second fit on ``out`` (new or --resume) is
    refused with one line naming the PID of the fit that holds it.

    The lock is :func:`svbrdf_render.plumbing.locked`, not waiting, the PID written in the
    lock file: a fit that dies, even by SIGKILL, releases it, so a lock file left by a dead
    process is simply taken over. The file is removed when the fit ends, and so is ``out`` if the
    fit made it and left it empty (refused early). Where ``flock`` is missing (Windows)
    ``filelock`` locks the same file, without the PID.
    """
    from svbrdf_render.plumbing import LockHeld, check_output_folder, locked

    from ..errors import TrainingError

    check_output_folder(out, "--out")
    made = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    held = contextlib.ExitStack()
    try:
        held.enter_context(locked(out / LOCK_NAME, wait=False, pid=True))
    except LockHeld as busy:
        if busy.holder is None:  # pragma: no cover - Windows: no PID to name
            raise TrainingError(
                f"--out {out}: another fit is writing there; wait for it to end or choose another --out"
            ) from None
        raise TrainingError(
            f"--out {out}: another fit (PID {busy.holder or 'unknown'}) is writing there; wait for it "
            "to end, or choose another --out"
        ) from None
    try:
        with held:
            yield
    finally:
        if made:
            with contextlib.suppress(OSError):
                out.rmdir()  # only when empty: a fit refused before it wrote anything


def _is_main() -> bool:
    import os

    return os.environ.get("RANK", "0") == "0"


COMMANDS = [fit]
