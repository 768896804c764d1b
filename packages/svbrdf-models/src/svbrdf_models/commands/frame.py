"""``svbrdf-models frame``: the printable capture frame, a PDF or PNG at its true size."""

from __future__ import annotations

import argparse

from svbrdf_render.plumbing import int_range

from .._registry import Registry

__all__ = ["add_parser", "run"]

#: Choices of --paper and bounds of --dpi (a 1200 dpi A4 sheet is 140 megapixels: the limit).
PAPER_CHOICES = ("a4", "letter")
MIN_DPI, MAX_DPI = 72, 1200

EPILOG_FRAME = """\
examples:
  svbrdf-models frame -o frame.pdf                       # A4, a 10 cm window, 300 dpi
  svbrdf-models frame -o frame.pdf --paper letter --window-cm 8
  svbrdf-models frame -o frame.png --dpi 600             # an image to print from elsewhere

The sheet: a square window to cut out, eight AprilTag 36h11 markers around it (each window
size has its own, so a photo says which frame it shows), a reference strip of plain paper
under them, the window's size, a 5 cm ruler and these steps:

  1. Print at 100% (actual size: no scaling, no "fit to page"), on matte paper.
  2. Measure the ruler: it must be 5 cm, and the window its stated size. If not, the printer
     scaled the page: print again at 100%.
  3. Cut out the window along the dashed line.
  4. Lay the sheet flat on the material, the window over the part to capture, the title's
     side where the top of the maps should be.
  5. State the strip's albedo: plain printer paper is about 0.8; a matte 18% grey card glued
     on the strip is 0.18 and more exact.
  6. Take flash photos from above (flash on, other lights off, exposure locked so that the
     highlight is not white), every marker and the strip in each picture; move the phone
     between shots so that the flash's highlight falls in different places.

Exit status: 0 written; 2 bad arguments (an unknown suffix, a window that is not offered or
does not fit the paper); 3 the file could not be written (nothing half-written is left).
"""


def add_parser(sub) -> None:
    """The ``frame`` sub-command and its options."""
    from ..capture.frame import DEFAULT_DPI, MAX_WINDOW_CM, MIN_WINDOW_CM, WINDOW_STEP_CM, FrameLayout

    p = sub.add_parser(
        "frame",
        help="a printable capture frame (PDF or PNG): markers around a window, a reference strip",
        description="Write the printable capture frame: fiducial markers around a square window to lay "
        "over the material, a reference strip of known albedo, a ruler to check the print's scale.",
        epilog=EPILOG_FRAME,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "-o", "--output", required=True, metavar="FILE", help="the file to write: NAME.pdf or NAME.png"
    )
    p.add_argument(
        "--window-cm",
        type=float,
        default=10.0,
        metavar="CM",
        help=f"the window's side in cm, {MIN_WINDOW_CM:g} to {MAX_WINDOW_CM:g} in steps of "
        f"{WINDOW_STEP_CM:g} "
        f"(at most {FrameLayout.largest_window_cm('letter'):g} on letter paper) (default: 10)",
    )
    p.add_argument("--paper", choices=PAPER_CHOICES, default="a4", help="paper size (default: a4)")
    p.add_argument(
        "--dpi",
        type=int_range(MIN_DPI, MAX_DPI),
        default=DEFAULT_DPI,
        help=f"resolution of the drawn sheet, {MIN_DPI} to {MAX_DPI} (default: {DEFAULT_DPI})",
    )


def run(args, registry: Registry | None, out) -> None:
    from ..capture.frame import FrameLayout, write_frame

    layout = FrameLayout(window_cm=args.window_cm, paper=args.paper)
    path = write_frame(args.output, layout, args.dpi)
    ids = layout.marker_ids
    print(
        f"wrote {path}: {args.paper} paper, a {layout.window_cm:g} cm window, AprilTag 36h11 markers "
        f"{ids[0]}-{ids[-1]}, {args.dpi} dpi; print at 100% and check that the ruler measures 5 cm",
        file=out,
    )
