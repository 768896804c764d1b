"""``predict --shots``: its run, a part of :mod:`svbrdf_models.commands.predict` (whose
:func:`~svbrdf_models.commands.predict.add_options` declares --shots with the other options,
and whose :func:`~svbrdf_models.commands.predict.run_predict` runs it through :func:`run_shots`)."""

from __future__ import annotations

import sys

__all__ = ["run_shots"]


def run_shots(args, options, load, prog: str) -> int:
    """``predict PHOTO... --shots``: the shots found, posed and rectified before the model loads
    (a shot without the frame skipped with a line), captured as one material into
    OUT/FIRST-STEM/ (:mod:`svbrdf_models.capture.shots`); the folder printed. ``load`` as
    :func:`~svbrdf_models.commands.predict.run_predict`'s."""
    from svbrdf_render.plumbing import ProgressBar, check_output_folder, pick_device

    from ..capture.batch import announce_model, set_threads
    from ..capture.frame import FLASH_OFFSET_CM
    from ..capture.shotcapture import capture_shots
    from ..capture.shots import prepare_shots

    device = pick_device(args.device)
    check_output_folder(args.out, "-o")
    shots = prepare_shots(args.photos, args.out, options, strip_albedo=args.strip_albedo,
                          flash_offset_cm=args.flash_offset or FLASH_OFFSET_CM,
                          warn=lambda line: print(f"{prog}: {line}", file=sys.stderr))  # fmt: skip
    model, line = load(args, device)
    announce_model(model, line, None)
    set_threads(args.threads)
    bar = ProgressBar(shots.folder.name)
    try:
        capture_shots(model, shots, options, progress=bar)
    finally:
        bar.close()
    print(str(shots.folder), flush=True)
    return 0
