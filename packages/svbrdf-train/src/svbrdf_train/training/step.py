"""One training step of the GAN, as one object that owns everything the step changes.

:class:`GanStep` holds the generator G, the discriminator D (or none), their Adam
optimisers, the learning-rate schedule, the generator of the light/view configurations and
the step count. ``gan(batch)`` does one step (``step`` counts generator steps)::

    pred = G(photo)
    renderings of pred and of the truth under N light/view configurations (Deschaintre 2018)
    every g_steps_per_d steps: D learns real (truth) against fake (pred, detached)
    L_G = adv * L_adv(D(pred)) + render * L_render + svbrdf * L_svbrdf;  G steps

The discriminator sees log renderings (``log(R + eps)``, as the rendering loss compares them)
of all N configurations, or the maps themselves for ``multi``. A non-finite loss or gradient
steps nothing, on any process, and is named in the result.

``state_dict()`` / ``load_state_dict()`` carry the weights, both optimisers, the step and
this process's random state, so a step resumed from them draws exactly what it would have.

How the step runs (recipe ``train`` fields, each off by default; see the README for the
measurements behind the defaults): ``compile`` (``torch.compile`` of both networks),
``channels_last`` (NHWC memory layout for the convolutions), ``precision: bf16`` (the networks
under bfloat16 autocast; the renderer and the losses stay float32). The renderings of the
losses use ``train.render_backend`` (compiled by default).
"""

from __future__ import annotations

import contextlib
from dataclasses import replace
from typing import Any

import torch
from torch import Tensor, nn

from svbrdf_models import create_discriminator, create_generator
from svbrdf_render import SVBRDF, Scene, render, training_scene

from ..recipe import Recipe
from . import distributed
from .checkpoint import load_weights, rng_state, set_rng_state
from .losses import loss_of
from .schedule import LrSchedule, optimiser_of

__all__ = ["GanStep", "scene_rows", "unwrap"]


def unwrap(module: nn.Module | None) -> nn.Module | None:
    """The network under DistributedDataParallel and ``torch.compile`` wrappers."""
    while True:
        if isinstance(module, nn.parallel.DistributedDataParallel):
            module = module.module
        elif hasattr(module, "_orig_mod"):  # torch.compile's OptimizedModule
            module = module._orig_mod
        else:
            return module


def scene_rows(scene: Scene, start: int, stop: int) -> Scene:
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


class GanStep:
    """G, D, their optimisers and schedule, and one step of training them (module doc).

    The recipe's sections say what the pieces are: :func:`~.schedule.optimiser_of` makes each
    optimiser and the rate it follows, :func:`~.losses.loss_of` the objectives
    (:class:`~svbrdf_train.training.losses.GanLoss`).

    Args:
        recipe: what to train (networks, losses, optimiser, ``train`` settings).
        dist: this process and its peers (one process: ``distributed.Dist()``).
        epoch_samples: samples in one epoch of all processes (the schedule counts epochs).

    The networks are made from ``train.seed``, the same on every process.
    """

    def __init__(self, recipe: Recipe, dist: distributed.Dist, epoch_samples: int):
        self.recipe, self.dist, self.device = recipe, dist, dist.device
        t, o = recipe.train, recipe.optim
        torch.manual_seed(t.seed)
        self.generator = create_generator(recipe.generator.name, recipe.generator.config).to(self.device)
        self.discriminator = None
        if recipe.discriminator is not None:
            d = recipe.discriminator
            self.discriminator = create_discriminator(d.name, d.config).to(self.device)
        self.schedule = LrSchedule(o, t.batch * dist.world, epoch_samples)
        self.g_opt, g_rate = optimiser_of(o, self.generator.parameters(), self.schedule)
        self.d_opt, self._rates = None, [g_rate]
        if self.discriminator is not None:
            d_params = self.discriminator.parameters()
            self.d_opt, d_rate = optimiser_of(o, d_params, self.schedule, discriminator=True)
            self._rates.append(d_rate)
        self.scene_gen = torch.Generator().manual_seed(t.seed + 7919)
        self.loss = loss_of(recipe.loss)
        self.step = 0
        # What a step calls: the networks, wrapped by prepare() for several processes or compiling.
        self.G: nn.Module = self.generator
        self.D: nn.Module | None = self.discriminator
        self._judge: nn.Module | None = self.discriminator  # D as G's loss calls it (no DDP)

    # -- set-up -----------------------------------------------------------------------------

    def load_weights(self, source: str, generator: dict, discriminator: dict | None) -> None:
        """Weights into the networks, or one line naming ``source`` and how they differ."""
        load_weights(self.generator, generator, f"{source}: generator {self.recipe.generator.name!r}")
        if discriminator is not None and self.discriminator is not None:
            name = self.recipe.discriminator.name
            load_weights(self.discriminator, discriminator, f"{source}: discriminator {name!r}")

    def prepare(self) -> None:
        """Wrap the networks for the run: channels-last, DistributedDataParallel, compiled.

        Call once, after the weights are loaded (the state dicts stay the plain networks').
        """
        t = self.recipe.train
        if t.channels_last:
            self.generator.to(memory_format=torch.channels_last)
            if self.discriminator is not None:
                self.discriminator.to(memory_format=torch.channels_last)
        if self.dist.active:
            from torch.nn.parallel import DistributedDataParallel as DDP

            ids = [self.device.index] if self.device.type == "cuda" else None
            self.G = DDP(self.generator, device_ids=ids)
            if self.discriminator is not None:
                self.D = DDP(self.discriminator, device_ids=ids)
        if t.compile:
            self.G = torch.compile(self.G)
            if self.D is not None:
                self.D = torch.compile(self.D)
                self._judge = torch.compile(self.discriminator)

    # -- state ------------------------------------------------------------------------------

    def state_dict(self) -> dict[str, Any]:
        """Weights, optimisers, step and schedule position (random states: :meth:`rng_state`)."""
        return {
            "step": self.step,
            "generator": self.generator.state_dict(),
            "discriminator": self.discriminator.state_dict() if self.discriminator is not None else None,
            "optimizers": {
                "g": self.g_opt.state_dict(),
                "d": self.d_opt.state_dict() if self.d_opt else None,
            },
            "schedule": {
                "samples": self.schedule.samples(self.step),
                "lr_factor": self.schedule.factor(self.step),
            },
        }

    def load_state_dict(self, state: dict[str, Any], source: str = "checkpoint") -> None:
        """What :meth:`state_dict` gave (the random state: :meth:`set_rng_state`)."""
        self.load_weights(source, state["generator"], state.get("discriminator"))
        if self.d_opt is not None:
            self.d_opt.load_state_dict(state["optimizers"]["d"])
        self.g_opt.load_state_dict(state["optimizers"]["g"])
        self.step = int(state["step"])

    def rng_state(self) -> dict[str, Any]:
        """This process's random state: torch's and the light/view configurations'."""
        return rng_state(self.scene_gen)

    def set_rng_state(self, state: dict[str, Any]) -> None:
        set_rng_state(state, self.scene_gen)

    # -- one step ---------------------------------------------------------------------------

    def __call__(self, batch: dict) -> tuple[dict[str, float], str | None]:
        """One generator step (and a discriminator step when due).

        Returns the loss terms, and the name of a non-finite loss term or gradient (then
        nothing is stepped with it, on any process).
        """
        for rate in self._rates:  # the rates of this step (the schedule is a function of it)
            rate.at(self.step)
        photo = batch["input"].to(self.device, non_blocking=True)
        if self.recipe.train.channels_last:
            photo = photo.contiguous(memory_format=torch.channels_last)
        target = SVBRDF.unpack(batch["maps"].to(self.device, non_blocking=True), validate=False)
        self.G.train()
        with self._autocast():
            pred = self.G(photo)
        rendered = self._render(pred, target)
        out: dict[str, float] = {}
        if self.D is not None and self.step % self.recipe.optim.g_steps_per_d == 0:
            bad = self._discriminator_step(pred, target, rendered, out)
            if bad is not None:
                return out, bad
        bad = self._generator_step(pred, target, rendered, out)
        if bad is None:
            self.step += 1
        return out, bad

    def _autocast(self):
        if self.recipe.train.precision == "bf16":
            return torch.autocast(self.device.type, dtype=torch.bfloat16)
        return contextlib.nullcontext()

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
        return scene_rows(full, start, start + t.batch).to(self.device)

    def _render(self, pred: SVBRDF, target: SVBRDF) -> tuple[Tensor, Tensor] | None:
        """Renderings of the prediction and of the truth, when the loss or D needs them."""
        if self.recipe.loss.render <= 0 and self.D is None:
            return None
        scene = self.scene()
        backend = self.recipe.train.render_backend
        fake = render(pred, scene, backend=backend)
        with torch.no_grad():
            real = render(target, scene, backend=backend)
        return fake, real

    def _discriminator_step(self, pred: SVBRDF, target: SVBRDF, rendered, out: dict) -> str | None:
        fake, real = rendered
        n = target.normal.shape[0]
        both = SVBRDF.cat([target, pred.detach()])
        looks = self.loss.looks(torch.cat([real, fake.detach()]))
        with self._autocast():
            logits = self.D(maps=both, renderings=looks)  # one pass: one DDP sync
        logits = [x.float() for x in logits]
        d_loss = self.loss.discriminator([x[:n] for x in logits], [x[n:] for x in logits])
        (bad,) = self.dist.any(not torch.isfinite(d_loss.detach()))
        if bad:
            return "discriminator"
        self.d_opt.zero_grad(set_to_none=True)
        d_loss.backward()
        d_norm = _grad_norm(self.discriminator)  # all-reduced already: the same on every process
        if not torch.isfinite(d_norm):
            return "discriminator gradient"
        self.d_opt.step()
        out["d_loss"] = float(d_loss.detach())
        out["d_grad_norm"] = float(d_norm)
        return None

    def _fake_logits(self, pred: SVBRDF, rendered) -> list[Tensor] | None:
        """D's verdict on the prediction, with D's weights held (only G learns from it)."""
        if self.D is None:
            return None
        d = self.discriminator
        d.requires_grad_(False)
        try:
            with self._autocast():
                logits = self._judge(maps=pred, renderings=self.loss.looks(rendered[0]))
        finally:
            d.requires_grad_(True)
        return [x.float() for x in logits]

    def _generator_step(self, pred: SVBRDF, target: SVBRDF, rendered, out: dict) -> str | None:
        fake_logits = self._fake_logits(pred, rendered)
        total, terms = self.loss(pred, target, fake_logits=fake_logits, rendered=rendered)
        name = _first_bad(terms)
        (bad,) = self.dist.any(name is not None)
        if bad:
            return name or "(on another process)"
        self.g_opt.zero_grad(set_to_none=True)
        total.backward()
        g_norm = _grad_norm(self.generator)
        if not torch.isfinite(g_norm):
            return "generator gradient"
        out["grad_norm"] = float(g_norm)
        self.g_opt.step()
        out.update({("loss" if k == "total" else k): float(v.detach()) for k, v in terms.items()})
        return None
