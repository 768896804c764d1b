"""Scenes: a camera, lights and the effects the rendering declares.

Geometry: the material patch spans ``[-1, 1]^2`` at ``z = 0`` and fills the image; the
camera looks at it from ``+z``. Positions may carry leading *configuration* dimensions:
``(3,)`` for one configuration, ``(K, 3)`` for K configurations shared by every material,
``(B, K, 3)`` for K configurations per material. ``render`` then returns ``(B, 3, H, W)``
or ``(B, K, 3, H, W)``. A camera or light marked ``directional`` sits at infinity in the
direction of its ``position`` (no parallax, no falloff); the mark may itself be a bool
tensor of the configuration shape, so one batch can mix both kinds.

Scenes round-trip through plain dicts (and YAML, with the ``io`` extra)::

    camera: {position: [0, 0, 2.2], fov: 48.9}
    lights:
      - {type: flash, intensity: 9.0}
      - {type: point, position: [1, 1, 2], intensity: 3.0, color: [1, 0.9, 0.8]}
    effects: [diffuse, specular, fresnel, masking, cosine, falloff]
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from ._optional import require
from .effects import DES18_EFFECTS, resolve_effects
from .errors import SceneError
from .formats.yamlio import safe_load

__all__ = ["Camera", "PointLight", "Flash", "Light", "Scene", "DES18_DISTANCE"]

#: Camera/flash distance that reproduces the Des18 inputs: flashes fitted to the Des18 photos
#: by least squares sit near it (docs/svbrdf-render.md).
DES18_DISTANCE = 2.2


def _vec3(value, what: str) -> Tensor:
    t = torch.as_tensor(value, dtype=torch.float32) if not isinstance(value, Tensor) else value
    if t.dim() == 0 or t.shape[-1] != 3:
        raise SceneError(f"{what}: expected shape (..., 3), got {tuple(t.shape)}")
    if not t.is_floating_point():
        t = t.float()
    if not bool(torch.isfinite(t).all()):
        raise SceneError(f"{what}: expected finite values, got {t.tolist()}")
    return t


def _scalar(value, what: str) -> Tensor:
    t = torch.as_tensor(value, dtype=torch.float32) if not isinstance(value, Tensor) else value
    if not t.is_floating_point():
        t = t.float()
    if not bool(torch.isfinite(t).all()) or bool((t < 0).any()):
        raise SceneError(f"{what}: expected finite values >= 0, got {t.tolist()}")
    return t


def _flag(value, what: str) -> bool | Tensor:
    if isinstance(value, bool):
        return value
    t = torch.as_tensor(value)
    if t.dtype != torch.bool:
        raise SceneError(f"{what}: expected a bool or a bool tensor, got {value!r}")
    return t


def _to_plain(value):
    """Tensors to nested lists; float32 values by their shortest repr (2.2, not 2.2000000477)."""
    if isinstance(value, Tensor):
        arr = value.detach().cpu().numpy()
        if arr.dtype in (np.float32, np.float16):
            arr = np.array([float(str(x)) for x in arr.ravel()]).reshape(arr.shape)
        return arr.tolist()
    return value


@dataclass(frozen=True, eq=False)
class Camera:
    """Where the image is seen from.

    Args:
        position: ``(..., 3)``; with ``directional=True`` the direction towards the camera.
        fov: full field of view in degrees of an on-axis camera that frames the patch
            (used by vignetting; :meth:`framing` derives the distance from it).
        directional: bool or bool tensor of the configuration shape.
    """

    position: Tensor = field(default_factory=lambda: torch.tensor([0.0, 0.0, DES18_DISTANCE]))
    fov: float = 2 * math.degrees(math.atan(1 / DES18_DISTANCE))
    directional: bool | Tensor = False

    def __post_init__(self):
        object.__setattr__(self, "position", _vec3(self.position, "camera position"))
        object.__setattr__(self, "directional", _flag(self.directional, "camera directional"))
        if not 0 < float(self.fov) < 180:
            raise SceneError(f"camera fov: expected degrees in (0, 180), got {self.fov}")

    @classmethod
    def framing(cls, fov: float) -> Camera:
        """An on-axis camera at the distance where a ``fov``-degree view just spans the patch."""
        if not 0 < fov < 180:
            raise SceneError(f"camera fov: expected degrees in (0, 180), got {fov}")
        d = 1.0 / math.tan(math.radians(fov) / 2)
        return cls(torch.tensor([0.0, 0.0, d]), fov)

    def to_dict(self) -> dict[str, Any]:
        d = {"position": _to_plain(self.position), "fov": float(self.fov)}
        if self.directional is not False:
            d["directional"] = _to_plain(self.directional)
        return d


@dataclass(frozen=True, eq=False)
class PointLight:
    """A point light (or, ``directional=True``, a light at infinity towards ``position``).

    ``intensity`` is a float or a tensor of the configuration shape; ``color`` an RGB triple.
    Radiance reaching a pixel is ``intensity * color * f * cos / distance^2`` (the last two
    when the ``cosine``/``falloff`` effects are declared).
    """

    position: Tensor
    intensity: float | Tensor = 1.0
    color: Tensor = field(default_factory=lambda: torch.ones(3))
    directional: bool | Tensor = False

    def __post_init__(self):
        object.__setattr__(self, "position", _vec3(self.position, "light position"))
        object.__setattr__(self, "intensity", _scalar(self.intensity, "light intensity"))
        object.__setattr__(self, "color", _vec3(self.color, "light color"))
        object.__setattr__(self, "directional", _flag(self.directional, "light directional"))

    def to_dict(self) -> dict[str, Any]:
        d = {
            "type": "point",
            "position": _to_plain(self.position),
            "intensity": _to_plain(self.intensity),
            "color": _to_plain(self.color),
        }
        if self.directional is not False:
            d["directional"] = _to_plain(self.directional)
        return d


@dataclass(frozen=True, eq=False)
class Flash:
    """A point light that travels with the camera: at ``camera.position + offset``."""

    intensity: float | Tensor = 1.0
    offset: Tensor = field(default_factory=lambda: torch.zeros(3))
    color: Tensor = field(default_factory=lambda: torch.ones(3))

    def __post_init__(self):
        object.__setattr__(self, "offset", _vec3(self.offset, "flash offset"))
        object.__setattr__(self, "intensity", _scalar(self.intensity, "flash intensity"))
        object.__setattr__(self, "color", _vec3(self.color, "flash color"))

    def to_dict(self) -> dict[str, Any]:
        return {
            "type": "flash",
            "intensity": _to_plain(self.intensity),
            "offset": _to_plain(self.offset),
            "color": _to_plain(self.color),
        }

    def resolve(self, camera: Camera) -> PointLight:
        """The point light this flash is for ``camera``."""
        return PointLight(camera.position + self.offset, self.intensity, self.color, camera.directional)


Light = PointLight | Flash


@dataclass(frozen=True, eq=False)
class Scene:
    """Camera, lights and declared effects (see :mod:`svbrdf_render.effects`).

    ``effects`` is resolved on construction: unknown names or parameters are errors.
    """

    camera: Camera = field(default_factory=Camera)
    lights: tuple[Light, ...] = field(default_factory=lambda: (Flash(),))
    effects: Any = DES18_EFFECTS

    def __post_init__(self):
        lights = self.lights
        if isinstance(lights, (PointLight, Flash)):
            lights = (lights,)
        lights = tuple(lights)
        for i, light in enumerate(lights):
            if not isinstance(light, (PointLight, Flash)):
                raise SceneError(f"lights[{i}]: expected a PointLight or Flash, got {light!r}")
        if not lights:
            raise SceneError("scene: expected at least one light")
        object.__setattr__(self, "lights", lights)
        object.__setattr__(self, "effects", resolve_effects(self.effects))
        self.config_shape  # noqa: B018 - validates that the shapes broadcast

    # -- presets --------------------------------------------------------------------------

    @classmethod
    def flash(
        cls,
        distance: float = DES18_DISTANCE,
        intensity: float = 1.0,
        effects=DES18_EFFECTS,
    ) -> Scene:
        """A phone-style capture: on-axis camera at ``distance`` with a co-located flash."""
        fov = 2 * math.degrees(math.atan(1 / distance))
        return cls(Camera(torch.tensor([0.0, 0.0, distance]), fov), (Flash(intensity),), effects)

    # -- shapes ---------------------------------------------------------------------------

    @property
    def point_lights(self) -> tuple[PointLight, ...]:
        """Every light as a :class:`PointLight` (flashes resolved against the camera)."""
        return tuple(lt.resolve(self.camera) if isinstance(lt, Flash) else lt for lt in self.lights)

    @property
    def config_shape(self) -> torch.Size:
        """Broadcast of every per-configuration shape: ``()``, ``(K,)`` or ``(B, K)``."""
        shapes = [self.camera.position.shape[:-1]]
        if isinstance(self.camera.directional, Tensor):
            shapes.append(self.camera.directional.shape)
        for light in self.lights:
            shapes.append(light.intensity.shape)
            if isinstance(light, PointLight):
                shapes.append(light.position.shape[:-1])
                if isinstance(light.directional, Tensor):
                    shapes.append(light.directional.shape)
        shape = _broadcast(shapes)
        if shape is None:
            raise SceneError(f"scene: per-configuration shapes {[tuple(s) for s in shapes]} do not broadcast")
        if len(shape) > 2:
            raise SceneError(
                f"scene: expected configuration shape (), (K,) or (B, K), got {tuple(shape)}"
            )
        return shape

    def with_effects(self, effects) -> Scene:
        """The same camera and lights with another effect declaration."""
        return replace(self, effects=effects)

    def to(self, device=None, dtype=None) -> Scene:
        """Move every tensor (positions, intensities, colours)."""

        def mv(t):
            if not isinstance(t, Tensor):
                return t
            if t.is_floating_point():
                return t.to(device=device, dtype=dtype)
            return t.to(device=device)

        cam = replace(self.camera, position=mv(self.camera.position), directional=mv(self.camera.directional))
        lights = []
        for lt in self.lights:
            if isinstance(lt, Flash):
                lights.append(
                    replace(lt, intensity=mv(lt.intensity), offset=mv(lt.offset), color=mv(lt.color))
                )
            else:
                lights.append(
                    replace(
                        lt,
                        position=mv(lt.position),
                        intensity=mv(lt.intensity),
                        color=mv(lt.color),
                        directional=mv(lt.directional),
                    )
                )
        return replace(self, camera=cam, lights=tuple(lights))

    # -- serialisation --------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """Plain Python data (lists, floats, strings) that :meth:`from_dict` reads back."""
        return {
            "camera": self.camera.to_dict(),
            "lights": [lt.to_dict() for lt in self.lights],
            "effects": {name: dict(params) for name, params in self.effects.items()},
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, source: str = "scene") -> Scene:
        """Build a scene from plain data; errors name ``source`` and the offending key."""
        if not isinstance(data, Mapping):
            raise SceneError(f"{source}: expected a mapping with camera/lights/effects, got {data!r}")
        unknown = set(data) - {"camera", "lights", "effects"}
        if unknown:
            raise SceneError(
                f"{source}: unknown key(s) {sorted(unknown)}; expected camera, lights, effects"
            )
        try:
            cam_d = dict(data.get("camera") or {})
            bad = set(cam_d) - {"position", "fov", "directional"}
            if bad:
                raise SceneError(f"camera: unknown key(s) {sorted(bad)}; expected position, fov, directional")
            if "position" not in cam_d and "fov" in cam_d:
                camera = Camera.framing(float(cam_d["fov"]))
            else:
                camera = Camera(**cam_d)
            lights = []
            for i, ld in enumerate(data.get("lights") or [{"type": "flash"}]):
                ld = dict(ld)
                kind = ld.pop("type", "point")
                try:
                    if kind == "flash":
                        lights.append(Flash(**ld))
                    elif kind == "point":
                        lights.append(PointLight(**ld))
                    else:
                        raise SceneError(f"type must be 'flash' or 'point', got {kind!r}")
                except TypeError as e:
                    raise SceneError(f"lights[{i}] ({kind}): {e}") from None
                except SceneError as e:
                    raise SceneError(f"lights[{i}]: {e}") from None
            return cls(camera, tuple(lights), data.get("effects", DES18_EFFECTS))
        except (SceneError, TypeError, ValueError) as e:
            raise SceneError(f"{source}: {e}") from None

    def to_yaml(self) -> str:
        yaml = _yaml()
        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    @classmethod
    def from_yaml(cls, text: str, *, source: str = "scene") -> Scene:
        yaml = _yaml()
        try:
            data = safe_load(text)  # 1e5 is a number, as in YAML 1.2
        except yaml.YAMLError as e:
            raise SceneError(f"{source}: not valid YAML ({e})") from None
        return cls.from_dict(data, source=source)

    def save(self, path) -> None:
        from .plumbing import write_text

        write_text(path, self.to_yaml())

    @classmethod
    def load(cls, path) -> Scene:
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as e:
            raise SceneError(f"{path}: cannot read the scene file ({e.strerror})") from None
        except UnicodeDecodeError as e:
            raise SceneError(
                f"{path}: is not UTF-8 text (byte {e.start}); save the scene file as UTF-8 YAML"
            ) from None
        return cls.from_yaml(text, source=str(path))


def _yaml():
    return require("yaml", "PyYAML", "scene YAML (or use Scene.from_dict)")


def _broadcast(shapes: list) -> torch.Size | None:
    """The broadcast of ``shapes`` (numpy's rule), None when they do not broadcast. Written out:
    torch.broadcast_shapes goes through torch._refs, 3 ms a call on a CPU, a third of a
    second of a 256 px refinement that asks for it every step."""
    ndim = max((len(s) for s in shapes), default=0)
    out = [1] * ndim
    for s in shapes:
        for i, n in enumerate(s, ndim - len(s)):
            if n != 1:
                if out[i] not in (1, n):
                    return None
                out[i] = n
    return torch.Size(out)
