"""The HTML material viewer: a self-contained page whose WebGL shader draws what ``render`` draws.

The browser tests open the page in headless Chromium (software WebGL, SwiftShader), take a
screenshot and compare the canvas with ``svbrdf_render.render`` under the same light, displayed
the same way (clamped, sRGB-encoded). They skip when Chromium is missing, except under CI
(``CI`` set), where they fail: the set-up installs it (``apt-get install -y chromium``).

Tolerances, in display values in [0, 1]:

- Against the render of the maps *as the page embeds them* (8-bit PNGs, decoded as the shader
  decodes them), the only expected difference is the screenshot's 8-bit rounding: RMSE
  ``1 / (255 sqrt(12)) = 0.00113`` for values spread over the rounding step. The bound is 1.5x
  that; float32 differences between the GPU and torch move a value by at most one step, so
  fewer than 0.1% of values may be more than 1.5 steps off.
- Against the render of the original float maps, texture and screenshot quantisation add up to
  ``Q`` = RMSE(rounded render of the embedded maps, render of the original maps), computed here
  for the test material (about 0.002); the bound is 1.5 Q. A light 0.05 off in x, or an
  intensity 3% off, costs about 0.006 on this material.
"""

from __future__ import annotations

import base64
import io
import json
import math
import re
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from conftest import CHROMIUM, require_chromium
from svbrdf_render import (
    DES18_DISTANCE,
    SVBRDF,
    MapError,
    Scene,
    SceneError,
    SVBRDFError,
    linear_to_srgb,
    render,
    srgb_to_linear,
    surface_positions,
)
from svbrdf_render.viewer import VIEWER_INTENSITY, viewer_scene, write_viewer

SIZE = 256
LIGHTS = ((0.35, 0.25, 2.2), (-0.5, -0.4, 2.6))
#: RMSE of rounding values spread over a step to 8 bits: what a screenshot alone costs.
SCREENSHOT_RMSE = 1 / (255 * math.sqrt(12))
FACTOR = 1.5


def bumpy_material(n: int = SIZE) -> SVBRDF:
    """Ridged bumps, a coloured checker, roughness rising left to right, specular stripes."""
    x, y, _ = surface_positions(n, n)
    a, b = 0.05, 0.03  # height h = a sin(3 pi x) cos(2 pi y) + b sin(6 pi (x + y))
    ridge = b * 6 * math.pi * torch.cos(6 * math.pi * (x + y))
    hx = a * 3 * math.pi * torch.cos(3 * math.pi * x) * torch.cos(2 * math.pi * y) + ridge
    hy = -a * 2 * math.pi * torch.sin(3 * math.pi * x) * torch.sin(2 * math.pi * y) + ridge
    normal = torch.stack([-hx, -hy, torch.ones_like(x)])
    normal = normal / normal.norm(dim=0, keepdim=True)
    checker = (torch.floor((x + 1) * 4) + torch.floor((y + 1) * 4)) % 2
    diffuse = torch.stack([0.15 + 0.175 * (x + 1), 0.1 + 0.15 * (y + 1), 0.25 + 0.1 * checker])
    diffuse = diffuse * (1 - 0.4 * checker)
    roughness = (0.2 + 0.3 * (x + 1) + 0.05 * torch.sin(5 * math.pi * y)).clamp(0, 1)
    stripes = (torch.sin(4 * math.pi * y) > 0).float()
    specular = (0.04 + 0.225 * stripes * (y + 1)) * torch.tensor([1.0, 0.9, 0.8]).view(3, 1, 1)
    return SVBRDF(normal[None], diffuse[None], roughness[None, None], specular[None])


def displayed(maps: SVBRDF, light) -> np.ndarray:
    """``(H, W, 3)`` float64: the render under the viewer's scene, clamped and sRGB-encoded."""
    with torch.no_grad():
        img = linear_to_srgb(render(maps, viewer_scene(light)).clamp(0, 1))
    return img[0].permute(1, 2, 0).double().numpy()


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


def page_data(path: Path) -> dict:
    text = path.read_text(encoding="utf-8")
    found = re.search(r'<script type="application/json" id="svbrdf-data">(.*?)</script>', text, re.S)
    assert found, "the page has no data block"
    return json.loads(found.group(1))


def embedded_maps(path: Path) -> SVBRDF:
    """The maps the page carries, decoded as its shader decodes them."""
    uris = page_data(path)["maps"]

    def png(name: str) -> torch.Tensor:
        head, _, body = uris[name].partition(",")
        assert head == "data:image/png;base64"
        with Image.open(io.BytesIO(base64.b64decode(body))) as im:
            assert im.mode in ("RGB", "L") and not ({"gamma", "icc_profile", "srgb"} & set(im.info))
            arr = np.asarray(im, dtype=np.float32) / 255
        arr = arr[..., None] if arr.ndim == 2 else arr
        return torch.from_numpy(arr).permute(2, 0, 1)[None]

    n = png("normal") * 2 - 1
    return SVBRDF(
        n / n.norm(dim=1, keepdim=True),
        srgb_to_linear(png("diffuse")),
        png("roughness"),
        srgb_to_linear(png("specular")),
    )


# -- the page, without a browser --------------------------------------------------------------


def test_the_page_is_self_contained_and_embeds_the_maps_to_8_bits(tmp_path):
    m = bumpy_material(64)
    page = write_viewer(tmp_path / "out" / "index.html", m, title="bumps")
    text = page.read_text(encoding="utf-8")
    assert "://" not in text  # nothing fetched: no http(s), no file URL
    assert not re.search(r"""(?:src|href)\s*=\s*["'](?!data:)""", text)
    assert text.count("<script") == 2  # the data block and the inline program
    q = embedded_maps(page)
    assert q.size == (64, 64)
    half = 0.5 / 255 + 1e-6
    # albedos are stored sRGB-encoded: half a step in encoded values
    for name in ("diffuse", "specular"):
        err = (linear_to_srgb(getattr(q, name)) - linear_to_srgb(getattr(m, name))).abs().max()
        assert err <= half, name
    assert (q.roughness - m.roughness).abs().max() <= half
    # normal as (n + 1) / 2, renormalised: within a step of the stored components
    assert ((q.normal - m.normal).abs().max()) <= 2 / 255
    data = page_data(page)
    assert data["intensity"] == pytest.approx(math.pi * DES18_DISTANCE**2)
    assert data["light"] == [0.0, 0.0, DES18_DISTANCE]


def test_large_maps_are_downsampled_and_the_title_escaped(tmp_path):
    m = SVBRDF.constant(1, (40, 20), diffuse=(0.2, 0.5, 0.7), normal=(0.3, -0.2, 1.0))
    page = write_viewer(tmp_path / "v.html", m, title="<script>x</script> & co", max_size=16, light=(1, 2, 3))
    text = page.read_text(encoding="utf-8")
    assert "&lt;script&gt;x&lt;/script&gt; &amp; co" in text and "<script>x" not in text
    data = page_data(page)
    assert (data["width"], data["height"]) == (8, 16) and data["light"] == [1.0, 2.0, 3.0]
    q = embedded_maps(page)
    assert q.size == (16, 8)
    assert torch.allclose(q.diffuse, m.diffuse[:, :, :16, :8], atol=0.01)
    assert torch.allclose(q.normal, m.normal[:, :, :16, :8], atol=0.01)


def test_the_viewer_scene_is_the_des18_flash_at_the_command_line_intensity():
    m = bumpy_material(32)
    flash = Scene.flash(intensity=VIEWER_INTENSITY)
    assert torch.equal(render(m, viewer_scene()), render(m, flash))
    assert not torch.allclose(render(m, viewer_scene((0.5, 0.0, 2.2))), render(m, flash))


@pytest.mark.parametrize(
    ("kwargs", "error", "words"),
    [
        ({"light": (0.0, 0.0, 0.0)}, SceneError, "z must be > 0"),
        ({"light": (1.0, 2.0)}, SceneError, "three finite numbers"),
        ({"light": (0.0, float("nan"), 1.0)}, SceneError, "three finite numbers"),
        ({"max_size": 0}, SVBRDFError, "max_size"),
    ],
)
def test_bad_arguments_are_refused_in_one_line(tmp_path, kwargs, error, words):
    with pytest.raises(error, match=words) as info:
        write_viewer(tmp_path / "v.html", SVBRDF.constant(1, 8), **kwargs)
    assert "\n" not in str(info.value)
    assert not (tmp_path / "v.html").exists()


def test_a_batch_is_refused(tmp_path):
    with pytest.raises(MapError, match="batch size 1"):
        write_viewer(tmp_path / "v.html", SVBRDF.constant(2, 8))


# -- the page in headless Chromium --------------------------------------------------------------


def _need_chromium() -> None:
    require_chromium()


def _chromium(page: Path, fragment: str, *args: str) -> subprocess.CompletedProcess:
    with tempfile.TemporaryDirectory(prefix="svbrdf-chromium-") as profile:
        return subprocess.run(
            [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
             "--enable-unsafe-swiftshader", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             f"--user-data-dir={profile}", "--force-device-scale-factor=1", "--hide-scrollbars",
             "--force-color-profile=srgb", "--virtual-time-budget=10000", *args,
             f"{page.resolve().as_uri()}#{fragment}"],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip


def screenshot(page: Path, light, size: int = SIZE) -> np.ndarray:
    """The canvas (top-left ``size`` x ``size``) of the page under ``#light=...``, in [0, 1]."""
    out = page.with_name(f"shot-{'_'.join(map(str, light))}.png")
    fragment = f"light={light[0]},{light[1]},{light[2]}&size={size}"
    r = _chromium(page, fragment, f"--window-size={size + 64},{size + 200}", f"--screenshot={out}")
    assert r.returncode == 0 and out.is_file(), f"chromium failed: {r.stderr[-1000:]}"
    with Image.open(out) as im:
        return np.asarray(im.convert("RGB"), dtype=np.float64)[:size, :size] / 255


def page_says(page: Path, light) -> str:
    """The page's status and error lines (for failure messages)."""
    r = _chromium(page, f"light={light[0]},{light[1]},{light[2]}&size={SIZE}", "--dump-dom")
    lines = re.findall(r'<div id="(?:status|error)">(.*?)</div>', r.stdout, re.S)
    return " | ".join(lines) or r.stderr[-500:]


def quantisation_rmse(page: Path, light) -> float:
    """Q: what texture and screenshot quantisation alone cost a perfect viewer under ``light``."""
    exact = displayed(embedded_maps(page), light)
    return rmse(np.round(exact * 255) / 255, displayed(bumpy_material(), light))


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    _need_chromium()
    page = write_viewer(tmp_path_factory.mktemp("viewer") / "index.html", bumpy_material())
    return page, {light: screenshot(page, light) for light in LIGHTS}


@pytest.mark.parametrize("light", LIGHTS)
def test_the_browser_draws_what_the_renderer_draws(shots, light):
    page, views = shots
    view = views[light]
    assert view.shape == (SIZE, SIZE, 3)
    # Not blank: the body's background is #1e1e1e; a failed WebGL context leaves it there.
    background = np.all(np.abs(view - 30 / 255) < 1.5 / 255, axis=-1).mean()
    assert background < 0.01 and view.std() > 0.05, page_says(page, light)

    exact = displayed(embedded_maps(page), light)
    got = rmse(view, exact)
    assert got <= FACTOR * SCREENSHOT_RMSE, f"RMSE {got:.5f} vs the embedded maps; {page_says(page, light)}"
    assert np.mean(np.abs(view - exact) > 1.5 / 255) < 1e-3

    original = displayed(bumpy_material(), light)
    q = quantisation_rmse(page, light)
    assert rmse(view, original) <= FACTOR * q
    # ...and the bound is fine enough to refuse a viewer whose light is 0.05 off in x
    nudged = displayed(bumpy_material(), (light[0] + 0.05, light[1], light[2]))
    assert rmse(nudged, original) > FACTOR * q


def test_moving_the_light_changes_the_image_where_the_renderer_says(shots):
    page, views = shots
    a, b = LIGHTS
    moved = views[a] - views[b]
    expected = displayed(bumpy_material(), a) - displayed(bumpy_material(), b)
    # each end may be off by FACTOR * Q, independently
    tolerance = FACTOR * math.hypot(quantisation_rmse(page, a), quantisation_rmse(page, b))
    assert rmse(moved, expected) <= tolerance
    assert rmse(expected, 0 * expected) > 10 * tolerance  # the move is far above the tolerance
    changed = np.abs(expected) > 0.05
    assert changed.mean() > 0.05
    agree = (np.sign(moved) == np.sign(expected)) & (np.abs(moved) > 0.025)
    assert agree[changed].mean() > 0.99


def test_the_shots_of_a_capture_are_listed_for_the_keys(tmp_path):
    """A capture of several photos hands the viewer where each shot's flash was: the page's data
    lists them (at most 9, keys 1-9), and a shot below the patch is refused like a light."""
    shots = [("a.jpg", (0.1, 0.2, 2.0)), ("b.jpg", [-0.3, 0.0, 3.0])]
    page = write_viewer(tmp_path / "v.html", SVBRDF.constant(1, 8), shots=shots)
    assert page_data(page)["shots"] == [
        {"name": "a.jpg", "light": [0.1, 0.2, 2.0]}, {"name": "b.jpg", "light": [-0.3, 0.0, 3.0]},
    ]  # fmt: skip
    many = write_viewer(tmp_path / "m.html", SVBRDF.constant(1, 8), shots=[(str(i), (0, 0, 1)) for i in range(12)])
    assert len(page_data(many)["shots"]) == 9
    assert page_data(write_viewer(tmp_path / "n.html", SVBRDF.constant(1, 8)))["shots"] == []
    with pytest.raises(SceneError, match="z must be > 0"):
        write_viewer(tmp_path / "bad.html", SVBRDF.constant(1, 8), shots=[("low", (0, 0, -1))])


def test_the_browser_says_which_key_puts_the_light_at_which_shot(tmp_path):
    _need_chromium()
    page = write_viewer(tmp_path / "v.html", SVBRDF.constant(1, 8), shots=[("a.jpg", (0.1, 0.2, 2.0))])
    r = _chromium(page, "size=64", "--dump-dom")
    assert re.search(r'<div id="shots">Keys 1-1: the light where each shot\'s flash was \(1 a\.jpg\)\.</div>', r.stdout)
