"""What a fit says: its plan, its MLflow run (params and tags), why it stopped, its summary."""

from __future__ import annotations

import torch
from torch import nn

from svbrdf_models import config_to_dict, resolve_config
from svbrdf_render.errors import SVBRDFError

from ..tracking import Tracker, flatten_params, run_tags
from .clock import CLOCK_TAG
from .progress import format_duration
from .run import Run

__all__ = ["open_tracker", "plan", "nan_message", "with_checkpoint_kept", "summary_metrics", "count_params"]


def count_params(module: nn.Module | None) -> int:
    return 0 if module is None else sum(p.numel() for p in module.parameters())


def open_tracker(run: Run, experiment: str, run_name: str | None, parent_run: str | None) -> Tracker:
    """The MLflow run of the fit: a new one with the recipe as params, or the resumed one."""
    from ..tracking import MlflowTracker

    recipe, gan = run.recipe, run.gan
    if run.run_id is not None:  # resumed: a benchmark run again adopts the fit as its child
        more = {"mlflow.parentRunId": parent_run} if parent_run else {}
        return MlflowTracker(
            experiment=experiment, run_id=run.run_id, tags={"svbrdf.resumed_at": str(gan.step), **more}
        )
    tags = run_tags(
        recipe=recipe.name,
        size=recipe.size,
        seed=recipe.train.seed,
        device=str(run.dist.device),
        world_size=run.dist.world,
    )
    tags[CLOCK_TAG] = run.watch.clock.name
    tags.update(run.init or {})
    if parent_run:
        tags["mlflow.parentRunId"] = parent_run
    params = flatten_params(recipe.to_dict())
    for kind in ("generator", "discriminator"):
        section = getattr(recipe, kind)
        if section is not None:
            resolved = config_to_dict(resolve_config(kind, section.name, section.config))
            params.update(flatten_params({f"{kind}.resolved": resolved}))
    params["parameters.generator"] = str(count_params(gan.generator))
    params["parameters.discriminator"] = str(count_params(gan.discriminator))
    params["steps_per_epoch"] = str(run.order.steps_per_epoch)
    params["total_steps"] = str(run.order.total_steps)
    params["world_size"] = str(run.dist.world)
    return MlflowTracker(
        experiment=experiment,
        run_name=run_name or f"{recipe.name}-{recipe.size}",
        tags=tags,
        params=params,
    )


def _threads(device) -> str:
    """`` (2 torch threads)`` on a CPU, where they set the speed; nothing elsewhere."""
    if str(device) != "cpu":
        return ""
    n = torch.get_num_threads()
    return f" ({n} torch thread{'s' if n != 1 else ''})"


def plan(run: Run, real_validation: str | None) -> str:
    """The lines a fit prints when it starts: what, how long, on what, where it writes."""
    t, gan, start = run.recipe.train, run.gan, run.start_step
    name = f"{run.recipe.name} ({run.recipe.size})"
    what = f"resuming {name} at step {start}" if start else f"fitting {name}"
    budget = f"{run.order.total_steps} steps ({run.order.steps_per_epoch}/epoch)"
    if t.max_minutes is not None:
        budget += f" or {format_duration(t.max_minutes * 60)} of training ({run.watch.clock.describe()})"
    d = gan.discriminator
    lines = [
        f"{what}: {budget}, batch {t.batch} x {run.dist.world} process(es) at {t.resolution} px "
        f"on {run.dist.device}{_threads(run.dist.device)}; G {count_params(gan.generator) / 1e6:.2f}M params"
        + (f", D {count_params(d) / 1e6:.2f}M" if d is not None else ", no D")
    ]
    if real_validation:
        lines.append(f"  real validation: {real_validation}")
    if run.init:
        lines.append(
            f"  weights from: {run.init['svbrdf.init']} (step {run.init['svbrdf.init_step']}; "
            f"discriminator: {run.init['svbrdf.init_discriminator']})"
        )
    lines += [f"  checkpoints: {run.ckpt_path}", f"  tracking: {run.tracker.describe()}"]
    return "\n".join(lines)


def nan_message(run: Run, term: str) -> str:
    """Why a fit stopped FAILED: which term or gradient, what was kept, what to change."""
    kept = (
        f"the checkpoint of step {run.saved_at} ({run.ckpt_path}) is kept"
        if run.saved_at > 0
        else "no checkpoint had been written yet"
    )
    hint = "lower optim.lr / optim.d_lr, or check the data for NaN or inf values"
    step = run.gan.step + 1
    what = (
        f"non-finite {term} at step {step}"
        if term.endswith("gradient")
        else f"non-finite loss at step {step}: term {term!r}"
    )
    return f"{what}; nothing was stepped with it; {kept}; {hint}"


def summary_metrics(run: Run) -> dict[str, float]:
    """The figures logged once at the end: times, throughput, peak memory."""
    out = {"train/total_seconds": run.watch.seconds, "train/total_wall_seconds": run.watch.wall_seconds}
    rate = run.watch.steady_rate()
    if rate is not None:
        out["train/steady_samples_per_s"] = rate
    try:
        import resource

        out["train/peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    except (ImportError, OSError):  # not on every platform
        pass
    if run.dist.device.type == "cuda":
        import torch

        out["train/peak_cuda_mb"] = torch.cuda.max_memory_allocated(run.dist.device) / 2**20
    return out


def with_checkpoint_kept(error: SVBRDFError, run: Run) -> SVBRDFError:
    """A write failure during the fit, saying which checkpoint is left to resume from."""
    kept = (
        f"the checkpoint of step {run.saved_at} is kept: --resume continues from it"
        if run.ckpt_path.is_file()
        else "no checkpoint was written yet"
    )
    said = type(error)(f"{error}; {kept}")
    said.exit_code = error.exit_code
    return said
