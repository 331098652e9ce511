"""The progress line's counts at scale (workflows.console.StageCounter): the same numbers as a
full recount in every state of a build (fresh, running, resumed), and a tick whose file-system
calls do not grow with the number of models. Behaviour only: calls are counted, never timed."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from pipeline.core.atomic import write_json
from pipeline.core.records import model_dir, write_ok
from workflows import console, steps
from workflows.build_settings import BuildSettings
from workflows.console import StageCounter, batch_task_ids, stage_counts
from workflows.tasks import BuildDataset, CategoryShards, FitBatch, PrepareBatch, RenderBatch

CATEGORIES = "mug,knife"


def _root(tmp_path: Path, models: int, batch_size: int = 4, **kw) -> BuildDataset:
    return BuildDataset(
        categories=CATEGORIES,
        models_per_category=models,
        batch_size=batch_size,
        work_dir=str(tmp_path / "work"),
        dataset_dir=str(tmp_path / "ds"),
        **kw,
    )


def _finish(s: BuildSettings, stage: str, lst: dict, batch: int) -> None:
    write_json(steps.batch_path(s, stage, lst, batch), {"stage": stage, "models": []})


def _record(s: BuildSettings, stage: str, lst: dict, m: dict) -> None:
    write_ok(model_dir(s.stage_dir(stage), lst["category"], m["work_id"]))


def _task(root: BuildDataset, lst: dict, family: type, batch: int):
    return root.clone(CategoryShards, category=lst["category"], listing=lst["key"]).clone(family, batch=batch)


@pytest.fixture(autouse=True)
def _no_racy_rereads(monkeypatch: pytest.MonkeyPatch) -> None:
    # files written by a test are seconds old at most: without this every tick would re-read them
    monkeypatch.setattr(console, "RACY_S", 0.0)


def test_task_ids_are_luigis(tmp_path: Path) -> None:
    root = _root(tmp_path, 10)
    listings = root.listings()
    ids = batch_task_ids(root, listings)
    assert len(ids) == 3 * 2 * 3  # 3 stages x 2 categories x 3 batches of 4, 4, 2
    for lst in listings:
        for family, stage in ((PrepareBatch, "prepare"), (RenderBatch, "render")):
            assert ids[_task(root, lst, family, 2).task_id] == (stage, lst["category"], 2)


def test_counts_match_a_full_recount_through_a_build(tmp_path: Path) -> None:
    root = _root(tmp_path, 10)
    s, listings = root.build, root.listings()
    counter = StageCounter(s, listings, batch_task_ids(root, listings))
    assert (
        counter.counts()
        == stage_counts(s, listings)
        == {"prepare": (0, 20), "render": (0, 20), "augment": (0, 20), "shards": (0, 2)}
    )
    mug, knife = listings
    _finish(s, "prepare", mug, 0)
    _finish(s, "prepare", knife, 2)  # the short last batch: 2 models
    steps.record_run(s, _task(root, mug, RenderBatch, 0).task_id, "start")  # running, 3 of 4 done
    for m in steps.batch_models(s, mug, 0)[:3]:
        _record(s, "render", mug, m)
    assert counter.counts() == stage_counts(s, listings)
    assert counter.counts()["prepare"] == (6, 20) and counter.counts()["render"] == (3, 20)
    _record(s, "render", mug, steps.batch_models(s, mug, 0)[3])
    _finish(s, "render", mug, 0)  # finished: counts whole, no longer looked at as running
    assert counter.counts() == stage_counts(s, listings)
    assert counter.counts()["render"] == (4, 20)
    assert not counter.stages["render"]["mug"].running
    # a resumed build: a new counter finds the finished batches and the one a killed run left
    steps.record_run(s, _task(root, knife, PrepareBatch, 0).task_id, "start")
    _record(s, "prepare", knife, steps.batch_models(s, knife, 0)[0])
    fresh = StageCounter(s, listings, batch_task_ids(root, listings))
    assert fresh.counts() == counter.counts() == stage_counts(s, listings)
    assert fresh.counts()["prepare"] == (7, 20)


def test_a_build_with_the_fit_stage_counts_it(tmp_path: Path) -> None:
    root = _root(tmp_path, 10, fit_patches=True)
    s, listings = root.build, root.listings()
    ids = batch_task_ids(root, listings)
    assert len(ids) == 4 * 2 * 3
    mug = listings[0]
    assert ids[_task(root, mug, FitBatch, 1).task_id] == ("fit", "mug", 1)
    counter = StageCounter(s, listings, ids)
    assert list(counter.counts()) == ["prepare", "render", "augment", "fit", "shards"]
    _finish(s, "fit", mug, 0)
    assert counter.counts() == stage_counts(s, listings)
    assert counter.counts()["fit"] == (4, 20)


def _calls(monkeypatch: pytest.MonkeyPatch, counter: StageCounter) -> dict[str, int]:
    """File-system and settings calls of one tick."""
    calls = {"stat": 0, "listdir": 0, "stage_dir": 0, "category_problems": 0}
    stat, listdir, stage_dir, problems = os.stat, os.listdir, BuildSettings.stage_dir, steps.category_problems

    def count(name, fn):
        def wrapped(*a, **k):
            calls[name] += 1
            return fn(*a, **k)

        return wrapped

    with monkeypatch.context() as m:
        m.setattr(os, "stat", count("stat", stat))
        m.setattr(os, "listdir", count("listdir", listdir))
        m.setattr(BuildSettings, "stage_dir", count("stage_dir", stage_dir))
        m.setattr(steps, "category_problems", count("category_problems", problems))
        counter.counts()
    return calls


@pytest.mark.parametrize("started", [False, True])
def test_a_tick_costs_the_same_for_40_and_4000_models(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, started: bool
) -> None:
    ticks = []
    for models in (40, 4000):
        root = _root(tmp_path / str(models), models)
        s, listings = root.build, root.listings()
        for b in range(0, steps.n_batches(models, s.batch_size), 2):  # every other batch finished
            _finish(s, "prepare", listings[0], b)
        if started:
            steps.record_run(s, _task(root, listings[0], PrepareBatch, 1).task_id, "start")
        counter = StageCounter(s, listings, batch_task_ids(root, listings))
        first = counter.counts()
        assert first == stage_counts(s, listings)
        ticks.append(_calls(monkeypatch, counter))
    small, large = ticks
    assert small == large
    # nothing changed: one stat per watched folder/file and per running model, nothing re-read
    assert large == {
        "stat": 1 + 3 * 2 + 2 * 2 + (4 if started else 0),
        "listdir": 0,
        "stage_dir": 0,
        "category_problems": 0,
    }


def test_a_finished_batch_re_lists_only_its_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    root = _root(tmp_path, 400)
    s, listings = root.build, root.listings()
    counter = StageCounter(s, listings, batch_task_ids(root, listings))
    counter.counts()
    _finish(s, "augment", listings[1], 7)
    calls = _calls(monkeypatch, counter)
    assert calls["listdir"] == 1 and calls["stage_dir"] == 0
    assert counter.counts()["augment"] == (4, 800)


def test_a_change_within_a_coarse_timestamp_is_seen(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A folder read right after it changed is read again on the next tick, even when its mtime
    did not move (a file system with 1 s or 2 s timestamps)."""
    monkeypatch.setattr(console, "RACY_S", 3600.0)
    root = _root(tmp_path, 40)
    s, listings = root.build, root.listings()
    counter = StageCounter(s, listings, batch_task_ids(root, listings))
    _finish(s, "prepare", listings[0], 0)
    counter.counts()
    folder = steps.batch_path(s, "prepare", listings[0], 0).parent
    st = os.stat(folder)
    _finish(s, "prepare", listings[0], 1)
    os.utime(folder, ns=(st.st_atime_ns, st.st_mtime_ns))  # the second file left the mtime as it was
    assert counter.counts()["prepare"] == (8, 80)


def test_shards_are_re_checked_when_the_category_folder_changes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    root = _root(tmp_path, 8)
    s, listings = root.build, root.listings()
    counter = StageCounter(s, listings, batch_task_ids(root, listings))
    assert counter.counts()["shards"] == (0, 2)
    (Path(s.dataset_dir) / "mug").mkdir(parents=True)
    calls = _calls(monkeypatch, counter)
    assert calls["category_problems"] == 1  # mug's folder appeared; knife's unchanged


def test_console_prints_the_counters_line(tmp_path: Path) -> None:
    import io

    root = _root(tmp_path, 10)
    s, listings = root.build, root.listings()
    _finish(s, "prepare", listings[0], 1)
    out = io.StringIO()
    con = console.Console(out)
    con.watch(root)
    con.finish()
    assert "prepare 4/20 | render 0/20 | augment 0/20 | shards 0/2" in out.getvalue()
