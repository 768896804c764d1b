"""Pictures for people: tiles laid out in a labelled grid, and error heat maps.

The photo tool draws its rerender.png (:func:`rerender_figure`) and relit.png with them;
svbrdf-train's contact sheets and svbrdf-bench's figures use :func:`image_grid` too. Text is
drawn with Pillow's default font (Pillow comes with svbrdf-render's ``io`` extra, or this
package's ``photo`` extra).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from svbrdf_render import linear_to_srgb

from ..errors import DataError

__all__ = ["HEAT_MAX", "error_heatmap", "image_grid", "rerender_figure"]

_BACKGROUND = 30  # 8-bit grey behind the tiles
_TEXT = (235, 235, 235)
#: Linear error shown at the top of the heat map's scale.
HEAT_MAX = 0.25

_HEAT = torch.tensor(  # black -> purple -> orange -> pale yellow (inferno-like)
    [[0.0, 0.0, 0.0], [0.34, 0.06, 0.43], [0.87, 0.32, 0.23], [0.99, 0.99, 0.64]]
)


def error_heatmap(a: Tensor, b: Tensor, top: float = HEAT_MAX) -> Tensor:
    """``|a - b|`` (mean over channels) of two ``(3, H, W)`` images as a ``(3, H, W)`` heat map in
    [0, 1]: black for 0, pale yellow for ``top`` or more."""
    e = ((a - b).abs().mean(0) / top).clamp(0, 1).nan_to_num(1.0) * (len(_HEAT) - 1)
    i = e.floor().long().clamp(max=len(_HEAT) - 2)
    f = (e - i)[None]
    return (_HEAT[i].permute(2, 0, 1) * (1 - f) + _HEAT[i + 1].permute(2, 0, 1) * f).contiguous()


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: one bitmap size only
        return ImageFont.load_default()


def image_grid(
    rows: Sequence[Sequence[Tensor]],
    columns: Sequence[str],
    labels: Sequence[str],
    *,
    gap: int = 4,
    min_tile: int = 0,
) -> Tensor:
    """Tiles ``(3, H, W)`` in [0, 1] laid out in rows, under column titles, each row labelled.

    Tiles narrower than ``min_tile`` pixels are enlarged by a whole factor (nearest neighbour,
    so pixels stay sharp) to be seen at all. Returns ``(3, H', W')`` values in [0, 1] (8-bit
    steps), ready for ``svbrdf_render.write_image``.
    """
    import numpy as np
    from PIL import Image, ImageDraw

    n = len(rows)
    labels = list(labels)
    if len(labels) != n:
        raise DataError(f"image grid: {len(labels)} labels for {n} rows")
    if n == 0:
        raise DataError("image grid: no rows to draw")
    grow = max(1, min_tile // rows[0][0].shape[-1])
    if grow > 1:
        rows = [[t.repeat_interleave(grow, -1).repeat_interleave(grow, -2) for t in row] for row in rows]
    h, w = rows[0][0].shape[-2:]
    font = _font(max(10, min(h, w) // 14))
    draw = ImageDraw.Draw(Image.new("RGB", (1, 1)))

    def text_size(s: str) -> tuple[int, int]:
        left, top, right, bottom = draw.textbbox((0, 0), s, font=font)
        return right - left, bottom - top

    label_w = max(text_size(s)[0] for s in labels) + 2 * gap
    header_h = max(text_size(c)[1] for c in columns) + 3 * gap
    width = label_w + len(columns) * (w + gap) + gap
    height = header_h + n * (h + gap)
    canvas = np.full((height, width, 3), _BACKGROUND, dtype=np.uint8)
    for r, tiles in enumerate(rows):
        top = header_h + r * (h + gap)
        for c, tile in enumerate(tiles):
            left = label_w + c * (w + gap) + gap
            pixels = (tile.detach().float().cpu().clamp(0, 1).permute(1, 2, 0).numpy() * 255).round()
            canvas[top : top + h, left : left + w] = pixels.astype(np.uint8)
    image = Image.fromarray(canvas)
    draw = ImageDraw.Draw(image)
    for c, title in enumerate(columns):
        tw, _ = text_size(title)
        draw.text((label_w + c * (w + gap) + gap + (w - tw) // 2, gap), title, fill=_TEXT, font=font)
    for r, label in enumerate(labels):
        _, th = text_size(label)
        draw.text((gap, header_h + r * (h + gap) + (h - th) // 2), label, fill=_TEXT, font=font)
    return torch.from_numpy(np.asarray(image).copy()).permute(2, 0, 1).float() / 255


def rerender_figure(photo: Tensor, renderings: list[Tensor], rmse: list[float], names: list[str]) -> Tensor:
    """rerender.png: the photo, its re-rendering by each version of the maps, and their error
    heat maps; the row's label gives the RMSE of each (network first)."""
    shown = [linear_to_srgb(photo), *(linear_to_srgb(r) for r in renderings)]
    shown += [error_heatmap(photo, r) for r in renderings]
    scale = f"|error| 0-{HEAT_MAX:g}"
    if len(names) == 1:
        columns = ["photo", names[0], scale]
    else:
        columns = ["photo", *(f"{n} re-rendering" for n in names), *(f"{n} {scale}" for n in names)]
    label = "RMSE " + " -> ".join(f"{r:.4f}" for r in rmse)
    return image_grid([shown], columns, [label])
