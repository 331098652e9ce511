"""Luigi tasks. Thin: parameters, dependencies, targets; each run() is one call into
workflows.steps. Order: SourceList → PrepareBatch → RenderBatch → AugmentBatch (per batch of
models; with --fit-patches also FitBatch after PrepareBatch) → CategoryShards → BuildCategory
or BuildDataset (manifest.json). Parameters are checked when a task is made (workflows.validate)."""

from __future__ import annotations

import contextlib
import functools
from typing import Iterator

import luigi

from workflows import lifetime, steps, validate
from workflows.build_settings import BuildSettings
from workflows.listing import current_listing, list_path, read_listing
from workflows.params import settings_values, with_parameters


@with_parameters(BuildSettings)  # one parameter per BuildSettings field (--views, --render-settings, ...)
class _BuildTask(luigi.Task):
    """Parameters shared by every task of a build (Luigi task ids include them all)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        # Every parameter is checked when the task is made, before anything is scheduled or run
        # (the `luigi` command makes the root task first); a bad one stops with one line.
        validate.check_settings(self.build)

    @functools.cached_property
    def build(self) -> BuildSettings:
        return validate.build_settings(settings_values(BuildSettings, self))

    @contextlib.contextmanager
    def recorded(self) -> Iterator[None]:
        """Record this run's start and finish under <work>/_runs (see steps.record_run)."""
        lifetime.die_with_parent()  # a task process of --workers N must not outlive the `luigi` process
        steps.record_run(self.build, self.task_id, "start")
        yield
        steps.record_run(self.build, self.task_id, "done")

    def progress(self, done: int, total: int, message: str) -> None:
        """Progress callback handed to the batch functions: shows in Luigi's scheduler UI."""
        self.set_status_message(message)
        self.set_progress_percentage(int(100 * done / max(total, 1)))


class _ListedTask(_BuildTask):
    """A task of one category's model list, named by the list's key (see workflows.listing)."""

    category = luigi.Parameter()
    listing = luigi.Parameter(description="key of the category's model list (set by BuildCategory)")

    @functools.cached_property
    def build(self) -> BuildSettings:
        # under --preset per-category each category's tasks build with the preset of its name
        return validate.category_build(validate.build_settings(settings_values(BuildSettings, self)), self.category)

    @functools.cached_property
    def lst(self) -> dict:
        # read once per task: a list is immutable under its key, and the scheduler asks every
        # task for its output() (which needs the list) before anything runs
        return read_listing(self.build, self.category, self.listing)


class SourceList(_ListedTask):
    def output(self):
        return luigi.LocalTarget(list_path(self.build, self.category, self.listing))

    def run(self):
        with self.recorded():
            steps.write_source_list(self.build, self.category)


class PrepareBatch(_ListedTask):
    batch = luigi.IntParameter()

    def requires(self):
        return self.clone(SourceList)

    def output(self):
        return luigi.LocalTarget(steps.batch_path(self.build, "prepare", self.lst, self.batch))

    def run(self):
        with self.recorded():
            steps.prepare_step(self.build, self.lst, self.batch, self.progress)


class RenderBatch(_ListedTask):
    batch = luigi.IntParameter()
    resources = {"blender": 1}
    crash_retries = luigi.IntParameter(
        default=1,
        significant=False,
        description="re-runs of a batch whose Blender crashed or hung ([RenderBatch] in luigi.cfg)",
    )

    def requires(self):
        return self.clone(PrepareBatch)

    def output(self):
        return luigi.LocalTarget(steps.batch_path(self.build, "render", self.lst, self.batch))

    def run(self):
        with self.recorded():
            steps.render_step(self.build, self.lst, self.batch, self.progress, self.crash_retries)


class AugmentBatch(_ListedTask):
    batch = luigi.IntParameter()

    def requires(self):
        return self.clone(RenderBatch)

    def output(self):
        return luigi.LocalTarget(steps.batch_path(self.build, "augment", self.lst, self.batch))

    def run(self):
        with self.recorded():
            steps.augment_step(self.build, self.lst, self.batch, self.progress)


class FitBatch(_ListedTask):
    """The category's template fitted to the batch's prepared models (with --fit-patches)."""

    batch = luigi.IntParameter()

    def requires(self):
        return self.clone(PrepareBatch)

    def output(self):
        return luigi.LocalTarget(steps.batch_path(self.build, "fit", self.lst, self.batch))

    def run(self):
        with self.recorded():
            steps.fit_step(self.build, self.lst, self.batch, self.progress)


class CategoryShards(_ListedTask):
    """The category's shards + category.json in the dataset folder, current for these settings
    and this model list; damaged or missing shards make it incomplete, so a re-run repairs them."""

    verify = luigi.BoolParameter(
        default=False, significant=False, description="check every shard's sha256, not only its size"
    )

    def requires(self):
        # Batches are static dependencies: with a central scheduler every worker then knows them
        # and can take any (dynamic ones would be runnable only by the worker that yielded them).
        n = steps.n_batches(len(self.lst["models"]), self.batch_size)
        fits = [self.clone(FitBatch, batch=b) for b in range(n)] if self.build.fit_patches else []
        return [self.clone(SourceList)] + [self.clone(AugmentBatch, batch=b) for b in range(n)] + fits

    def complete(self):
        return not steps.category_problems(self.build, self.lst, self.verify)

    def run(self):
        with self.recorded():
            steps.shards_step(self.build, self.lst, self.progress)


class _BuildRoot(_BuildTask):
    """What BuildCategory and BuildDataset share: the source lists, re-read on every run, and
    the failure threshold."""

    verify = luigi.BoolParameter(
        default=False,
        significant=False,
        description="check every shard's sha256 (default: sizes, and sha256 of shards edited after the build)",
    )
    max_failed_fraction = luigi.FloatParameter(
        default=1.0,
        significant=False,
        description="fail when more than this fraction of a category's models failed "
        "(a category with no model built fails at any value)",
    )

    def category_list(self) -> list[str]:
        raise NotImplementedError

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        validate.check_categories(self.build, self.category_list())
        # under --preset per-category each category's own settings (the root's were checked above)
        for cs in {validate.category_build(self.build, c) for c in self.category_list()} - {self.build}:
            validate.check_settings(cs)
        validate.check_fraction(self.max_failed_fraction)
        validate.check_dataset_dir(self.build, self.category_list())

    def listings(self) -> list[dict]:
        """Each category's model list as the source is now (re-read on every call)."""
        return [current_listing(self.build.for_category(c), c) for c in self.category_list()]

    def requires(self):
        return [self.clone(CategoryShards, category=lst["category"], listing=lst["key"]) for lst in self.listings()]

    def complete(self):
        return steps.manifest_is_current(self.build, self.listings(), self.verify) and not steps.too_many_failures(
            self.build, self.category_list(), self.max_failed_fraction
        )

    def run(self):
        lifetime.die_with_parent()
        steps.manifest_step(self.build)
        over = steps.too_many_failures(self.build, self.category_list(), self.max_failed_fraction)
        if over:
            raise steps.TooManyFailures("; ".join(over))


class BuildCategory(_BuildRoot):
    """One category rebuilt as needed, then manifest.json merged from every category present."""

    category = luigi.Parameter()

    def category_list(self) -> list[str]:
        return [self.category]


class BuildDataset(_BuildRoot):
    """Every category of the source (or --categories a,b,c), and manifest.json."""

    categories = luigi.Parameter(default="", description="comma-separated categories (default: all of the source)")

    def category_list(self) -> list[str]:
        if self.categories:
            return [c.strip() for c in str(self.categories).split(",") if c.strip()]
        from pipeline.sources.layouts import list_categories

        return list_categories(self.source)
