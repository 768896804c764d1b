"""The maps of procedural materials: a family drawn for each sample, mixed, toned, batched.

Sample ``index`` of data set ``seed`` draws its recipe from its own stream (:mod:`..seeds`): a
family of :data:`FAMILIES` by :data:`FAMILY_WEIGHTS` (or, with probability ``mix``, two of
them blended through a soft noise mask, as Deschaintre et al. 2018 mix materials), its
diffuse albedo shown at a drawn brightness and chroma (from greyer to more saturated than
its palette), its relief scaled by a drawn strength (30% of materials flattened, some nearly
flat). The fields of a batch are computed one family at a time (:mod:`.families`), on the
CPU in chunks of about :data:`_CHUNK_PIXELS` pixels, on an accelerator all at once.

Maps: heights become normals by central differences in patch units (the patch spans
``[-1, 1]^2``; normal ``(-dh/dx, -dh/dy, 1)`` normalised, x right, y up, image row 0 at
``y = +1``), computed on a grid one pixel larger than the image so that edges are exact.
Diffuse, roughness and specular are clamped to ``[0, 1]``.
"""

from __future__ import annotations

import operator
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from svbrdf_models.errors import DataError
from svbrdf_render import SVBRDF

from ..seeds import COMPONENT, MASK, MATERIAL, key
from .families import FAMILY_TABLE, Fields, pixel_grid, stack_choices
from .noise import Draw, fbm, smoothstep
from .noise import mix as blend

__all__ = ["FAMILIES", "FAMILY_WEIGHTS", "material", "materials"]

#: The material families, in the order they are drawn from (their declared ``order``).
FAMILIES: tuple[str, ...] = tuple(FAMILY_TABLE)
#: How often each family is drawn, relatively: each family's ``weight``, declared in its own
#: module (:mod:`.families`), read here. The families of the Des18 materials (stone, tiles,
#: cells, metal) keep the bulk (about 55%), metals a little more (often dark, often coloured);
#: the surfaces Des18 lacks share the rest: painted and rusted metal most of them (metal and
#: dielectric in one material, as Des18's bumpy metal is too), plaster and rock (common, and
#: the low and the strong relief of rough near-grey surfaces), wood and fabric, and bark least
#: (the narrowest look).
FAMILY_WEIGHTS: dict[str, float] = {name: family.weight for name, family in FAMILY_TABLE.items()}

#: Pixels generated together (see :func:`materials`).
_CHUNK_PIXELS = 2 * 256 * 256


@dataclass(frozen=True)
class MaterialRecipe:
    """What one sample is made of: its family name, components ``(family, seed)``, the seed
    of the mixing mask, a bump strength, the scale of its diffuse albedo's value
    (brightness) and chroma (distance from grey), and its relief scale (1, or a flattening
    below 1); the heights are scaled by ``bump * relief``."""

    family: str
    components: tuple[tuple[str, int], ...]
    mask_seed: int
    bump: float
    value: float = 1.0
    chroma: float = 1.0
    relief: float = 1.0


def check_families(families: Sequence[str] | None) -> tuple[str, ...]:
    """``families`` as a tuple of known family names (None: all of :data:`FAMILIES`)."""
    if families is None:
        return FAMILIES
    if isinstance(families, str):
        families = [families]
    families = tuple(families)
    if not families:
        raise DataError(f"families: expected at least one of {', '.join(FAMILIES)}")
    unknown = [f for f in families if f not in FAMILY_TABLE]
    if unknown:
        raise DataError(
            f"unknown material famil{'y' if len(unknown) == 1 else 'ies'} "
            f"{', '.join(repr(f) for f in unknown)}; choose from {', '.join(FAMILIES)}"
        )
    return families


def sample_recipe(
    seed: int, index: int, families: tuple[str, ...], mix_p: float, family: str | None
) -> MaterialRecipe:
    """The recipe of sample ``index`` of ``seed``: its family drawn from ``families`` (two of
    them with probability ``mix_p``; ``family`` forces one, or ``"a+b"``) and its tone and relief."""
    d = Draw(key(seed, index, MATERIAL))
    weights = [FAMILY_WEIGHTS[f] for f in families]
    mixed, first, second = d.chance(mix_p), d.choice(families, weights), d.choice(families, weights)
    bump = d.log_uniform(0.8, 2.4)
    # Albedos: every material is shown at a brightness of 30-100% of its palette's (real
    # albedos are darker than the palettes alone) and a chroma of 0.2-2x its palette's,
    # log-uniform (geometric mean 0.63; about 30% above the palette's, eased near the
    # gamut's edge, see packed_materials). A spread, not one set's level: the Des18 materials
    # are greyish (mean HSV saturation 0.25 [p10 0.09, p90 0.53] on des18-dev), scanned bark,
    # rust, wood and fabric more saturated (0.47 [0.16, 0.75] on unseen-dev); the v2 range
    # of 20-90% matched only the first. On 256 samples W1 of the saturation moves from
    # 0.07 to 0.13 against des18-dev and from 0.17 to 0.12 against unseen-dev.
    value, chroma = d.log_uniform(0.3, 1.0), d.log_uniform(0.2, 2.0)
    # Relief: the bump above spans the Des18 relief (slope p90 0.07-1.0), but real scanned
    # surfaces are often much flatter (plaster, paint, fabric, polished stone: slope p90
    # below 0.01 for a third of unseen-dev). So 30% of materials, of any family, are
    # flattened by a factor log-uniform in 0.02-1 (down to a slope p90 of a few
    # thousandths, nearly a flat normal map), the rest keep their relief: on 256 samples W1
    # of slope p90 falls from 0.33 to 0.22 against unseen-dev and rises from 0.07 to 0.12
    # against des18-dev (its noise floor: 0.11-0.17). Drawn last, so the draws above stay
    # what they were.
    flat, flattening = d.chance(0.3), d.log_uniform(0.02, 1.0)
    relief = flattening if flat else 1.0
    if family is not None:
        names = tuple(family.split("+"))
        if len(names) > 2:
            raise DataError(f"family {family!r}: expected one family or two joined by '+'")
        check_families(names)
    else:
        names = (first, second) if mixed else (first,)
    components = tuple((name, key(seed, index, COMPONENT, slot)) for slot, name in enumerate(names))
    return MaterialRecipe("+".join(names), components, key(seed, index, MASK), bump, value, chroma, relief)


def _mask(seeds: list[int], x: Tensor, y: Tensor) -> tuple[Tensor, Tensor]:
    """Soft masks ``(B, 1, H, W)`` in [0, 1] that blend two materials: thresholded fBm, on
    the device of ``x`` and ``y``.

    Returns the mask of the albedos and roughness, and a wider one for the heights: two
    families' surfaces lie at different levels, and a sharp step between them would be a
    cliff of near-horizontal normals.
    """
    choices = []
    for s in seeds:
        d = Draw(s)
        cs, sn = d.angle()
        choices.append(
            {
                "cos": cs,
                "sin": sn,
                "freq": d.uniform(0.6, 2.0),
                "threshold": d.uniform(-0.3, 0.3),
                "softness": d.log_uniform(0.01, 0.2),
                "lattice": d.lattice(1),
            }
        )
    p = stack_choices(choices, x.device)
    u = (x * p["cos"] - y * p["sin"]) * p["freq"]
    v = (x * p["sin"] + y * p["cos"]) * p["freq"]
    n = fbm(p["lattice"], u, v, 4)
    t, soft = p["threshold"], p["softness"]
    return smoothstep(t - soft, t + soft, n), smoothstep(t - soft - 0.1, t + soft + 0.1, n)


def _fields(recipes: list[MaterialRecipe], resolution: int, device: torch.device | None = None) -> Fields:
    """The (mixed) fields of every recipe on the grid with a one-pixel margin, computed on
    ``device`` (default the CPU); the draws are made on the CPU and copied there."""
    x, y = pixel_grid(resolution, margin=1, device=device)
    b = len(recipes)
    # Jobs: every sample's first component, then the second of the mixed ones.
    jobs = [r.components[0] for r in recipes]
    mixed = [i for i, r in enumerate(recipes) if len(r.components) == 2]
    jobs += [recipes[i].components[1] for i in mixed]
    # One batched computation per family; then back to job order.
    order: list[int] = []
    parts: list[Fields] = []
    for name in dict.fromkeys(f for f, _ in jobs):
        members = [j for j, (f, _) in enumerate(jobs) if f == name]
        family = FAMILY_TABLE[name]
        choices = stack_choices([family.draw(Draw(jobs[j][1])) for j in members], device)
        parts.append(family.fields(choices, x, y))
        order += members
    inverse = torch.empty(len(jobs), dtype=torch.long)
    inverse[torch.tensor(order)] = torch.arange(len(jobs))
    inverse = inverse.to(x.device)
    maps = []
    for k in range(4):
        t = torch.cat([p[k].expand(-1, -1, resolution + 2, resolution + 2) for p in parts])
        maps.append(t.index_select(0, inverse))
    if mixed:
        mask, height_mask = _mask([recipes[i].mask_seed for i in mixed], x, y)
        idx = torch.tensor(mixed, device=x.device)
        for k in range(4):
            first, second = maps[k][idx], maps[k][b:]
            m = height_mask if k == 0 else mask
            maps[k] = maps[k][:b].index_copy(0, idx, blend(first, second, m))
    else:
        maps = [t[:b] for t in maps]
    return Fields(*maps, {})


def _normals(height: Tensor) -> Tensor:
    """Unit normals ``(B, 3, H, W)`` of heights ``(B, 1, H + 2, W + 2)`` in patch units."""
    h, w = height.shape[-2] - 2, height.shape[-1] - 2
    # Central differences over two pixels of 2/W (2/H) patch units; rows go down, y up.
    dhdx = (height[..., 1:-1, 2:] - height[..., 1:-1, :-2]) * (w / 4)
    dhdy = (height[..., :-2, 1:-1] - height[..., 2:, 1:-1]) * (h / 4)
    length = torch.sqrt(dhdx * dhdx + dhdy * dhdy + 1)
    return torch.cat([-dhdx / length, -dhdy / length, 1 / length], dim=1)


def as_device(device: torch.device | str | None) -> torch.device:
    """``device`` as a ``torch.device``; ``None`` is the CPU."""
    return torch.device("cpu") if device is None else torch.device(device)


def check_index(index, count: int | None = None) -> int:
    """``index`` as an int in ``[0, count)`` (``count`` None: any index >= 0)."""
    try:
        i = operator.index(index)
    except TypeError:
        raise TypeError(f"sample index: expected an integer, got {index!r}") from None
    if i < 0 or (count is not None and i >= count):
        raise IndexError(f"sample index {i} out of range for {count} samples")
    return i


def check_resolution(resolution: int) -> int:
    """``resolution`` as an int of at least 2 pixels."""
    r = operator.index(resolution)
    if r < 2:
        raise DataError(f"resolution: expected at least 2 pixels, got {r}")
    return r


def packed_materials(
    seed: int,
    indices: Sequence[int],
    resolution: int,
    families: Sequence[str] | None,
    mix: float,
    family: str | None,
    device: torch.device | str | None = None,
) -> tuple[Tensor, list[str]]:
    """:func:`materials` as one ``(B, 10, R, R)`` tensor in the ``SVBRDF.pack`` layout, on
    ``device`` (default the CPU)."""
    families = check_families(families)
    resolution = check_resolution(resolution)
    if not 0 <= mix <= 1:
        raise DataError(f"mix: expected a probability in [0, 1], got {mix}")
    indices = [check_index(i) for i in indices]
    if not indices:
        raise DataError("materials: expected at least one sample index")
    recipes = [sample_recipe(seed, i, families, mix, family) for i in indices]
    device = as_device(device)
    # On the CPU, chunks of about _CHUNK_PIXELS: larger batches spill the noise octaves out
    # of the caches and run slower (measured: 2 samples at 256 x 256 are fastest on 2 cores).
    # On an accelerator the whole batch at once: fewer, larger kernels.
    chunk = max(1, _CHUNK_PIXELS // (resolution * resolution)) if device.type == "cpu" else len(recipes)
    crop = (..., slice(1, -1), slice(1, -1))
    parts = []
    with torch.no_grad():
        for first in range(0, len(recipes), chunk):
            part = recipes[first : first + chunk]
            f = _fields(part, resolution, device)
            bump, value, chroma, relief = (
                torch.tensor([getattr(r, k) for r in part], dtype=torch.float32).view(-1, 1, 1, 1).to(device)
                for k in ("bump", "value", "chroma", "relief")
            )
            diffuse = f.diffuse[crop]
            grey = (diffuse[:, 0:1] + diffuse[:, 1:2] + diffuse[:, 2:3]) / 3
            # A chroma below 1 applies as drawn. Above 1 its excess is eased, pixel by pixel,
            # towards the headroom left before the lowest channel reaches 0 (the chroma
            # ``grey / (grey - low)``, less 1): 1 / excess' = 1 / excess + 1 / headroom. Small
            # boosts pass nearly whole, none reaches that edge: no channel is pushed below 0
            # (clipped), the hue stays, and no pixel turns a pure colour (HSV saturation 1).
            low = torch.minimum(torch.minimum(diffuse[:, 0:1], diffuse[:, 1:2]), diffuse[:, 2:3])
            headroom = (grey / (grey - low).clamp_min(1e-6) - 1).clamp_min(0.0)
            excess = (chroma - 1).clamp_min(0.0)
            eased = excess * headroom / (excess + headroom).clamp_min(1e-6)
            diffuse = (grey + (chroma.clamp_max(1.0) + eased) * (diffuse - grey)) * value
            maps = [
                _normals(f.height * (bump * relief)),
                diffuse.clamp(0, 1),
                f.roughness[crop].clamp(0, 1),
                f.specular[crop].clamp(0, 1),
            ]
            parts.append(torch.cat(maps, dim=1))
    return torch.cat(parts), [r.family for r in recipes]


def materials(
    seed: int,
    indices: Sequence[int],
    resolution: int,
    *,
    families: Sequence[str] | None = None,
    mix: float = 0.3,
    family: str | None = None,
    device: torch.device | str | None = None,
) -> tuple[SVBRDF, list[str]]:
    """The maps of samples ``indices`` of ``seed``, batched, and their family names.

    Args:
        families: the families to draw from (default: all of :data:`FAMILIES`).
        mix: probability that a sample blends two materials (named ``"a+b"``).
        family: force this family (or ``"a+b"``) for every sample instead of drawing one.
        device: where the maps are computed and returned (default the CPU); the random
            draws are made on the CPU either way.

    Returns:
        ``(SVBRDF of (B, C, R, R), names)``; float32, values in range, unit normals.
    """
    packed, names = packed_materials(seed, indices, resolution, families, mix, family, device)
    maps = SVBRDF.unpack(packed, validate=False)
    return SVBRDF(*(t.contiguous() for t in maps.maps().values()), validate=False), names


def material(
    seed: int,
    index: int,
    resolution: int,
    family: str | None = None,
    *,
    families: Sequence[str] | None = None,
    mix: float = 0.3,
) -> tuple[SVBRDF, str]:
    """The maps of one sample (batch of one) and its family name, e.g. ``"tiles"`` or
    ``"stone+metal"``. ``family`` forces the family; see :func:`materials`."""
    svbrdf, names = materials(seed, [index], resolution, families=families, mix=mix, family=family)
    return svbrdf, names[0]
