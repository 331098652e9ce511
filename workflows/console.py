"""What a person sees while a dataset builds, for `make dataset` and the `luigi` command alike.

- Luigi's own log goes to ``<work-dir>/luigi.log`` (buffered until the work folder is known).
- One live progress line: models done / total per stage, models per second and ETA, polled from
  the work folder once a second (batch outcome files, and the records of running batches), so it
  is right with any number of worker processes; a tick's cost does not grow with the number of
  models (StageCounter).
- A failed task prints one line at once (task, category, reason).
- At the end a table per category (built, failed, samples per split) with the first failures and
  their reasons, and a loud last line when anything failed; a bad parameter is one line, no
  traceback.
"""

from __future__ import annotations

import atexit
import logging
import logging.handlers
import os
import sys
import textwrap
import threading
import time
from pathlib import Path
from typing import Callable, TextIO

import luigi

from pipeline.core.records import model_dir
from pipeline.core.schema import FRAGMENT, MANIFEST, RECORD, SPLITS
from pipeline.dataset.manifest import read_manifest
from workflows import steps
from workflows.build_settings import BuildSettings
from workflows.validate import BuildParameterError

LOG_NAME = "luigi.log"
FIRST_FAILURES = 5
WIDTH = 100  # failure lines are wrapped at this width, never cut
# Exit code of the `luigi` command when Luigi's pid lock turns it away ([retcode] already_running
# must stay 0, see luigi.cfg): nothing was built, so it is not a success.
LOCK_REFUSED_EXIT = 45
# "py.warnings": library warnings (e.g. numpy's RuntimeWarning inside trimesh) are log lines
_LUIGI_LOGGERS = ("luigi", "luigi-interface", "luigi.scheduler", "py.warnings")


def wrap(text: str, indent: str = "    ") -> str:
    """``text`` wrapped at WIDTH on spaces only (paths and words stay whole), continuation lines
    indented: a long reason is shown in full."""
    return textwrap.fill(text, WIDTH, subsequent_indent=indent, break_long_words=False, break_on_hyphens=False)


STAGE_TASKS = {"prepare": "PrepareBatch", "render": "RenderBatch", "augment": "AugmentBatch", "fit": "FitBatch"}


# A folder or file looked at less than this long after its last change is looked at again on the
# next tick: a second change within a coarse timestamp (NFS, FAT: up to 2 s) would not move it.
RACY_S = 2.0


def stage_counts(s: BuildSettings, listings: list[dict]) -> dict[str, tuple[int, int]]:
    """(done, total) models per stage, and categories for "shards", counted from scratch (one
    stat per model of an unfinished batch: the reference StageCounter is checked against). A
    finished batch counts whole (its upstream failures included); a running one counts the
    models with a record."""
    out = {}
    builds = steps.category_builds(s, listings)
    for stage in steps.stages_of(builds):
        done = total = 0
        for cs, lst in builds:
            if stage not in steps.batch_stages(cs):
                continue
            root = cs.stage_dir(stage)  # once per stage, not per model: it re-derives the key chain
            total += len(lst["models"])
            for b in range(steps.n_batches(len(lst["models"]), cs.batch_size)):
                models = steps.batch_models(cs, lst, b)
                if (root / lst["category"] / steps.BATCHES / steps.batch_name(cs, lst, b)).exists():
                    done += len(models)
                else:
                    done += sum((model_dir(root, lst["category"], m["work_id"]) / RECORD).exists() for m in models)
        out[stage] = (done, total)
    out["shards"] = (sum(not steps.category_problems(cs, lst) for cs, lst in builds), len(listings))
    return out


def _stamp(path: Path) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return None
    return st.st_ino, st.st_mtime_ns


class _Cached:
    """``read()`` re-run only when one of ``paths`` may have changed: its (inode, mtime) moved,
    or the last read came within RACY_S of its change. A read that raises caches nothing."""

    def __init__(self, paths: tuple[Path, ...], read: Callable[[], object]) -> None:
        self.paths, self.read = paths, read
        self.stamp: tuple | None = None
        self.read_at = 0.0
        self.value: object = None

    def get(self) -> object:
        stamp = tuple(_stamp(p) for p in self.paths)
        newest = max((k[1] for k in stamp if k is not None), default=0) / 1e9
        if self.stamp is not None and stamp == self.stamp and self.read_at - newest >= RACY_S:
            return self.value
        now = time.time()
        self.value = self.read()
        self.stamp, self.read_at = stamp, now
        return self.value


def _names(folder: Path) -> Callable[[], frozenset[str]]:
    def read() -> frozenset[str]:
        try:
            return frozenset(os.listdir(folder))
        except FileNotFoundError:
            return frozenset()

    return read


class _StageBatches:
    """One category's batches in one stage: their outcome files' names, the finished ones, and
    the running ones with the models that have a record so far."""

    def __init__(self, s: BuildSettings, root: Path, lst: dict) -> None:
        self.s, self.root, self.lst = s, root, lst
        n = steps.n_batches(len(lst["models"]), s.batch_size)
        self.index = {steps.batch_name(s, lst, b): b for b in range(n)}
        self.sizes = [len(steps.batch_models(s, lst, b)) for b in range(n)]
        self.names = _Cached((root / lst["category"] / steps.BATCHES,), _names(root / lst["category"] / steps.BATCHES))
        self.finished: set[int] = set()
        self.finished_models = 0
        self.running: dict[int, tuple[list[Path], set[int]]] = {}  # batch -> (record paths, indices found)

    def start(self, batch: int) -> None:
        if batch not in self.finished and batch not in self.running:
            models = steps.batch_models(self.s, self.lst, batch)
            self.running[batch] = (
                [model_dir(self.root, self.lst["category"], m["work_id"]) / RECORD for m in models],
                set(),
            )

    def done(self) -> int:
        names = self.names.get()
        finished = {self.index[n] for n in names if n in self.index}
        if finished != self.finished:  # only when a batch finished: the sum is O(batches)
            self.finished, self.finished_models = finished, sum(self.sizes[b] for b in finished)
        partial = 0
        for b in list(self.running):
            paths, found = self.running[b]
            if b in finished:
                del self.running[b]
                continue
            # a record, once written, stays: stat only the models still without one
            found.update(i for i, p in enumerate(paths) if i not in found and p.exists())
            partial += len(found)
        return self.finished_models + partial


class StageCounter:
    """stage_counts(), kept up to date at a cost per tick that does not grow with the models.

    Paths are derived once. A tick stats each category's ``_batches`` folder per stage and
    re-lists it only when it changed; the running batches are the ones whose Luigi task has a
    ``<work>/_runs/<task id>/`` entry (written at its start by any worker, on any machine sharing
    the work folder) and no outcome file yet; only their models' records are looked at. So
    records of a batch that no task of this build's settings started are not counted until the
    batch finishes. Shards: a category is re-checked only when its folder or category.json changed.
    """

    def __init__(self, s: BuildSettings, listings: list[dict], task_ids: dict[str, tuple[str, str, int]]) -> None:
        self.s, self.listings, self.task_ids = s, listings, task_ids
        builds = steps.category_builds(s, listings)
        self.stages = {
            stage: {
                lst["category"]: _StageBatches(cs, cs.stage_dir(stage), lst)
                for cs, lst in builds
                if stage in steps.batch_stages(cs)
            }
            for stage in steps.stages_of(builds)
        }
        self.totals = {
            stage: sum(len(b.lst["models"]) for b in by_cat.values()) for stage, by_cat in self.stages.items()
        }
        runs = Path(s.work_dir) / steps.RUNS
        self.runs = _Cached((runs,), _names(runs))
        self.runs_seen: frozenset[str] = frozenset()
        self.shards = [self._shards_current(cs, lst) for cs, lst in builds]

    def _shards_current(self, cs: BuildSettings, lst: dict) -> _Cached:
        cat = Path(cs.dataset_dir) / lst["category"]
        return _Cached((cat, cat / FRAGMENT), lambda: not steps.category_problems(cs, lst))

    def counts(self) -> dict[str, tuple[int, int]]:
        runs = self.runs.get()
        for task_id in runs - self.runs_seen:  # tasks started since the last tick
            if task_id in self.task_ids:
                stage, category, batch = self.task_ids[task_id]
                self.stages[stage][category].start(batch)
        self.runs_seen = runs
        out = {
            stage: (sum(b.done() for b in by_cat.values()), self.totals[stage]) for stage, by_cat in self.stages.items()
        }
        out["shards"] = (sum(bool(c.get()) for c in self.shards), len(self.listings))
        return out


def batch_task_ids(root: luigi.Task, listings: list[dict]) -> dict[str, tuple[str, str, int]]:
    """Luigi task id -> (stage, category, batch) of every batch task under ``root``, computed the
    way Luigi names a task (one task instance made per stage and category, not per batch)."""
    from luigi.task import task_id_str

    from workflows import tasks

    out = {}
    for lst in listings:
        shards = root.clone(tasks.CategoryShards, category=lst["category"], listing=lst["key"])
        for stage in steps.batch_stages(shards.build):
            cls = getattr(tasks, STAGE_TASKS[stage])
            params = shards.clone(cls, batch=0).to_str_params(only_significant=True, only_public=True)
            for b in range(steps.n_batches(len(lst["models"]), root.build.batch_size)):
                out[task_id_str(cls.get_task_family(), {**params, "batch": str(b)})] = (stage, lst["category"], b)
    return out


def _clock(seconds: float) -> str:
    seconds = int(seconds)
    return (
        f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"
        if seconds >= 3600
        else f"{seconds // 60}:{seconds % 60:02d}"
    )


class Progress:
    """The live line. ``line(counts, now)`` is pure given the history it keeps (testable)."""

    def __init__(self) -> None:
        self.first: dict[str, tuple[float, int]] = {}  # stage -> (time, done) when it first moved

    def line(self, counts: dict[str, tuple[int, int]], now: float) -> str:
        parts = []
        for stage, (done, total) in counts.items():
            text = f"{stage} {done}/{total}"
            start = self.first.setdefault(stage, (now, done))
            if stage != "shards" and done > start[1] and done < total and now > start[0]:
                rate = (done - start[1]) / (now - start[0])
                text += f" {rate:.2f}/s ETA {_clock((total - done) / rate)}"
            elif start[1] == done and done < total:
                self.first[stage] = (now, done)  # not moving yet: the rate starts when it moves
            parts.append(text)
        return " | ".join(parts)


class Console:
    """Install once per process with ``Console.install()``; attach a build with ``watch()``."""

    _instance: "Console | None" = None

    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.tty = out.isatty()
        self.buffer = logging.handlers.MemoryHandler(capacity=100000, flushLevel=logging.CRITICAL + 1)
        self.log_path: Path | None = None
        self.root: luigi.Task | None = None
        self.listings: list[dict] = []
        self.stop = threading.Event()
        self.thread: threading.Thread | None = None
        self.last = ""
        self.lock = threading.Lock()
        self.failures: list[str] = []
        self.counter: StageCounter | None = None
        self.count_lock = threading.Lock()

    # ---- set-up
    @classmethod
    def install(cls, out: TextIO | None = None) -> "Console":
        """Take over Luigi's console logging and listen to its task events (idempotent)."""
        if cls._instance is not None:
            return cls._instance
        con = cls._instance = cls(out or sys.stdout)
        # Luigi must not add its own stderr handler: its documented switch, [core] no_configure_logging
        luigi.configuration.get_config().set("core", "no_configure_logging", "true")
        logging.captureWarnings(True)  # warnings.warn(...) -> the "py.warnings" logger -> luigi.log
        for name in _LUIGI_LOGGERS:
            lg = logging.getLogger(name)
            lg.setLevel(logging.INFO)
            lg.propagate = False
            lg.addHandler(con.buffer)
            lg.addHandler(_ErrorLine(con))
        for event in (luigi.Event.DEPENDENCY_PRESENT, luigi.Event.DEPENDENCY_DISCOVERED):
            luigi.Task.event_handler(event)(con._seen)  # the root is the first task they name
        luigi.Task.event_handler(luigi.Event.FAILURE)(con._failed)
        atexit.register(con._unclaimed)
        _refuse_loudly(con)
        return con

    def _unclaimed(self) -> None:
        """No build root ran (e.g. `luigi --module workflows SourceList ...`): Luigi's log to stderr."""
        if self.log_path is None and self.buffer.buffer and not self.failures:
            self.buffer.setTarget(logging.StreamHandler(sys.stderr))
            self.buffer.flush()

    def _seen(self, task: luigi.Task, *dependency) -> None:
        from workflows.tasks import _BuildRoot

        if self.root is None and isinstance(task, _BuildRoot):
            self.watch(task)
            atexit.register(self.finish)  # the `luigi` command: summary after Luigi's last word

    def watch(self, root: luigi.Task) -> None:
        """Log to the root's work folder and start the progress line."""
        self.root = root
        s = root.build
        self.log_path = Path(s.work_dir) / LOG_NAME
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        handler = logging.FileHandler(self.log_path)
        handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s: %(message)s"))
        self.buffer.setTarget(handler)
        self.buffer.flush()
        self.buffer.flushLevel = logging.DEBUG  # from now on every record goes straight through
        self.listings = root.listings()
        self.counter = None
        self.write(
            f"building {', '.join(root.category_list())} from {s.source} (Luigi log: {self.log_path})", final=True
        )
        self.thread = threading.Thread(target=self._poll, daemon=True)
        self.thread.start()

    # ---- output
    def write(self, text: str, final: bool) -> None:
        """A progress line (rewritten in place on a terminal) or a final line."""
        with self.lock:
            if self.tty:
                self.out.write("\r\033[K" + text + ("\n" if final else ""))
            elif final or text != self.last:
                self.out.write(text + "\n")
            self.out.flush()
            self.last = text

    def _counts(self) -> dict[str, tuple[int, int]]:
        with self.count_lock:  # finish() may count while a slow tick is still running
            if self.counter is None:  # the first tick: paths derived and batches counted once
                self.counter = StageCounter(self.root.build, self.listings, batch_task_ids(self.root, self.listings))
            return self.counter.counts()

    def _poll(self) -> None:
        progress = Progress()
        next_plain = 0.0
        while not self.stop.wait(1.0):
            try:
                line = progress.line(self._counts(), time.time())
            except (OSError, ValueError):
                continue  # a file replaced while being read: next tick
            if self.tty or time.time() >= next_plain:  # a log file gets a line every 15 s
                self.write(line, final=False)
                next_plain = time.time() + 15

    def _failed(self, task: luigi.Task, exc: BaseException) -> None:
        where = getattr(task, "category", None) or ""
        line = f"FAILED {task.get_task_family()}{f' {where}' if where else ''}: {type(exc).__name__}: {exc}"
        self.failures.append(line)
        self.write(wrap(line), final=True)

    def finish(self) -> bool:
        """Stop the progress line, print the summary; True if the build is complete and clean."""
        if self.root is None:
            return False
        self.stop.set()
        if self.thread is not None:
            self.thread.join(timeout=5)
        s = self.root.build
        if self.thread is not None and self.listings:
            try:
                self.write(Progress().line(self._counts(), time.time()), final=True)
            except (OSError, ValueError):
                pass
        complete = self.root.complete()
        self.write(summary(s, self.root.category_list()), final=True)
        if not complete:
            self.write(f"BUILD FAILED: see the FAILED lines above and {self.log_path}", final=True)
        self.root = None
        return complete


def _refuse_loudly(con: Console) -> None:
    """Luigi's pid lock (the `luigi` command without --no-lock) prints "Pid(s) {...} already
    running" and exits with [retcode] already_running, 0 here; say what happened and exit
    LOCK_REFUSED_EXIT instead. luigi.interface looks the function up on each call."""
    import luigi.lock

    acquire = luigi.lock.acquire_for

    def acquire_for(pid_dir: str, num_available: int = 1, kill_signal=None) -> bool:
        if acquire(pid_dir, num_available, kill_signal):
            return True
        line = (
            "error: not started: the same build command is already running on this machine (pid above, "
            "Luigi's lock); nothing was built. Wait for it to finish, or add --no-lock to start a second "
            "worker of a build shared through a central scheduler"
        )
        con.failures.append(line)
        con.write(wrap(line), final=True)
        raise SystemExit(LOCK_REFUSED_EXIT)

    luigi.lock.acquire_for = acquire_for


class _ErrorLine(logging.Handler):
    """Luigi logs an exception raised while making the root task (a bad parameter) or scheduling;
    show it as one line on the console, the traceback stays in the log."""

    def __init__(self, console: Console) -> None:
        super().__init__(logging.ERROR)
        self.console = console

    def emit(self, record: logging.LogRecord) -> None:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, BuildParameterError):
            line = f"error: {exc}"
        elif exc is not None and record.name == "luigi-interface" and "Uncaught" in record.getMessage():
            line = f"error: {type(exc).__name__}: {exc}"
        else:
            return
        self.console.failures.append(line)
        self.console.write(line, final=True)


def summary(s: BuildSettings, categories: list[str]) -> str:
    """Counts per category and split, the first failures with reasons, and totals."""
    ds = Path(s.dataset_dir)
    try:
        m = read_manifest(ds)
    except (OSError, ValueError):
        return f"no manifest.json in {ds.resolve()}"
    head = f"{'category':<12} {'built':>5} {'failed':>6} " + " ".join(f"{x:>5}" for x in SPLITS)
    lines = [f"dataset: {ds.resolve()}", head]
    built = failed = 0
    for name in categories:
        c = m["categories"].get(name)
        if c is None:
            lines.append(f"{name:<12} not built")
            continue
        built += c["models_built"]
        failed += c["models_failed"]
        lines.append(
            f"{name:<12} {c['models_built']:>5} {c['models_failed']:>6} "
            + " ".join(f"{c['splits'][x]['samples']:>5}" for x in SPLITS)
        )
    for name in categories:
        c = m["categories"].get(name) or {"failed": []}
        for f in c["failed"][:FIRST_FAILURES]:
            lines.append(wrap(f"  failed {name}/{f['model_id']} at {f['stage']}: {f['reason']}", "      "))
        if len(c["failed"]) > FIRST_FAILURES:
            lines.append(f"  ... and {len(c['failed']) - FIRST_FAILURES} more failures of {name} (category.json)")
    lines.append(f"manifest: {(ds / MANIFEST).resolve()} (checksum {m['checksum'][:16]})")
    if failed:
        lines.append(f"{failed} of {built + failed} models FAILED and are not in the dataset (reasons above)")
    return "\n".join(lines)
