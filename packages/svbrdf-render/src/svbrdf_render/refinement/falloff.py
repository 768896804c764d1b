"""Where the flash stood, read off the fall-off of its light over the whole photo.

A flash a little beside a phone's lens lights the surface most at its foot and less with the
distance from it (the cosine over the distance squared for the diffuse part, a lobe around the
same place for the specular part). When the phone is tilted or held off-centre, the foot moves
away from the captured square's centre; where the material shows a clear highlight
(:func:`~svbrdf_render.refinement.rings.find_highlight`) it marks the place, but a matte
material has none, and a bright patch of texture, a metal's flake or a reference card can pass
for one. The fall-off, though, is in every pixel. :func:`fall_off_point` fits it: the photo's
luminance, area-averaged down to :data:`WORK` pixels a side, against a flat material's image
under a flash at each candidate place, a diffuse part and a specular lobe of one of
:data:`LOBES` roughnesses with their two weights solved by non-negative least squares on
relative errors (texture multiplies the light, so each working pixel counts by its share);
first on a grid :data:`COARSE` half-widths apart, then :data:`FINE` apart around the best. A
flat material under a flash looks the same wherever the flash is, moved with it, so one
rendering over a wider patch gives every place's image as a window of it.
A specular lobe in the model matters: with the diffuse part alone, the broad lobe of a
roughness-0.5 material put the flash 20-30% too far from the centre.

On the handheld photos of ``benchmarks/shots.py`` (unseen-dev, 512 px, tilts up to 20
degrees) the point lay 0.01-0.24 half-widths from the true flash, against 0.05-0.6 for the
highlight where one was found and the square's centre where none was.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from ..maps import SVBRDF
from ..renderer import render

__all__ = ["COARSE", "FINE", "LOBES", "WORK", "fall_off_point", "tilted_view_factor"]

#: The working side, in pixels: the fall-off is smooth, and texture averages out.
WORK = 32
#: The roughnesses of the specular lobe tried (the diffuse part is always in).
LOBES = (0.25, 0.4, 0.6, 0.9)
#: The coarse grid's spacing and the fine grid's, in half-widths of the square (the fine one is
#: the pitch the flat material is rendered at: :data:`WORK` x ``_SUPER`` pixels over the square).
COARSE, FINE = 0.125, 0.03125
_SUPER = 2
#: A working pixel is used when at least this share of it is material (not ``ignore``d).
_COVERED = 0.99


def _working(photo: Tensor, ignore: Tensor | None) -> tuple[Tensor, Tensor]:
    """``(B, WORK * WORK)`` luminance and its ``(B, WORK * WORK)`` use (bool)."""
    y = photo.double().mean(1, keepdim=True)
    keep = torch.ones_like(y) if ignore is None else (~ignore.to(torch.bool)).double().expand_as(y)
    area = F.adaptive_avg_pool2d(keep, WORK).flatten(1)
    level = F.adaptive_avg_pool2d(y * keep, WORK).flatten(1) / area.clamp_min(1e-9)
    return level, (area > _COVERED) & (level > 1e-6) & torch.isfinite(level)


def _pitch() -> float:
    return 2.0 / (WORK * _SUPER)


def _big(height: float, margin: int) -> Tensor:
    """``(1 + len(LOBES), N, N)``: a flat material's luminance under a unit flash (the camera
    beside it) over the square's centre, rendered over a patch ``margin`` pitches wider on each
    side than the square, at :func:`_pitch`. A flat material under a flash is the same picture
    wherever the flash is, moved with it: each place's image is a window of this one. The patch
    of half-width ``R`` is rendered as the unit patch with the flash at ``height / R`` (angles,
    so the cosine and the lobes, are unchanged; the fall-off is scaled by a constant the
    weights absorb)."""
    from .fit import flash_scene

    n = WORK * _SUPER + 2 * margin
    r = n * _pitch() / 2
    scene = flash_scene(torch.tensor([[0.0, 0.0, float(height) / r]]), torch.ones(1))
    parts = [SVBRDF.constant(1, n, diffuse=(1.0,) * 3, specular=(0.0,) * 3, roughness=0.5)]
    parts += [SVBRDF.constant(1, n, diffuse=(0.0,) * 3, specular=(1.0,) * 3, roughness=r) for r in LOBES]
    return torch.cat([render(m, scene).reshape(1, 3, n, n).mean(1).double() for m in parts])


def _basis(big: Tensor, margin: int, steps: Tensor) -> Tensor:
    """``(K, 1 + len(LOBES), WORK * WORK)``: the images of :func:`_big` with the flash moved by
    ``steps`` ``(K, 2)`` pitches (x right, y up), area-averaged to :data:`WORK`."""
    side = WORK * _SUPER
    out = []
    for mx, my in steps.tolist():
        top, left = margin + int(my), margin - int(mx)  # rows run down, y up; the picture follows the flash
        window = big[:, top : top + side, left : left + side]
        out.append(F.avg_pool2d(window[None], _SUPER)[0].flatten(1))
    return torch.stack(out)


def _misfit(level: Tensor, use: Tensor, basis: Tensor) -> Tensor:
    """``(K,)``: the best mean relative error over the lobes of one photo's ``level`` ``(P,)``
    (pixels ``use``) against each place's ``basis``, two non-negative weights solved per lobe."""
    p = level[use]
    b = basis[:, :, use] / p  # relative: each pixel by its share
    d, target = b[:, :1], torch.ones_like(p)
    best = torch.full((basis.shape[0],), float("inf"), dtype=basis.dtype)
    for j in range(1, basis.shape[1]):
        s = b[:, j : j + 1]
        a = torch.cat([d, s], 1)  # (K, 2, P)
        gram = a @ a.transpose(1, 2)  # (K, 2, 2)
        rhs = a @ target  # (K, 2)
        det = gram[:, 0, 0] * gram[:, 1, 1] - gram[:, 0, 1] ** 2
        w0 = (gram[:, 1, 1] * rhs[:, 0] - gram[:, 0, 1] * rhs[:, 1]) / det.clamp_min(1e-30)
        w1 = (gram[:, 0, 0] * rhs[:, 1] - gram[:, 0, 1] * rhs[:, 0]) / det.clamp_min(1e-30)
        w = torch.stack([w0, w1], 1)
        alone = torch.stack([rhs[:, 0] / gram[:, 0, 0].clamp_min(1e-30), torch.zeros_like(w0)], 1)
        w = torch.where(((w0 < 0) | (w1 < 0))[:, None], alone, w)  # a negative lobe: diffuse alone
        err = ((w[:, :, None] * a).sum(1) - target).abs().mean(1)
        best = torch.minimum(best, err)
    return best


def _steps(centre: Tensor, half: int, every: int) -> Tensor:
    """``(K, 2)``: integer pitches, a square grid ``every`` apart out to ``half`` around ``centre``."""
    g = torch.arange(-half, half + 1, every)
    gy, gx = torch.meshgrid(g, g, indexing="ij")
    return torch.stack([gx.flatten(), gy.flatten()], 1) + centre


def fall_off_point(
    photo: Tensor,
    height: float,
    ignore: Tensor | None = None,
    *,
    around: Tensor | None = None,
    span: float = 1.0,
) -> tuple[Tensor, Tensor]:
    """The foot of the flash over each photo ``(B, 3, H, W)`` (linear, the captured square) taken
    from ``height`` half-widths: ``(points (B, 2), misfit (B,))``, points as
    :func:`~svbrdf_render.geometry.surface_positions` (x right, y up, in ``[-1, 1]`` over the
    square), the misfit the mean relative error of the best flat material there (0.1: the photo
    departs from a flat material's fall-off by 10% a pixel on average, texture included).

    ``ignore``: ``(B or 1, 1, H, W)``, true where the pixels are not the material (a reference
    card); ``around``: ``(2,)`` or ``(B, 2)``, the centre of the search (the square's centre when
    None), ``span`` half-widths each way. A photo with too few usable pixels (under a quarter of
    the working ones) gets ``around`` and an infinite misfit.
    """
    if photo.dim() != 4 or photo.shape[1] != 3:
        raise ValueError(f"fall_off_point: photo must be (B, 3, H, W), got {tuple(photo.shape)}")
    if not height > 0:
        raise ValueError(f"fall_off_point: height must be positive, got {height}")
    b = photo.shape[0]
    centre = torch.zeros(b, 2) if around is None else torch.as_tensor(around).reshape(-1, 2)
    centre = centre.double().expand(b, 2)
    levels, uses = _working(photo.detach().cpu(), None if ignore is None else ignore.detach().cpu())
    p = _pitch()
    at = torch.round(centre / p).long()  # the search's centre, in pitches
    reach = round(span / p)
    coarse, fine = round(COARSE / p), max(1, round(FINE / p))
    margin = int(at.abs().max()) + reach + coarse
    points, misfits = centre.clone(), torch.full((b,), float("inf"), dtype=torch.float64)
    with torch.no_grad():
        big = _big(height, margin)
        for i in range(b):
            if int(uses[i].sum()) < WORK * WORK // 4:
                continue
            grid = _steps(at[i], reach, coarse)
            err = _misfit(levels[i], uses[i], _basis(big, margin, grid))
            grid = _steps(grid[int(err.argmin())], coarse, fine)
            grid = grid[(grid - at[i]).abs().max(1).values <= reach + coarse]
            err = _misfit(levels[i], uses[i], _basis(big, margin, grid))
            j = int(err.argmin())
            points[i], misfits[i] = grid[j].double() * p, err[j]
    return points.float(), misfits.float()


def _plane_points(camera: Tensor, focal: float, u: Tensor, v: Tensor) -> Tensor:
    """``(N, 2)`` where the rays through square points ``(u, v)`` (the photo's axes, the square's
    units) of a pinhole at ``camera`` aimed at the square's centre, focal length ``focal`` in
    the same units, meet the plane z = 0 (the camera's up taken as near +y as it can be)."""
    forward = -camera / camera.norm()
    right = torch.linalg.cross(forward, camera.new_tensor([0.0, 1.0, 0.0]))
    right = right / right.norm()
    up = torch.linalg.cross(right, forward)
    rays = u[:, None] * right + v[:, None] * up + focal * forward
    return camera[:2] + (-camera[2] / rays[:, 2])[:, None] * rays[:, :2]


def tilted_view_factor(mask: Tensor, camera: Tensor, focal: float) -> float:
    """How much brighter a flash at ``camera`` (the lens, the flash beside it) lights the pixels
    of ``mask`` ``(1, 1, S, S)`` (the square's pixels) on the surface than the square's own
    coordinates say: a phone off the square's axis and aimed at its centre sees the surface
    in perspective, so a region on the far side lies farther from the flash than its place in
    the square, and one on the near side nearer.

    The surface is taken in the frame of the best similarity from the square to it (the frame
    a capture's maps are in) and the light as ``cos / d^2``. A flash read off a region as if the
    square were the surface is that factor too weak: multiply it by the factor. 1 for a camera
    on the axis; ``camera`` ``(3,)`` in the square's half-widths; ``focal`` (its focal length
    over half the square's side in pixels) is the distance at which the square spans 2 units.
    On the tilted handheld photos of ``benchmarks/shots.py`` (unseen-dev, 512 px), the true
    pose's factor took the card's reading at the true flash from 0.91-1.07 of the true
    intensity to 1.00-1.02.
    """
    camera = camera.detach().to("cpu", torch.float64).reshape(3)
    if not (bool(torch.isfinite(camera).all()) and float(camera[2]) > 0 and focal > 0):
        return 1.0
    size = mask.shape[-1]
    rows, cols = torch.nonzero(mask.reshape(mask.shape[-2:]), as_tuple=True)
    if rows.numel() == 0:
        return 1.0
    centre = lambda i: (i.to(torch.float64) + 0.5) / size * 2 - 1  # noqa: E731
    u, v = centre(cols), -centre(rows)
    grid = torch.linspace(-1, 1, 9, dtype=torch.float64)
    gu, gv = (t.reshape(-1) for t in torch.meshgrid(grid, grid, indexing="xy"))
    on = _plane_points(camera, focal, gu, gv)  # the square's grid on the surface
    z, w = torch.complex(gu, gv), torch.complex(on[:, 0], on[:, 1])
    a = ((z - z.mean()).conj() * (w - w.mean())).sum() / (z - z.mean()).abs().square().sum()
    b = w.mean() - a * z.mean()
    q = _plane_points(camera, focal, u, v)
    q = (torch.complex(q[:, 0], q[:, 1]) - b) / a
    f = (torch.complex(camera[0], camera[1]) - b) / a
    flash = torch.stack([f.real, f.imag, camera[2] / a.abs()])

    def light(x: Tensor, y: Tensor) -> Tensor:
        d = torch.stack([flash[0] - x, flash[1] - y, flash[2].expand_as(x)])
        return d[2] / d.square().sum(0).pow(1.5)

    factor = float(light(u, v).mean() / light(q.real, q.imag).mean())
    return factor if math.isfinite(factor) and factor > 0 else 1.0
