"""What recipe sections describe is built from them: ``optimiser_of(optim, ...)``, ``loss_of(loss)``
(in training, which imports the recipe), ``data.setup``."""

from __future__ import annotations

import pytest
import torch

from conftest import random_svbrdf
from svbrdf_train.recipe import LossSection, OptimSection, load_recipe
from svbrdf_train.training.losses import GanLoss, LossWeights, discriminator_loss, generator_loss, loss_of
from svbrdf_train.training.schedule import LrSchedule, optimiser_of


def test_optim_setup_makes_adam_at_the_sections_rates_and_betas_along_the_schedule():
    optim = OptimSection(lr=1e-3, d_lr=4e-4, betas=(0.3, 0.9), warmup_samples=8, decay_every_samples=16)
    schedule = LrSchedule(optim, 2, 100)
    g = torch.nn.Linear(2, 2)
    opt, rate = optimiser_of(optim, g.parameters(), schedule)
    d_opt, d_rate = optimiser_of(optim, torch.nn.Linear(2, 1).parameters(), schedule, discriminator=True)
    assert isinstance(opt, torch.optim.Adam) and opt.param_groups[0]["betas"] == (0.3, 0.9)
    assert rate.base == 1e-3 and d_rate.base == 4e-4
    # warm-up over 8 samples at 2 a step: steps 0..3 at 1/4..4/4; halved from sample 16 (step 8)
    for step, factor in ((0, 0.25), (1, 0.5), (3, 1.0), (7, 1.0), (8, 0.5), (16, 0.25)):
        assert rate.at(step) == pytest.approx(1e-3 * factor)
        assert d_rate.at(step) == pytest.approx(4e-4 * factor)
        assert opt.param_groups[0]["lr"] == pytest.approx(1e-3 * factor)
        assert d_opt.param_groups[0]["lr"] == pytest.approx(4e-4 * factor)
    # the optimiser steps with the rate set: a plain SGD-like first Adam step moves each weight by ~lr
    before = g.weight.detach().clone()
    rate.at(3)
    g(torch.ones(1, 2)).sum().backward()
    opt.step()
    assert torch.allclose((g.weight - before).abs(), torch.full_like(before, 1e-3), rtol=1e-3)


def test_loss_setup_gives_the_losses_of_the_sections_weights_and_kind():
    section = LossSection(adv=0.2, render=0.0, svbrdf=0.7, gan="lsgan", maps={"normal": 2.0, "diffuse": 0.0})
    loss = loss_of(section)
    assert isinstance(loss, GanLoss)
    pred, target = random_svbrdf(2, 16, seed=1), random_svbrdf(2, 16, seed=2)
    fake = [torch.randn(2, 1, 4, 4)]
    total, terms = loss(pred, target, fake_logits=fake)
    weights = LossWeights(adv=0.2, render=0.0, svbrdf=0.7)
    want, want_terms = generator_loss(
        pred, target, weights=weights, map_weights=section.maps, fake_logits=fake, gan="lsgan"
    )
    assert torch.equal(total, want) and terms.keys() == want_terms.keys()
    assert "render" not in terms and torch.isfinite(total)
    real = [torch.randn(2, 1, 4, 4)]
    assert torch.equal(loss.discriminator(real, fake), discriminator_loss(real, fake, "lsgan"))
    assert not torch.equal(loss.discriminator(real, fake), discriminator_loss(real, fake, "bce"))
    black = torch.zeros(1, 3, 4, 4)
    assert torch.allclose(loss.looks(black), torch.log(torch.tensor(section.eps)).expand(1, 3, 4, 4))


def test_data_setup_makes_the_training_and_held_out_sets_at_the_resolution():
    recipe = load_recipe("ours", "smoke", {"data.count": 6, "data.validation": 3})
    train, val = recipe.data.setup(24)
    assert (len(train), len(val)) == (6, 3)
    sample = train[0]
    assert sample["input"].shape[-2:] == (24, 24)
    assert not torch.equal(val[0]["maps"], sample["maps"])  # validation is drawn from seed + 1
