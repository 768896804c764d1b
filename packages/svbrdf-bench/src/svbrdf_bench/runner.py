"""``svbrdf-bench run``: train (or reuse) each model, evaluate all on one test set, log and report.

Model files trained elsewhere (``--from-models``, ``--models pretrained``) are scored beside them
as reference rows (:mod:`svbrdf_bench.references`): same test images, same figures, a label that
says they are not equal-budget competitors.

``--refine 0,50,200`` adds, per scored row and budget, a row of its maps refined against each
test photo (:mod:`svbrdf_bench.refinement`), each a child run of its own; with ``--real-data``
too, each refined row also refines its maps of each real photo (the real-photo figure), and the
report gets a real-photo sheet: each model's maps and re-renderings, its refined ones under it.

Each invocation is one MLflow parent run with a child run per model and per baseline, laid out
as :mod:`svbrdf_bench.layout` describes; :mod:`svbrdf_bench.report` builds every table and plot
from those runs alone, so ``svbrdf-bench report PARENT`` rebuilds them later.

:func:`run_bench` reads as its steps: :func:`_plan` checks every argument and builds the test set
before MLflow is touched; :func:`_open_parent` starts the parent run; then each fit
(:func:`_score_fit`), reference model file (:func:`_score_reference`) and baseline
(:func:`_score_baseline`) is scored by one :class:`~svbrdf_bench.scoring.RowScorer` into its
child run (:mod:`svbrdf_bench.children`); :func:`_report` writes the report and logs it, and
:func:`~svbrdf_bench.mlflow_view.describe_in_mlflow` sets what the MLflow UI shows.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import torch

from svbrdf_render.formats.files import check_output_folder

from .children import (
    baseline_child,
    fit_checkpoint,
    log_child,
    log_refined_children,
    resolve_reuse,
    reused_child,
    tracking_client,
    train,
)
from .errors import BenchError
from .layout import (
    BASELINE_TAG,
    BASELINES_PARAM,
    BENCH_KIND,
    GROUP_BY_PARAM,
    KIND_TAG,
    LPIPS_TAG,
    MINUTES_PARAM,
    MODEL_TAG,
    PRESET_PARAM,
    REAL_DATA_PARAM,
    REFERENCE_TAG,
    REFERENCES_PARAM,
    REFINE_BACKEND_PARAM,
    REFINE_FLASH_PARAM,
    REFINE_PARAM,
    REPORT_ARTIFACTS,
    TEST_GROUPS,
    TEST_SET_PARAM,
    phase_key,
    test_groups_json,
)
from .mlflow_view import describe_in_mlflow, metric_prefix, parent_metrics, parent_note
from .options import BASELINES, BenchOptions
from .references import (
    check_resolution,
    check_trained_strips,
    load_references,
    reference_child,
    reference_figures,
    split_pretrained,
)
from .scoring import RowScorer, comparison_grid, real_grid, training_figures
from .testset import TestSet

__all__ = ["BenchOptions", "run_bench", "BASELINES", "metric_prefix", "parent_metrics", "parent_note"]


@dataclass
class _Plan:
    """What one benchmark does, settled before its parent run exists."""

    to_train: list[str]
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

    @property
    def labels(self) -> list[str]:
        """Every row but the baselines', in the order they are scored."""
        return (
            [Path(m).stem for m in self.to_train]
            + [label for label, _ in self.reuse]
            + [r.short for r in self.refs]
        )


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
                               p.latency_repeats, options.say)  # fmt: skip
            bench = _Bench(options, plan, client, parent, work, scorer, phases)
            for job in _fits(bench):
                with phases(f"scoring {job[0]}"):
                    _score_fit(bench, *job)
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
    return parent.run_id


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
    test = None
    if recipes:
        overrides = parse_overrides([*p.overrides, *options.overrides])
        resolution = load_recipe(recipes[0], size, overrides).train.resolution
        check_resolution(refs, resolution, f"the resolution of recipe {recipes[0]!r} at size {size!r}")
        test = _test_set(options, resolution)
    reuse = resolve_reuse(options.from_runs)
    reused_labels = {label for label, _ in reuse}
    to_train = [m for m in recipes if Path(m).stem not in reused_labels]
    if not to_train and not reuse and not refs:
        raise BenchError("no models to compare: give --models, --from-runs and/or --from-models")
    _check_baselines(options.baselines, [Path(m).stem for m in to_train] + list(reused_labels))
    if test is None:
        test = _test_set(options, _models_resolution(reuse, refs))
    check_trained_strips(refs, test, options.allow_trained_strips, options.say)
    photos = None
    if options.real_data is not None:
        photos = PhotoFolder(options.real_data, encoding=options.real_encoding, pattern=options.real_pattern)
    lpips, lpips_note = load_lpips()
    return _Plan(to_train, reuse, refs, test, photos, size, device, lpips, lpips_note)


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
    """The training budget as the parent's param, and in words."""
    minutes = options.minutes if options.minutes is not None else options.preset.minutes
    if plan.to_train:
        budget = "recipe schedule" if minutes is None else str(minutes)
        words = "each recipe's full schedule" if minutes is None else f"{minutes:g} min of training per model"
    elif plan.reuse:
        budget = "reused fits, each with its own training budget (see the time table)"
        words = "reused fits, each with its own training budget"
    else:
        budget = words = "reference models only, each with the training budget its file records"
    if plan.refs and (plan.to_train or plan.reuse):
        words += "; reference rows: their own budgets, not equal"
    return budget, words


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
            TEST_SET_PARAM: test.description, "test_count": str(len(test)), GROUP_BY_PARAM: test.group_by,
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


def _fits(bench: _Bench) -> list[tuple[str, str, float | None, str | None, Path | None]]:
    """The fits to score: each recipe trained now, then each reused fit (its child run made):
    ``(label, evaluation run, training wall seconds, reused run, local checkpoint)``."""
    options, plan, parent = bench.options, bench.plan, bench.parent
    jobs = []
    for i, model in enumerate(plan.to_train, 1):
        options.say(f"[{i}/{len(plan.labels)}] training {model} ({plan.size} size)")
        with bench.phases(f"training {Path(model).stem}"):
            run_id, wall, local = train(model, options, parent.run_id, bench.work)
        jobs.append((Path(model).stem, run_id, wall, None, local))
    for label, source in plan.reuse:
        child = reused_child(bench.client, parent.experiment_id, parent.run_id, label, source)
        jobs.append((label, child, None, source, None))
    return jobs


def _score_fit(bench: _Bench, label: str, run_id: str, wall: float | None, source: str | None,
               local: Path | None) -> None:  # fmt: skip
    """A fit's row: its generator scored, its training figures, its refined rows."""
    from svbrdf_train import load_generator

    state = fit_checkpoint(source or run_id, local)
    generator, recipe = load_generator(state, bench.plan.device)
    figures, per_sample, refined = bench.scorer.score(label, generator)
    figures |= training_figures(bench.client, source or run_id, wall, recipe.train.batch, state["step"])
    bench.client.set_tag(run_id, MODEL_TAG, label)
    log_child(run_id, figures, per_sample, bench.work)
    if source is not None:
        bench.client.set_terminated(run_id)
    bench.refined_children((label, run_id, {}), refined, figures["model/params"])


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
