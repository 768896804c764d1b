"""Light/view configurations for the rendering loss and for evaluation.

Both return a :class:`~svbrdf_render.Scene` whose camera and light carry configuration
dimensions, so one ``render`` call draws every configuration of every material.
Random numbers come from a ``torch.Generator`` on the CPU: the same seed gives the same
configurations on any device.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from .effects import DES18_EFFECTS
from .scene import Camera, PointLight, Scene

__all__ = [
    "cosine_weighted_directions",
    "training_scene",
    "evaluation_scene",
    "EVAL_SEED",
    "EVAL_CONFIGS",
]

#: The evaluation protocol: 6 light/view pairs drawn from this seed, for every model.
EVAL_SEED = 0
EVAL_CONFIGS = 6


def cosine_weighted_directions(
    shape, generator: torch.Generator | None = None, low: float = 0.001, high: float = 0.95
) -> Tensor:
    """Unit vectors on the upper hemisphere, cosine-weighted: ``shape + (3,)``.

    ``sin^2(theta)`` is uniform in ``[low, high]`` (Deschaintre 2018 keeps away from the
    pole by ``low`` and from grazing angles by ``1 - high``).
    """
    shape = tuple(shape)
    r1 = low + (high - low) * torch.rand(shape, generator=generator)
    phi = 2 * math.pi * torch.rand(shape, generator=generator)
    r = torch.sqrt(r1)
    z = torch.sqrt(1 - r1)
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=-1)


def _log_normal_distance(shape, generator) -> Tensor:
    # Deschaintre 2018: exp(N(0.5, 0.75)), "a nice distance from a [-1, 1] surface".
    return torch.exp(0.5 + 0.75 * torch.randn(tuple(shape), generator=generator))


def training_scene(
    batch: int,
    *,
    generator: torch.Generator | None = None,
    n_random: int = 3,
    n_mirror: int = 6,
    intensity: float = math.pi,
    effects=DES18_EFFECTS,
    device=None,
) -> Scene:
    """Deschaintre 2018's rendering-loss configurations, ``batch x (n_random + n_mirror)``.

    - ``n_random``: light and view directions drawn independently (cosine-weighted),
      both at infinity (directional: no parallax, no falloff).
    - ``n_mirror``: a view direction and its mirror about the normal as the light
      direction, both moved by the same random shift in the patch plane and placed at
      independent log-normal distances, so the highlight lands somewhere on the patch.

    Light intensity is ``pi`` (Deschaintre's lamp factor); the log rendering loss is
    insensitive to the overall scale.
    """
    g = generator
    b = batch
    rand_v = cosine_weighted_directions((b, n_random), g)
    rand_l = cosine_weighted_directions((b, n_random), g)
    mir_dir = cosine_weighted_directions((b, n_mirror), g)
    mir_l_dir = mir_dir * torch.tensor([-1.0, -1.0, 1.0])
    shift = torch.cat(
        [2 * torch.rand((b, n_mirror, 2), generator=g) - 1, torch.full((b, n_mirror, 1), 1e-4)],
        dim=-1,
    )
    view_pos = mir_dir * _log_normal_distance((b, n_mirror, 1), g) + shift
    light_pos = mir_l_dir * _log_normal_distance((b, n_mirror, 1), g) + shift
    cam = torch.cat([rand_v, view_pos], dim=1)
    lit = torch.cat([rand_l, light_pos], dim=1)
    directional = torch.cat(
        [torch.ones(b, n_random, dtype=torch.bool), torch.zeros(b, n_mirror, dtype=torch.bool)],
        dim=1,
    )
    scene = Scene(
        Camera(cam, directional=directional),
        (PointLight(lit, intensity, directional=directional),),
        effects,
    )
    return scene.to(device) if device is not None else scene


def evaluation_scene(
    n: int = EVAL_CONFIGS,
    *,
    seed: int = EVAL_SEED,
    effects=DES18_EFFECTS,
    device=None,
) -> Scene:
    """The evaluation protocol: ``n`` random point light/view pairs from a fixed seed.

    Light and camera directions are cosine-weighted within 45 degrees of the normal, at
    distances uniform in ``[1.5, 3]``; the intensity is ``pi d^2`` so every configuration
    has the irradiance of a unit-``pi`` light at the patch centre. The same ``seed`` gives
    the same ``(n, 3)`` positions everywhere, shared by every material of a batch.
    """
    g = torch.Generator().manual_seed(seed)
    v_dir = cosine_weighted_directions((n,), g, high=0.5)
    l_dir = cosine_weighted_directions((n,), g, high=0.5)
    v_dist = 1.5 + 1.5 * torch.rand((n, 1), generator=g)
    l_dist = 1.5 + 1.5 * torch.rand((n, 1), generator=g)
    scene = Scene(
        Camera(v_dir * v_dist),
        (PointLight(l_dir * l_dist, math.pi * l_dist.squeeze(-1) ** 2),),
        effects,
    )
    return scene.to(device) if device is not None else scene
