"""``predict --shots``: its options and its run, a part of :mod:`svbrdf_models.commands.predict`
(declared in :func:`~svbrdf_models.commands.predict.add_options` through :func:`add_shots_options`,
run by :func:`~svbrdf_models.commands.predict.run_predict` through :func:`run_shots`)."""

from __future__ import annotations

import argparse
import sys

from svbrdf_render.plumbing import float_range

__all__ = ["add_shots_options", "run_shots"]


def add_shots_options(more) -> None:
    """``--shots``, ``--strip-albedo`` and ``--flash-offset``: several shots of one material in
    the printed frame (:mod:`svbrdf_models.capture.shots`)."""
    more.add_argument(
        "--shots",
        action="store_true",
        help="the photos are handheld flash shots of ONE material in the printed frame (svbrdf-models "
        "frame): each one's camera and flash placed by its markers (the focal length from the EXIF, or "
        "--fov), one material refined against all of them, written to OUT/FIRST-STEM/",
    )
    more.add_argument(
        "--strip-albedo",
        type=float_range(0.01, 1),
        metavar="A",
        help="with --shots: the albedo of the frame's paper (plain printer paper about 0.8): each shot's "
        "flash is read off the frame's reference strip (default: the shots' exposures relative to "
        "each other, the level from the network)",
    )
    more.add_argument(
        "--flash-offset",
        type=_offset,
        metavar="DX,DY",
        help="with --shots: the flash's place beside the lens in cm, right and up as the photo is "
        "shown (default: 1,0; measure your phone's)",
    )


def _offset(text: str) -> tuple[float, float]:
    try:
        dx, dy = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected DX,DY (two numbers in cm), got {text!r}") from None
    if not all(abs(v) <= 10 for v in (dx, dy)):
        raise argparse.ArgumentTypeError(f"the flash is within 10 cm of the lens, got {text!r}")
    return dx, dy


def run_shots(args, options, load, prog: str, announce) -> int:
    """``predict PHOTO... --shots``: the shots found, posed and rectified before the model loads
    (a shot without the frame skipped with a line), captured as one material into
    OUT/FIRST-STEM/ (:mod:`svbrdf_models.capture.shots`); the folder printed. ``load`` as
    :func:`~svbrdf_models.commands.predict.run_predict`'s; ``announce(model, line, None)`` names it."""
    from svbrdf_render.plumbing import ProgressBar, check_output_folder, pick_device

    from ..capture.batch import set_threads
    from ..capture.frame import FLASH_OFFSET_CM
    from ..capture.shotcapture import capture_shots
    from ..capture.shots import prepare_shots

    device = pick_device(args.device)
    check_output_folder(args.out, "-o")
    shots = prepare_shots(args.photos, args.out, options, strip_albedo=args.strip_albedo,
                          flash_offset_cm=args.flash_offset or FLASH_OFFSET_CM,
                          warn=lambda line: print(f"{prog}: {line}", file=sys.stderr))  # fmt: skip
    model, line = load(args, device)
    announce(model, line, None)
    set_threads(args.threads)
    bar = ProgressBar(shots.folder.name)
    try:
        capture_shots(model, shots, options, progress=bar)
    finally:
        bar.close()
    print(str(shots.folder), flush=True)
    return 0
