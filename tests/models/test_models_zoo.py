"""Every registered generator, attention module and discriminator, built-in or plugin (timm style).

The parameter lists are read from the registry at collection time, so a newly installed plugin
is tested the moment it is registered. Small presets keep the whole file fast.
"""

from __future__ import annotations

import pytest
import torch

import svbrdf_models as sm
from conftest import random_svbrdf
from svbrdf_render import SVBRDF, render, training_scene

GENERATORS = sm.list_models("generator")
ATTENTION = sm.list_models("attention")
DISCRIMINATORS = sm.list_models("discriminator")


def small_config(kind: str, name: str) -> dict:
    """The 'tiny' preset where the spec has one (all built-ins do)."""
    return {"preset": "tiny"} if "tiny" in sm.describe(kind, name).presets else {}


def make(kind: str, name: str, seed: int = 0, **runtime):
    torch.manual_seed(seed)
    return sm.create(kind, name, small_config(kind, name), **runtime)


def photo(batch=2, h=32, w=32, seed=1):
    return torch.rand(batch, 3, h, w, generator=torch.Generator().manual_seed(seed))


def has_parameters(module: torch.nn.Module) -> bool:
    """Baselines (``mean``, ``photo``) hold no parameters: nothing to train, seed or load."""
    return any(True for _ in module.parameters())


def assert_every_parameter_has_gradient(module: torch.nn.Module):
    missing = [n for n, p in module.named_parameters() if p.grad is None or not bool(p.grad.abs().sum() > 0)]
    bad = [n for n, p in module.named_parameters() if p.grad is not None and not torch.isfinite(p.grad).all()]
    assert not missing, f"no gradient reaches {missing}"
    assert not bad, f"non-finite gradient in {bad}"


def assert_valid_maps(maps: SVBRDF, shape):
    assert isinstance(maps, SVBRDF)
    assert maps.shape == shape
    for name in ("normal", "diffuse", "roughness", "specular"):
        t = getattr(maps, name)
        assert torch.isfinite(t).all(), name
    torch.testing.assert_close(maps.normal.norm(dim=1), torch.ones(shape), atol=1e-5, rtol=0)
    assert (maps.normal[:, 2] >= 0).all()
    for name in ("diffuse", "roughness", "specular"):
        t = getattr(maps, name)
        assert t.min() >= 0 and t.max() <= 1, name
    SVBRDF(maps.normal, maps.diffuse, maps.roughness, maps.specular, validate=True)


# -- generators --------------------------------------------------------------------------------


@pytest.mark.parametrize("name", GENERATORS)
@pytest.mark.parametrize("size", [(32, 32), (48, 32)])
def test_generator_forward_gives_valid_maps(name, size):
    g = make("generator", name).eval()
    with torch.no_grad():
        maps = g(photo(2, *size))
    assert_valid_maps(maps, (2, *size))


@pytest.mark.parametrize("name", GENERATORS)
def test_generator_backward_reaches_every_parameter(name):
    g = make("generator", name).train()
    if not has_parameters(g):
        pytest.skip(f"{name} has no parameters (a baseline): no gradient has anywhere to go")
    maps = g(photo())
    weights = torch.rand(maps.pack().shape, generator=torch.Generator().manual_seed(3))
    (maps.pack() * weights).sum().backward()
    assert_every_parameter_has_gradient(g)


@pytest.mark.parametrize("name", GENERATORS)
def test_generator_is_deterministic_under_a_seed(name):
    x = photo()
    outs = []
    for _ in range(2):
        g = make("generator", name, seed=7).train()
        torch.manual_seed(11)  # dropout masks
        outs.append(g(x).pack())
    torch.testing.assert_close(outs[0], outs[1], rtol=0, atol=0)
    other = make("generator", name, seed=8).eval()(x).pack()
    # A seed draws the initial weights; a generator without any gives the same maps whatever it is.
    assert torch.equal(other, outs[0]) == (not has_parameters(make("generator", name)))


@pytest.mark.parametrize("name", GENERATORS)
def test_generator_dropout_acts_in_train_mode_only(name):
    g = make("generator", name)
    x = photo()
    has_dropout = any(isinstance(m, torch.nn.Dropout) for m in g.modules())
    g.eval()
    with torch.no_grad():
        torch.testing.assert_close(g(x).pack(), g(x).pack(), rtol=0, atol=0)
        g.train()
        a, b = g(x).pack(), g(x).pack()
    assert (not torch.equal(a, b)) == has_dropout


@pytest.mark.parametrize("name", GENERATORS)
def test_generator_state_dict_round_trip(name):
    a, b = make("generator", name, seed=1).eval(), make("generator", name, seed=2).eval()
    x = photo()
    assert torch.equal(a(x).pack(), b(x).pack()) == (not has_parameters(a))
    b.load_state_dict(a.state_dict())
    torch.testing.assert_close(a(x).pack(), b(x).pack(), rtol=0, atol=0)


@pytest.mark.parametrize("name", GENERATORS)
@pytest.mark.parametrize("case", ["black", "overexposed", "negative-noise", "hdr"])
def test_generator_hard_inputs_stay_finite_forward_and_backward(name, case):
    x = {
        "black": torch.zeros(2, 3, 32, 32),
        "overexposed": torch.ones(2, 3, 32, 32),
        "negative-noise": photo() - 0.7,
        "hdr": photo() * 1e4,
    }[case].requires_grad_(True)
    g = make("generator", name).train()
    maps = g(x)
    assert_valid_maps(maps, (2, 32, 32))
    maps.pack().sum().backward()
    assert torch.isfinite(x.grad).all()
    assert all(torch.isfinite(p.grad).all() for p in g.parameters() if p.grad is not None)


# -- attention modules -----------------------------------------------------------------------


@pytest.mark.parametrize("name", ATTENTION)
@pytest.mark.parametrize("size", [(16, 16), (7, 5), (1, 1)])
def test_attention_output_shape(name, size):
    att = make("attention", name, channels=8)
    x = torch.randn(2, 8, *size)
    y = att(x)
    assert y.shape == (2, att.out_channels, *size)
    assert torch.isfinite(y).all()


@pytest.mark.parametrize("name", ATTENTION)
def test_attention_backward_reaches_every_parameter_and_input(name):
    att = make("attention", name, channels=8)
    x = torch.randn(2, 8, 12, 12, requires_grad=True)
    (att(x) * torch.randn(2, att.out_channels, 12, 12)).sum().backward()
    assert_every_parameter_has_gradient(att)
    assert x.grad is not None and torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0


@pytest.mark.parametrize("name", ATTENTION)
def test_attention_state_dict_round_trip_and_seed(name):
    x = torch.randn(2, 8, 8, 8)
    a, a2, b = (make("attention", name, seed=s, channels=8) for s in (1, 1, 2))
    torch.testing.assert_close(a(x), a2(x), rtol=0, atol=0)
    b.load_state_dict(a.state_dict())
    torch.testing.assert_close(a(x), b(x), rtol=0, atol=0)


# -- discriminators ------------------------------------------------------------------------


def disc_inputs(d, batch=2, size=32, seed=0):
    maps = random_svbrdf(batch, size, seed=seed)
    n = getattr(getattr(d, "config", None), "renderings", 9)
    scene = training_scene(batch, generator=torch.Generator().manual_seed(seed))
    r = render(maps, scene)  # (B, 9, 3, H, W): the renderings the trainer gives
    if n != r.shape[1]:
        r = r[:, :n] if n < r.shape[1] else r.repeat(1, -(-n // r.shape[1]), 1, 1, 1)[:, :n]
    return {"maps": maps, "renderings": r.clamp(0, 1)}


@pytest.mark.parametrize("name", DISCRIMINATORS)
@pytest.mark.parametrize("size", [32, 64])
def test_discriminator_returns_logit_maps(name, size):
    d = make("discriminator", name).eval()
    with torch.no_grad():
        out = d(**disc_inputs(d, size=size))
    assert isinstance(out, list) and out
    for logits in out:
        assert logits.dim() == 4 and logits.shape[:2] == (2, 1) and logits.shape[-1] >= 1
        assert torch.isfinite(logits).all()


@pytest.mark.parametrize("name", DISCRIMINATORS)
def test_discriminator_backward_reaches_every_parameter(name):
    d = make("discriminator", name).train()
    inputs = disc_inputs(d)
    sum(o.mean() for o in d(**inputs)).backward()
    assert_every_parameter_has_gradient(d)


@pytest.mark.parametrize("name", DISCRIMINATORS)
def test_discriminator_gradient_reaches_the_generator_side(name):
    # The adversarial loss must move the generator: gradients flow into maps and renderings.
    d = make("discriminator", name)
    inputs = disc_inputs(d)
    maps = inputs["maps"]
    leaves = [maps.normal, maps.diffuse, maps.roughness, maps.specular, inputs["renderings"]]
    for t in leaves:
        t.requires_grad_(True)
    sum(o.mean() for o in d(**inputs)).backward()
    reached = [t.grad is not None and bool(t.grad.abs().sum() > 0) for t in leaves]
    assert any(reached)
    assert all(torch.isfinite(t.grad).all() for t in leaves if t.grad is not None)


@pytest.mark.parametrize("name", DISCRIMINATORS)
def test_discriminator_seed_state_dict_and_modes(name):
    a, a2, b = (make("discriminator", name, seed=s) for s in (1, 1, 2))
    inputs = disc_inputs(a)
    for m in (a, a2, b):
        m.eval()
    with torch.no_grad():
        first = torch.cat([o.flatten() for o in a(**inputs)])
        torch.testing.assert_close(first, torch.cat([o.flatten() for o in a2(**inputs)]), rtol=0, atol=0)
        assert not torch.equal(first, torch.cat([o.flatten() for o in b(**inputs)]))
        b.load_state_dict(a.state_dict())
        torch.testing.assert_close(first, torch.cat([o.flatten() for o in b(**inputs)]), rtol=0, atol=0)
        # No dropout in the discriminators: train mode with instance norm gives the same logits.
        if not any(isinstance(m, torch.nn.modules.batchnorm._BatchNorm) for m in a.modules()):
            a.train()
            torch.testing.assert_close(first, torch.cat([o.flatten() for o in a(**inputs)]))
