"""``svbrdf-train export``: a checkpoint -> a model file that runs with svbrdf-models alone."""

from __future__ import annotations

from pathlib import Path

import click

EPILOG = """\b
Examples:
  svbrdf-train export runs/ours-cpu/last.pt -o ours.pt
  svbrdf-train export --run 3f2a... -o ours.pt --register svbrdf-ours
  svbrdf-train export runs/ours-cpu -o ours.pt --half --hash-name

\b
The file holds the generator's weights (no discriminator, optimiser or random state: about a
third of a checkpoint), its registry name and complete config, the training resolution, the
recipe, and provenance: git sha, steps, training time, hardware, the data (with the names of
the real files it learnt) and the run. Load it without svbrdf-train:

\b
  import svbrdf_models as sm
  model = sm.load_model("ours.pt")      # or an https URL, models:/NAME/VERSION, runs:/ID/...
  maps = model.predict(photo)           # linear (3, H, W) photo -> SVBRDF

\b
--half stores float16 weights (half the size); they are widened back to float32 to run. The
export measures and prints what the rounding moves in the maps (RMSE and largest change per
map on 8 procedural photos) and records it in the file.
--hash-name names the file NAME-<8 hex digits of its SHA-256>.pt, the name torch.hub checks a
download against: publish it under that name for load_model(URL).
--register NAME logs the file to MLflow as a model of the python_function flavour (in the
training run when the store has it) and adds it as a new version of registered model NAME,
tagged with its config, metrics and SHA-256; the UI lists it under Models,
mlflow.pyfunc.load_model(URI).predict(photos) and `mlflow models serve -m URI --env-manager
local` run it, and predict --model / svbrdf-bench run --from-models take the URI it prints.
"""


def _parse_metric(ctx, param, values):
    out = {}
    for item in values:
        key, sep, value = item.partition("=")
        try:
            out[key.strip()] = float(value)
        except ValueError:
            raise click.BadParameter(f"expected NAME=NUMBER, got {item!r}") from None
        if not sep or not key.strip():
            raise click.BadParameter(f"expected NAME=NUMBER, got {item!r}")
    return out


@click.command("export", epilog=EPILOG)
@click.argument("checkpoint", required=False, type=click.Path(path_type=Path))
@click.option("--run", "run_id", metavar="RUN_ID", help="Export the weights an MLflow run logged instead.")
@click.option(
    "-o",
    "--out",
    type=click.Path(path_type=Path, dir_okay=False),
    required=True,
    help="The model file to write.",
)
@click.option("--half", is_flag=True, help="Store float16 weights (half the size; the effect is measured).")
@click.option("--hash-name", is_flag=True, help="Name the file NAME-<SHA-256 prefix>.pt (for URLs).")
@click.option("--register", "register_as", metavar="NAME", help="Register it in the MLflow model registry.")
@click.option(
    "--metric",
    "metrics",
    multiple=True,
    metavar="NAME=VALUE",
    callback=_parse_metric,
    help="A figure to record with the model (repeatable), e.g. --metric des18-dev/rmse/render=0.094.",
)
@click.option("--force", is_flag=True, help="Replace -o even when it is not a model file (a checkpoint...).")
def export(checkpoint, run_id, out, half, hash_name, register_as, metrics, force):
    """Write a trained generator as one model file: weights, config, resolution, provenance.

    CHECKPOINT is a checkpoint file (last.pt, weights.pt) or a fit's --out folder.
    """
    from svbrdf_models.modelfile.download import hash_name as hashed
    from svbrdf_models.modelfile.files import save_model
    from svbrdf_render.plumbing import check_output_folder

    from ..errors import CheckpointError

    if (checkpoint is None) == (run_id is None):
        raise CheckpointError("give the weights as CHECKPOINT (a file or a fit's folder) or --run RUN_ID")
    check_output_folder(out.parent, "-o")
    from ..training.export import check_export_target, export_contents, register

    check_export_target(out, force)  # a fit's last.pt under -o would be lost: refused
    state, source, run = _read(checkpoint, run_id)

    contents = export_contents(state, source, half=half, run=run, metrics=metrics)
    sha = save_model(out, contents)
    if hash_name:
        final = hashed(out, sha)
        if final != out:
            try:
                check_export_target(final, force)
            except Exception:
                out.unlink(missing_ok=True)
                raise
        out.replace(final)
        out = final
    out.with_name(out.name + ".sha256").write_text(f"{sha}  {out.name}\n")
    info = contents["provenance"]
    size = out.stat().st_size / 2**20
    click.echo(
        f"{out}: generator {contents['generator']['name']} at {contents['resolution']} px, "
        f"{info['steps']} steps ({info['train_seconds'] / 3600:.2f} h of training), "
        f"{contents['precision']}, {size:.1f} MiB",
        err=True,
    )
    click.echo(f"SHA-256 {sha} (also in {out.name}.sha256)", err=True)
    if half:
        worst = max(info["half_effect"].items(), key=lambda kv: kv[1]["max"])
        parts = ", ".join(f"{m} {e['rmse']:.1e}" for m, e in info["half_effect"].items())
        click.echo(
            f"float16 weights move the maps by an RMSE of {parts}; at most {worst[1]['max']:.1e} "
            f"({worst[0]}), on 8 procedural photos",
            err=True,
        )
    if register_as:
        uri, logged_in = register(out, contents, sha, register_as, info.get("run_id"))
        click.echo(f"registered as {uri} (model logged in MLflow run {logged_in})", err=True)
        click.echo(uri)
    else:
        click.echo(str(out))


def _read(checkpoint: Path | None, run_id: str | None):
    """The checkpoint's state, a name for it, and the MLflow run's tags and metrics (--run only)."""
    from ..training.checkpoint import CHECKPOINT_NAME, load_checkpoint

    if checkpoint is not None:
        path = checkpoint / CHECKPOINT_NAME if checkpoint.is_dir() else checkpoint
        return load_checkpoint(path), str(path), None
    from mlflow import MlflowClient

    from ..training.init import download_run_checkpoint

    state = download_run_checkpoint(run_id)
    data = MlflowClient().get_run(run_id).data
    metrics = {k: v for k, v in data.metrics.items() if k.startswith(("val/", "val_real/"))}
    return state, f"MLflow run {run_id}", {"tags": dict(data.tags), "metrics": metrics}


COMMANDS = [export]
