"""What the paper says each network is: eq. 1, the down/up blocks, the global track, the heads."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

import svbrdf_models as sm
from svbrdf_models.networks.attention import MultiScaleAttention
from svbrdf_models.networks.generators import DownBlock, UNetGenerator, encode_photo, maps_from_output


def test_multiscale_attention_is_equation_1():
    torch.manual_seed(0)
    att = sm.create_attention("multiscale", 4, {"scales": [1, 2, 4]})
    x = torch.randn(2, 4, 16, 16)
    # Eq. 1 written out: pool by s, shared 1x1 conv W_c, bilinear back up, sum, sigmoid, product.
    logits = sum(
        F.interpolate(
            att.conv(F.avg_pool2d(x, s)) if s > 1 else att.conv(x),
            size=(16, 16),
            mode="bilinear",
            align_corners=False,
        )
        for s in (1, 2, 4)
    )
    expected = torch.cat([x, torch.sigmoid(logits) * x], dim=1)
    torch.testing.assert_close(att(x), expected)
    assert att.out_channels == 8


def test_multiscale_attention_gradcheck_float64():
    torch.manual_seed(0)
    att = sm.create_attention("multiscale", 3, {"scales": [1, 2, 3]}).double()
    x = torch.randn(1, 3, 7, 6, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(att, (x,))


@pytest.mark.parametrize("name", ["se", "cbam"])
def test_channel_attention_keeps_shape_and_gates_within_the_input(name):
    att = sm.create_attention(name, 16)
    x = torch.rand(2, 16, 9, 9) + 0.1
    y = att(x)
    # Sigmoid gates scale each value by a factor in (0, 1).
    assert y.shape == x.shape and (y > 0).all() and (y < x).all()


def test_generator_blocks_follow_the_paper():
    g = sm.create_generator("ours", preset="tiny")
    assert isinstance(g, UNetGenerator) and len(g.down) == 4 and len(g.up) == 4
    for level, block in enumerate(g.down):
        assert isinstance(block, DownBlock)
        assert isinstance(block.attention, MultiScaleAttention)
        assert block.fc is not None  # the global track
        # Innermost level: no instance norm (a 1x1 map at the paper's size).
        assert isinstance(block.norm, torch.nn.InstanceNorm2d) == (level < 3)
    # Skips: the attention doubles channels, and the up blocks take them.
    assert g.down[0].out_channels == 16 and g.up[1].deconv.in_channels == g.down[1].out_channels + 16
    dropouts = [k for k, up in enumerate(g.up) if k and isinstance(up.dropout, torch.nn.Dropout)]
    assert dropouts == [1, 2, 3]


def test_unet_has_no_global_track_and_no_attn_has_no_attention():
    unet = sm.create_generator("unet", preset="tiny")
    assert all(b.fc is None for b in unet.down)
    assert all(isinstance(b.attention, MultiScaleAttention) for b in unet.down)
    plain = sm.create_generator("no-attn", preset="tiny")
    assert all(b.attention.out_channels == b.attention.in_channels for b in plain.down)
    assert all(b.fc is not None for b in plain.down)
    # A config, not a copy: same class, same config type.
    assert type(plain) is type(unet) is UNetGenerator


def test_global_track_feeds_the_image_statistics_to_every_level():
    torch.manual_seed(0)
    g = sm.create_generator("ours", preset="tiny").eval()
    x = torch.rand(1, 3, 32, 32)
    captured = []
    hook = g.down[3].fc.register_forward_hook(lambda m, i, o: captured.append(i[0]))
    g(x)
    hook.remove()
    # Level 4's FC reads [level-3 global vector, level-4 spatial mean].
    assert captured[0].shape == (1, g.down[2].out_channels + g.down[3].out_channels)


def test_attention_can_differ_per_level():
    g = sm.create_generator("ours", {"preset": "tiny", "attention": ["multiscale", "se", "cbam", "none"]})
    kinds = [type(b.attention).__name__ for b in g.down]
    assert kinds == ["MultiScaleAttention", "SqueezeExcitation", "CBAMAttention", "NoAttention"]
    assert g(torch.rand(1, 3, 32, 32)).normal.shape == (1, 3, 32, 32)


def test_generator_rejects_photos_it_cannot_take():
    g = sm.create_generator("ours", preset="tiny")
    with pytest.raises(ValueError, match="multiples of 16"):
        g(torch.rand(1, 3, 40, 32))
    with pytest.raises(ValueError, match=r"\(B, 3, H, W\)"):
        g(torch.rand(1, 4, 32, 32))


def test_photo_encoding_maps_the_unit_range_to_minus_one_one():
    e = encode_photo(torch.tensor([0.0, 1.0, -0.5]))
    torch.testing.assert_close(e, torch.tensor([-1.0, 1.0, -1.0]))


@pytest.mark.parametrize("value", [-1.0, 1.0, 0.0])
def test_output_head_extremes_are_valid_maps(value):
    t = torch.full((1, 9, 4, 4), value, requires_grad=True)
    maps = maps_from_output(t)
    torch.testing.assert_close(maps.normal.norm(dim=1), torch.ones(1, 4, 4))
    assert (maps.normal[:, 2] > 0).all()
    for m in (maps.diffuse, maps.roughness, maps.specular):
        assert m.min() >= 0 and m.max() <= 1
    maps.pack().sum().backward()
    assert torch.isfinite(t.grad).all()


def test_generator_under_bfloat16_autocast_gives_valid_maps():
    g = sm.create_generator("ours", preset="tiny").eval()
    with torch.autocast("cpu", dtype=torch.bfloat16), torch.no_grad():
        maps = g(torch.rand(1, 3, 32, 32))
    for m in (maps.diffuse, maps.roughness, maps.specular):
        assert torch.isfinite(m).all() and m.min() >= 0 and m.max() <= 1
    assert torch.isfinite(maps.normal).all()
    assert maps.normal.dtype == maps.diffuse.dtype == torch.float32


@pytest.mark.slow
def test_paper_generator_at_256():
    # The paper's default: 8 levels x 64 base channels on 256x256, down to a 1x1 bottleneck.
    g = sm.create_generator("ours")
    assert g.config.depth == 8 and g.config.base_channels == 64
    x = torch.rand(1, 3, 256, 256)
    maps = g(x)
    assert maps.shape == (1, 256, 256)
    maps.pack().mean().backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in g.parameters())


def _nyquist_share(t: torch.Tensor) -> float:
    """Share of a map's variance (channels summed) at a 2-pixel period, vertical or horizontal:
    the power on the row and column of the spectrum at half the sampling rate."""
    x = t - t.mean(dim=(-2, -1), keepdim=True)
    f = torch.fft.fft2(x.double()).abs().square().sum(0)
    n = f.shape[-1] // 2
    nyquist = f[n, :].sum() + f[:, n].sum() - f[n, n]
    return float(nyquist / f.sum().clamp_min(1e-300))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_resize_upsampling_leaves_no_two_pixel_pattern_on_a_uniform_photo(seed):
    # The maps predicted for a uniform photo should be uniform but for the borders (zero
    # padding), whose effect is smooth. Bound: white noise puts (2N - 1) / N^2 of its power on
    # those two lines of an N x N spectrum (~2/N); a map free of a 2-pixel pattern puts less
    # there than noise would. The paper's transposed convolutions (the control) put far more.
    photo = torch.full((1, 3, 64, 64), 0.1)
    bound = (2 * 64 - 1) / 64**2
    shares = {}
    for upsample in ("resize", "transpose"):
        torch.manual_seed(seed)
        g = sm.create_generator("ours", {"preset": "tiny", "upsample": upsample}).eval()
        with torch.no_grad():
            maps = g(photo)
        shares[upsample] = max(_nyquist_share(m[0]) for m in (maps.normal, maps.diffuse, maps.roughness, maps.specular))
    assert shares["resize"] < bound, shares
    assert shares["transpose"] > bound, shares


def test_median_input_norm_makes_the_maps_independent_of_exposure():
    torch.manual_seed(0)
    photo = torch.rand(2, 3, 32, 32) * 0.4
    for cfg, invariant in (({"input_norm": "median"}, True), ({}, False)):
        torch.manual_seed(0)
        g = sm.create_generator("ours", {"preset": "tiny", **cfg}).eval()
        with torch.no_grad():
            a, b = g(photo), g(photo * 2.0)
        change = (a.diffuse - b.diffuse).abs().max().item()
        assert (change < 1e-5) == invariant, (cfg, change)


def test_input_level_reaches_the_maps_and_needs_the_norm_and_the_track():
    torch.manual_seed(0)
    g = sm.create_generator("ours", {"preset": "tiny", "input_norm": "median", "input_level": True}).eval()
    photo = torch.rand(1, 3, 32, 32) * 0.4
    with torch.no_grad():
        assert (g(photo).diffuse - g(photo * 2.0).diffuse).abs().max() > 1e-4
    for bad in ({"input_level": True}, {"input_level": True, "input_norm": "median", "global_track": False}):
        with pytest.raises(ValueError, match="input_level"):
            sm.create_generator("ours", {"preset": "tiny", **bad})


@pytest.mark.parametrize("photo", [torch.zeros(1, 3, 32, 32), torch.ones(1, 3, 32, 32), torch.full((1, 3, 32, 32), 1e-9)])
def test_median_input_norm_is_finite_forward_and_backward_on_hard_photos(photo):
    g = sm.create_generator("ours", {"preset": "tiny", "input_norm": "median", "input_level": True, "upsample": "resize"})
    photo = photo.clone().requires_grad_(True)
    maps = g(photo)
    loss = sum(m.sum() for m in (maps.normal, maps.diffuse, maps.roughness, maps.specular))
    loss.backward()
    assert all(torch.isfinite(m).all() for m in (maps.normal, maps.diffuse, maps.roughness, maps.specular))
    assert all(torch.isfinite(p.grad).all() for p in g.parameters() if p.grad is not None)
    assert torch.isfinite(photo.grad).all()
