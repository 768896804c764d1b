"""The paper's losses: values against hand computations, weights, skipped terms, GAN objectives,
and hard cases (black maps, extreme roughness, grazing normals, huge logits) forward and backward."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from conftest import random_svbrdf
from svbrdf_models.networks.discriminators import PatchGAN
from svbrdf_render import (
    DES18_EFFECTS,
    MAP_NAMES,
    PHOTO_EFFECTS,
    SVBRDF,
    Scene,
    log_radiance,
    render,
    training_scene,
)
from svbrdf_train.recipe.paper_weights import MAP_WEIGHTS
from svbrdf_train.training import losses
from svbrdf_train.training.losses import (
    GAN_KINDS,
    LossWeights,
    discriminator_loss,
    generator_adversarial_loss,
    generator_loss,
    map_loss,
    rendering_loss,
)

B, SIZE = 2, 16


def scene(seed: int = 0) -> Scene:
    return training_scene(B, generator=torch.Generator().manual_seed(seed))


def with_grad(m: SVBRDF) -> SVBRDF:
    """A copy of ``m`` whose maps are leaves that require grad."""
    return SVBRDF(*(getattr(m, n).detach().clone().requires_grad_() for n in MAP_NAMES), validate=False)


def grads(m: SVBRDF) -> dict[str, torch.Tensor]:
    return {n: getattr(m, n).grad for n in MAP_NAMES}


@pytest.fixture
def pair() -> tuple[SVBRDF, SVBRDF]:
    return random_svbrdf(B, SIZE, seed=1), random_svbrdf(B, SIZE, seed=2)


# -- map loss ----------------------------------------------------------------------------


def test_map_weights_are_the_papers():
    assert dict(MAP_WEIGHTS) == {"normal": 1.0, "diffuse": 1.0, "roughness": 0.5, "specular": 0.5}
    with pytest.raises(TypeError):
        MAP_WEIGHTS["normal"] = 2.0  # read-only: a shared default must not be mutated


def test_map_loss_value_by_hand(pair):
    pred, target = pair
    total, terms = map_loss(pred, target)
    hand = {n: (getattr(pred, n) - getattr(target, n)).abs().mean() for n in MAP_NAMES}
    assert set(terms) == set(MAP_NAMES)
    for n in MAP_NAMES:
        torch.testing.assert_close(terms[n], hand[n])
    expected = hand["normal"] + hand["diffuse"] + 0.5 * hand["roughness"] + 0.5 * hand["specular"]
    torch.testing.assert_close(total, expected)


def test_map_loss_zero_when_equal(pair):
    pred, _ = pair
    total, terms = map_loss(pred, pred)
    assert total.item() == 0.0
    assert all(t.item() == 0.0 for t in terms.values())


def test_map_loss_weights_scale_terms(pair):
    pred, target = pair
    _, terms = map_loss(pred, target)
    total, terms2 = map_loss(pred, target, {"roughness": 3.0, "specular": 0.0})
    assert set(terms2) == {"roughness", "specular"}
    torch.testing.assert_close(total, 3.0 * terms["roughness"])


def test_map_loss_keeps_the_graph_and_reaches_every_map(pair):
    pred, target = with_grad(pair[0]), pair[1]
    total, terms = map_loss(pred, target)
    assert all(t.requires_grad for t in terms.values())
    total.backward()
    for n, g in grads(pred).items():
        assert g is not None and g.abs().sum() > 0, n


@pytest.mark.parametrize(
    "weights, match",
    [
        ({"albedo": 1.0}, "albedo"),
        ({"normal": -1.0}, "normal"),
        ({"normal": float("nan")}, "normal"),
        ({}, "no map weights"),
    ],
)
def test_map_loss_bad_weights(pair, weights, match):
    with pytest.raises(ValueError, match=match):
        map_loss(*pair, weights)


def test_map_loss_shape_mismatch(pair):
    with pytest.raises(ValueError, match="same"):
        map_loss(pair[0], random_svbrdf(B, SIZE * 2, seed=3))


# -- rendering loss ----------------------------------------------------------------------


def test_rendering_loss_value_by_hand(pair):
    pred, target = pair
    s = scene()
    hand = (log_radiance(render(pred, s), 0.01) - log_radiance(render(target, s), 0.01)).abs().mean()
    torch.testing.assert_close(rendering_loss(pred, target, s), hand)
    hand = (torch.log(render(pred, s) + 0.1) - torch.log(render(target, s) + 0.1)).abs().mean()
    torch.testing.assert_close(rendering_loss(pred, target, s, eps=0.1), hand)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rendering_loss_uses_the_same_configurations_for_both(pair, seed):
    # A random training scene: pred == target is exactly 0 only if configuration k of one
    # is compared with configuration k of the other.
    pred, _ = pair
    assert rendering_loss(pred, pred, scene(seed)).item() == 0.0
    # also with a noisy scene: the same noise draw for both
    noisy = training_scene(B, generator=torch.Generator().manual_seed(seed), effects=PHOTO_EFFECTS)
    assert rendering_loss(pred, pred, noisy).item() == 0.0


def test_rendering_loss_target_gets_no_gradient(pair):
    pred, target = with_grad(pair[0]), with_grad(pair[1])
    rendering_loss(pred, target, scene()).backward()
    assert all(g is None for g in grads(target).values())
    for n, g in grads(pred).items():
        assert g is not None and g.isfinite().all() and g.abs().sum() > 0, n


def test_rendering_loss_renders_target_without_grad(pair, monkeypatch):
    modes = []

    def spy(svbrdf, scene, **kw):
        modes.append(torch.is_grad_enabled())
        return render(svbrdf, scene, **kw)

    monkeypatch.setattr(losses, "render", spy)
    rendering_loss(with_grad(pair[0]), pair[1], scene())
    assert modes == [True, False]


def test_rendering_loss_passes_the_backend(pair, monkeypatch):
    seen = []

    def spy(svbrdf, scene, *, backend="eager", **kw):
        seen.append(backend)
        return render(svbrdf, scene, backend="eager", **kw)

    monkeypatch.setattr(losses, "render", spy)
    rendering_loss(*pair, scene(), backend="compiled")
    assert seen == ["compiled", "compiled"]


def _hard(target: SVBRDF, case: str) -> SVBRDF:
    n, d, r, s = (getattr(target, k).clone() for k in MAP_NAMES)
    if case == "black":
        d, s = torch.zeros_like(d), torch.zeros_like(s)
    elif case == "roughness0":
        r = torch.zeros_like(r)
    elif case == "roughness1":
        r = torch.ones_like(r)
    elif case == "grazing":  # normals almost in the surface plane, alternating directions
        n = torch.tensor([1.0, 0.0, 1e-6]).view(1, 3, 1, 1).expand_as(n).clone()
        n[:, :, ::2] = torch.tensor([0.0, -1.0, 1e-6]).view(1, 3, 1, 1)
        n = n / n.norm(dim=1, keepdim=True)
    return SVBRDF(n, d, r, s)


def no_fresnel_scene(seed: int = 0) -> Scene:
    """A training scene with F = s: black maps (diffuse = specular = 0) render exactly 0.

    Under the Des18 Fresnel, ``F(s=0) = 2^(...) > 0``, so black maps still show a faint
    grazing highlight there.
    """
    effects = [e for e in DES18_EFFECTS if e != "fresnel"]
    return training_scene(B, generator=torch.Generator().manual_seed(seed), effects=effects)


@pytest.mark.parametrize("case", ["black", "roughness0", "roughness1", "grazing"])
@pytest.mark.parametrize("side", ["pred", "target"])
@pytest.mark.parametrize("make_scene", [scene, no_fresnel_scene], ids=["des18", "no-fresnel"])
def test_rendering_loss_hard_cases_finite_and_bounded(case, side, make_scene):
    target = random_svbrdf(B, SIZE, seed=5)
    hard = _hard(target, case)
    pred, target = (hard, target) if side == "pred" else (random_svbrdf(B, SIZE, seed=6), hard)
    pred = with_grad(pred)
    loss = rendering_loss(pred, target, make_scene())
    # |log(x + eps)| stays below ~|log 0.01| + log(GGX peak ~3.2e5 * pi): a few tens at most
    assert loss.isfinite() and 0 < loss.item() < 30
    loss.backward()
    for n, g in grads(pred).items():
        assert g.isfinite().all(), n
        assert g.abs().max() < 10, (n, g.abs().max())


@pytest.mark.parametrize("black_side", ["pred", "target"])
def test_rendering_loss_black_renders_give_log_eps(pair, black_side):
    s = no_fresnel_scene()
    black = _hard(pair[1], "black")
    assert render(black, s).abs().max() == 0
    pred, target = (with_grad(black), pair[1]) if black_side == "pred" else (with_grad(pair[1]), black)
    loss = rendering_loss(pred, target, s, eps=0.01)
    hand = (log_radiance(render(pair[1], s)) - math.log(0.01)).abs().mean()
    torch.testing.assert_close(loss, hand)
    loss.backward()
    for n, g in grads(pred).items():
        assert g.isfinite().all(), n


# -- adversarial losses ------------------------------------------------------------------


def logit_maps(value: float, n: int = 2, requires_grad: bool = False) -> list[torch.Tensor]:
    return [torch.full((B, 1, 3, 3), value, requires_grad=requires_grad) for _ in range(n)]


def test_gan_values_at_zero_logits():
    zero = logit_maps(0.0)
    assert discriminator_loss(zero, zero, "bce").item() == pytest.approx(2 * math.log(2))
    assert generator_adversarial_loss(zero, "bce").item() == pytest.approx(math.log(2))
    assert discriminator_loss(zero, zero, "lsgan").item() == pytest.approx(1.0)
    assert generator_adversarial_loss(zero, "lsgan").item() == pytest.approx(1.0)


def test_gan_values_by_hand_average_over_the_list():
    g = torch.Generator().manual_seed(0)
    real = [torch.randn(B, 1, 5, 5, generator=g), torch.randn(B, 1, 2, 2, generator=g)]
    fake = [torch.randn(B, 1, 5, 5, generator=g), torch.randn(B, 1, 2, 2, generator=g)]
    sig = torch.sigmoid
    d_bce = (
        sum(-(sig(r).log().mean() + (1 - sig(f)).log().mean()) for r, f in zip(real, fake, strict=True)) / 2
    )
    g_bce = sum(-sig(f).log().mean() for f in fake) / 2
    d_ls = sum(((r - 1) ** 2).mean() + (f**2).mean() for r, f in zip(real, fake, strict=True)) / 2
    g_ls = sum(((f - 1) ** 2).mean() for f in fake) / 2
    torch.testing.assert_close(discriminator_loss(real, fake, "bce"), d_bce)
    torch.testing.assert_close(generator_adversarial_loss(fake, "bce"), g_bce)
    torch.testing.assert_close(discriminator_loss(real, fake, "lsgan"), d_ls)
    torch.testing.assert_close(generator_adversarial_loss(fake, "lsgan"), g_ls)


def test_generator_bce_is_non_saturating():
    # The discriminator is sure the fake is fake (logit -50): the saturating log(1 - D) has a
    # gradient sigmoid(-50) ~ 2e-22; the non-saturating -log D keeps ~ -1 per logit.
    fake = logit_maps(-50.0, n=1, requires_grad=True)
    generator_adversarial_loss(fake, "bce").backward()
    g = fake[0].grad
    assert g.isfinite().all()
    torch.testing.assert_close(g, torch.full_like(g, -1.0 / g.numel()))
    sat = fake[0].detach().clone().requires_grad_()
    (-F.softplus(sat)).mean().backward()  # log(1 - sigmoid(x)) = -softplus(x)
    assert sat.grad.abs().max() < 1e-20


@pytest.mark.parametrize("kind", GAN_KINDS)
@pytest.mark.parametrize("value", [1e4, -1e4])
def test_gan_extreme_logits_finite_and_bounded(kind, value):
    real = logit_maps(value, requires_grad=True)
    fake = logit_maps(-value, requires_grad=True)
    d = discriminator_loss(real, fake, kind)
    gen_fake = logit_maps(value, requires_grad=True)
    g = generator_adversarial_loss(gen_fake, kind)
    d.backward()
    g.backward()
    for t in real + fake + gen_fake:
        assert t.grad.isfinite().all()
        # d/dx of the mean over n logits: <= 1/n for bce, 2 (|x| + 1) / n for lsgan
        bound = 1.0 if kind == "bce" else 2 * (abs(value) + 1)
        assert t.grad.abs().max() <= bound / t.numel() * 1.0001
    assert d.isfinite() and g.isfinite()
    if kind == "bce":  # softplus(1e4) = 1e4, exactly; no overflow to inf
        assert d.item() <= 2e4 + 1 and g.item() <= 1e4 + 1


@pytest.mark.parametrize("kind", GAN_KINDS)
def test_gan_half_precision_logits_are_upcast(kind):
    fake = [torch.full((B, 1, 3, 3), 1e3, dtype=torch.float16)]
    assert generator_adversarial_loss(fake, kind).isfinite()


def test_gan_bad_inputs():
    zero = logit_maps(0.0)
    with pytest.raises(ValueError, match="bce, lsgan"):
        discriminator_loss(zero, zero, "wgan")
    with pytest.raises(ValueError, match="bce, lsgan"):
        generator_adversarial_loss(zero, "hinge")
    with pytest.raises(ValueError, match="empty"):
        generator_adversarial_loss([])
    with pytest.raises(ValueError, match="empty"):
        discriminator_loss([], zero)
    with pytest.raises(ValueError, match="empty"):
        discriminator_loss(zero, [])
    with pytest.raises(ValueError, match="1 real and 2 fake"):
        discriminator_loss(zero[:1], zero)
    with pytest.raises(ValueError, match="list"):
        generator_adversarial_loss(zero[0])


# -- loss weights ------------------------------------------------------------------------


def test_loss_weights_defaults_are_the_papers():
    w = LossWeights()
    assert (w.adv, w.render, w.svbrdf) == (0.1, 0.5, 0.5)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"adv": -0.1}, "adv"),
        ({"render": float("inf")}, "render"),
        ({"svbrdf": float("nan")}, "svbrdf"),
        ({"adv": "0.1"}, "adv"),
        ({"adv": 0, "render": 0, "svbrdf": 0}, "every weight is 0"),
    ],
)
def test_loss_weights_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        LossWeights(**kwargs)


# -- generator loss ----------------------------------------------------------------------


def test_generator_loss_total_and_terms_by_hand(pair):
    pred, target = pair
    s = scene()
    fake = logit_maps(0.3)
    w = LossWeights(adv=0.2, render=0.7, svbrdf=1.5)
    total, terms = generator_loss(pred, target, scene=s, weights=w, fake_logits=fake)
    adv = generator_adversarial_loss(fake)
    ren = rendering_loss(pred, target, s)
    svb, per_map = map_loss(pred, target)
    assert set(terms) == {"adv", "render", "svbrdf", "total"} | {f"map/{n}" for n in MAP_NAMES}
    torch.testing.assert_close(terms["adv"], adv)
    torch.testing.assert_close(terms["render"], ren)
    torch.testing.assert_close(terms["svbrdf"], svb)
    for n in MAP_NAMES:
        torch.testing.assert_close(terms[f"map/{n}"], per_map[n])
    torch.testing.assert_close(total, 0.2 * adv + 0.7 * ren + 1.5 * svb)
    assert terms["total"] is total


def test_generator_loss_weights_scale_linearly(pair):
    pred, target = pair
    s, fake = scene(), logit_maps(-0.5)
    t1, _ = generator_loss(pred, target, scene=s, weights=LossWeights(1.0, 1.0, 1.0), fake_logits=fake)
    t2, _ = generator_loss(pred, target, scene=s, weights=LossWeights(2.0, 2.0, 2.0), fake_logits=fake)
    torch.testing.assert_close(t2, 2 * t1)


def test_generator_loss_gan_kind_and_map_weights(pair):
    pred, target = pair
    fake = logit_maps(0.0)
    w = LossWeights(adv=1.0, render=0.0, svbrdf=1.0)
    total, terms = generator_loss(
        pred, target, weights=w, fake_logits=fake, gan="lsgan", map_weights={"diffuse": 2.0}
    )
    assert terms["adv"].item() == pytest.approx(1.0)
    assert set(terms) == {"adv", "svbrdf", "map/diffuse", "total"}
    torch.testing.assert_close(total, 1.0 + 2.0 * terms["map/diffuse"])


def test_generator_loss_zero_render_weight_renders_nothing(pair, monkeypatch):
    calls = []
    monkeypatch.setattr(losses, "render", lambda *a, **k: calls.append(1) or render(*a, **k))
    w = LossWeights(adv=0.1, render=0.0, svbrdf=0.5)
    _, terms = generator_loss(*pair, weights=w, fake_logits=logit_maps(0.0))  # no scene needed
    assert calls == [] and "render" not in terms
    generator_loss(*pair, scene=scene(), weights=LossWeights(), fake_logits=logit_maps(0.0))
    assert len(calls) == 2  # pred and target, once each


def test_generator_loss_zero_adv_weight_needs_no_discriminator(pair):
    w = LossWeights(adv=0.0)
    total, terms = generator_loss(*pair, scene=scene(), weights=w)
    assert "adv" not in terms
    torch.testing.assert_close(total, 0.5 * terms["render"] + 0.5 * terms["svbrdf"])


def test_generator_loss_zero_svbrdf_weight_skips_maps(pair, monkeypatch):
    monkeypatch.setattr(losses, "map_loss", lambda *a, **k: pytest.fail("map_loss ran"))
    _, terms = generator_loss(
        *pair, scene=scene(), weights=LossWeights(svbrdf=0.0), fake_logits=logit_maps(0.0)
    )
    assert set(terms) == {"adv", "render", "total"}


def test_generator_loss_zero_when_equal_without_adv(pair):
    pred, _ = pair
    total, terms = generator_loss(pred, pred, scene=scene(3), weights=LossWeights(adv=0.0))
    assert total.item() == 0.0 and terms["render"].item() == 0.0 and terms["svbrdf"].item() == 0.0


def test_generator_loss_requirements(pair):
    with pytest.raises(ValueError, match="fake_logits"):
        generator_loss(*pair, scene=scene(), weights=LossWeights(adv=0.1))
    with pytest.raises(ValueError, match="fake_logits"):
        generator_loss(*pair, scene=scene(), weights=LossWeights(adv=0.0), fake_logits=logit_maps(0.0))
    with pytest.raises(ValueError, match="scene"):
        generator_loss(*pair, weights=LossWeights(adv=0.0))
    with pytest.raises(ValueError, match="bce, lsgan"):
        generator_loss(*pair, scene=scene(), weights=LossWeights(adv=0.0), gan="wgan")
    with pytest.raises(ValueError, match="LossWeights"):
        generator_loss(*pair, scene=scene(), weights=(0.1, 0.5, 0.5), fake_logits=logit_maps(0.0))


@pytest.mark.parametrize("gan", GAN_KINDS)
def test_generator_loss_gradients_reach_every_map_through_every_term(pair, gan):
    # A tiny PatchGAN on the renderings, as the paper's discriminator: the adversarial term
    # alone must also reach every map.
    torch.manual_seed(0)
    s = scene()
    disc = PatchGAN(3 * 9, base_channels=4, layers=2)
    for w in (LossWeights(), LossWeights(adv=1.0, render=0.0, svbrdf=0.0), LossWeights(0.0, 1.0, 0.0)):
        pred = with_grad(pair[0])
        fake = [disc(render(pred, s).flatten(1, 2))] if w.adv > 0 else None
        total, _ = generator_loss(pred, pair[1], scene=s, weights=w, fake_logits=fake, gan=gan)
        total.backward()
        for n, g in grads(pred).items():
            assert g is not None and g.isfinite().all() and g.abs().sum() > 0, (w, n)
