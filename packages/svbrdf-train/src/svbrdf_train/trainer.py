"""The GAN trainer: one fit of a recipe, tracked in MLflow, resumable, on one process or many.

A step (``step`` counts generator steps)::

    pred = G(photo)
    renderings of pred and of the truth under N light/view configurations (Deschaintre 2018)
    every g_steps_per_d steps: D learns real (truth) against fake (pred, detached)
    L_G = adv * L_adv(D(pred)) + render * L_render + svbrdf * L_svbrdf;  G steps

The discriminator sees log renderings (``log(R + eps)``, as the rendering loss compares them)
of all N configurations, or the maps themselves for ``multi``. Learning rates follow the
paper's step decay counted in samples seen (:mod:`svbrdf_train.schedule`); the fit warns when
that would stop learning early in its budget. Training time is counted
without validation and checkpoint writing, so ``max_minutes`` budgets compare models fairly.

Stopping: at the step budget (``epochs``, ``max_steps``) or the time budget; on a non-finite
loss (FAILED: nothing is stepped with it and the last checkpoint stays as it was); on Ctrl-C
or SIGTERM (KILLED, after saving a checkpoint at the end of the current step).

Reproducibility: every random draw comes from the seed, the step and RNG states saved in the
checkpoint, so a fit stopped at any point and resumed reaches the same weights as one that
never stopped; bitwise on CPU with the same number of threads and processes.
"""

from __future__ import annotations

import contextlib
import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn
from torch.utils.data import DataLoader, Dataset, DistributedSampler, Sampler

from svbrdf_models import config_to_dict, create_discriminator, create_generator, resolve_config
from svbrdf_render import (
    SVBRDF,
    Scene,
    evaluation_scene,
    log_radiance,
    render,
    training_scene,
)
from svbrdf_render.errors import OutputError, SVBRDFError
from svbrdf_render.files import write_text

from . import distributed
from .checkpoint import (
    CHECKPOINT_NAME,
    load_checkpoint,
    load_weights,
    remove_leftovers,
    rng_state,
    save_checkpoint,
    set_rng_state,
)
from .clock import CLOCK_TAG, TrainClock
from .errors import CheckpointError, TrainingError
from .init import InitWeights
from .losses import LossWeights, discriminator_loss, generator_loss
from .metrics import METRIC_NAMES, display_rendering, map_rmse, preview_flash, render_rmse
from .progress import Progress, format_duration
from .recipe import Recipe, check_recipe, recipe_differences, recipe_from_dict
from .schedule import LrSchedule
from .tracking import Tracker, flatten_params, run_tags

__all__ = ["FitOptions", "FitResult", "fit", "RESUMABLE_CHANGES", "load_generator"]

#: Recipe fields a ``--resume`` may change: budgets, cadences and loader workers.
RESUMABLE_CHANGES = (
    "train.epochs",
    "train.max_steps",
    "train.max_minutes",
    "train.log_every",
    "train.validate_every",
    "train.checkpoint_every",
    "data.workers",
)
#: Steps left out of the throughput figure: the first ones pay for lazy initialisation.
WARMUP_STEPS = 3
#: Samples drawn in the sample grid of each validation.
GRID_SAMPLES = 4
#: Tiles of the sample grid smaller than this many pixels are enlarged (nearest neighbour).
GRID_MIN_SIZE = 96


@dataclass
class FitOptions:
    """How to run a fit (the recipe says what to train).

    Attributes:
        out: folder of the checkpoint (``last.pt``), the resolved recipe and sample grids.
        resume: continue from ``out/last.pt`` (and its MLflow run).
        force: start afresh even though ``out`` holds a checkpoint (it is replaced).
        device: ``auto``, ``cpu``, ``cuda`` or ``cuda:K``.
        experiment: MLflow experiment name.
        run_name: MLflow run name (default ``<recipe>-<size>``).
        progress: show the progress line.
        track: log to MLflow (rank 0); False records nothing but the local files.
        parent_run: make the MLflow run a child of this run (a benchmark's parent run).
        init: start from these weights (a checkpoint file, a fit's folder or an MLflow run id;
            :mod:`svbrdf_train.init`) in a new fit and a new run.
    """

    out: Path
    resume: bool = False
    force: bool = False
    device: str = "auto"
    experiment: str = "svbrdf"
    run_name: str | None = None
    progress: bool = True
    track: bool = True
    parent_run: str | None = None
    init: str | None = None


@dataclass
class FitResult:
    """How a fit ended. ``status`` is MLflow's: FINISHED, FAILED or KILLED."""

    status: str
    step: int
    total_steps: int
    run_id: str | None
    checkpoint: Path | None
    train_seconds: float
    message: str
    metrics: dict[str, float] = field(default_factory=dict)
    samples_per_s: float | None = None
    """Training throughput of all processes after the first :data:`WARMUP_STEPS` steps of this
    session (None when it made no more steps than that)."""

    @property
    def exit_code(self) -> int:
        return {"FINISHED": 0, "KILLED": 130}.get(self.status, 1)


# -- pieces ---------------------------------------------------------------------------------


def _unwrap(module: nn.Module) -> nn.Module:
    return module.module if isinstance(module, nn.parallel.DistributedDataParallel) else module


def _scene_rows(scene: Scene, start: int, stop: int) -> Scene:
    """The materials ``start:stop`` of a per-material ``(B, K)`` scene."""

    def rows(t):
        return t[start:stop] if isinstance(t, Tensor) and t.dim() >= 2 else t

    cam = replace(
        scene.camera, position=rows(scene.camera.position), directional=rows(scene.camera.directional)
    )
    lights = tuple(
        replace(
            lt, position=rows(lt.position), intensity=rows(lt.intensity), directional=rows(lt.directional)
        )
        for lt in scene.point_lights
    )
    return replace(scene, camera=cam, lights=lights)


class _From(Sampler[int]):
    """The indices of ``sampler`` from position ``start`` on (to resume mid-epoch)."""

    def __init__(self, sampler: Sampler[int], start: int, length: int):
        self.sampler, self.start, self.length = sampler, start, length

    def __iter__(self) -> Iterator[int]:
        for i, index in enumerate(self.sampler):
            if i >= self.length:
                return
            if i >= self.start:
                yield index

    def __len__(self) -> int:
        return self.length - self.start


def _first_bad(terms: dict[str, Tensor]) -> str | None:
    for name, value in terms.items():
        if not torch.isfinite(value.detach()).all():
            return name
    return None


def _grad_norm(module: nn.Module) -> Tensor:
    """The L2 norm of all of a module's gradients together (inf or nan if any entry is)."""
    grads = [p.grad for p in module.parameters() if p.grad is not None]
    if not grads:
        return torch.zeros(())
    total_norm = getattr(torch.nn.utils, "get_total_norm", None)  # torch >= 2.6
    if total_norm is not None:
        return total_norm(grads)
    return torch.linalg.vector_norm(torch.stack([torch.linalg.vector_norm(g) for g in grads]))


def _peak_memory(device: torch.device) -> dict[str, float]:
    """Peak resident memory of this process, and of the GPU allocator on CUDA, in MiB."""
    out: dict[str, float] = {}
    try:
        import resource

        kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
        out["train/peak_rss_mb"] = kib / 1024
    except (ImportError, OSError):  # not on every platform
        pass
    if device.type == "cuda":
        out["train/peak_cuda_mb"] = torch.cuda.max_memory_allocated(device) / 2**20
    return out


def _count_params(module: nn.Module | None) -> int:
    return 0 if module is None else sum(p.numel() for p in module.parameters())


def load_generator(
    checkpoint: dict[str, Any], device: str | torch.device = "cpu", source: str = "checkpoint"
) -> tuple[nn.Module, Recipe]:
    """The generator of a checkpoint (eval mode) and the recipe it was trained with."""
    recipe = recipe_from_dict(checkpoint.get("recipe") or {}, where=f"{source}: its recipe")
    if recipe.generator is None or checkpoint.get("generator") is None:
        raise CheckpointError(f"{source}: it names no generator (its recipe or weights are missing)")
    g = create_generator(recipe.generator.name, recipe.generator.config)
    load_weights(g, checkpoint["generator"], f"{source}: generator {recipe.generator.name!r}")
    return g.to(device).eval(), recipe


# -- the fit --------------------------------------------------------------------------------


class _Interrupt:
    """Ctrl-C / SIGTERM: the first asks to stop after the current step, the second stops now."""

    def __init__(self, progress: Progress):
        self.requested: str | None = None
        self.progress = progress
        self._old: dict[int, Any] = {}

    def __enter__(self):
        if hasattr(signal, "SIGTERM"):
            for sig in (signal.SIGINT, signal.SIGTERM):
                try:
                    self._old[sig] = signal.signal(sig, self._handle)
                except ValueError:  # not the main thread: leave signals alone
                    pass
        return self

    def _handle(self, signum, frame):
        name = signal.Signals(signum).name
        if self.requested is not None:
            raise KeyboardInterrupt
        self.requested = name
        self.progress.message(f"{name}: saving a checkpoint after this step (again to stop at once)")

    def __exit__(self, *exc):
        for sig, old in self._old.items():
            signal.signal(sig, old)


class _Fit:
    def __init__(
        self,
        recipe: Recipe,
        options: FitOptions,
        dist: distributed.Dist,
        state: dict | None,
        init: InitWeights | None = None,
    ):
        self.recipe, self.options, self.dist = recipe, options, dist
        self.device = dist.device
        t, o = recipe.train, recipe.optim
        self.out = Path(options.out)
        self.ckpt_path = self.out / CHECKPOINT_NAME

        torch.manual_seed(t.seed)
        self.G = create_generator(recipe.generator.name, recipe.generator.config).to(self.device)
        self.D = None
        if recipe.discriminator is not None:
            self.D = create_discriminator(recipe.discriminator.name, recipe.discriminator.config).to(
                self.device
            )
        self.init: dict[str, str] | None = None  # where the starting weights came from
        if init is not None and state is None:
            self._take(init)
        self.g_opt = torch.optim.Adam(self.G.parameters(), lr=o.lr, betas=tuple(o.betas))
        self.d_opt = (
            torch.optim.Adam(self.D.parameters(), lr=o.d_lr, betas=tuple(o.betas))
            if self.D is not None
            else None
        )

        from .fitdata import build_datasets, real_validation_set

        self.train_set, self.val_set = build_datasets(recipe)
        self.real_val = real_validation_set(recipe.data.real_validation, t.resolution)
        per_step = t.batch * dist.world
        self.steps_per_epoch = len(self.train_set) // per_step
        if self.steps_per_epoch == 0:
            raise TrainingError(
                f"{recipe.source}: {len(self.train_set)} training samples do not fill one step of "
                f"{t.batch} x {dist.world} process(es); lower train.batch or add data (data.count)"
            )
        total = t.epochs * self.steps_per_epoch
        self.total_steps = min(total, t.max_steps) if t.max_steps is not None else total
        self.schedule = LrSchedule(o, per_step, self.steps_per_epoch * per_step)
        self.scene_gen = torch.Generator().manual_seed(t.seed + 7919)
        self.weights = LossWeights(adv=recipe.loss.adv, render=recipe.loss.render, svbrdf=recipe.loss.svbrdf)
        self.step = 0
        self.train_seconds = 0.0
        self.wall_seconds = 0.0
        self.clock = TrainClock(t.clock, self.device)
        self.run_id: str | None = None
        if state is not None:
            self._restore(state)
        else:
            # Dropout masks differ per process; the weights above are the same everywhere.
            torch.manual_seed(t.seed * 1000 + 1 + dist.rank)

        if dist.active:
            from torch.nn.parallel import DistributedDataParallel as DDP

            ids = [self.device.index] if self.device.type == "cuda" else None
            self.G = DDP(self.G, device_ids=ids)
            if self.D is not None:
                self.D = DDP(self.D, device_ids=ids)
        self.eval_scene = evaluation_scene(device=self.device)
        self.flash = preview_flash(self.device)

    # -- state ------------------------------------------------------------------------------

    def _take(self, init: InitWeights) -> None:
        """The generator's weights of ``init``, and the discriminator's when it is the same one."""
        from .init import same_discriminator

        both = self.D is not None and same_discriminator(init, self.recipe)
        self._load(f"--init {init.source}", init.generator, init.discriminator if both else None)
        self.init = {
            **init.tags(),
            "svbrdf.init_discriminator": "taken" if both else ("new" if self.D is not None else "none"),
        }

    def _load(self, source: str, generator: dict, discriminator: dict | None) -> None:
        """Weights into the networks, or one line naming ``source`` and how they differ."""
        load_weights(self.G, generator, f"{source}: generator {self.recipe.generator.name!r}")
        if discriminator is not None:
            load_weights(self.D, discriminator, f"{source}: discriminator {self.recipe.discriminator.name!r}")

    def _restore(self, state: dict) -> None:
        if state.get("world_size", 1) != self.dist.world:
            raise CheckpointError(
                f"{self.ckpt_path}: written by {state.get('world_size')} process(es), resumed with "
                f"{self.dist.world}; resume with --nproc_per_node={state.get('world_size')} "
                "(the data order and batch depend on it)"
            )
        self._load(str(self.ckpt_path), state["generator"], state["discriminator"] if self.D else None)
        if self.D is not None:
            self.d_opt.load_state_dict(state["optimizers"]["d"])
        self.g_opt.load_state_dict(state["optimizers"]["g"])
        self.step = int(state["step"])
        self.train_seconds = float(state.get("train_seconds", 0.0))
        self.wall_seconds = float(state.get("wall_seconds", self.train_seconds))
        self.run_id = state.get("run_id")
        self.init = state.get("init")
        set_rng_state(state["rng"][self.dist.rank], self.scene_gen)

    def _state(self, rngs: list) -> dict:
        return {
            "recipe": self.recipe.to_dict(),
            "step": self.step,
            "epoch": self.step // self.steps_per_epoch,
            "generator": _unwrap(self.G).state_dict(),
            "discriminator": _unwrap(self.D).state_dict() if self.D is not None else None,
            "optimizers": {
                "g": self.g_opt.state_dict(),
                "d": self.d_opt.state_dict() if self.d_opt else None,
            },
            "schedule": {
                "samples": self.schedule.samples(self.step),
                "lr_factor": self.schedule.factor(self.step),
            },
            "rng": rngs,
            "run_id": self.run_id,
            "init": self.init,
            "train_seconds": self.train_seconds,
            "wall_seconds": self.wall_seconds,
            "world_size": self.dist.world,
        }

    def save(self, tracker: Tracker) -> None:
        """Every rank's RNG state to rank 0, which writes the checkpoint and logs it."""
        rngs = self.dist.gather(rng_state(self.scene_gen))
        if self.dist.main:
            save_checkpoint(self.ckpt_path, self._state(rngs))
            tracker.log_artifact(self.ckpt_path, "checkpoints")
        self.dist.barrier()

    # -- data -------------------------------------------------------------------------------

    def batches(self) -> Iterator[dict]:
        """Batches from the current step to the end of the step budget."""
        from .fitdata import set_epoch

        t = self.recipe.train
        while self.step < self.total_steps:
            epoch, offset = divmod(self.step, self.steps_per_epoch)
            set_epoch(self.train_set, epoch)
            sampler = DistributedSampler(
                self.train_set,
                num_replicas=self.dist.world,
                rank=self.dist.rank,
                shuffle=True,
                seed=t.seed,
                drop_last=True,
            )
            sampler.set_epoch(epoch)
            loader = DataLoader(
                self.train_set,
                batch_size=t.batch,
                sampler=_From(sampler, offset * t.batch, self.steps_per_epoch * t.batch),
                num_workers=self.recipe.data.workers,
                drop_last=True,
                pin_memory=self.device.type == "cuda",
                # Worker seeds from (seed, epoch), not from the global RNG, which would then
                # depend on how often a loader was made (resuming mid-epoch makes one more).
                generator=torch.Generator().manual_seed(t.seed * 100_003 + epoch),
            )
            for batch in loader:
                yield batch
                if self.step >= self.total_steps:
                    return

    def scene(self) -> Scene:
        """This process's rows of one scene drawn for the whole (all-process) batch."""
        t = self.recipe.train
        n_random = t.renderings // 3
        full = training_scene(
            t.batch * self.dist.world,
            generator=self.scene_gen,
            n_random=n_random,
            n_mirror=t.renderings - n_random,
        )
        start = self.dist.rank * t.batch
        return _scene_rows(full, start, start + t.batch).to(self.device)

    # -- one step ---------------------------------------------------------------------------

    def _set_rates(self) -> None:
        """Both optimisers' rates for this step, from the schedule (a function of the step)."""
        f = self.schedule.factor(self.step)
        o = self.recipe.optim
        for opt, base in ((self.g_opt, o.lr), (self.d_opt, o.d_lr)):
            if opt is not None:
                for group in opt.param_groups:
                    group["lr"] = base * f

    def train_step(self, batch: dict) -> tuple[dict[str, float], str | None]:
        """One generator step (and a discriminator step when due).

        Returns the loss terms, and the name of a non-finite loss term or gradient (then
        nothing is stepped with it, on any process).
        """
        loss = self.recipe.loss
        self._set_rates()
        photo = batch["input"].to(self.device, non_blocking=True)
        target = SVBRDF.unpack(batch["maps"].to(self.device, non_blocking=True), validate=False)
        self.G.train()
        pred = self.G(photo)
        rendered = None
        if loss.render > 0 or self.D is not None:
            scene = self.scene()
            backend = self.recipe.train.render_backend
            fake = render(pred, scene, backend=backend)
            with torch.no_grad():
                real = render(target, scene, backend=backend)
            rendered = (fake, real)
        out: dict[str, float] = {}

        if self.D is not None and self.step % self.recipe.optim.g_steps_per_d == 0:
            fake, real = rendered
            n = photo.shape[0]
            both = SVBRDF.cat([target, pred.detach()])
            looks = log_radiance(torch.cat([real, fake.detach()]), loss.eps)
            logits = self.D(maps=both, renderings=looks)  # one pass: one DistributedDataParallel sync
            d_loss = discriminator_loss([x[:n] for x in logits], [x[n:] for x in logits], loss.gan)
            (bad,) = self.dist.any(not torch.isfinite(d_loss.detach()))
            if bad:
                return out, "discriminator"
            self.d_opt.zero_grad(set_to_none=True)
            d_loss.backward()
            d_norm = _grad_norm(self.D)  # all-reduced already: every process sees the same
            if not torch.isfinite(d_norm):
                return out, "discriminator gradient"
            self.d_opt.step()
            out["d_loss"] = float(d_loss.detach())
            out["d_grad_norm"] = float(d_norm)

        fake_logits = None
        if self.D is not None:
            d = _unwrap(self.D)
            d.requires_grad_(False)
            try:
                fake_logits = d(maps=pred, renderings=log_radiance(rendered[0], loss.eps))
            finally:
                d.requires_grad_(True)
        total, terms = generator_loss(
            pred,
            target,
            weights=self.weights,
            map_weights=loss.maps,
            fake_logits=fake_logits,
            gan=loss.gan,
            eps=loss.eps,
            rendered=rendered,
        )
        name = _first_bad(terms)
        (bad,) = self.dist.any(name is not None)
        if bad:
            return out, name or "(on another process)"
        self.g_opt.zero_grad(set_to_none=True)
        total.backward()
        g_norm = _grad_norm(self.G)
        if not torch.isfinite(g_norm):
            return out, "generator gradient"
        out["grad_norm"] = float(g_norm)
        self.g_opt.step()
        self.step += 1
        out.update({("loss" if k == "total" else k): float(v.detach()) for k, v in terms.items()})
        return out, None

    # -- validation -------------------------------------------------------------------------

    @torch.no_grad()
    def validate(self) -> tuple[dict[str, float], Tensor | None]:
        """Mean per-sample RMSE of each map and of renderings on the held-out set (``val/``) and on
        the real validation set if any (``val_real/``), and the sample grid of the held-out set."""
        g = _unwrap(self.G)
        g.eval()
        try:
            metrics, grid = self._validate_set(g, self.val_set, "val", grid=True)
            if self.real_val is not None:
                metrics.update(self._validate_set(g, self.real_val[0], "val_real", grid=False)[0])
        finally:
            g.train()
        return metrics, grid

    def _validate_set(
        self, g: nn.Module, data: Dataset, prefix: str, *, grid: bool
    ) -> tuple[dict[str, float], Tensor | None]:
        if len(data) == 0:
            return {}, None
        sums = dict.fromkeys(METRIC_NAMES, 0.0)
        grid_rows: list = []
        labels: list[str] = []
        loader = DataLoader(
            data, batch_size=self.recipe.train.batch, generator=torch.Generator().manual_seed(0)
        )  # its own generator: validating must not draw from the training RNG
        for batch in loader:
            photo = batch["input"].to(self.device)
            target = SVBRDF.unpack(batch["maps"].to(self.device), validate=False)
            pred = g(photo)
            for name, v in map_rmse(pred, target).items():
                sums[name] += float(v.sum())
            sums["render"] += float(render_rmse(pred, target, self.eval_scene).sum())
            if grid and len(grid_rows) < 2 * GRID_SAMPLES:
                grid_rows += self._grid_rows(photo, pred, target)
                labels += [f"{n} {k}" for n in batch["name"] for k in ("true", "pred")]
        n = len(data)
        metrics = {f"{prefix}/rmse/{k}": v / n for k, v in sums.items()}
        if not grid:
            return metrics, None
        keep = 2 * GRID_SAMPLES
        from .data.sheet import image_grid

        sheet = image_grid(
            grid_rows[:keep],
            ("input", "normal", "diffuse", "roughness", "specular", "flash"),
            [s[-28:] for s in labels[:keep]],
            min_tile=GRID_MIN_SIZE,
        )
        return metrics, sheet

    def _grid_rows(self, photo: Tensor, pred: SVBRDF, target: SVBRDF) -> list:
        from svbrdf_render import linear_to_srgb

        from .data.sheet import map_tiles

        rows = []
        shown = linear_to_srgb(photo.float().cpu())
        looks = {
            "true": display_rendering(target, self.flash).cpu(),
            "pred": display_rendering(pred, self.flash).cpu(),
        }
        for k in range(photo.shape[0]):
            for which, maps in (("true", target), ("pred", pred)):
                rows.append([shown[k], *map_tiles(maps.pack()[k]), looks[which][k]])
        return rows


# -- entry point ----------------------------------------------------------------------------


def _check_out(options: FitOptions, dist: distributed.Dist) -> dict | None:
    """The checkpoint to resume from (``--resume``), after refusing to overwrite one silently.

    Temporary checkpoint files left by a fit killed mid-write are removed first.
    """
    ckpt = Path(options.out) / CHECKPOINT_NAME
    if dist.main:
        remove_leftovers(options.out)
    if options.resume and options.init:
        raise CheckpointError(
            "--init starts a new fit from trained weights and --resume continues one; give one of them"
        )
    if options.resume:
        if not ckpt.is_file():
            raise CheckpointError(
                f"{ckpt}: nothing to resume; run without --resume to start, or give the --out of the fit"
            )
        return load_checkpoint(ckpt)
    if ckpt.is_file() and not options.force:
        raise CheckpointError(
            f"{ckpt}: a checkpoint of an earlier fit is there; pass --resume to continue it, "
            "--force to start again over it, or choose another --out"
        )
    return None


def _resolve_resume(recipe: Recipe | None, state: dict | None) -> Recipe:
    if state is None:
        assert recipe is not None
        return recipe
    saved = recipe_from_dict(state["recipe"], where="checkpoint recipe")
    if recipe is None:
        return saved
    changed = recipe_differences(saved, recipe, ignore=RESUMABLE_CHANGES)
    if changed:
        raise CheckpointError(
            "--resume with a recipe that differs from the checkpoint's in "
            + "; ".join(changed)
            + f". A resumed fit may change only {', '.join(RESUMABLE_CHANGES)}; "
            "start a new fit (another --out) "
            "to train something else"
        )
    # keep the checkpoint's name/size/source; take the new budgets
    return replace(saved, train=recipe.train, data=replace(saved.data, workers=recipe.data.workers))


def fit(recipe: Recipe | None, options: FitOptions) -> FitResult:
    """Train ``recipe`` (None with ``options.resume``: the checkpoint's recipe); see the module doc.

    Raises:
        RecipeError, DataError, CheckpointError, TrainingError: before training starts, for
            settings that cannot work (each names what to change).
    """
    dist = distributed.init(options.device)
    try:
        return _fit(recipe, options, dist)
    finally:
        dist.close()


def _fit(recipe: Recipe | None, options: FitOptions, dist: distributed.Dist) -> FitResult:
    state = _check_out(options, dist)
    recipe = _resolve_resume(recipe, state)
    check_recipe(recipe, recipe.source or recipe.name)  # a Recipe made in Python is checked too
    init = None
    if options.init and state is None:
        from .init import check_generator, load_init

        init = load_init(options.init)
        check_generator(init, recipe)
    t = recipe.train
    run = _Fit(recipe, options, dist, state, init)
    del init
    del state
    out = run.out
    start_step = run.step
    progress = Progress(
        run.total_steps,
        start=start_step,
        budget_s=t.max_minutes * 60 if t.max_minutes is not None else None,
        enabled=options.progress,
        messages=dist.main,
    )
    tracker = Tracker()
    if dist.main:
        out.mkdir(parents=True, exist_ok=True)
        config_file = out / "recipe.yaml"
        import yaml

        write_text(config_file, yaml.safe_dump(recipe.to_dict(), sort_keys=False))
        if options.track:
            tracker = _tracker(recipe, options, run, dist)
            run.run_id = tracker.run_id
            if start_step == 0:
                tracker.log_artifact(config_file, "config")
        progress.message(_plan(recipe, run, dist, tracker, start_step))
    # with a time budget, the steps it allows are known after a few steps (below)
    warned = t.max_minutes is None and _warn_schedule(
        run, tracker, progress, run.total_steps, "the step budget"
    )

    status, message = "FINISHED", ""
    last_metrics: dict[str, float] = {}
    sums: dict[str, float] = {}
    count = 0
    saved_at = start_step
    samples = 0
    steady: tuple[float, int] | None = None  # (train seconds, samples) when warm-up ended
    tick = run.clock.now()
    wall_tick = time.perf_counter()
    window_start, window_samples = run.train_seconds, 0
    with _Interrupt(progress) as interrupt:
        try:
            for batch in run.batches():
                terms, bad = run.train_step(batch)
                run.train_seconds += run.clock.now() - tick
                run.wall_seconds += time.perf_counter() - wall_tick
                n = batch["input"].shape[0] * dist.world
                samples += n
                window_samples += n
                if run.step - start_step == WARMUP_STEPS:
                    steady = (run.train_seconds, samples)
                if not warned and steady is not None and run.step - start_step == 2 * WARMUP_STEPS:
                    warned = _warn_time_budget(run, tracker, progress, steady[0])
                if bad is not None:
                    status = "FAILED"
                    message = _nan_message(run, bad, saved_at)
                    break
                for k, v in terms.items():
                    sums[k] = sums.get(k, 0.0) + v
                count += 1
                rate = window_samples / max(run.train_seconds - window_start, 1e-9)
                shown = {k: terms[k] for k in ("loss", "adv", "render", "svbrdf", "d_loss") if k in terms}
                progress.update(run.step, shown, rate, run.train_seconds)
                step = run.step
                if step % t.log_every == 0 or step == run.total_steps:
                    metrics = {f"train/{k}": v / count for k, v in sums.items()}
                    metrics.update(
                        {
                            "train/lr": run.g_opt.param_groups[0]["lr"],
                            "train/samples_per_s": rate,
                            "train/epoch": step / run.steps_per_epoch,
                            "train/seconds": run.train_seconds,
                        }
                    )
                    tracker.log_metrics(metrics, step)
                    sums, count = {}, 0
                    window_start, window_samples = run.train_seconds, 0
                time_up = t.max_minutes is not None and run.train_seconds >= t.max_minutes * 60
                stop, time_up = dist.any(interrupt.requested is not None, time_up)
                last = step >= run.total_steps or stop or time_up
                if dist.main and (step % t.validate_every == 0 or last):
                    last_metrics = _validate(run, tracker, step)
                if step % t.checkpoint_every == 0 or last:
                    run.save(tracker)
                    saved_at = step
                if stop:
                    status = "KILLED"
                    message = f"stopped by {interrupt.requested or 'another process'} at step {step}"
                    break
                if time_up:
                    message = f"time budget of {t.max_minutes:g} min reached at step {step}"
                    break
                tick = run.clock.now()
                wall_tick = time.perf_counter()
        except KeyboardInterrupt:
            status = "KILLED"
            message = f"stopped at once at step {run.step}; the checkpoint of step {saved_at} is kept"
        except BaseException as e:
            progress.close()
            with contextlib.suppress(Exception):  # the store may be what failed: keep that error
                tracker.finish("FAILED")
            if isinstance(e, SVBRDFError) and e.exit_code == OutputError.exit_code:
                kept = (
                    f"the checkpoint of step {saved_at} is kept: --resume continues from it"
                    if run.ckpt_path.is_file()
                    else "no checkpoint was written yet"
                )
                said = type(e)(f"{e}; {kept}")
                said.exit_code = e.exit_code
                raise said from None
            raise
    progress.close()
    samples_per_s = (
        (samples - steady[1]) / (run.train_seconds - steady[0])
        if steady is not None and samples > steady[1]
        else None
    )
    if status == "FINISHED" and not message:
        message = f"{run.step} steps, {format_duration(run.train_seconds)} of training"
    if dist.main:
        tracker.set_tags({"svbrdf.stop": message, "svbrdf.steps": run.step})
        summary = {
            "train/total_seconds": run.train_seconds,
            "train/total_wall_seconds": run.wall_seconds,
            **_peak_memory(dist.device),
        }
        if samples_per_s is not None:
            summary["train/steady_samples_per_s"] = samples_per_s
        tracker.log_metrics(summary, run.step)
    tracker.finish(status)
    return FitResult(
        samples_per_s=samples_per_s,
        status=status,
        step=run.step,
        total_steps=run.total_steps,
        run_id=run.run_id,
        checkpoint=run.ckpt_path if run.ckpt_path.is_file() else None,
        train_seconds=run.train_seconds,
        message=message,
        metrics=last_metrics,
    )


def _tracker(recipe: Recipe, options: FitOptions, run: _Fit, dist: distributed.Dist) -> Tracker:
    from .tracking import MlflowTracker

    tags = run_tags(
        recipe=recipe.name,
        size=recipe.size,
        seed=recipe.train.seed,
        device=str(dist.device),
        world_size=dist.world,
    )
    tags[CLOCK_TAG] = run.clock.name
    tags.update(run.init or {})
    if run.run_id is not None:
        return MlflowTracker(
            experiment=options.experiment, run_id=run.run_id, tags={"svbrdf.resumed_at": str(run.step)}
        )
    params = flatten_params(recipe.to_dict())
    g_cfg = resolve_config("generator", recipe.generator.name, recipe.generator.config)
    params.update(flatten_params({"generator.resolved": config_to_dict(g_cfg)}))
    if recipe.discriminator is not None:
        d_cfg = resolve_config("discriminator", recipe.discriminator.name, recipe.discriminator.config)
        params.update(flatten_params({"discriminator.resolved": config_to_dict(d_cfg)}))
    params["parameters.generator"] = str(_count_params(_unwrap(run.G)))
    params["parameters.discriminator"] = str(_count_params(_unwrap(run.D) if run.D is not None else None))
    params["steps_per_epoch"] = str(run.steps_per_epoch)
    params["total_steps"] = str(run.total_steps)
    params["world_size"] = str(dist.world)
    return MlflowTracker(
        experiment=options.experiment,
        run_name=options.run_name or f"{recipe.name}-{recipe.size}",
        tags={**tags, **({"mlflow.parentRunId": options.parent_run} if options.parent_run else {})},
        params=params,
    )


def _validate(run: _Fit, tracker: Tracker, step: int) -> dict[str, float]:
    metrics, grid = run.validate()
    if metrics:
        # with the training time so far, so curves can be drawn against time as well as steps
        tracker.log_metrics({**metrics, "val/train_seconds": run.train_seconds}, step)
    if grid is not None:
        from svbrdf_render import write_image

        path = write_image(run.out / "samples" / f"step_{step:07d}.png", grid)
        tracker.log_artifact(path, "samples")
        tracker.log_image(path, "samples", step)  # the same grid, shown with a step slider
    return metrics


def _plan(recipe: Recipe, run: _Fit, dist: distributed.Dist, tracker: Tracker, start: int) -> str:
    t = recipe.train
    what = (
        f"resuming {recipe.name} ({recipe.size}) at step {start}"
        if start
        else f"fitting {recipe.name} ({recipe.size})"
    )
    budget = f"{run.total_steps} steps ({run.steps_per_epoch}/epoch)"
    if t.max_minutes is not None:
        budget += f" or {format_duration(t.max_minutes * 60)} of training ({run.clock.describe()})"
    return (
        f"{what}: {budget}, batch {t.batch} x {dist.world} process(es) at {t.resolution} px "
        f"on {dist.device}; "
        f"G {_count_params(_unwrap(run.G)) / 1e6:.2f}M params"
        + (f", D {_count_params(_unwrap(run.D)) / 1e6:.2f}M" if run.D is not None else ", no D")
        + (f"\n  real validation: {run.real_val[1]}" if run.real_val is not None else "")
        + (
            f"\n  weights from: {run.init['svbrdf.init']} (step {run.init['svbrdf.init_step']}; "
            f"discriminator: {run.init['svbrdf.init_discriminator']})"
            if run.init
            else ""
        )
        + f"\n  checkpoints: {run.ckpt_path}\n  tracking: {tracker.describe()}"
    )


def _warn_schedule(run: _Fit, tracker: Tracker, progress: Progress, budget: int, what: str) -> bool:
    """Say once, on the main process and in the run's tags, that the schedule kills the rate
    early in ``budget`` steps. True when it warned."""
    text = run.schedule.warning(budget, what)
    if text is None:
        return False
    if run.dist.main:
        progress.message(text)
        tracker.set_tags({"svbrdf.warning": text[:5000]})
    return True


def _warn_time_budget(run: _Fit, tracker: Tracker, progress: Progress, steady_seconds: float) -> bool:
    """:func:`_warn_schedule` for the steps a time budget allows, at the pace of the
    :data:`WARMUP_STEPS` steps since warm-up ended at ``steady_seconds``."""
    minutes = run.recipe.train.max_minutes
    pace = (run.train_seconds - steady_seconds) / WARMUP_STEPS
    if minutes is None or pace <= 0:
        return False
    budget = min(run.total_steps, run.step + int((minutes * 60 - run.train_seconds) / pace))
    return _warn_schedule(run, tracker, progress, budget, f"{minutes:g} min at {pace * 1000:.0f} ms/step")


def _nan_message(run: _Fit, term: str, saved_at: int) -> str:
    kept = (
        f"the checkpoint of step {saved_at} ({run.ckpt_path}) is kept"
        if saved_at > 0
        else "no checkpoint had been written yet"
    )
    hint = "lower optim.lr / optim.d_lr, or check the data for NaN or inf values"
    step = run.step + 1
    what = (
        f"non-finite {term} at step {step}"
        if term.endswith("gradient")
        else (f"non-finite loss at step {step}: term {term!r}")
    )
    return f"{what}; nothing was stepped with it; {kept}; {hint}"
