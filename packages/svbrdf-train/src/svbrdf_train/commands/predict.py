"""``svbrdf-train predict``: write the maps a trained generator sees in photos."""

from __future__ import annotations

import sys
from pathlib import Path

import click

EPILOG = """\b
Examples:
  svbrdf-train predict photo.jpg --checkpoint runs/ours-cpu/last.pt -o maps/
  svbrdf-train predict shots/*.png --run 3f2a... -o maps/ --linear --bits 16

\b
Each photo gets a folder DIR/NAME/ with normal.png (OpenGL, stored (n+1)/2), diffuse.png,
roughness.png, specular.png (albedos linear, as Des18 stores them) and input.png (the square
the network saw, sRGB-encoded). A photo that cannot be read is reported and skipped;
the exit code is 2 if any was.
"""


@click.command("predict", epilog=EPILOG)
@click.argument("photos", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "--checkpoint", type=click.Path(path_type=Path, dir_okay=False), help="A checkpoint file (last.pt)."
)
@click.option(
    "--run", "run_id", metavar="RUN_ID", help="An MLflow run of svbrdf-train fit (its logged checkpoint)."
)
@click.option(
    "-o", "--out", type=click.Path(path_type=Path, file_okay=False), required=True, help="Output folder."
)
@click.option(
    "--linear", is_flag=True, help="The photos hold linear values (default: sRGB-encoded, as cameras save)."
)
@click.option("--bits", type=click.Choice(["8", "16"]), default="8", show_default=True, help="PNG bit depth.")
@click.option("--device", default="cpu", show_default=True, help="cpu, cuda or cuda:K.")
def predict(photos, checkpoint, run_id, out, linear, bits, device):
    """Predict normal, diffuse, roughness and specular maps from flash photos.

    The centre square of each photo is resized to the resolution the generator was trained at.
    """
    from svbrdf_render import (
        SVBRDFError,
        linear_to_srgb,
        read_image,
        srgb_to_linear,
        write_image,
        write_map_folder,
    )

    from ..data.photos import square_photo
    from ..errors import CheckpointError
    from ..predict import Predictor

    if (checkpoint is None) == (run_id is None):
        raise CheckpointError("give the generator with --checkpoint FILE or --run RUN_ID (one of them)")
    model = (
        Predictor.from_checkpoint(checkpoint, device) if checkpoint else Predictor.from_run(run_id, device)
    )
    click.echo(
        f"generator {model.recipe.generator.name} from {model.source} (step {model.step}), "
        f"{model.resolution}x{model.resolution}",
        err=True,
    )
    failed = 0
    used: set[str] = set()
    for path in photos:
        try:
            photo = read_image(path)
            if not linear:
                photo = srgb_to_linear(photo)
            svbrdf = model.predict(photo)
        except (SVBRDFError, OSError) as e:
            failed += 1
            text = str(e) if str(e).startswith(str(path)) else f"{path}: {e}"
            click.echo(f"svbrdf-train: error: {text}", err=True)
            continue
        name, k = path.stem, 1
        while name in used:
            k += 1
            name = f"{path.stem}-{k}"
        used.add(name)
        folder = out / name
        write_map_folder(folder, svbrdf, bits=int(bits))
        write_image(
            folder / "input.png", linear_to_srgb(square_photo(photo, model.resolution)), bits=int(bits)
        )
        click.echo(str(folder))
    if failed:
        click.echo(f"{failed} of {len(photos)} photo(s) failed", err=True)
        sys.exit(2)


COMMANDS = [predict]
