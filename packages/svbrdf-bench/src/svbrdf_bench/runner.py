"""``svbrdf-bench run``: train (or reuse) each model, evaluate all on one test set, log and report.

Model files trained elsewhere (``--from-models``, ``--models pretrained``) are scored beside them
as reference rows (:mod:`svbrdf_bench.references`): same test images, same figures, a label that
says they are not equal-budget competitors.

``--refine 0,50,200`` adds, per scored row and budget, a row of its maps refined against each
test photo (:mod:`svbrdf_bench.refinement`), each a child run of its own; with ``--real-data``
too, each refined row also refines its maps of each real photo (the real-photo figure), and the
report gets a real-photo sheet: each model's maps and re-renderings, its refined ones under it.

``--seeds 3`` trains each model three times (seed s set as ``train.seed`` and ``data.seed``), a
row per seed; ``--minutes 2,8,32`` (or ``--steps 500,2000``) trains one fit per model and seed to
the largest budget and scores its snapshot at each as a row (:mod:`svbrdf_bench.seeding`,
:func:`~svbrdf_bench.children.fit_rows`); the report adds "Across seeds and budgets".

Each invocation is one MLflow parent run with a child run per model, seed and budget and per
baseline, laid out as :mod:`svbrdf_bench.layout` describes; :mod:`svbrdf_bench.report` builds every
table and plot from those runs alone, so ``svbrdf-bench report PARENT`` rebuilds them later.

:func:`run_bench` reads as its steps: :func:`_plan` checks every argument and builds the test set
before MLflow is touched; :func:`_open_parent` starts the parent run; then each fit
(:func:`_score_fit`), reference model file (:func:`_score_reference`) and baseline
(:func:`_score_baseline`) is scored by one :class:`~svbrdf_bench.scoring.RowScorer` into its
child run (:mod:`svbrdf_bench.children`); :func:`_report` writes the report and logs it, and
:func:`~svbrdf_bench.mlflow_view.describe_in_mlflow` sets what the MLflow UI shows.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from collections import Counter
from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import torch

from svbrdf_render.plumbing import check_output_folder

from .children import (
    Fit,
    FitRow,
    baseline_child,
    fit_checkpoint,
    fits_folder,
    fit_rows,
    fit_seed,
    log_child,
    log_refined_children,
    resolve_reuse,
    snapshot_checkpoint,
    snapshot_figures,
    tracking_client,
    train,
)
from .errors import BenchError
from .layout import (
    BASELINE_TAG,
    BASELINES_PARAM,
    BENCH_KIND,
    BUDGETS_PARAM,
    GROUP_BY_PARAM,
    KIND_TAG,
    LPIPS_TAG,
    MINUTES_PARAM,
    MISSED_BUDGETS,
    MODEL_TAG,
    PRESET_PARAM,
    PUBLISHED_PARAM,
    REAL_DATA_PARAM,
    REFERENCE_TAG,
    REFERENCES_PARAM,
    REFINE_BACKEND_PARAM,
    REFINE_FLASH_PARAM,
    REFINE_PARAM,
    REPORT_ARTIFACTS,
    SEEDS_PARAM,
    TEST_GROUPS,
    TEST_RESOLUTION_PARAM,
    TEST_SET_PARAM,
    missed_json,
    phase_key,
    test_groups_json,
)
from .mlflow_view import describe_in_mlflow
from .options import BenchOptions
from .published import check_test_set, log_published
from .references import (
    check_resolution,
    check_trained_strips,
    load_references,
    reference_child,
    reference_figures,
    split_pretrained,
)
from .scoring import RowScorer, comparison_grid, real_grid, training_figures
from .seeding import TrainBudget, budget_text, check_overrides, row_label
from .testset import TestSet

__all__ = ["run_bench"]


@dataclass
class _Plan:
    """What one benchmark does, settled before its parent run exists."""

    #: The fits to train: ``(recipe, seed)``; seed None: the recipe's own (one fit per model).
    to_train: list[tuple[str, int | None]]
    #: ``--from-runs`` fits: ``(label, run id)``.
    reuse: list[tuple[str, str]]
    #: Reference model files (:class:`svbrdf_bench.references.Reference`).
    refs: list
    test: TestSet
    #: The real photos (``--real-data``), or None.
    photos: object
    size: str
    device: torch.device
    #: The LPIPS network (None when skipped) and what the report says of it.
    lpips: object
    lpips_note: str
    #: How long each fit trains, and at which budgets it is scored.
    budget: TrainBudget = field(default_factory=TrainBudget)

    @property
    def labels(self) -> list[str]:
        """Every model but the baselines, in the order they are scored (a model of several seeds once)."""
        return list(dict.fromkeys(
            [Path(m).stem for m, _ in self.to_train]
            + [label for label, _ in self.reuse]
            + [r.short for r in self.refs]
        ))  # fmt: skip


class _Phases:
    """Wall seconds of each phase of a benchmark, logged on its parent run as each phase ends
    (:func:`svbrdf_bench.layout.phase_key`; the report's "Where the time went"). Phases that end
    before the parent run exists are logged when it is attached."""

    def __init__(self) -> None:
        self.done: list[tuple[str, float]] = []
        self._run: tuple | None = None  # (MLflow client, parent run id)

    @contextmanager
    def __call__(self, name: str):
        start = time.perf_counter()
        yield
        self.done.append((name, time.perf_counter() - start))
        self._log(len(self.done) - 1)

    def attach(self, client, run_id: str) -> None:
        self._run = (client, run_id)
        for i in range(len(self.done)):
            self._log(i)

    def _log(self, i: int) -> None:
        if self._run is not None:
            name, seconds = self.done[i]
            self._run[0].log_metric(self._run[1], phase_key(i + 1, name), round(seconds, 2))


@dataclass
class _Bench:
    """A benchmark under way: its parent run, MLflow client, scratch folder and row scorer."""

    options: BenchOptions
    plan: _Plan
    client: object
    parent: object  # svbrdf_train.MlflowTracker
    work: Path
    scorer: RowScorer
    phases: _Phases = field(default_factory=_Phases)

    def refined_children(self, base: tuple[str, str, dict[str, str]], refined: dict, params: float) -> None:
        """The child runs of ``base``'s refined rows (:func:`~svbrdf_bench.children.log_refined_children`)."""
        log_refined_children(self.client, self.parent.experiment_id, self.parent.run_id, base, refined,
                             self.options.refine, params, self.work)  # fmt: skip


def run_bench(options: BenchOptions) -> str:
    """Run the benchmark; returns the parent run id (the report is in ``options.out``)."""
    from svbrdf_train import git_revision, ui_hint

    from .report import terminal

    phases = _Phases()
    with phases("checks and test set"):
        plan = _plan(options)
    with phases("MLflow store"):
        client = tracking_client()
        sha, dirty = git_revision()
        parent = _open_parent(options, plan, sha, dirty)
    phases.attach(client, parent.run_id)
    status = "FAILED"
    try:
        with tempfile.TemporaryDirectory(prefix="svbrdf-bench-") as tmp:
            work = Path(tmp)
            if plan.test.groups is not None:  # the report averages per material: which sample shows which
                groups_file = work / Path(TEST_GROUPS).name
                groups_file.write_text(test_groups_json(plan.test.group_by, plan.test.sample_names,
                                                        plan.test.groups))  # fmt: skip
                parent.log_artifact(groups_file, str(Path(TEST_GROUPS).parent))
            p = options.preset
            scorer = RowScorer(plan.test, plan.device, plan.lpips, plan.photos, options.refine,
                               p.latency_repeats, options.say, options.latency_points(), p.grid_repeats,
                               options.published.scorer if options.published else None)  # fmt: skip
            bench = _Bench(options, plan, client, parent, work, scorer, phases)
            for row in _fits(bench):
                with phases(f"scoring {row.label}"):
                    _score_fit(bench, row)
            for ref in plan.refs:  # trained elsewhere: scored, not trained; the label says so
                with phases(f"scoring the reference {ref.name}"):
                    _score_reference(bench, ref)
            for name in options.baselines:
                with phases(f"scoring the baseline {name}"):
                    _score_baseline(bench, name)
            start = time.perf_counter()
            report = _report(bench)
            view = describe_in_mlflow(client, parent, plan.test, options.out, options.test_data, sha)
        status = "FINISHED"
        options.say(terminal(report))
        options.say(f"report: {options.out}/report.md (written in {time.perf_counter() - start:.0f} s); "
                    f"MLflow parent run {parent.run_id}")
        options.say(f"  MLflow: {ui_hint(parent.uri, parent.experiment_id, view=view)}")
    except KeyboardInterrupt:
        status = "KILLED"
        raise
    finally:
        parent.finish(status)
        _fits_left(options, status)
    return parent.run_id


def _fits_left(options: BenchOptions, status: str) -> None:
    """The fits' folder (:func:`~svbrdf_bench.children.fits_folder`): removed when the benchmark
    finished (every fit is in MLflow), else kept, and said, for the same command to resume."""
    folder = fits_folder(options.out)
    if not folder.is_dir():
        return
    if status == "FINISHED":
        shutil.rmtree(folder, ignore_errors=True)
    else:
        options.say(f"the fits so far are kept in {folder}: run the same command again to resume them "
                    "(a fit that finished is scored again, not trained again)")


# -- before MLflow: the arguments -----------------------------------------------------------------


def _plan(options: BenchOptions) -> _Plan:
    """Every argument checked and the test set built, before MLflow is touched (a bad path
    should not wait for a store; ``--from-runs`` alone is looked up there)."""
    from svbrdf_train import PhotoFolder, load_recipe, parse_overrides

    from .metrics import load_lpips

    recipes, shipped = split_pretrained(options.models)
    _check_models(recipes)
    check_output_folder(options.out, "-o")  # before hours of training, not after
    p = options.preset
    size = options.size or p.size
    device = torch.device(options.device)
    refs = load_references(
        [(s, "--models") for s in shipped] + [(s, "--from-models") for s in options.from_models], device
    )
    budget = options.train_budget()
    check_overrides([*p.overrides, *options.overrides], budget, options.seeds)
    test = None
    if recipes:
        overrides = parse_overrides([*p.overrides, *options.overrides])
        resolution = load_recipe(recipes[0], size, overrides).train.resolution
        check_resolution(refs, resolution, f"the resolution of recipe {recipes[0]!r} at size {size!r}")
        test = _test_set(options, resolution)
    reuse = resolve_reuse(options.from_runs, options.seeds, [Path(m).stem for m in recipes])
    to_train = _to_train(recipes, reuse, options.seeds)
    if not to_train and not reuse and not refs:
        raise BenchError("no models to compare: give --models, --from-runs and/or --from-models")
    _check_baselines(options.baselines, [Path(m).stem for m, _ in to_train] + [r for r, _ in reuse])
    if test is None:
        test = _test_set(options, _models_resolution(reuse, refs))
    check_trained_strips(refs, test, options.allow_trained_strips, options.say)
    check_test_set(options.published, test)  # published numbers on another test set: refused
    photos = None
    if options.real_data is not None:
        photos = PhotoFolder(options.real_data, encoding=options.real_encoding, pattern=options.real_pattern)
    lpips, lpips_note = load_lpips()
    return _Plan(to_train, reuse, refs, test, photos, size, device, lpips, lpips_note, budget)


def _to_train(
    recipes: Sequence[str], reuse: list[tuple[str, str]], seeds: int
) -> list[tuple[str, int | None]]:
    """``(recipe, seed)`` of each fit to train: every seed of each recipe that no reused fit has
    (one seed: the recipe's own, unless a fit of the recipe is reused)."""
    if seeds == 1:
        reused = {label for label, _ in reuse}
        return [(m, None) for m in recipes if Path(m).stem not in reused]
    client = tracking_client()
    have = {(label, fit_seed(client.get_run(run))) for label, run in reuse}
    return [(m, s) for m in recipes for s in range(seeds) if (Path(m).stem, s) not in have]


def _check_models(models: Sequence[str]) -> None:
    from svbrdf_train import list_recipes

    known = list_recipes()
    for m in models:
        if m not in known and Path(m).suffix not in (".yaml", ".yml"):
            import difflib

            close = difflib.get_close_matches(m, known, n=2, cutoff=0.5)
            hint = f" (did you mean {' or '.join(map(repr, close))}?)" if close else ""
            raise BenchError(f"unknown model {m!r}{hint}; models are recipes: {', '.join(known)}")


def _check_baselines(baselines: Sequence[str], labels: Sequence[str]) -> None:
    import svbrdf_models as sm

    known = sm.list_models("generator")
    for name in baselines:
        if name not in known:
            raise BenchError(f"unknown baseline {name!r}; registered generators: {', '.join(known)}")
        if name in labels:
            raise BenchError(
                f"model {name!r} has the name of a baseline; rename the recipe or use --no-baselines"
            )


def _test_set(options: BenchOptions, resolution: int) -> TestSet:
    from .testset import test_set

    count = options.test_count or options.preset.test_count
    test = test_set(options.test_data, resolution, count, options.group_by)
    if len(test) == 0:
        raise BenchError(f"the test set ({test.description}) is empty")
    return test


def _models_resolution(reuse: list[tuple[str, str]], refs: list) -> int:
    """The resolution of the test images when no recipe is trained: the first reused fit's, else
    the first reference model's; every reference model must have it."""
    if reuse:
        resolution = int(tracking_client().get_run(reuse[0][1]).data.params.get("train.resolution", 256))
        why = f"the resolution of the reused fit {reuse[0][0]}"
    else:
        resolution, why = refs[0].model.resolution, f"the resolution of {refs[0].source}"
    check_resolution(refs, resolution, why)
    return resolution


# -- the parent run -------------------------------------------------------------------------------


def _budget(options: BenchOptions, plan: _Plan) -> tuple[str, str]:
    """The training budget as the parent's param, and in words (:func:`~svbrdf_bench.seeding.budget_text`)."""
    return budget_text(plan.budget, options.seeds, bool(plan.to_train), bool(plan.reuse), bool(plan.refs))


def _open_parent(options: BenchOptions, plan: _Plan, sha: str, dirty: bool):
    """The parent run, tagged and with the benchmark's params; says what the benchmark will do."""
    from svbrdf_train import MlflowTracker, source_tags

    p, test, refine = options.preset, plan.test, options.refine
    budget, words = _budget(options, plan)
    parent = MlflowTracker(
        experiment=options.experiment,
        run_name=f"bench-{','.join(plan.labels)}-{p.name}",
        tags={KIND_TAG: BENCH_KIND, "preset": p.name, "models": ",".join(plan.labels), "git_sha": sha,
              "git_dirty": str(dirty).lower(), "device": str(plan.device), "version.torch": torch.__version__,
              LPIPS_TAG: plan.lpips_note, **source_tags("svbrdf-bench run", sha)},
        params={
            PRESET_PARAM: p.name, "recipe_size": plan.size, MINUTES_PARAM: budget,
            SEEDS_PARAM: str(options.seeds), BUDGETS_PARAM: plan.budget.param,
            TEST_SET_PARAM: test.description, "test_count": str(len(test)), GROUP_BY_PARAM: test.group_by,
            TEST_RESOLUTION_PARAM: str(test.resolution),
            **({PUBLISHED_PARAM: options.published.origin} if options.published else {}),
            "overrides": " ".join([*p.overrides, *options.overrides]) or "-",
            REAL_DATA_PARAM: f"{len(plan.photos)} photos of {options.real_data} ({options.real_encoding})"
            if plan.photos else "-",
            BASELINES_PARAM: ",".join(options.baselines) or "-",
            REFERENCES_PARAM: " ".join(f"{r.source}@{r.model.sha256[:12]}" for r in plan.refs) or "-",
            REFINE_PARAM: ",".join(map(str, refine.budgets)),
            **({REFINE_BACKEND_PARAM: refine.backend, REFINE_FLASH_PARAM: refine.flash_words()}
               if refine.active else {}),
        },
    )  # fmt: skip
    log_published(parent, options.published)
    refining = (
        f"; refinement budgets: {', '.join(map(str, refine.budgets))} steps "
        f"({refine.backend}, flash: {refine.flash_words()})"
        if refine.active
        else ""
    )
    options.say(
        f"benchmark {', '.join(plan.labels)} ({p.name}: {words}); "
        f"baselines: {', '.join(options.baselines) or 'none'}; test set: {test.description}, "
        f"{test.grouping_words()}; {plan.lpips_note}{refining}\n  MLflow parent run: {parent.run_id}"
    )
    return parent


# -- the rows ---------------------------------------------------------------------------------------


def _fits(bench: _Bench) -> list[FitRow]:
    """The rows to score: each fit trained now (per model and seed), then each reused fit, as one
    row or a row per budget (:func:`~svbrdf_bench.children.fit_rows`, their child runs made);
    budgets a fit never reached are said, and logged on the parent run."""
    options, plan, client, parent = bench.options, bench.plan, bench.client, bench.parent
    counts = Counter([Path(m).stem for m, _ in plan.to_train] + [label for label, _ in plan.reuse])
    fits = []
    for i, (model, seed) in enumerate(plan.to_train, 1):
        stem = Path(model).stem
        label = row_label(stem, seed if counts[stem] > 1 else None, None)
        options.say(f"[{i}/{len(plan.to_train)}] training {label} ({plan.size} size)")
        with bench.phases(f"training {label}"):
            run_id, wall, out = train(model, options, parent.run_id, fits_folder(options.out), seed=seed,
                                      budget=plan.budget, name=label)  # fmt: skip
        own = seed if seed is not None else fit_seed(client.get_run(run_id))
        fits.append(Fit(stem, own, run_id, wall, out, seeds_shown=counts[stem] > 1))
    for label, source in plan.reuse:
        fits.append(Fit(label, fit_seed(client.get_run(source)), source, seeds_shown=counts[label] > 1))
    rows, missed = [], []
    for fit in fits:
        more, lost = fit_rows(client, parent, fit, plan.budget)
        rows, missed = rows + more, missed + lost
    if missed:
        for m in missed:
            options.say(f"{m['model']} seed {m['seed']}: no row at {m['budget']}: {m['why']}")
        target = bench.work / Path(MISSED_BUDGETS).name
        target.write_text(missed_json(missed))
        parent.log_artifact(target, str(Path(MISSED_BUDGETS).parent))
    return rows


def _score_fit(bench: _Bench, row: FitRow) -> None:
    """A fit's row (the fit, or its snapshot at one budget) scored, its training figures, its
    seed and budget tags, its refined rows."""
    from svbrdf_train import load_generator

    state = snapshot_checkpoint(row, bench.work) if row.snapshot else fit_checkpoint(row.fit_run, row.local)
    generator, recipe = load_generator(state, bench.plan.device)
    figures, per_sample, refined = bench.scorer.score(row.label, generator)
    figures |= training_figures(bench.client, row.fit_run, row.wall, recipe.train.batch, state["step"])
    if row.snapshot:
        figures = snapshot_figures(figures, state["snapshot"])
    for key, value in {MODEL_TAG: row.label, **row.tags}.items():
        bench.client.set_tag(row.run_id, key, value)
    log_child(row.run_id, figures, per_sample, bench.work)
    if row.run_id != row.fit_run:  # a child made here (a reused fit's, a budget's): finished now
        bench.client.set_terminated(row.run_id)
    bench.refined_children((row.label, row.run_id, {}), refined, figures["model/params"])


def _score_reference(bench: _Bench, ref) -> None:
    """A reference model file's row (trained elsewhere) and its refined rows."""
    parent = bench.parent
    run_id = reference_child(bench.client, parent.experiment_id, parent.run_id, ref)
    figures, per_sample, refined = bench.scorer.score(ref.label, ref.model.generator, ref.short)
    log_child(run_id, figures | reference_figures(ref), per_sample, bench.work)
    bench.client.set_terminated(run_id)
    bench.refined_children((ref.label, run_id, {REFERENCE_TAG: ref.name}), refined, figures["model/params"])


def _score_baseline(bench: _Bench, name: str) -> None:
    """An untrained baseline's row (built from the registry) and its refined rows."""
    run_id, generator = baseline_child(bench.client, bench.parent.experiment_id, bench.parent.run_id, name)
    figures, per_sample, refined = bench.scorer.score(name, generator.to(bench.plan.device))
    log_child(run_id, figures, per_sample, bench.work)
    bench.client.set_terminated(run_id)
    bench.refined_children((name, run_id, {BASELINE_TAG: "true"}), refined, figures["model/params"])


def _report(bench: _Bench):
    """The report, built from the runs as ``svbrdf-bench report`` would, written to ``--out`` with
    the comparison sheets, and logged in the parent run."""
    from .report import build_report, write_report

    report = build_report(bench.parent.run_id)
    shown, real_shown = bench.scorer.shown, bench.scorer.real_shown
    grid = comparison_grid(shown, bench.work / "comparison.png") if shown else None
    if real_shown:
        real = real_grid(real_shown, bench.work / "real_comparison.png")
        files = write_report(report, bench.options.out, grid=grid, real_grid=real)
    else:
        files = write_report(report, bench.options.out, grid=grid)
    for f in files:
        bench.parent.log_artifact(f, REPORT_ARTIFACTS)
    return report
