"""A training checkpoint -> a model file that inference loads with svbrdf-models alone.

``svbrdf-train export`` calls :func:`export_contents` on a checkpoint (a file, or the weights an
MLflow run logged) and writes it with :func:`svbrdf_models.save_model`; ``--register`` then
logs the file to MLflow as an MLflow model (:mod:`svbrdf_models.modelfile.pyfunc`) and makes it a version
of a registered model (:func:`register`). A finished fit logs its generator the same way
(:func:`log_fit_model`).

The file keeps the generator only (no discriminator, optimiser or random state), its complete
config, the training resolution and recipe, and where it came from (:func:`provenance`).
"""

from __future__ import annotations

import contextlib
import datetime
import importlib.metadata
from pathlib import Path
from typing import Any

import torch

from svbrdf_models import create_generator
from svbrdf_models.modelfile.files import model_dict
from svbrdf_render import MAP_NAMES

from ..errors import CheckpointError

__all__ = [
    "export_contents", "provenance", "describe_data", "half_effect", "register", "log_fit_model",
    "MODEL_ARTIFACT", "check_export_target",
]  # fmt: skip

#: The name of the MLflow model a finished fit logs in its run (``runs:/RUN_ID/model``);
#: ``--register`` logs ``model-<SHA-256 prefix>``, one name per file.
MODEL_ARTIFACT = "model"


def describe_data(recipe: dict[str, Any]) -> dict[str, Any]:
    """What a fit trained on, from its recipe: sources, weights, paths and the real files used.

    The names of the real files (Des18 strips, shards) are listed when their folder is still
    there, so a benchmark can refuse to judge a model on the strips it learnt.
    """
    data = recipe.get("data") or {}
    entries = data.get("mix") if data.get("source") == "mix" else [data]
    sources = []
    for entry in entries or []:
        source = {"source": entry.get("source", "procedural")}
        if "weight" in entry:
            source["weight"] = entry["weight"]
        if source["source"] == "procedural":
            source["seed"] = entry.get("seed", data.get("seed", 0))
        else:
            paths = entry.get("path") or data.get("path")
            paths = [paths] if isinstance(paths, str) else list(paths or [])
            source["path"] = paths
            files = [
                p.name
                for f in paths
                for p in (sorted(Path(f).iterdir()) if Path(f).is_dir() else [Path(f)])
                if Path(f).exists() and p.suffix.lower() in (".png", ".h5", ".hdf5")
            ]
            if files:
                source["files"] = files
        sources.append(source)
    return {"sources": sources, "samples_per_epoch": data.get("count")}


def provenance(state: dict[str, Any], source: str, run: dict[str, Any] | None = None) -> dict[str, Any]:
    """Where the weights came from: code, steps, time, data, machine, run."""
    recipe = state.get("recipe") or {}
    made = dict(state.get("made_with") or {})
    tags = (run or {}).get("tags", {})
    train = recipe.get("train") or {}
    steps = int(state.get("step", 0))
    return {
        "git_sha": made.get("git_sha") or tags.get("git_sha", "unknown"),
        "git_dirty": made.get("git_dirty") or tags.get("git_dirty", "unknown"),
        "recipe": recipe.get("name"),
        "size": recipe.get("size"),
        "steps": steps,
        "samples": steps * int(train.get("batch", 0)) * int(state.get("world_size") or 1),
        "train_seconds": float(state.get("train_seconds", 0.0)),
        "wall_seconds": float(state.get("wall_seconds", 0.0)),
        "clock": train.get("clock", "auto"),
        "hardware": made.get("hardware") or tags.get("device", "unknown"),
        "device": made.get("device") or tags.get("device", "unknown"),
        "world_size": int(state.get("world_size") or 1),
        "data": describe_data(recipe),
        "init": state.get("init"),
        "run_id": state.get("run_id"),
        "checkpoint": source,
        "exported_at": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "exported_with": {
            dist: importlib.metadata.version(dist) for dist in ("svbrdf-models", "svbrdf-train")
        }
        | {"torch": str(torch.__version__)},
    }


@torch.no_grad()
def half_effect(name: str, config: dict[str, Any], weights: dict[str, torch.Tensor], resolution: int) -> dict:
    """How much rounding the weights to float16 moves the maps: RMSE and largest difference per
    map, on 8 procedural photos at the model's resolution (seed 123, not a training seed)."""
    from ..data.procedural import ProceduralMaterials

    photos = ProceduralMaterials(8, resolution, seed=123).batch(range(8))["input"]
    full = create_generator(name, config).eval()
    full.load_state_dict(weights)
    half = create_generator(name, config).eval()
    half.load_state_dict({k: v.half().float() if v.is_floating_point() else v for k, v in weights.items()})
    a, b = full(photos), half(photos)
    effect = {}
    for m in MAP_NAMES:
        d = getattr(a, m) - getattr(b, m)
        effect[m] = {"rmse": float(d.square().mean().sqrt()), "max": float(d.abs().max())}
    return effect


def check_export_target(out: Path, force: bool = False) -> None:
    """Refuse (:class:`~svbrdf_render.SVBRDFError`, before any work) to write a model file over
    a file that is not one (a fit's checkpoint, a photo, anything else) unless ``force``: the
    file would be lost, and a checkpoint overwritten can no longer be resumed. A model file over
    a model file, or a new path, is always fine; a folder in the way is always refused."""
    from svbrdf_models.modelfile.modelcheck import is_model_file
    from svbrdf_render import SVBRDFError

    out = Path(out)
    if out.is_dir():
        raise SVBRDFError(f"-o {out}: is a folder; give the path of the model file to write")
    if force or not out.exists() or is_model_file(out):
        return
    from .checkpoint import FORMAT

    try:
        head = torch.load(out, map_location="cpu", weights_only=True, mmap=True)
        what = "a training checkpoint" if isinstance(head, dict) and head.get("format") == FORMAT else None
    except Exception:  # not a torch file at all
        what = None
    what = what or "a file that is not a model file"
    raise SVBRDFError(
        f"-o {out}: {what} is there and would be lost; pass --force to replace it, or choose another -o"
    )


def export_contents(
    state: dict[str, Any],
    source: str,
    *,
    half: bool = False,
    run: dict[str, Any] | None = None,
    metrics: dict[str, float] | None = None,
) -> dict[str, Any]:
    """The model file's contents for a checkpoint ``state`` (see :mod:`svbrdf_models.modelfile.files`)."""
    recipe = state.get("recipe") or {}
    generator = recipe.get("generator") or {}
    if state.get("generator") is None or not generator.get("name"):
        raise CheckpointError(f"{source}: it holds no generator weights or no recipe; nothing to export")
    resolution = int((recipe.get("train") or {}).get("resolution", 256))
    name, config = generator["name"], generator.get("config") or {}
    info = provenance(state, source, run)
    if half:
        info["half_effect"] = half_effect(name, config, state["generator"], resolution)
    merged = {**(run or {}).get("metrics", {}), **(metrics or {})}
    return model_dict(
        name,
        config,
        state["generator"],
        resolution=resolution,
        recipe=recipe,
        provenance=info,
        metrics=merged,
        half=half,
    )


def log_fit_model(run, metrics: dict[str, float]) -> str | None:
    """A finished fit's generator as the MLflow model ``model`` of its run (``run``: a
    :class:`svbrdf_train.training.run.Run`), made as ``svbrdf-train export`` makes a model file, with
    the last validation ``metrics``; its URI (``models:/MODEL_ID``).

    A failure (the store, the disk) does not fail the finished fit: it is said on the terminal
    and in the run's tags, and None is returned, as it is for a fit that is not tracked.
    """
    if run.run_id is None:  # not tracked: mlflow may not even be installed
        return None
    import tempfile

    from svbrdf_models.modelfile.files import save_model
    from svbrdf_models.modelfile.pyfunc import log_pyfunc_model

    try:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / f"{run.recipe.name}.pt"
            save_model(path, export_contents(run.state([]), str(run.ckpt_path), metrics=metrics))
            return log_pyfunc_model(path, MODEL_ARTIFACT, run_id=run.run_id, step=run.gan.step).model_uri
    except Exception as e:  # MLflow's and the disk's errors alike; the checkpoint is saved
        why = (str(e).strip().splitlines() or [""])[0][:200]
        text = (
            f"the trained model was not logged to MLflow ({type(e).__name__}: {why}); "
            f"make it with `svbrdf-train export {run.out} -o MODEL.pt --register NAME`"
        )
        run.progress.message(text)
        with contextlib.suppress(Exception):  # the store may be what failed
            run.tracker.set_tags({"svbrdf.warning.model": text})
        return None


def register(
    path: Path, contents: dict[str, Any], sha256: str, name: str, run_id: str | None
) -> tuple[str, str]:
    """Log the model file as an MLflow model and register it as a new version of ``name``.

    The MLflow model (:mod:`svbrdf_models.modelfile.pyfunc`: the file, a signature, an input example and
    requirements; ``mlflow.pyfunc.load_model`` and ``mlflow models serve`` take it) is logged as
    ``model-<SHA-256 prefix>`` of the training run (``run_id``) when the store has it, else of a
    new run of experiment ``svbrdf-models`` holding the provenance; the version carries the
    generator, its config and the metrics as tags. Returns ``(model URI, run id)``.
    """
    from mlflow.exceptions import MlflowException

    from svbrdf_models.modelfile.pyfunc import log_pyfunc_model

    client, run_id = _export_run(contents, run_id)
    logged = log_pyfunc_model(path, f"{MODEL_ARTIFACT}-{sha256[:8]}", run_id=run_id)
    try:
        client.create_registered_model(name, description="svbrdf generators (svbrdf-train export --register)")
    except MlflowException:
        pass  # it exists: a new version is added
    info = contents["provenance"]
    version = client.create_model_version(
        name,
        source=logged.model_uri,
        run_id=run_id,
        tags=_version_tags(contents, sha256),
        description=f"{path.name}: {contents['generator']['name']} at {contents['resolution']} px, "
        f"{info['steps']} steps; SHA-256 {sha256}",
        model_id=logged.model_id,
    )
    return f"models:/{name}/{version.version}", run_id


def _export_run(contents: dict[str, Any], run_id: str | None):
    """An MlflowClient and the run to log the model in: the training run ``run_id`` when the store
    has it, else a new finished run of experiment ``svbrdf-models`` holding the file's metrics
    (at its training step, so that the logged model shows them)."""
    import mlflow
    from mlflow.exceptions import MlflowException

    from ..tracking import experiment_id, open_client

    uri = mlflow.get_tracking_uri()
    client = open_client(uri)
    if run_id:
        try:
            return client, client.get_run(run_id).info.run_id
        except MlflowException:
            pass
    exp_id = experiment_id(client, uri, "svbrdf-models")
    run = client.create_run(exp_id, run_name=f"export-{contents['generator']['name']}")
    client.log_param(run.info.run_id, "generator", contents["generator"]["name"])
    for key, value in contents["metrics"].items():
        client.log_metric(run.info.run_id, key.replace(":", "_"), value, step=contents["provenance"]["steps"])
    client.set_terminated(run.info.run_id)
    return client, run.info.run_id


def _version_tags(contents: dict[str, Any], sha256: str) -> dict[str, str]:
    """A registered version's tags: what the file is, where from, its config and metrics."""
    info = contents["provenance"]
    return {
        "generator": contents["generator"]["name"],
        "resolution": str(contents["resolution"]),
        "precision": contents["precision"],
        "sha256": sha256,
        "steps": str(info["steps"]),
        "train_hours": f"{info['train_seconds'] / 3600:.2f}",
        "git_sha": str(info["git_sha"]),
        "hardware": str(info["hardware"]),
        **{f"config.{k}": str(v) for k, v in contents["generator"]["config"].items()},
        **{f"metric.{k}": f"{v:.6g}" for k, v in contents["metrics"].items()},
    }
