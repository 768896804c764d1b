"""The printed capture frame in a photo: its markers found, the window rectified into the
material's square, and the camera and the flash placed over it.

:func:`find_frame` finds the markers of a :class:`~svbrdf_models.capture.frame.FrameLayout` in a
photo and fits the homography from the frame's plane (cm; origin at the window's centre, x
right, y up) to the photo's pixels; :func:`rectify` warps the window into the square ``[-1,
1]^2`` (the top row at y = +1, whatever the phone's roll) and samples the reference strip;
:func:`shot_pose` places the camera and the flash in the patch's frame (unit: half the window's
side, +z towards the camera) from the markers and the lens's focal length. A multi-shot capture
builds on these: each shot's view and light from its markers, its exposure from the strip.

Refused, one line naming the photo (:class:`~svbrdf_models.errors.DataError`): fewer than
:data:`~svbrdf_models.capture.frame.MIN_MARKERS` markers of the frame seen, or agreeing on one
flat sheet ("frame not found in NAME"); the markers of a frame printed at another size ("markers
of another frame"). OpenCV (the ``photo`` extra) is imported on the first call.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from ..errors import DataError
from .frame import DICTIONARY, FLASH_OFFSET_CM, MIN_MARKERS, FrameLayout, require_opencv

__all__ = ["FrameDetection", "Rectified", "ShotPose", "find_frame", "rectify", "shot_pose"]

#: What a photo of the frame needs, said when it is not found.
_HOW = "photograph the whole frame, flat, sharp, lit by the flash, with no hand or material over its markers"


@dataclass(frozen=True)
class FrameDetection:
    """A frame found in a photo. Pixel coordinates follow OpenCV: x right, y down, the centre of
    the top-left pixel at (0, 0).

    ``ids``/``corners``: the markers of the frame that the homography explains (N, and (N, 4, 2)
    pixels, sub-pixel); ``homography``: frame-plane cm -> pixels (3 x 3); ``window`` and
    ``strip``: their corners in pixels (top-left, top-right, bottom-right, bottom-left of the
    sheet); ``rms_px``: the markers' corners' distance from the homography's prediction;
    ``ignored``: ids seen but not used (another frame's, or disagreeing with the rest)."""

    name: str
    layout: FrameLayout
    image_size: tuple[int, int]
    ids: np.ndarray
    corners: np.ndarray
    homography: np.ndarray
    window: np.ndarray
    strip: np.ndarray
    rms_px: float
    ignored: tuple[int, ...] = ()

    def to_pixels(self, xy_cm) -> np.ndarray:
        """(N, 2) points in the frame's plane (cm) -> (N, 2) pixels."""
        return _apply(self.homography, np.asarray(xy_cm, dtype=np.float64))

    def object_points(self) -> np.ndarray:
        """(4N, 3): the found markers' corners in the frame's plane (cm, z = 0)."""
        layout = self.layout
        index = [layout.marker_ids.index(int(i)) for i in self.ids]
        xy = layout.marker_corners[index].reshape(-1, 2)
        return np.concatenate([xy, np.zeros((len(xy), 1))], axis=1)

    def image_points(self) -> np.ndarray:
        """(4N, 2): the found markers' corners in pixels, in the order of :meth:`object_points`."""
        return self.corners.reshape(-1, 2)


def _apply(h: np.ndarray, xy: np.ndarray) -> np.ndarray:
    p = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ h.T
    return p[:, :2] / p[:, 2:3]


def _as_hwc(image) -> np.ndarray:
    """A photo as an (H, W, C) numpy array: a torch tensor (3, H, W) (the project's photos) or
    (H, W, 3); a numpy (H, W, 3), (H, W, 4) (alpha dropped) or (H, W)."""
    if isinstance(image, torch.Tensor):
        array = image.detach().cpu()
        if array.dim() == 3 and array.shape[0] in (1, 3, 4) and array.shape[-1] not in (3, 4):
            array = array.permute(1, 2, 0)
        array = array.numpy()
    else:
        array = np.asarray(image)
    if array.ndim == 2:
        array = array[..., None]
    if array.ndim != 3 or array.shape[-1] not in (1, 3, 4):
        raise DataError(f"expected an image (H, W, 3) or (3, H, W), got shape {tuple(array.shape)}")
    return array[..., :3] if array.shape[-1] == 4 else array


def _grey8(array: np.ndarray, linear: bool) -> np.ndarray:
    """An 8-bit grey image for the detector: sRGB-encoded (a linear photo is encoded first, so
    that its dark half keeps its levels)."""
    if array.dtype == np.uint8 and not linear:
        grey = array.astype(np.float32).mean(axis=-1) / 255
    else:
        scale = 255.0 if array.dtype == np.uint8 else 65535.0 if array.dtype == np.uint16 else 1.0
        values = np.clip(np.nan_to_num(array.astype(np.float32) / scale), 0, 1)
        if linear:
            values = np.where(values <= 0.0031308, 12.92 * values, 1.055 * np.power(values, 1 / 2.4) - 0.055)
        grey = values.mean(axis=-1)
    return np.clip(np.round(grey * 255), 0, 255).astype(np.uint8)


def find_frame(
    image, layout: FrameLayout | None = None, *, name: str = "the photo", linear: bool = False
) -> FrameDetection:
    """Find the printed frame in a photo: its markers, the homography from the frame's plane to
    the photo, the window's and the strip's corners.

    ``image``: (H, W, 3) numpy (uint8, uint16 or float in [0, 1]) or a torch tensor (3, H, W),
    sRGB-encoded unless ``linear``. ``layout``: the frame printed; None takes the frame whose
    markers the photo shows most (every window size has its own ids). ``name`` (the file) is
    named in errors.

    Raises :class:`DataError` when fewer than :data:`MIN_MARKERS` markers of the frame are
    seen or agree with each other ("frame not found in NAME"), and when the markers seen are
    another frame's ("markers of another frame")."""
    grey = _grey8(_as_hwc(image), linear)
    found = _detect(grey)
    by_window: dict[float, list[int]] = {}
    for marker_id in sorted(found):
        window = FrameLayout.window_of_id(marker_id)
        if window is not None:
            by_window.setdefault(window, []).append(marker_id)
    layout = _which_frame(by_window, layout, name)
    mine = by_window[layout.window_cm]
    others = tuple(i for w, ids in sorted(by_window.items()) if w != layout.window_cm for i in ids)
    homography, keep = _fit(layout, mine, found, grey.shape, name)
    ids = np.array(mine)[keep]
    quads = np.stack([found[i] for i in ids.tolist()])
    src = layout.marker_corners[[layout.marker_ids.index(i) for i in ids.tolist()]].reshape(-1, 2)
    rms = float(np.sqrt(np.mean(np.sum((_apply(homography, src) - quads.reshape(-1, 2)) ** 2, axis=1))))
    return FrameDetection(
        name=name,
        layout=layout,
        image_size=grey.shape,
        ids=ids,
        corners=quads,
        homography=homography,
        window=_apply(homography, layout.window_corners),
        strip=_apply(homography, layout.strip_corners),
        rms_px=rms,
        ignored=tuple(int(i) for i in np.array(mine)[~keep]) + others,
    )


def _detect(grey: np.ndarray) -> dict[int, np.ndarray]:
    """Marker id -> its (4, 2) corners in pixels, sub-pixel; an id seen twice is dropped (which
    of the two is the frame's cannot be told)."""
    aruco = require_opencv().aruco
    params = aruco.DetectorParameters()
    params.cornerRefinementMethod = aruco.CORNER_REFINE_SUBPIX
    detector = aruco.ArucoDetector(aruco.getPredefinedDictionary(getattr(aruco, DICTIONARY)), params)
    corners, ids, _ = detector.detectMarkers(grey)
    found: dict[int, np.ndarray | None] = {}
    for marker_id, quad in zip([] if ids is None else ids.ravel().tolist(), corners, strict=True):
        found[marker_id] = None if marker_id in found else np.asarray(quad, dtype=np.float64).reshape(4, 2)
    return {k: v for k, v in found.items() if v is not None}


def _which_frame(by_window: dict[float, list[int]], layout: FrameLayout | None, name: str) -> FrameLayout:
    """The frame to use: ``layout``, or the one with the most markers seen; refused when too
    few of its markers are seen, naming another frame whose markers are."""
    if layout is None:
        if not by_window:
            raise DataError(f"frame not found in {name}: no marker of a printed frame seen; {_HOW}")
        layout = FrameLayout(window_cm=max(by_window, key=lambda w: (len(by_window[w]), w)))
    mine = by_window.get(layout.window_cm, [])
    if len(mine) >= MIN_MARKERS:
        return layout
    others = {w: ids for w, ids in by_window.items() if w != layout.window_cm}
    best = max(others, key=lambda w: len(others[w]), default=None)
    if best is not None and len(others[best]) >= MIN_MARKERS:
        raise DataError(
            f"markers of another frame in {name}: {len(others[best])} markers of the {best:g} cm frame, "
            f"{len(mine)} of {layout.describe()} expected; photograph the frame you printed, or state its "
            f"window size ({best:g} cm)"
        )
    raise DataError(
        f"frame not found in {name}: {len(mine)} markers of {len(layout.marker_ids)} seen (at least "
        f"{MIN_MARKERS} needed); {_HOW}"
    )


def _fit(layout: FrameLayout, mine: list[int], found: dict, shape: tuple[int, int], name: str):
    """The homography (frame cm -> pixels) of the markers that agree (RANSAC, then least squares
    on them), and which of ``mine`` those are."""
    cv2 = require_opencv()
    src = layout.marker_corners[[layout.marker_ids.index(i) for i in mine]].reshape(-1, 2)
    dst = np.stack([found[i] for i in mine]).reshape(-1, 2)
    threshold = max(2.0, 0.002 * max(shape))  # pixels
    homography, mask = cv2.findHomography(src, dst, cv2.RANSAC, threshold)
    keep = np.zeros(len(mine), dtype=bool) if homography is None else mask.reshape(-1, 4).all(axis=1)
    if keep.sum() < MIN_MARKERS:
        raise DataError(
            f"frame not found in {name}: its {len(mine)} markers do not agree on one flat sheet (at most "
            f"{int(keep.sum())} do); lay the frame flat; {_HOW}"
        )
    corners = np.repeat(keep, 4)
    homography, _ = cv2.findHomography(src[corners], dst[corners], 0)
    if homography is None or not np.isfinite(homography).all():
        raise DataError(f"frame not found in {name}: the markers' corners give no perspective; {_HOW}")
    return homography, keep


# --- the window rectified -----------------------------------------------------------------------
class Rectified(NamedTuple):
    """The window as the material's square, and the reference strip sampled at the same density.

    ``window``: (3, size, size), the top row at y = +1 of the patch (the title's side of the
    sheet), the left column at x = -1. ``strip``: (3, h, w), the strip inset from its outline;
    ``strip_xy``: (2, h, w) where each strip sample lies, in the patch's units (half-widths of
    the window, z = 0). Values as the photo gives them (uint8 scaled to [0, 1]): give a linear
    photo for maps and exposure."""

    window: Tensor
    strip: Tensor
    strip_xy: Tensor


def _float_image(array: np.ndarray) -> np.ndarray:
    if array.dtype == np.uint8:
        return array.astype(np.float32) / 255
    if array.dtype == np.uint16:
        return array.astype(np.float32) / 65535
    return np.ascontiguousarray(array, dtype=np.float32)


def rectify(image, detection: FrameDetection, size: int) -> Rectified:
    """Warp the photo's window into the material's square, ``size`` pixels a side (the map size),
    and sample the reference strip at the same density (inset by a quarter of its height from
    the outline and the cut). A photo much larger than the square is first reduced by area
    averaging, so that the warp does not alias."""
    cv2 = require_opencv()
    if int(size) < 1:
        raise DataError(f"the square's size must be at least 1 pixel, got {size}")
    size = int(size)
    array = _float_image(_as_hwc(image))
    if array.shape[:2] != detection.image_size:
        raise DataError(
            f"{detection.name}: the image is {array.shape[1]}x{array.shape[0]} but the frame was found in a "
            f"{detection.image_size[1]}x{detection.image_size[0]} one"
        )
    layout = detection.layout
    homography = detection.homography
    sides = np.linalg.norm(detection.window - np.roll(detection.window, 1, axis=0), axis=1)
    reduce = float(sides.mean()) / size
    if reduce > 1.5:  # area-average first; pixel centres: x' = (x + 0.5) / f - 0.5
        h, w = array.shape[:2]
        nw, nh = max(1, round(w / reduce)), max(1, round(h / reduce))
        array = cv2.resize(array, (nw, nh), interpolation=cv2.INTER_AREA)
        fx, fy = nw / w, nh / h
        shrink = np.array([[fx, 0, 0.5 * fx - 0.5], [0, fy, 0.5 * fy - 0.5], [0, 0, 1]])
        homography = shrink @ homography
    if array.ndim == 2:
        array = array[..., None]
    per_cm = size / layout.window_cm

    def sample(x0: float, y1: float, cols: int, rows: int) -> np.ndarray:
        # output pixel (j, i) -> cm (x0 + (j + 0.5) / per_cm, y1 - (i + 0.5) / per_cm)
        to_cm = np.array([[1 / per_cm, 0, x0 + 0.5 / per_cm], [0, -1 / per_cm, y1 - 0.5 / per_cm], [0, 0, 1]])
        out = cv2.warpPerspective(
            array,
            homography @ to_cm,
            (cols, rows),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_REPLICATE,
        )
        return out.reshape(rows, cols, -1)

    half = layout.half_width_cm
    window = sample(-half, half, size, size)
    x0, y0, x1, y1 = layout.strip_rect
    inset = layout.strip_cm / 4
    cols = max(1, round((x1 - x0 - 2 * inset) * per_cm))
    rows = max(1, round((y1 - y0 - 2 * inset) * per_cm))
    strip = sample(x0 + inset, y1 - inset, cols, rows)
    xs = (x0 + inset + (np.arange(cols) + 0.5) / per_cm) / half
    ys = (y1 - inset - (np.arange(rows) + 0.5) / per_cm) / half
    grid = np.stack(np.meshgrid(xs, ys, indexing="xy"))

    def chw(a: np.ndarray) -> Tensor:
        t = torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1))).float()
        return t.expand(3, -1, -1).contiguous() if t.shape[0] == 1 else t

    return Rectified(chw(window), chw(strip), torch.from_numpy(grid).float())


# --- the camera and the flash -------------------------------------------------------------------
class ShotPose(NamedTuple):
    """Where a shot was taken from, in the patch's frame: the window is [-1, 1]^2 at z = 0, x
    right, y up (the title's side), +z towards the camera; unit: half the window's side.

    ``camera``, ``flash``: (3,); ``rotation``: (3, 3), the camera's axes (x right, y down, z
    along the view, OpenCV's) as columns in the patch's frame; ``rms_px``: the markers' corners'
    reprojection error."""

    camera: Tensor
    flash: Tensor
    rotation: Tensor
    rms_px: float


def shot_pose(
    detection: FrameDetection,
    focal_px: float,
    principal: tuple[float, float] | None = None,
    *,
    flash_offset_cm: tuple[float, float] = FLASH_OFFSET_CM,
) -> ShotPose:
    """The camera's and the flash's positions of a shot, from the markers' corners and the
    camera's intrinsics (``cv2.solvePnP``, planar IPPE refined by Levenberg-Marquardt; lens
    distortion assumed corrected, as phones do).

    ``focal_px``: the focal length in pixels of the photo as given (e.g. from its EXIF:
    :func:`svbrdf_models.capture.geometry.focal_pixels`); ``principal``: the optical centre in pixels (default
    the image's centre, ((W - 1) / 2, (H - 1) / 2)); ``flash_offset_cm``: the flash's position
    beside the lens in cm along the photo's x (right) and y (up) as the photo is shown."""
    cv2 = require_opencv()
    if not (math.isfinite(focal_px) and focal_px > 0):
        raise DataError(
            f"{detection.name}: the focal length must be a positive number of pixels, got {focal_px}"
        )
    h, w = detection.image_size
    cx, cy = principal if principal is not None else ((w - 1) / 2, (h - 1) / 2)
    k = np.array([[focal_px, 0, cx], [0, focal_px, cy], [0, 0, 1]], dtype=np.float64)
    obj, img = detection.object_points(), detection.image_points()
    ok, rvec, tvec = cv2.solvePnP(obj, img, k, None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise DataError(f"{detection.name}: no camera position explains the frame's markers")
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, k, None, rvec, tvec)
    rot, _ = cv2.Rodrigues(rvec)
    t = tvec.reshape(3)
    camera_cm = -rot.T @ t
    if camera_cm[2] <= 0:
        raise DataError(f"{detection.name}: the camera comes out behind the frame; is the photo mirrored?")
    dx, dy = flash_offset_cm
    flash_cm = rot.T @ (np.array([dx, -dy, 0.0]) - t)
    projected, _ = cv2.projectPoints(obj, rvec, tvec, k, None)
    rms = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - img) ** 2, axis=1))))
    half = detection.layout.half_width_cm
    return ShotPose(
        camera=torch.from_numpy(camera_cm / half).float(),
        flash=torch.from_numpy(flash_cm / half).float(),
        rotation=torch.from_numpy(rot.T.copy()).float(),
        rms_px=rms,
    )
