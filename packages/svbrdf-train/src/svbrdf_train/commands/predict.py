"""``svbrdf-train predict``: capture maps a material artist can use from flash photos.

The photo tool itself lives in svbrdf-models (:mod:`svbrdf_models.capture.one`, ``svbrdf-models
predict``), and so do its options: this command passes its arguments unparsed to the parser of
:func:`svbrdf_models.commands.predict.add_options` (one declaration for both command lines),
adds the models only svbrdf-train reads, training checkpoints (--checkpoint) and the checkpoints
logged by fits in MLflow (--run), and keeps the network's maps by default (--refine 0).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import click

EPILOG = """\
examples:
  svbrdf-train predict photo.jpg -o maps/                  # the model shipped with svbrdf-models
  svbrdf-train predict photo.jpg --checkpoint runs/ours-cpu/last.pt -o maps/
  svbrdf-train predict photo.jpg --model models:/svbrdf-ours/2 -o maps/
  svbrdf-train predict shots/*.png --run 3f2a... -o maps/ --linear --bits 16
  svbrdf-train predict big.jpg --checkpoint last.pt -o maps/ --tiles --map-size 1024
  svbrdf-train predict IMG_0042.jpg --checkpoint last.pt -o maps/ --crop 600,200,1800
  svbrdf-train predict photo.jpg --checkpoint last.pt -o maps/ --refine 150   # + refinement

The model: --model (a file of svbrdf-train export, an https URL whose name carries its
SHA-256 prefix, models:/NAME/VERSION or runs:/ID/PATH of MLflow, pretrained[:NAME]),
--checkpoint (a training checkpoint or a model file) or --run (a fit's MLflow run). With
none of them, the model shipped inside svbrdf-models (pretrained) is used and named on stderr;
its model card says what it was trained on and how well it does on real materials.
The same tool without training code: svbrdf-models predict (it refines by default).

"""

#: Everything after ``predict`` reaches the argparse parser as typed, --help included.
PASS_THROUGH = {"ignore_unknown_options": True, "allow_extra_args": True}


def build_parser(prog: str = "svbrdf-train predict") -> argparse.ArgumentParser:
    """svbrdf-models' predict options (:func:`~svbrdf_models.commands.predict.add_options`,
    --refine 0 by default) and this command's --checkpoint and --run; usage errors are one line
    with exit status 2."""
    from svbrdf_models.capture.batch import help_text
    from svbrdf_models.commands.predict import add_options
    from svbrdf_render import DEFAULT_REFINE_STEPS
    from svbrdf_render.plumbing import OneLineParser

    parser = OneLineParser(
        prog=prog,
        description="Capture normal, diffuse, roughness and specular maps from flash photos. The maps\n"
        "are judged by re-rendering them under a flash fitted to the photo: the RMSE against the\n"
        "photo is printed per photo and as the median of the batch.",
        epilog=EPILOG + help_text(0),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_options(
        parser,
        refine=0,
        refine_note=f"svbrdf-models predict refines by default, {DEFAULT_REFINE_STEPS} steps",
        sources=_add_sources,
    )
    return parser


def _add_sources(parser) -> None:
    """The models only svbrdf-train reads, after --model."""
    parser.add_argument(
        "--checkpoint",
        type=_checkpoint_file,
        metavar="FILE",
        help="a training checkpoint (last.pt, weights.pt) or a model file",
    )
    parser.add_argument(
        "--run", metavar="RUN_ID", help="an MLflow run of svbrdf-train fit (its logged checkpoint)"
    )


def _checkpoint_file(text: str) -> Path:
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(
            f"{text} is a folder; give a file in it (last.pt, weights.pt) or a model file"
        )
    return path


class _AsTyped(click.Command):
    """A command that keeps its arguments as typed: click's parser drops ``--``, which argparse
    needs to take a photo whose name starts with ``-`` (``predict -o maps -- -x.jpg``)."""

    def parse_args(self, ctx, args):
        ctx.meta[_TYPED] = list(args)
        return super().parse_args(ctx, args)


_TYPED = "svbrdf_train.predict.typed"


@click.command("predict", cls=_AsTyped, context_settings=PASS_THROUGH, add_help_option=False)
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
@click.pass_context
def predict(ctx, args):
    """Capture normal, diffuse, roughness and specular maps from flash photos.

    The options are svbrdf-models predict's, with --checkpoint and --run: see
    svbrdf-train predict --help.
    """
    from svbrdf_models.commands.predict import run_predict

    from ..errors import CheckpointError

    root = ctx.find_root()
    prog = f"{getattr(root.command, 'prog', None) or root.info_name} {ctx.info_name}"
    try:
        parsed = build_parser(prog).parse_args(ctx.meta.get(_TYPED, list(args)))
    except SystemExit as e:  # --help (0) or a usage error (one line, 2)
        ctx.exit(e.code if isinstance(e.code, int) else 2)
    if sum(x is not None for x in (parsed.model, parsed.checkpoint, parsed.run)) > 1:
        raise CheckpointError("give the generator with one of --model, --checkpoint and --run, not several")
    status = run_predict(parsed, _load_model, prog="svbrdf-train")
    if status:
        ctx.exit(status)


def _load_model(args, device):
    """The :class:`~svbrdf_train.predict.Predictor` of --model, --checkpoint or --run (the shipped
    model when none is given, said on stderr) and the line naming it."""
    from ..predict import Predictor

    if args.checkpoint is not None:
        model = Predictor.from_checkpoint(args.checkpoint, device)
    elif args.run is not None:
        from ..training.checkpoint import check_run_kept

        hint = f"restore it (mlflow runs restore --run-id {args.run}) or give another run"
        check_run_kept(args.run, "--run", hint)
        model = Predictor.from_run(args.run, device)
    else:
        if args.model is None:
            from svbrdf_models.modelfile.files import PRETRAINED, card_path

            click.echo(
                f"no --model, --checkpoint or --run: using the model shipped with svbrdf-models "
                f"(pretrained:{PRETRAINED}; its card: {card_path()})",
                err=True,
            )
        model = Predictor.from_model(args.model or "pretrained", device)
    size = f"{model.resolution}x{model.resolution}"
    return model, model.card or f"generator {model.name} from {model.source} (step {model.steps}), {size}"


COMMANDS = [predict]
