"""Luigi tasks. Thin: parameters, dependencies, targets; each run() is one call into
workflows.steps. Order: SourceList → PrepareBatch → RenderBatch → AugmentBatch (per batch of
models) → CategoryShards → BuildCategory → BuildDataset (manifest.json)."""

from __future__ import annotations

import contextlib
import functools
from pathlib import Path
from typing import Iterator

import luigi

from pipeline.build_settings import BuildSettings
from workflows import steps


class _BuildTask(luigi.Task):
    """Parameters shared by every task of a build (Luigi task ids include them all)."""

    source = luigi.Parameter(default="procedural", description="'procedural' or a ShapeNet / <root>/<category>/ folder")
    models_per_category = luigi.IntParameter(default=16, description="models per category (0 = all)")
    views = luigi.IntParameter(default=4, description="rendered views per model")
    variants = luigi.IntParameter(default=2, description="pencil variants per view")
    image_size = luigi.IntParameter(default=256, description="render size in pixels")
    out_size = luigi.IntParameter(default=128, description="sketch size in pixels")
    seed = luigi.IntParameter(default=0)
    batch_size = luigi.IntParameter(default=16, significant=False, description="models per batch task")
    prepare_settings = luigi.Parameter(default="", description="JSON object of PrepareSettings overrides")
    render_settings = luigi.Parameter(default="", description="JSON object of RenderSettings overrides")
    augment_settings = luigi.Parameter(default="", description="JSON object of AugmentSettings overrides")
    shard_settings = luigi.Parameter(default="", description="JSON object of ShardSettings overrides")
    work_dir = luigi.Parameter(default="data/work")
    dataset_dir = luigi.Parameter(default="data/dataset")

    @property
    def build(self) -> BuildSettings:
        return BuildSettings(
            source=self.source, models_per_category=self.models_per_category, views=self.views,
            variants=self.variants, image_size=self.image_size, out_size=self.out_size, seed=self.seed,
            prepare_overrides=self.prepare_settings, render_overrides=self.render_settings,
            augment_overrides=self.augment_settings, shard_overrides=self.shard_settings,
            work_dir=Path(self.work_dir), dataset_dir=Path(self.dataset_dir), batch_size=self.batch_size)

    @contextlib.contextmanager
    def recorded(self) -> Iterator[None]:
        """Record this run's start and finish under <work>/_runs (see steps.record_run)."""
        steps.record_run(self.build, self.task_id, "start")
        yield
        steps.record_run(self.build, self.task_id, "done")

    def progress(self, done: int, total: int, message: str) -> None:
        """Progress callback handed to the batch functions: shows in Luigi's scheduler UI."""
        self.set_status_message(message)
        self.set_progress_percentage(int(100 * done / max(total, 1)))


class SourceList(_BuildTask):
    category = luigi.Parameter()

    def output(self):
        return luigi.LocalTarget(steps.list_path(self.build, self.category))

    def run(self):
        with self.recorded():
            steps.write_source_list(self.build, self.category)


class PrepareBatch(_BuildTask):
    category = luigi.Parameter()
    batch = luigi.IntParameter()

    def requires(self):
        return self.clone(SourceList)

    def output(self):
        return luigi.LocalTarget(steps.batch_path(self.build, "prepare", self.category, self.batch))

    def run(self):
        with self.recorded():
            steps.prepare_step(self.build, self.category, self.batch, self.progress)


class RenderBatch(_BuildTask):
    category = luigi.Parameter()
    batch = luigi.IntParameter()
    resources = {"blender": 1}
    crash_retries = luigi.IntParameter(default=1, significant=False,
                                       description="re-runs of a batch whose Blender crashed or hung ([RenderBatch] in luigi.cfg)")

    def requires(self):
        return self.clone(PrepareBatch)

    def output(self):
        return luigi.LocalTarget(steps.batch_path(self.build, "render", self.category, self.batch))

    def run(self):
        with self.recorded():
            steps.render_step(self.build, self.category, self.batch, self.progress, self.crash_retries)


class AugmentBatch(_BuildTask):
    category = luigi.Parameter()
    batch = luigi.IntParameter()

    def requires(self):
        return self.clone(RenderBatch)

    def output(self):
        return luigi.LocalTarget(steps.batch_path(self.build, "augment", self.category, self.batch))

    def run(self):
        with self.recorded():
            steps.augment_step(self.build, self.category, self.batch, self.progress)


class CategoryShards(_BuildTask):
    """The category's shards + category.json in the dataset folder, current for these settings."""

    category = luigi.Parameter()

    def requires(self):
        # Batches are static dependencies, counted without opening a mesh: with a central
        # scheduler every worker then knows them and can take any (dynamic ones would be runnable
        # only by the worker that yielded them).
        return [self.clone(SourceList)] + self.batch_tasks(self.expected_models)

    @functools.cached_property
    def expected_models(self) -> int:
        # Luigi calls requires() several times per task; count (list a source folder) once
        return steps.expected_models(self.build, self.category)

    def complete(self):
        return steps.category_is_current(self.build, self.category)

    def batch_tasks(self, n_models: int) -> list[AugmentBatch]:
        """The last batch task of each batch of a category of ``n_models`` models."""
        return [self.clone(AugmentBatch, batch=b) for b in range(steps.n_batches(n_models, self.batch_size))]

    def run(self):
        # The listed count normally equals the expected one; if the source folder changed in
        # between, the missing batches are added here as dynamic dependencies.
        yield self.batch_tasks(len(steps.read_list(self.build, self.category)))
        steps.shards_step(self.build, self.category, self.progress)


class BuildCategory(_BuildTask):
    """One category rebuilt as needed, then manifest.json merged from every category present."""

    category = luigi.Parameter()

    def requires(self):
        return self.clone(CategoryShards)

    def complete(self):
        return steps.manifest_is_current(self.build, [self.category])

    def run(self):
        steps.manifest_step(self.build)


class BuildDataset(_BuildTask):
    """Every category of the source (or --categories a,b,c), and manifest.json."""

    categories = luigi.Parameter(default="", description="comma-separated categories (default: all of the source)")

    def category_list(self) -> list[str]:
        if self.categories:
            return [c.strip() for c in str(self.categories).split(",") if c.strip()]
        from pipeline.sources import list_categories

        return list_categories(self.source)

    def requires(self):
        return [self.clone(BuildCategory, category=c) for c in self.category_list()]

    def complete(self):
        return steps.manifest_is_current(self.build, self.category_list())

    def run(self):
        steps.manifest_step(self.build)
