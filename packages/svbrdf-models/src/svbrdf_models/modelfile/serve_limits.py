"""What one request may ask of ``svbrdf-models serve`` (:mod:`svbrdf_models.modelfile.serve`),
checked before any work: :class:`ServeLimits` (one option each), the request's photos and
parameters (:func:`parse_request`), and what answering it would cost (:func:`estimate_request`,
:func:`check_cost`): the answer's size, the memory and the time, each estimated from the photos'
shape and the refinement budget alone, so that a request the server cannot answer within its
limits is refused in one line instead of taking the machine's memory or the worker's hours.

The estimates are figures measured on this project's 2-core machine (each constant says how);
they are there to refuse, not to promise. The refinement itself still stops at the request's
deadline (:class:`svbrdf_models.modelfile.serve._Worker`), and a worker held past 1.5 times the
timeout is answered 504.
"""

from __future__ import annotations

import json
import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import DataError

__all__ = [
    "ServeLimits",
    "PHOTOS",
    "MAP_VALUES_PER_PIXEL",
    "Refused",
    "RequestCost",
    "check_photo_array",
    "refine_budget",
    "check_depth",
    "parse_request",
    "estimate_request",
    "check_cost",
]

#: What a photo array must be, as the refusals say it.
PHOTOS = "photos (linear RGB in [0, 1], shape (N, H, W, 3) or (H, W, 3))"
#: Values per pixel of an answer's maps: normal 3, diffuse 3, roughness 1, specular 3.
MAP_VALUES_PER_PIXEL = 10


@dataclass(frozen=True)
class ServeLimits:
    """What one request may ask of the server; each has a ``svbrdf-models serve`` option, and a
    value out of range is a :class:`DataError` naming it."""

    #: Request body, MiB (``--max-body-mb``): a 2048x2048 photo is 60-120 MB of JSON.
    body_mb: float = 128.0
    #: Pixels of all the photos of one request (``--max-pixels``): 2048x2048.
    pixels: int = 4 * 1024 * 1024
    #: Refinement steps one request may ask (``--max-refine``).
    refine: int = 500
    #: Seconds a request may take, upload and queue included (``--timeout``).
    timeout: float = 60.0
    #: Nesting of the JSON body: a batch of photos is 4 deep inside its object; 8 leaves room.
    depth: int = 8
    #: Photos of one request (``--max-photos``): each is its own network pass and maps.
    photos: int = 16
    #: The answer's JSON, MiB (``--max-answer-mb``): a 1024 px refined material is 110 MB.
    answer_mb: float = 128.0
    #: Seconds an upload may go without a byte before it is answered 408 (``--read-timeout``).
    read_timeout: float = 10.0
    #: Connections at once; beyond them a request is answered 503 (``--max-connections``).
    connections: int = 64

    def __post_init__(self):
        positive = {"--max-body-mb": self.body_mb, "--max-answer-mb": self.answer_mb,
                    "--timeout": self.timeout, "--read-timeout": self.read_timeout}  # fmt: skip
        counts = {"--max-pixels": self.pixels, "--max-photos": self.photos,
                  "--max-connections": self.connections, "JSON depth": self.depth}  # fmt: skip
        for option, value in positive.items():
            number = isinstance(value, (int, float)) and not isinstance(value, bool)
            if not number or not 0 < value < np.inf:  # NaN fails both
                raise DataError(f"{option} must be a finite number above 0, got {value!r}")
        for option, value in {**counts, "--max-refine": self.refine}.items():
            low = 0 if option == "--max-refine" else 1
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise DataError(f"{option} must be a whole number >= {low}, got {value!r}")


class Refused(Exception):
    """A request answered with ``status`` and one line, ``reason``."""

    def __init__(self, status: int, reason: str):
        super().__init__(reason)
        self.status, self.reason = status, reason

    def __reduce__(self):  # from the child process that parses a large body
        return Refused, (self.status, self.reason)


def check_photo_array(photos: Any, max_pixels: int, limit_name: str) -> np.ndarray:
    """``photos`` (nested lists or an array) as a float32 ``(N, H, W, 3)`` array of linear RGB in
    [0, 1] (an ``(H, W, 3)`` photo gets a batch axis), with at most ``max_pixels`` pixels in all
    (``limit_name``: the setting that changes it); a :class:`DataError` that says what is wrong."""
    try:
        array = np.asarray(photos)
    except Exception as e:  # ragged nested lists, objects numpy cannot hold in one array
        raise DataError(f"{PHOTOS}: not an array ({type(e).__name__})") from None
    if array.dtype.kind not in "fiu":
        raise DataError(f"{PHOTOS}: expected numbers, got {array.dtype} values ({type(photos).__name__})")
    if array.ndim == 3:
        array = array[None]
    if array.ndim != 4 or array.shape[-1] != 3 or 0 in array.shape:
        hint = "; channels go last" if array.ndim == 4 and array.shape[1] == 3 else ""
        raise DataError(f"{PHOTOS}: got shape {tuple(np.shape(photos))}{hint}")
    pixels = int(np.prod(array.shape[:3]))
    if pixels > max_pixels:
        raise DataError(f"{PHOTOS}: {pixels:,} pixels in one request, over this server's limit of "
                        f"{max_pixels:,} ({limit_name}); send fewer or smaller photos")  # fmt: skip
    array = array.astype(np.float32, copy=False)
    bad = int(np.count_nonzero(~np.isfinite(array)))
    if bad:
        raise DataError(f"{PHOTOS}: {bad} values are NaN or infinite; give finite pixel values")
    low, high = float(array.min()), float(array.max())
    if low < 0:
        raise DataError(f"{PHOTOS}: values down to {low:.4g}; linear radiance is never below 0")
    if high > 1:
        raise DataError(f"{PHOTOS}: values span [{low:.4g}, {high:.4g}]; scale 8-bit values by 1/255, and "
                        "decode sRGB to linear first")  # fmt: skip
    return array


def refine_budget(refine: Any, limit: int, limit_name: str) -> int:
    """A request's refinement steps (an integer >= 0; numpy integers too) at most ``limit``
    (``limit_name``: the setting that changes it); a :class:`DataError` otherwise."""
    from ..capture.refining import check_refine

    if isinstance(refine, np.integer):  # MLflow's parameter schema may hand numpy integers
        refine = int(refine)
    # The server's own limit first: its deadline bounds every run, so the library's rule for
    # steps without a time limit is not the one to quote.
    if isinstance(refine, numbers.Integral) and not isinstance(refine, bool) and refine > limit:
        raise DataError(
            f"params: refine {refine} is over this server's limit of {limit} steps ({limit_name}); "
            "ask for fewer"
        )
    try:
        return check_refine(refine)
    except DataError as e:
        raise DataError(f"params: {e}") from None


def check_depth(body: bytes, limit: int) -> None:
    """Refuse a body whose brackets nest deeper than ``limit`` (read as bytes in 8 MiB chunks,
    before any parser recurses into it; brackets inside strings count too, which a photo has
    none of)."""
    depth, chunk = 0, 8 << 20
    for start in range(0, len(body), chunk):
        b = np.frombuffer(body, np.uint8, min(chunk, len(body) - start), start)
        step = np.isin(b, (91, 123)).astype(np.int32) - np.isin(b, (93, 125))  # [{ minus ]}
        levels = depth + np.cumsum(step)
        if levels.size and int(levels.max()) > limit:
            raise Refused(400, f"body: JSON nested more than {limit} deep; a batch of photos is 4 deep")
        depth = int(levels[-1]) if levels.size else depth


def parse_request(body: bytes, limits: ServeLimits) -> tuple[np.ndarray, int]:
    """``(photos (N, H, W, 3) float32, refinement steps)`` from a request body, or :class:`Refused`."""
    check_depth(body, limits.depth)
    try:
        doc = json.loads(body)
    except (ValueError, RecursionError) as e:  # JSONDecodeError, bad UTF-8: the position, not the text
        raise Refused(400, f"body: not JSON ({type(e).__name__} {str(e)[:80]})") from None
    shape = 'expected {"inputs": photos, "params": {"refine": STEPS}}'
    if not isinstance(doc, dict) or not {"inputs", "instances"} & doc.keys():
        raise Refused(400, f"body: {shape}")
    params = doc.get("params") or {}
    if not isinstance(params, dict) or set(params) - {"refine"}:
        raise Refused(400, f"params: {shape}; refine is the only parameter")
    try:
        photos = check_photo_array(doc.get("inputs", doc.get("instances")), limits.pixels, "--max-pixels")
        steps = refine_budget(params.get("refine", 0), limits.refine, "--max-refine")
    except DataError as e:
        raise Refused(400, str(e)) from None
    if len(photos) > limits.photos:
        raise Refused(400, f"{PHOTOS}: {len(photos)} photos in one request, over this server's limit of "
                           f"{limits.photos} (--max-photos); send them in several requests")  # fmt: skip
    return photos, steps


# -- what a request costs, estimated before any work -------------------------------------------

#: Bytes of the answer's JSON per map value: ``-0.123456,`` and the brackets (:func:`~svbrdf_models.
#: modelfile.serve_json.encode_answer` writes 6 decimals; measured 10.8).
ANSWER_BYTES_PER_VALUE = 11
#: Seconds to encode one value (:func:`~svbrdf_models.modelfile.serve_json.encode_answer`, numpy's
#: fixed-width text): measured 0.16-0.3 us on one busy core (1.7-3.1 s for a 1024 px material).
ANSWER_SECONDS_PER_VALUE = 3e-7
#: Memory per value while the answer is made: the float32 map, its float64 and int64 copies, the
#: text (10 B) two or three times over while it is nested, its bytes and the body's.
ANSWER_BYTES_PER_VALUE_HELD = 70
#: The network, per pixel at the model's resolution: seconds (0.04 s a 128 px photo on one busy
#: core) and bytes (its activations: 780 MB for 64 photos at 128 px, measured).
NETWORK_SECONDS_PER_PIXEL = 2.5e-6
NETWORK_BYTES_PER_PIXEL = 800
#: Per pixel of the photos as sent: seconds to crop and resize them (0.04 s a 1024 px photo)
#: and bytes held (the float32 array, its torch square and the resized copy).
PHOTO_SECONDS_PER_PIXEL = 4e-8
PHOTO_BYTES_PER_PIXEL = 36
#: A refinement's start and first step, per pixel of the maps: the highlight found (at a fixed
#: working size), the start deringed and brought to the photo's size, the flash placed, the loss
#: built and one step, none of which a time budget can cut short. Measured on one busy core:
#: 0.9 s at 512 px, 4.1 s at 1024 px, 28 s at 2048 px (its memory traffic costs more a pixel).
REFINE_START_SECONDS_PER_PIXEL = 5e-6


@dataclass(frozen=True)
class RequestCost:
    """What answering a request would take, before any work (:func:`estimate_request`)."""

    photos: int
    #: Side of the maps the answer holds: the model's resolution at refine 0, the photo's square's
    #: side (its shorter side) when refined.
    side: int
    answer_bytes: int
    memory_bytes: int
    network_s: float
    #: The refinement's start and first step (nothing without refinement).
    setup_s: float
    #: One more refinement step, all photos.
    step_s: float
    answer_s: float

    @property
    def least_s(self) -> float:
        """Seconds no request of this shape can take less than: every stage, one refinement step."""
        return self.network_s + self.setup_s + self.answer_s


def estimate_request(shape: tuple[int, ...], steps: int, resolution: int) -> RequestCost:
    """The cost of answering photos of ``shape`` ``(N, H, W[, 3])`` refined for ``steps`` steps
    by a model of ``resolution`` px (see the constants above for what each figure rests on)."""
    from ..capture.refining import refine_cost

    n, h, w = (int(x) for x in shape[:3])
    side = min(h, w) if steps else int(resolution)
    values = n * side * side * MAP_VALUES_PER_PIXEL
    network_px = n * int(resolution) ** 2
    refine_s, refine_bytes = refine_cost(side, 1) if steps else (0.0, 0)
    setup_s = n * side * side * REFINE_START_SECONDS_PER_PIXEL if steps else 0.0
    memory = (n * h * w * PHOTO_BYTES_PER_PIXEL + network_px * NETWORK_BYTES_PER_PIXEL
              + n * refine_bytes + values * ANSWER_BYTES_PER_VALUE_HELD)  # fmt: skip
    return RequestCost(
        photos=n, side=side, answer_bytes=values * ANSWER_BYTES_PER_VALUE, memory_bytes=memory,
        network_s=network_px * NETWORK_SECONDS_PER_PIXEL + n * h * w * PHOTO_SECONDS_PER_PIXEL,
        setup_s=setup_s, step_s=n * refine_s, answer_s=values * ANSWER_SECONDS_PER_VALUE,
    )  # fmt: skip


def check_cost(cost: RequestCost, steps: int, limits: ServeLimits, *, spent: float, free: int | None,
               upload: float | None = None) -> None:  # fmt: skip
    """Refuse (:class:`Refused` 400, one line naming the option to raise) a request whose answer
    would exceed ``limits.answer_mb``, whose memory exceeds ``free`` bytes (None: unknown), or
    whose every stage, with one refinement step, cannot end within ``limits.timeout`` after
    ``spent`` seconds already gone, ``upload`` of them its upload (None: all): 408 when the
    request would fit but for its upload (a slow client), 400 when the server's stages cannot."""
    maps = f"{cost.photos} material{'s' * (cost.photos > 1)} of {cost.side} px"
    smaller = "send fewer photos" + bool(steps) * (
        ", or smaller ones (refined maps come back at the photo's size)"
    )
    mb = cost.answer_bytes / 2**20
    if mb > limits.answer_mb:
        raise Refused(400, f"answer: {maps} would be about {mb:.0f} MB of JSON, over this server's limit of "
                           f"{limits.answer_mb:g} MB (--max-answer-mb); {smaller}")  # fmt: skip
    if free is not None and cost.memory_bytes > free:
        need, have = cost.memory_bytes / 2**30, free / 2**30
        raise Refused(400, f"memory: {maps} would need about {need:.1f} GB, and this machine has "
                           f"{have:.1f} GB free; {smaller}")  # fmt: skip
    total, upload = spent + cost.least_s, spent if upload is None else upload
    if total > limits.timeout and total - upload <= limits.timeout:  # it would fit but for its upload
        raise Refused(408, f"body: the upload took {upload:.1f} s of the {limits.timeout:g} s timeout "
                           f"(--timeout), too little left for this request's work (about "
                           f"{total - upload:.0f} s); send it faster, or fewer photos")  # fmt: skip
    if total > limits.timeout:
        parsing = f"parsing {spent - upload:.1f} s, " if spent > upload else ""
        parts = f"upload {upload:.1f} s, {parsing}network {cost.network_s:.1f} s, " + (
            f"refinement's start {cost.setup_s:.1f} s, " if steps else "") + f"answer {cost.answer_s:.1f} s"
        raise Refused(400, f"time: this request would take about {total:.0f} s ({parts}), over the "
                           f"{limits.timeout:g} s timeout (--timeout); send a smaller photo or fewer photos"
                           + (", or refine 0" if steps else ""))  # fmt: skip
