"""A material viewer: one self-contained HTML page that relights the maps in the browser.

:func:`write_viewer` writes ``index.html``: the four maps embedded as PNG ``data:`` URIs, and
a WebGL 2 fragment shader that evaluates, per pixel, what :func:`svbrdf_render.render`
computes under :func:`viewer_scene` (the Des18 BRDF: GGX ``D`` with the affine alpha floor,
Schlick-GGX masking with ``k = alpha/2``, the spherical-Gaussian Schlick Fresnel, the
``d (1 - s) / pi`` diffuse, cosine and inverse-square falloff), then shows it as the project
displays renderings: clamped to [0, 1], sRGB-encoded. The page needs no network and no
server: it opens from the file system (a ``file://`` page may not upload ``file://`` images
to WebGL, which is why the maps travel inside the page).

The page
    The canvas is the patch ``[-1, 1]^2`` seen frontally, each pixel a point of the patch at
    ``z = 0`` seen from the camera at ``(0, 0, 2.2)`` (the Des18 capture distance), with the
    view vector of that pixel, as in the renderer. The light is a white point light of
    intensity ``pi * 2.2^2`` (the command line's default: a white Lambertian patch under a
    light at 2.2 shows 1.0). Its x, y follow the mouse (the point under the pointer), the
    wheel changes its height, ``R`` puts it back at the camera, ``T`` or the checkbox tiles the
    maps 2x2 (to check that they tile). A text line shows the light position. With ``shots``
    (a capture of several photos), the keys ``1``-``9`` put the light where each shot's flash
    was, and a line lists them.

Fixed views, for tests and reproducible screenshots::

    index.html#light=0.3,0.2,2.2&size=512&tile=0

``light`` is the light position (``z > 0``), ``size`` the longer side of the image in CSS
pixels (16 to 8192; default 512), ``tile=1`` the 2x2 tiling. The mouse still moves the light.

Encodings (8 bits a channel, what every browser uploads exactly):
    - diffuse, specular: sRGB-encoded, uploaded as sRGB textures, so the GPU decodes them to
      linear *before* filtering. An 8-bit linear albedo has steps of 1/255, which after the
      display's sRGB curve are up to ~13 display levels apart in the darks; sRGB-encoded, the
      steps are about one display level everywhere.
    - normal: ``(n + 1) / 2``, the project's stored normal encoding; renormalised per pixel by
      the shader as by the renderer.
    - roughness: linear grey, as Des18 files store it.
    The PNGs carry no gamma or colour-profile chunk and the page uploads them with
    ``UNPACK_COLORSPACE_CONVERSION_WEBGL = NONE`` and no premultiplied alpha, so the browser
    hands the stored bytes to the shader without colour management.

Needs the ``io`` extra (Pillow) to encode the PNGs.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from importlib import resources
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .effects import DES18_EFFECTS, EFFECTS
from .errors import MapError, SceneError, SVBRDFError
from .formats.mapfiles import _encode_maps, _pil, linear_to_srgb
from .maps import MAP_NAMES, SVBRDF
from .plumbing import write_text
from .scene import DES18_DISTANCE, Camera, PointLight, Scene

__all__ = ["write_viewer", "viewer_scene", "VIEWER_INTENSITY", "VIEWER_SIZE", "SRGB_MAPS"]

#: Intensity of the viewer's light: ``pi * 2.2^2``, the command line's default, so a white
#: Lambertian patch under a light at the Des18 distance shows 1.0.
VIEWER_INTENSITY = math.pi * DES18_DISTANCE**2
#: Default longer side of the page's image, in CSS pixels (``#size=`` overrides it).
VIEWER_SIZE = 512
#: Maps the page stores sRGB-encoded (the others are stored as ``(n+1)/2`` or linear).
SRGB_MAPS = ("diffuse", "specular")
_TEMPLATE = "viewer.html"


def viewer_scene(light=None, intensity: float | None = None) -> Scene:
    """The scene the page shows: the Des18 camera at ``(0, 0, 2.2)``, one white point light.

    Args:
        light: ``(x, y, z)`` light position, ``z > 0``; ``None`` puts it at the camera (a flash).
        intensity: the light's intensity (default :data:`VIEWER_INTENSITY`).

    Effects are the default Des18 set.
    ``linear_to_srgb(render(maps, viewer_scene(light)).clamp(0, 1))`` is what the page draws
    for ``#light=x,y,z`` at the maps' own size.
    """
    pos = _light_position(light)
    camera = Camera(torch.tensor([0.0, 0.0, DES18_DISTANCE]))
    power = VIEWER_INTENSITY if intensity is None else _intensity(intensity)
    return Scene(camera, (PointLight(torch.tensor(pos), power),), DES18_EFFECTS)


def _intensity(value) -> float:
    ok = (
        isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0
    )
    if not ok:
        raise SVBRDFError(f"write_viewer: intensity must be a finite number > 0, got {value!r}")
    return float(value)


def _light_position(light) -> list[float]:
    if light is None:
        return [0.0, 0.0, DES18_DISTANCE]
    try:
        pos = [float(v) for v in (light.tolist() if isinstance(light, Tensor) else light)]
    except (TypeError, ValueError):
        pos = []
    if len(pos) != 3 or not all(math.isfinite(v) for v in pos):
        raise SceneError(f"viewer light: expected three finite numbers (x, y, z), got {light!r}")
    if pos[2] <= 0:
        raise SceneError(
            f"viewer light {pos}: z must be > 0 (the patch lies at z = 0; below it nothing is lit)"
        )
    return pos


def _png_data_uri(values: Tensor) -> str:
    """``(C, H, W)`` values in [0, 1] as an 8-bit RGB (C = 3) or grey (C = 1) PNG data URI."""
    Image = _pil()
    arr = values.nan_to_num(0.0).clamp(0, 1).permute(1, 2, 0).numpy()
    q = np.round(arr * 255).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(q[..., 0] if q.shape[2] == 1 else q).save(buf, format="PNG")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _embedded_maps(svbrdf: SVBRDF) -> dict[str, str]:
    stored = _encode_maps(svbrdf)  # normal as (n + 1) / 2, the others linear
    for name in SRGB_MAPS:
        stored[name] = linear_to_srgb(stored[name])
    return {name: _png_data_uri(stored[name]) for name in MAP_NAMES}


def _page_data(maps: SVBRDF, light, intensity: float, shots: list | None = None) -> dict:
    """What the page's script reads: the size, camera, light, BRDF constants, the shots' flash
    positions and the maps."""
    h, w = maps.size
    return {
        "shots": shots or [],
        "width": w,
        "height": h,
        "size": VIEWER_SIZE,
        "camera": [0.0, 0.0, DES18_DISTANCE],
        "light": light,
        "intensity": intensity,
        "alpha_min": EFFECTS["specular"].defaults["alpha_min"],
        "min_distance": EFFECTS["falloff"].defaults["min_distance"],
        "maps": _embedded_maps(maps),
    }


def write_viewer(
    path,
    svbrdf: SVBRDF,
    *,
    title: str = "svbrdf material",
    light=None,
    max_size: int = 1024,
    intensity: float | None = None,
    shots=None,
) -> Path:
    """Write a self-contained HTML viewer of one material; returns ``path``.

    Args:
        path: the HTML file to write (e.g. ``out/index.html``); written atomically.
        svbrdf: the maps of a single material (batch size 1), linear values.
        title: shown as the page's title and heading (HTML-escaped).
        light: the light's starting position ``(x, y, z)``, ``z > 0``; ``None``: at the camera.
        max_size: maps larger than this (longer side, pixels) are resized to it first
            (bilinear with antialiasing, normals renormalised); the page grows by about
            4 bytes per texel of the four maps.
        intensity: the light's intensity (default :data:`VIEWER_INTENSITY`, which shows a
            white Lambertian patch at 1.0; the photo tool gives the flash it found, so the
            page shows the material as the photo's flash lit it).
        shots: ``[(name, (x, y, z)), ...]``: where the flash of each photo of a capture was
            (at most 9; keys ``1``-``9`` put the light there), each ``z > 0``.

    Open the page with ``#light=x,y,z&size=N&tile=0|1`` for a fixed view (see the module's
    docstring). Raises :class:`MapError` for anything but one material,
    :class:`SceneError` for a light below the patch, :class:`SVBRDFError` for a bad ``max_size``.

    Example:
        >>> write_viewer("out/index.html", SVBRDF.constant(1, 64), title="grey plastic")
        PosixPath('out/index.html')
    """
    if not isinstance(svbrdf, SVBRDF):
        raise MapError(f"write_viewer: expected an SVBRDF, got {type(svbrdf).__name__}")
    if svbrdf.batch_size != 1:
        raise MapError(
            f"write_viewer: expected the maps of one material (batch size 1), got a batch of "
            f"{svbrdf.batch_size}; pass svbrdf[i:i + 1]"
        )
    if isinstance(max_size, bool) or not isinstance(max_size, int) or max_size < 1:
        raise SVBRDFError(f"write_viewer: max_size must be an integer >= 1, got {max_size!r}")
    start = _light_position(light)
    shown = [{"name": str(name), "light": _light_position(pos)} for name, pos in list(shots or [])[:9]]
    maps = svbrdf.detach().to("cpu", torch.float32)
    h, w = maps.size
    if max(h, w) > max_size:
        scale = max_size / max(h, w)
        maps = maps.resize(max(1, round(h * scale)), max(1, round(w * scale)))
    data = _page_data(maps, start, VIEWER_INTENSITY if intensity is None else _intensity(intensity), shown)
    # "</" would end the <script> block early; "<\/" is the same string to JSON.
    blob = json.dumps(data).replace("</", "<\\/")
    template = resources.files("svbrdf_render").joinpath(_TEMPLATE).read_text(encoding="utf-8")
    # The data first: a title is inserted after it, so no title can inject into the data.
    page = template.replace("__SVBRDF_DATA__", blob).replace("__SVBRDF_TITLE__", html.escape(str(title)))
    return write_text(path, page)
