"""``svbrdf-bench run``: which model, at what cost."""

from __future__ import annotations

import re
from pathlib import Path

import click

from svbrdf_train import experiment_option, system_metrics_option

from ..presets import PRESETS
from ..refinement import REFINE_BACKENDS

EPILOG = (
    """\b
Examples:
  svbrdf-bench run --models ours,no-attn                     # quick preset: < 10 min on 2 CPU cores
  svbrdf-bench run --models ours,no-attn,radn --preset standard --device cuda
  svbrdf-bench run --models no-adv --from-runs ours          # reuse the last finished run of ours
  svbrdf-bench run --models ours,no-attn --test-data DATA/des18-dev
  svbrdf-bench run --models ours,no-attn --real-data DATA/real-dev --real-pattern 'luo*'
  svbrdf-bench run --models ours --no-baselines              # without the mean/photo baselines
  svbrdf-bench run --models ours --from-models fold0.pt --test-data DIR   # + fold0.pt, a reference row
  svbrdf-bench run --models pretrained --test-data DIR       # the model shipped with svbrdf-models
  svbrdf-bench run --models ours --refine 0,50,200           # + each row's maps refined 50 and 200 steps
  svbrdf-bench run --models ours,no-attn --seeds 3           # 3 fits per model: verdicts across seeds
  svbrdf-bench run --models ours,no-attn --minutes 2,8,32    # one fit per model scored at 2, 8, 32 min
  svbrdf-bench run --models ours --from-runs ours --seeds 3  # reuse finished seeds, train the others

\b
Presets (every model gets the same training-time budget, counted on the fit's train.clock:
  process CPU time over its threads on a CPU, which other programs tilt far less than wall time;
  GPU time on a GPU):
"""
    + "\n".join(f"  {p.name:<9} {p.expected}" for p in PRESETS.values())
    + """

\b
Baselines: `mean` (constant maps from the photo's median) and `photo` (the photo, its flash
fall-off divided out, as diffuse) need no training and are evaluated on the same test images;
the report says, map by map, whether each trained model beats `mean` (paired bootstrap).

\b
Reference rows: --from-models FILE,... (paths, pretrained[:NAME], hash-named URLs, MLflow
models:/ or runs:/ URIs) and --models pretrained[:NAME] score model files trained elsewhere on
the same test images with the same figures; nothing is trained for them and they do not replace
the --models recipes. They were not trained at this benchmark's budget, so each row is labelled
with what its file records, e.g. `fold0 (reference: ours, 128 px, 8.3k steps, 1.1 h CPU;
not equal-budget)`. Refused before any training: a file that cannot be loaded, a model trained
at another resolution than the test images, and a model whose provenance lists test strips
among the real strips it trained on (unless --allow-trained-strips).

\b
Refinement budgets: --refine 0,50,200 gives every row (trained models, reference rows, the
baselines) one more row per budget N > 0, `NAME +refine N`: its maps of each test photo refined
by svbrdf_render.refine_maps for N Adam steps against that photo, scored with the same figures,
with the seconds per image (network + refinement, one image at a time). `mean +refine N` refines
constant maps: the pure-optimisation baseline, against which each refined model is held at the
same N. Plot: accuracy_vs_capture_time.png. Default 0: no refinement.

\b
Seeds and budgets: --seeds N trains N fits per model, seed s = 0..N-1 set as train.seed and
data.seed (everything else equal), a row per seed (`ours seed 1`). --minutes 2,8,32 (or --steps
500,2000 for equal steps) trains one fit per model and seed to the largest budget, saving its
weights at every budget (train.snapshot_minutes / snapshot_steps), and scores each as a row
(`ours @ 8 min`); a budget a fit never reached is said, never dropped. A single --minutes keeps
its meaning: one budget, no snapshots. With several seeds or budgets the report adds "Across
seeds and budgets": per model and budget, each RMSE averaged over seeds with the between-seed
spread and a 95% interval that resamples seeds, then materials; "A beats B at a budget" only
when that interval of the paired difference excludes 0; each model's gain from one budget to
the next; the front of render RMSE against training minutes; and accuracy_vs_training_time.png.
--from-runs takes finished fits of a recipe as its seeds (several run ids of one recipe with
different train.seed; a recipe name: its last finished fit of each seed).

\b
Published numbers: --published FILE.yaml sets figures copied from papers beside the rows, each
marked `NAME (published, not rerun)`: no interval, no verdict, outside the Pareto front; the
report states their protocol and where this benchmark scores otherwise. The file names its test
set (des18: needs --test-data of Des18 strips); none ship with svbrdf-bench. With a `scorer`
(window centre-crop|resize, size, values, rmse per-image|pooled) each row is also scored the way
the file says the papers scored, in a table beside theirs.

\b
Inference cost: every row gets its FLOPs per 256x256 image (torch.utils.flop_counter; they grow
with the pixel count, x4 at 512 px, x16 at 1024 px) and its latency on --device at each
SIZExBATCH point of the latency grid: ms per forward pass of BATCH images of SIZE px, median of
a few timed runs after 2 warm-ups, torch.no_grad, one torch thread on a CPU. The grid is the
preset's (quick: 256x1,256x8,512x1; standard and paper: 256, 512, 1024 px x batch 1 and 8) or
--latency-grid's; 256x1 is always in. A point a network cannot take (a U-Net takes multiples
of 2**depth px) is left out of its row. On CUDA each point also gets the peak memory.

\b
Test data: Des18 tiles and shards larger than the models are resized to the models'
resolution (area filter), never centre-cropped: models see the field of view they trained at.

\b
Per material: with --test-data a folder of strips, the accuracy tables average per source
material, not per strip: a Des18 strip (ID;MatAXMatB;varAXvarB.png) counts for both materials
its name gives, other files are one material each (--group-by). A material shown by 3 strips
weighs as much as one shown by 1; bootstrap intervals and the paired comparisons with `mean`
resample materials. Per-strip figures stay in results.json and in MLflow. Procedural test
images are each a material of their own. Material folds that keep judged materials out of
training: svbrdf-train data folds.

\b
Output: the tables in the terminal (a headline per model on whether it beats `mean`; rows =
models, reference rows, then baselines; RMSE and SSIM per map and on renderings under 6 fixed
light/view pairs, each with a 95% bootstrap interval; the difference to `mean`; time and
memory; inference cost; what each trained model's extra accuracy costs against each other one),
and in --out:
report.md, results.csv, results.json, costs.csv, against_mean.csv, learning_curves.png,
pareto.png, comparison.png (and accuracy_vs_capture_time.png with --refine; real_comparison.png
with --refine and --real-data; accuracy_vs_training_time.png with several seeds or budgets).
MLflow: one parent run, one child per model (and seed and budget), reference row, baseline and
refined row; `svbrdf-bench report
PARENT_RUN_ID` rebuilds the report later. The parent's description gives the verdict and links
the report (logged under report/), its metrics hold each row's figures (ours/rmse_render with
ours/rmse_render_lower and _upper, the 95% interval; SSIM and latency likewise); every run
records the test set as its dataset. The last line printed is the UI's address of the saved
view "svbrdf: benchmarks (test figures)": each benchmark's rows and figures, grouped.
"""
)


def _split(value: str | None) -> list[str]:
    return [x.strip() for x in (value or "").split(",") if x.strip()]


def _once(flag: str, values: tuple):
    """The one value of an option read with ``multiple=True``; refuse it given twice."""
    if len(values) > 1:
        from ..errors import BenchError

        raise BenchError(
            f"{flag} is given {len(values)} times ({', '.join(map(str, values))}); give it once "
            "(one benchmark tests on one data set: run one benchmark per data set)"
        )
    return values[0] if values else None


@click.command("run", epilog=EPILOG)
@click.option(
    "--models",
    default="",
    metavar="A,B,...",
    help="Recipes to train and compare (svbrdf-train recipes); `pretrained` or `pretrained:NAME` "
    "scores the model shipped with svbrdf-models as a reference row instead of training. "
    "Example: --models ours,pretrained.",
)
@click.option(
    "--preset",
    type=click.Choice(list(PRESETS)),
    default="quick",
    show_default=True,
    help="Budget and test size.",
)
@click.option(
    "--from-runs", default="", metavar="ID|RECIPE,...", help="Reuse finished fits instead of training."
)
@click.option(
    "--from-models",
    default="",
    metavar="FILE|SOURCE,...",
    help="Model files trained elsewhere, scored as reference rows (not equal-budget) beside the "
    "trained models: paths, pretrained[:NAME], URLs or MLflow URIs (svbrdf_models.load_model). "
    "Example: --models ours --from-models fold0.pt,pretrained. `--models pretrained[:NAME]` "
    "adds the model shipped with svbrdf-models the same way.",
)
@click.option(
    "--allow-trained-strips",
    is_flag=True,
    help="Score a reference model (--from-models, --models pretrained) even on test strips its "
    "provenance lists among the real strips it trained on (refused otherwise); its row then says "
    "how many. Example: --from-models fold0.pt --test-data des18-dev --allow-trained-strips.",
)
@click.option(
    "--test-data",
    type=click.Path(path_type=Path),
    multiple=True,  # only to see a second one: click keeps the last without a word
    callback=lambda ctx, param, values: _once("--test-data", values),
    help="A Des18 folder or .h5 shards, resized to the models' resolution [default: procedural test "
    "materials from a fixed seed].",
)
@click.option(
    "--group-by",
    type=click.Choice(["auto", "des18", "file"]),
    default="auto",
    show_default=True,
    help="How --test-data strips are grouped into source materials for the per-material means: des18 "
    "(both materials of ID;MatAXMatB;varAXvarB.png; any other name is an error), file (one material per "
    "file), auto (des18 when every name parses, else file).",
)
@click.option(
    "--real-data",
    type=click.Path(path_type=Path, file_okay=False),
    help="A folder of real flash photos (no ground truth): adds each model's median re-rendering RMSE "
    "under the flash fitted to each photo.",
)
@click.option(
    "--real-encoding",
    type=click.Choice(["srgb", "linear"]),
    default="srgb",
    show_default=True,
    help="How the real photos store values (phones: srgb; Deschaintre's examples: linear).",
)
@click.option(
    "--real-pattern", default="*", show_default=True, help="Shell pattern on the real photos' names."
)
@click.option("--test-count", type=click.IntRange(min=1), help="Size of the procedural test set [preset's].")
@click.option(
    "--minutes",
    metavar="M[,M,...]",
    help="Training minutes per model [preset's]; several (increasing) score one fit per model and seed at "
    "each, from its snapshots. Example: --minutes 2,8,32.",
)
@click.option(
    "--steps",
    metavar="N[,N,...]",
    help="Equal steps instead of equal minutes: generator steps per model; several score one fit at each. "
    "Example: --steps 500,2000.",
)
@click.option(
    "--seeds",
    default="1",
    show_default=True,
    metavar="N",
    help="Fits per model, seed s = 0..N-1 as train.seed and data.seed; the report's verdicts then hold "
    "across seeds. Example: --seeds 3.",
)
@click.option(
    "--set", "sets", multiple=True, metavar="SECTION.FIELD=VALUE", help="Recipe override for every model."
)
@click.option(
    "-o",
    "--out",
    type=click.Path(path_type=Path, file_okay=False),
    default=Path("bench-report"),
    show_default=True,
)
@click.option(
    "--device", default="cpu", show_default=True, help="cpu, cuda or cuda:K (training and evaluation)."
)
@click.option(
    "--size", type=click.Choice(["paper", "cpu", "smoke"]), help="Recipe size instead of the preset's."
)
@click.option(
    "--latency-grid",
    metavar="SxB,SxB,...",
    help="Where each row's inference latency is timed: SIZExBATCH points, SIZE the image side in px "
    "(16-8192), BATCH the images per forward pass (1-256); 256x1 is always in [preset's: quick "
    "256x1,256x8,512x1; standard, paper 256/512/1024 x 1/8]. Example: --latency-grid 256x1,256x8,1024x1.",
)
@experiment_option("svbrdf-bench")
@click.option(
    "--refine",
    default="0",
    show_default=True,
    metavar="N,N,...",
    help="Refinement budgets in Adam steps (integers >= 0; 0, the row as it is, is always in): each row "
    "gets a row per budget N > 0, its maps refined against each test photo (and, with --real-data, "
    "against each real photo). Example: --refine 0,50,200.",
)
@click.option(
    "--refine-backend",
    type=click.Choice(REFINE_BACKENDS),
    default="compiled",
    show_default=True,
    help="Renderer backend of the refinement (compiled: torch.compile, warmed up before timing).",
)
@click.option(
    "--refine-flash",
    default="axis",
    show_default=True,
    metavar="axis|fit|INTENSITY",
    help="How the refinement finds each photo's flash: axis (on-axis, intensity from the maps), fit "
    "(position too), or the intensity of the on-axis flash the photos were taken with (e.g. 15).",
)
@click.option(
    "--published",
    metavar="FILE.yaml",
    help="Published numbers to set beside the rows, copied from papers into a YAML file (its test set, "
    "protocol and rows: docs/svbrdf-bench.md, \"Published numbers\"); each row is shown as "
    "`NAME (published, not rerun)`, with no interval and no verdict. None ship with svbrdf-bench. "
    "Example: --test-data DATA/des18-dev --published des18-papers.yaml.",
)
@click.option(
    "--no-baselines",
    is_flag=True,
    help="Leave out the untrained baselines `mean` and `photo` (and the comparison with `mean`).",
)
@system_metrics_option()
def run(**flags):
    """Train (or reuse) each model under one budget, test all on the same images, compare;
    score model files trained elsewhere beside them as reference rows (--from-models).

    Answers "which model, at what cost?": accuracy per map and on renderings with bootstrap
    intervals, next to training time, throughput, inference latency, size and memory, and
    whether each model beats constant maps derived from the photo (the `mean` baseline).
    """
    from ..runner import run_bench

    run_bench(_bench_options(flags))


def _bench_options(flags: dict):
    """The benchmark's :class:`~svbrdf_bench.options.BenchOptions` from the command's flags;
    refuses a bad refinement budget, a reused run in the trash, and nothing to compare."""
    from ..errors import BenchError
    from ..inference import parse_latency_grid
    from ..options import BASELINES, BenchOptions
    from ..presets import get_preset
    from ..published import read_published
    from ..refinement import RefinePlan, parse_budgets, parse_flash
    from ..seeding import parse_seeds, train_budget

    refine = parse_budgets(flags["refine"])
    seeds, preset = parse_seeds(flags["seeds"]), get_preset(flags["preset"])
    budget = None
    if flags["minutes"] is not None or flags["steps"] is not None:
        budget = train_budget(flags["minutes"], flags["steps"], preset.minutes)
    plan = RefinePlan(refine, flags["refine_backend"], parse_flash(flags["refine_flash"]))
    chosen, reused, files = _split(flags["models"]), _split(flags["from_runs"]), _split(flags["from_models"])
    for item in reused:
        if re.fullmatch(r"[0-9a-f]{32}", item):  # a run id (else a recipe: its last finished run)
            from svbrdf_train import check_run_kept

            hint = f"restore it (mlflow runs restore --run-id {item}) or give another run"
            check_run_kept(item, "--from-runs", hint)
    if not chosen and not reused and not files:
        raise BenchError(
            "nothing to compare: give --models A,B (recipes), --from-runs ID,... "
            "and/or --from-models FILE,..."
        )
    test_data, real_data = flags["test_data"], flags["real_data"]
    published = read_published(flags["published"]) if flags["published"] is not None else None
    return BenchOptions(
        models=chosen,
        preset=preset,
        from_runs=reused,
        from_models=files,
        allow_trained_strips=flags["allow_trained_strips"],
        test_data=str(test_data) if test_data else None,
        group_by=flags["group_by"],
        real_data=str(real_data) if real_data else None,
        real_encoding=flags["real_encoding"],
        real_pattern=flags["real_pattern"],
        test_count=flags["test_count"],
        minutes=budget.marks[0] if budget and budget.kind == "minutes" and not budget.curve else None,
        seeds=seeds,
        budget=budget,
        overrides=list(flags["sets"]),
        out=flags["out"],
        device=flags["device"],
        experiment=flags["experiment"],
        size=flags["size"],
        baselines=[] if flags["no_baselines"] else list(BASELINES),
        refine=plan,
        published=published,
        latency_grid=parse_latency_grid(flags["latency_grid"]) if flags["latency_grid"] is not None else (),
        say=lambda s: click.echo(s, err=not s.startswith("svbrdf-bench:")),
    )


COMMANDS = [run]
