"""Flash fitting: recover a known flash, and reproduce the Des18 inputs from their maps."""

from __future__ import annotations

import pytest
import torch

from conftest import random_svbrdf
from svbrdf_render import SVBRDF, Camera, PointLight, Scene, fit_flash, read_des18, render


def test_recovers_a_known_colocated_flash():
    m = random_svbrdf(2, 32, seed=8, roughness=(0.2, 0.5))
    truth = torch.tensor([[0.2, -0.1, 2.5], [-0.3, 0.25, 1.9]])
    power = torch.tensor([12.0, 20.0])
    photos = torch.stack([
        render(m[i], Scene(Camera(truth[i]), (PointLight(truth[i], float(power[i])),)))[0].clamp(0, 1)
        for i in range(2)
    ])
    fit = fit_flash(m, photos, steps=300, fit_size=None)
    assert torch.allclose(fit.position, truth, atol=0.05)
    assert torch.allclose(fit.intensity, power, rtol=0.05)
    assert float(fit.rmse.max()) < 2e-3
    again = render(m[0], fit.scene(0))[0].clamp(0, 1)
    assert torch.allclose(again, fit.rendering[0], atol=1e-5)


def test_bad_photo_shape_is_refused():
    with pytest.raises(Exception, match="photo has shape"):
        fit_flash(SVBRDF.constant(1, 8), torch.zeros(1, 3, 4, 4))


@pytest.mark.slow
@pytest.mark.data
def test_reproduces_the_des18_inputs(shared_data, capsys):
    files = sorted((shared_data / "des18-dev").glob("*.png"))
    samples = [read_des18(f) for f in files]
    maps = SVBRDF.cat([s.svbrdf for s in samples])
    photos = torch.cat([s.input for s in samples])
    fit = fit_flash(maps, photos)
    median = float(fit.rmse.median())
    with capsys.disabled():
        print(f"\nDes18 re-rendering RMSE over {len(files)} samples: median {median:.4f}, "
              f"max {float(fit.rmse.max()):.4f}")
    # The Des18 photos: a simple fit reaches about 0.04; a renderer convention error (gamma,
    # normal flip, wrong Fresnel) takes it well above 0.06.
    assert median < 0.05
    flipped = SVBRDF(maps.normal * torch.tensor([1.0, -1.0, 1.0]).view(1, 3, 1, 1),
                     maps.diffuse, maps.roughness, maps.specular)
    assert float(fit_flash(flipped, photos, steps=60).rmse.median()) > median


def test_the_hand_written_adam_steps_exactly_as_torch_optim_adam():
    # refine_maps and fit_flash step their own Adam (torch.optim's first step imports
    # torch._dynamo, 0.8 s); its steps must be torch.optim.Adam's, groups and learning rates too.
    from svbrdf_render.refinement.fit import _Adam

    gen = torch.Generator().manual_seed(0)
    start = [torch.randn(2, 3, 8, 8, generator=gen), torch.randn(2, 1, 1, 1, generator=gen), torch.randn(4)]
    ours = [t.clone().requires_grad_() for t in start]
    theirs = [t.clone().requires_grad_() for t in start]
    opt_ours = _Adam([{"params": ours[:2], "lr": 0.05}, {"params": ours[2:], "lr": 0.2}])
    opt_theirs = torch.optim.Adam([{"params": theirs[:2], "lr": 0.05}, {"params": theirs[2:], "lr": 0.2}])
    for step in range(25):
        for params, opt in ((ours, opt_ours), (theirs, opt_theirs)):
            opt.zero_grad()
            used = params if step % 5 else params[:2]  # every fifth step one tensor gets no gradient
            loss = sum((p.sin() * (i + 1)).square().sum() for i, p in enumerate(used))
            loss.backward()
            opt.step()
    for a, b in zip(ours, theirs, strict=True):
        assert torch.equal(a.detach(), b.detach())
