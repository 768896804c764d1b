"""The SVBRDF map container and its geometric transforms.

Conventions (docs/svbrdf-render.md, "The renderer in one screen"):

==========  ========  ==========================================================
map         shape     values
==========  ========  ==========================================================
normal      (B,3,H,W) unit length, tangent space, +z out of the surface,
                      x right, y up (OpenGL); image row 0 is the top (y = +1)
diffuse     (B,3,H,W) linear albedo in [0, 1]
roughness   (B,1,H,W) [0, 1]; the microfacet alpha is roughness**2
specular    (B,3,H,W) linear specular albedo (F0) in [0, 1]
==========  ========  ==========================================================

Every transform here moves pixels *and* rotates the normal vectors with them, so a
transformed material renders as the transformed image of the original under a scene
that is symmetric about the camera axis.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from .errors import MapError
from .geometry import safe_normalize

__all__ = [
    "SVBRDF",
    "MAP_NAMES",
    "MAP_CHANNELS",
    "PACKED_CHANNELS",
    "encode_normal",
    "decode_normal",
    "stored_value",
]

MAP_NAMES = ("normal", "diffuse", "roughness", "specular")
MAP_CHANNELS = {"normal": 3, "diffuse": 3, "roughness": 1, "specular": 3}
#: Channels of :meth:`SVBRDF.pack`: normal 3, diffuse 3, roughness 1, specular 3.
PACKED_CHANNELS = 10


def encode_normal(normal: Tensor) -> Tensor:
    """A normal map as files store it: ``(n + 1) / 2`` per channel, in [0, 1] for unit normals.

    The one place the project writes this encoding; map files, shards, metrics on stored values
    and the material files all go through it (or :func:`decode_normal`).

    >>> encode_normal(torch.tensor([0.0, 0.0, 1.0])).tolist()
    [0.5, 0.5, 1.0]
    """
    return (normal + 1) / 2


def decode_normal(stored: Tensor, dim: int = -3) -> Tensor:
    """Unit normals from their stored values (:func:`encode_normal`'s inverse), renormalised
    along ``dim`` (channels of ``(..., 3, H, W)`` by default) since 8-bit files round them."""
    return safe_normalize(stored * 2 - 1, dim=dim)


def stored_value(name: str, t: Tensor) -> Tensor:
    """Map ``name`` on the values a map file stores: the normal encoded, the others as they are."""
    return encode_normal(t) if name == "normal" else t


def check_map_set(
    maps: dict[str, Tensor],
    channels: dict[str, int],
    bounded: tuple[str, ...],
    *,
    what: str,
    first: str,
    hint: str,
) -> None:
    """Check a set of maps that make one material: each a floating-point ``(B, C, H, W)``
    tensor with its ``channels``, all of the first map's batch, size, device and dtype, and the
    ``bounded`` ones in ``[0, 1]`` (one device sync). Raises :class:`MapError` naming the map
    (``what`` 'NAME'), ``first`` (how the first map is called) and ``hint`` (what to do)."""
    ref = next(iter(maps.values()))
    for name, t in maps.items():
        if not isinstance(t, Tensor):
            raise MapError(f"{what} '{name}': expected a torch.Tensor, got {type(t).__name__}")
        want_c = channels[name]
        if t.dim() != 4 or t.shape[1] != want_c:
            raise MapError(f"{what} '{name}': expected shape (B, {want_c}, H, W), got {tuple(t.shape)}")
        if not t.is_floating_point():
            raise MapError(f"{what} '{name}': expected a floating-point tensor, got {t.dtype}")
        if (t.shape[0], t.shape[2], t.shape[3]) != (ref.shape[0], ref.shape[2], ref.shape[3]):
            raise MapError(
                f"{what} '{name}': batch and size {(t.shape[0], t.shape[2], t.shape[3])} differ "
                f"from {first}'s {(ref.shape[0], ref.shape[2], ref.shape[3])} (B, H, W)"
            )
        if t.device != ref.device:
            raise MapError(f"{what} '{name}' is on {t.device}, {first} on {ref.device}")
        if t.dtype != ref.dtype:
            raise MapError(f"{what} '{name}' is {t.dtype}, {first} {ref.dtype}")
    for name in bounded:
        t = maps[name].detach()
        bad = ~((t >= 0) & (t <= 1))
        if bool(bad.any()):
            lo, hi = t.nan_to_num(nan=float("inf")).min(), t.nan_to_num(nan=-1).max()
            raise MapError(
                f"{what} '{name}': expected values in [0, 1], found {int(bad.sum())} outside "
                f"(min {float(lo):.4g}, max {float(hi):.4g}"
                f"{', NaN present' if bool(t.isnan().any()) else ''}); {hint}"
            )


@dataclass(frozen=True, eq=False)
class SVBRDF:
    """Four maps of a batch of materials, validated on construction.

    Args:
        normal: ``(B, 3, H, W)``; normalised by the renderer, so near-unit is fine.
        diffuse: ``(B, 3, H, W)`` in ``[0, 1]``.
        roughness: ``(B, 1, H, W)`` in ``[0, 1]``.
        specular: ``(B, 3, H, W)`` in ``[0, 1]``.
        validate: check value ranges too (one device sync). Shapes, dtypes and
            devices are always checked.

    Example:
        >>> m = SVBRDF.constant(batch=2, size=64)
        >>> m.normal.shape
        torch.Size([2, 3, 64, 64])
        >>> m.flip_horizontal().rot90(1).shape
        (2, 64, 64)
    """

    normal: Tensor
    diffuse: Tensor
    roughness: Tensor
    specular: Tensor
    validate: bool = True

    def __post_init__(self):
        check_map_set(
            {name: getattr(self, name) for name in MAP_NAMES},
            MAP_CHANNELS,
            ("diffuse", "roughness", "specular") if self.validate else (),
            what="map",
            first="the normal map",
            hint="clamp the map or check its encoding",
        )

    # -- construction -------------------------------------------------------------------

    @classmethod
    def constant(
        cls,
        batch: int = 1,
        size: int | tuple[int, int] = 256,
        *,
        diffuse=(0.5, 0.5, 0.5),
        roughness: float = 0.5,
        specular=(0.04, 0.04, 0.04),
        normal=(0.0, 0.0, 1.0),
        dtype: torch.dtype = torch.float32,
        device=None,
    ) -> SVBRDF:
        """A spatially uniform material; handy in tests and examples."""
        h, w = (size, size) if isinstance(size, int) else size

        def fill(values) -> Tensor:
            v = torch.as_tensor(values, dtype=dtype, device=device).reshape(1, -1, 1, 1)
            return v.expand(batch, -1, h, w).clone()

        n = fill(normal)
        n = n / n.norm(dim=1, keepdim=True)
        return cls(n, fill(diffuse), fill([roughness]), fill(specular))

    @classmethod
    def unpack(cls, packed: Tensor, *, validate: bool = True) -> SVBRDF:
        """Inverse of :meth:`pack`: ``(B, 10, H, W)`` -> SVBRDF.

        ``(B, 12, H, W)`` (roughness stored in three channels, as in Des18 networks) is
        accepted too; the three roughness channels are averaged.
        """
        if packed.dim() != 4 or packed.shape[1] not in (10, 12):
            raise MapError(
                f"packed SVBRDF: expected shape (B, 10, H, W) or (B, 12, H, W), "
                f"got {tuple(packed.shape)}"
            )
        n, d = packed[:, 0:3], packed[:, 3:6]
        if packed.shape[1] == 10:
            r, s = packed[:, 6:7], packed[:, 7:10]
        else:
            r, s = packed[:, 6:9].mean(dim=1, keepdim=True), packed[:, 9:12]
        return cls(n, d, r, s, validate=validate)

    def pack(self) -> Tensor:
        """Concatenate the maps to ``(B, 10, H, W)``: normal, diffuse, roughness, specular."""
        return torch.cat([self.normal, self.diffuse, self.roughness, self.specular], dim=1)

    # -- properties ---------------------------------------------------------------------

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(B, H, W)``."""
        b, _, h, w = self.normal.shape
        return (b, h, w)

    @property
    def batch_size(self) -> int:
        return self.normal.shape[0]

    @property
    def size(self) -> tuple[int, int]:
        """``(H, W)``."""
        return (self.normal.shape[2], self.normal.shape[3])

    @property
    def dtype(self) -> torch.dtype:
        return self.normal.dtype

    @property
    def device(self) -> torch.device:
        return self.normal.device

    def maps(self) -> dict[str, Tensor]:
        return {name: getattr(self, name) for name in MAP_NAMES}

    def __len__(self) -> int:
        return self.batch_size

    def __repr__(self) -> str:
        b, h, w = self.shape
        return f"SVBRDF(batch={b}, size={h}x{w}, dtype={self.dtype}, device={self.device})"

    # -- generic helpers ----------------------------------------------------------------

    def _map(self, fn, normal_fn=None, validate: bool = False) -> SVBRDF:
        """Apply ``fn`` to every map (``normal_fn`` to normals when given)."""
        normal_fn = normal_fn or fn
        return SVBRDF(
            normal_fn(self.normal),
            fn(self.diffuse),
            fn(self.roughness),
            fn(self.specular),
            validate=validate,
        )

    def to(self, *args, **kwargs) -> SVBRDF:
        """``Tensor.to`` on every map (device and/or dtype)."""
        return self._map(lambda t: t.to(*args, **kwargs))

    def detach(self) -> SVBRDF:
        return self._map(Tensor.detach)

    def __getitem__(self, index) -> SVBRDF:
        """Select materials of the batch; an integer keeps the batch dimension."""
        if isinstance(index, int):
            index = slice(index, index + 1 if index != -1 else None)
        return self._map(lambda t: t[index])

    @staticmethod
    def cat(items: list[SVBRDF]) -> SVBRDF:
        """Concatenate along the batch dimension."""
        if not items:
            raise MapError("SVBRDF.cat: expected at least one SVBRDF, got none")
        return SVBRDF(
            *(torch.cat([getattr(m, name) for m in items]) for name in MAP_NAMES),
            validate=False,
        )

    def normalized(self) -> SVBRDF:
        """Normals rescaled to unit length (zero or NaN normals become ``(0, 0, 1)``)."""
        from .geometry import safe_normalize

        return SVBRDF(
            safe_normalize(self.normal, dim=1),
            self.diffuse,
            self.roughness,
            self.specular,
            validate=False,
        )

    # -- geometric transforms -----------------------------------------------------------

    def crop(self, top: int, left: int, height: int, width: int | None = None) -> SVBRDF:
        """Crop every map to ``[top:top+height, left:left+width]``."""
        width = height if width is None else width
        h, w = self.size
        if top < 0 or left < 0 or height <= 0 or width <= 0 or top + height > h or left + width > w:
            raise MapError(
                f"crop (top={top}, left={left}, {height}x{width}) does not fit in the "
                f"{h}x{w} maps"
            )
        return self._map(lambda t: t[:, :, top : top + height, left : left + width])

    def center_crop(self, height: int, width: int | None = None) -> SVBRDF:
        """The centred ``height x width`` window (the Des18 evaluation crop)."""
        width = height if width is None else width
        h, w = self.size
        return self.crop((h - height) // 2, (w - width) // 2, height, width)

    def resize(self, height: int, width: int | None = None, *, mode: str = "bilinear") -> SVBRDF:
        """Resample every map; normals are re-normalised, other maps clamped to [0, 1]."""
        width = height if width is None else width
        if height <= 0 or width <= 0:
            raise MapError(f"resize: expected a positive size, got {height}x{width}")
        antialias = mode in ("bilinear", "bicubic")
        align = False if mode in ("bilinear", "bicubic") else None

        def rs(t: Tensor) -> Tensor:
            return F.interpolate(
                t, size=(height, width), mode=mode, align_corners=align, antialias=antialias
            )

        return self.filtered(rs)

    def filtered(self, fn: Callable[[Tensor], Tensor]) -> SVBRDF:
        """``fn`` (a filter or resampling of ``(B, C, H, W)``) applied to every map; normals
        re-normalised, the other maps clamped to [0, 1]."""
        return SVBRDF(
            safe_normalize(fn(self.normal), dim=1),
            fn(self.diffuse).clamp(0, 1),
            fn(self.roughness).clamp(0, 1),
            fn(self.specular).clamp(0, 1),
            validate=False,
        )

    def flip_horizontal(self) -> SVBRDF:
        """Mirror left-right: columns reversed, normal x negated."""
        sign = self.normal.new_tensor([-1.0, 1.0, 1.0]).view(1, 3, 1, 1)
        return self._map(lambda t: t.flip(3), lambda n: n.flip(3) * sign)

    def flip_vertical(self) -> SVBRDF:
        """Mirror top-bottom: rows reversed, normal y negated."""
        sign = self.normal.new_tensor([1.0, -1.0, 1.0]).view(1, 3, 1, 1)
        return self._map(lambda t: t.flip(2), lambda n: n.flip(2) * sign)

    def rot90(self, k: int = 1) -> SVBRDF:
        """Rotate by ``k`` quarter turns counter-clockwise as displayed (row 0 on top).

        A counter-clockwise quarter turn maps a tangent vector ``(x, y)`` to ``(-y, x)``.
        """
        k = k % 4
        if k == 0:
            return self._map(lambda t: t)

        def rotate_normal(n: Tensor) -> Tensor:
            n = torch.rot90(n, k, dims=(2, 3))
            x, y, z = n[:, 0:1], n[:, 1:2], n[:, 2:3]
            for _ in range(k):
                x, y = -y, x
            return torch.cat([x, y, z], dim=1)

        return self._map(lambda t: torch.rot90(t, k, dims=(2, 3)), rotate_normal)

    def transpose(self) -> SVBRDF:
        """Swap rows and columns (the 8th element of the dihedral group with flips/rot90)."""
        return self.rot90(1).flip_vertical()
