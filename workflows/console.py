"""What a person sees while a dataset builds, for `make dataset` and the `luigi` command alike.

- Luigi's own log goes to ``<work-dir>/luigi.log`` (buffered until the work folder is known).
- One live progress line: models done / total per stage, models per second and ETA, polled from
  the work folder once a second (the stages' record files), so it is right with any number of
  worker processes.
- A failed task prints one line at once (task, category, reason).
- At the end a table per category (built, failed, samples per split) with the first failures and
  their reasons, and a loud last line when anything failed; a bad parameter is one line, no
  traceback.
"""

from __future__ import annotations

import atexit
import logging
import logging.handlers
import sys
import textwrap
import threading
import time
from pathlib import Path
from typing import TextIO

import luigi

from pipeline.build.settings import BuildSettings
from pipeline.core.records import model_dir
from pipeline.core.schema import MANIFEST, RECORD, SPLITS
from pipeline.dataset.manifest import read_manifest
from workflows import steps
from workflows.validate import BuildParameterError

LOG_NAME = "luigi.log"
STAGES = ("prepare", "render", "augment")
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


def stage_counts(s: BuildSettings, listings: list[dict]) -> dict[str, tuple[int, int]]:
    """(done, total) models per stage, and categories for "shards". A finished batch counts whole
    (its upstream failures included); a running one counts the models with a record."""
    out = {}
    for stage in STAGES:
        done = total = 0
        for lst in listings:
            total += len(lst["models"])
            for b in range(steps.n_batches(len(lst["models"]), s.batch_size)):
                models = steps.batch_models(s, lst, b)
                if steps.batch_path(s, stage, lst, b).exists():
                    done += len(models)
                else:
                    done += sum((model_dir(s.stage_dir(stage), lst["category"], m["work_id"]) / RECORD).exists()
                                for m in models)
        out[stage] = (done, total)
    out["shards"] = (sum(not steps.category_problems(s, lst) for lst in listings), len(listings))
    return out


def _clock(seconds: float) -> str:
    seconds = int(seconds)
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}" if seconds >= 3600 \
        else f"{seconds // 60}:{seconds % 60:02d}"


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

    # ---- set-up
    @classmethod
    def install(cls, out: TextIO | None = None) -> "Console":
        """Take over Luigi's console logging and listen to its task events (idempotent)."""
        if cls._instance is not None:
            return cls._instance
        con = cls._instance = cls(out or sys.stdout)
        from luigi.setup_logging import InterfaceLogging

        InterfaceLogging._configured = True  # Luigi must not add its own stderr handler
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
        self.write(f"building {', '.join(root.category_list())} from {s.source} "
                   f"(Luigi log: {self.log_path})", final=True)
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

    def _poll(self) -> None:
        progress = Progress()
        next_plain = 0.0
        while not self.stop.wait(1.0):
            try:
                line = progress.line(stage_counts(self.root.build, self.listings), time.time())
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
                self.write(Progress().line(stage_counts(s, self.listings), time.time()), final=True)
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
        line = ("error: not started: the same build command is already running on this machine (pid above, "
                "Luigi's lock); nothing was built. Wait for it to finish, or add --no-lock to start a second "
                "worker of a build shared through a central scheduler")
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
        lines.append(f"{name:<12} {c['models_built']:>5} {c['models_failed']:>6} "
                     + " ".join(f"{c['splits'][x]['samples']:>5}" for x in SPLITS))
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
