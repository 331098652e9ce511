"""Trust at the borders (issue 31): the build never deletes what it did not write, a category the
source lost leaves the manifest, a folder in a shard's place is repaired or named, two builds on
one dataset folder do not wreck each other, killing the build kills its workers, and a build that
built nothing fails loudly.

Shard-level cases use synthetic stage folders (no renderer); build-level ones use the embree
backend at tiny settings, or only broken meshes (no renderer at all).
"""

from __future__ import annotations

import contextlib
import io
import json
import multiprocessing
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import luigi
import pytest
import trimesh

sys.path.insert(0, str(Path(__file__).parent))
from test_shards import make_model_dirs  # noqa: E402

from pipeline.core.atomic import write_json  # noqa: E402
from pipeline.dataset.manifest import read_manifest  # noqa: E402
from pipeline.dataset.shards import (
    LOCK_FILE,
    OWNED_FILE,
    CategoryBusy,
    NotOurFiles,
    ShardSettings,  # noqa: E402
    category_lock,
    list_shards,
    retire_category,
    write_category_shards,
)
from pipeline.dataset.verify import verify_dataset  # noqa: E402
from workflows import BuildDataset  # noqa: E402
from workflows.build_settings import BuildSettings  # noqa: E402
from workflows.console import WIDTH, Console, summary  # noqa: E402
from workflows.lifetime import die_with_parent  # noqa: E402
from workflows.steps import gone_categories, too_many_failures  # noqa: E402
from workflows.validate import BuildParameterError  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
LUIGI = [str(ROOT / ".venv" / "bin" / "luigi"), "--module", "workflows", "BuildDataset", "--local-scheduler"]
EMBREE = '{"backend": "embree"}'
TINY = dict(
    models_per_category=0, views=1, variants=1, image_size=64, out_size=64, batch_size=2, render_settings=EMBREE
)
ST = ShardSettings(max_samples_per_shard=2)


def box(path: Path, extents: tuple[float, float, float]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=extents).export(str(path))


def run_build(src: Path, root: Path, **kw) -> bool:
    task = BuildDataset(source=str(src), work_dir=str(root / "work"), dataset_dir=str(root / "ds"), **{**TINY, **kw})
    return luigi.build([task], local_scheduler=True, workers=1, log_level="WARNING")


def models(tmp: Path, n: int = 6) -> list:
    return [make_model_dirs(tmp / "stages", "mug", f"{i:05d}", views=1, variants=1) for i in range(n)]


def files(d: Path) -> dict[str, bytes]:
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


# ---------------------------------------------------------------- 4: never delete what the build did not write


@pytest.mark.parametrize("name", ["test-00007.tar", "train-00000.tar"], ids=["beside-ours", "in-our-place"])
def test_users_shard_named_file_stops_the_write_untouched(tmp_path: Path, name: str) -> None:
    cat = tmp_path / "ds" / "mug"
    cat.mkdir(parents=True)
    (cat / name).write_bytes(b"the user's own tar")
    with pytest.raises(NotOurFiles) as err:
        write_category_shards("mug", models(tmp_path), cat, ST, 0, "h")
    msg = str(err.value)
    assert f"{name}: a file" in msg and "move it away or choose another --dataset-dir" in msg and "\n" not in msg
    assert sorted(p.name for p in cat.iterdir()) == [name]  # nothing written, no staging, no lock left
    assert (cat / name).read_bytes() == b"the user's own tar"


def test_users_link_named_like_a_shard_is_named(tmp_path: Path) -> None:
    cat = tmp_path / "ds" / "mug"
    cat.mkdir(parents=True)
    (tmp_path / "elsewhere.tar").write_bytes(b"x")
    (cat / "val-00000.tar").symlink_to(tmp_path / "elsewhere.tar")
    with pytest.raises(NotOurFiles, match=r"val-00000.tar: a link"):
        write_category_shards("mug", models(tmp_path), cat, ST, 0, "h")
    assert (tmp_path / "elsewhere.tar").read_bytes() == b"x" and (cat / "val-00000.tar").is_symlink()


@pytest.mark.parametrize("record", [OWNED_FILE, "category.json", "manifest.json"])
def test_shards_any_one_record_lists_are_replaced_and_removed(tmp_path: Path, record: str) -> None:
    """Our marker, category.json or manifest.json: any one that survives vouches for the names."""
    cat = tmp_path / "ds" / "mug"
    first = write_category_shards("mug", models(tmp_path), cat, ST, 0, "h")
    listed = {"splits": {s: {"shards": [i.to_json() for i in infos]} for s, infos in first.shards.items()}}
    (cat / OWNED_FILE).unlink()
    if record == OWNED_FILE:
        write_json(cat / OWNED_FILE, {"shards": [p.name for p in list_shards(cat)]})
    elif record == "category.json":
        write_json(cat / "category.json", {"category": "mug", **listed})
    else:
        write_json(tmp_path / "ds" / "manifest.json", {"categories": {"mug": listed}})
    for p in list_shards(cat):
        p.write_bytes(b"damaged")  # listed, so ours to repair whatever its bytes
    again = write_category_shards("mug", models(tmp_path)[:1], cat, ST, 0, "h")
    names = [i.name for infos in again.shards.values() for i in infos]
    assert [p.name for p in list_shards(cat)] == names and len(names) == 1
    assert sorted(again.removed) == sorted(set(i.name for infos in first.shards.values() for i in infos) - set(names))
    assert json.loads((cat / OWNED_FILE).read_text()) == {"shards": names}


def test_marker_is_deterministic_and_nothing_else_is_left(tmp_path: Path) -> None:
    a = write_category_shards("mug", models(tmp_path), tmp_path / "a" / "mug", ST, 0, "h")
    write_category_shards("mug", models(tmp_path), tmp_path / "b" / "mug", ST, 0, "h")
    assert files(tmp_path / "a") == files(tmp_path / "b")
    names = sorted(i.name for infos in a.shards.values() for i in infos)
    assert sorted(p.name for p in (tmp_path / "a" / "mug").iterdir()) == sorted(names + [OWNED_FILE])


def test_validation_names_users_file_before_anything_runs(tmp_path: Path) -> None:
    box(tmp_path / "src" / "mug" / "a.obj", (1, 1, 1))
    (tmp_path / "ds" / "mug").mkdir(parents=True)
    (tmp_path / "ds" / "mug" / "test-00007.tar").write_bytes(b"mine")
    with pytest.raises(BuildParameterError) as err:
        run_build(tmp_path / "src", tmp_path)
    assert "mug holds test-00007.tar: a file; not written by this build" in str(err.value)
    assert not (tmp_path / "work").exists()
    assert (tmp_path / "ds" / "mug" / "test-00007.tar").read_bytes() == b"mine"


# ---------------------------------------------------------------- 6: a folder where a shard belongs


def test_empty_folder_in_a_shards_place_is_replaced(tmp_path: Path) -> None:
    cat = tmp_path / "ds" / "mug"
    first = write_category_shards("mug", models(tmp_path), cat, ST, 0, "h")
    victim = cat / first.shards["train"][0].name
    victim.unlink()
    victim.mkdir()
    (cat / "test-00009.tar").mkdir()  # unlisted and empty: holds nothing, goes
    again = write_category_shards("mug", models(tmp_path), cat, ST, 0, "h")
    assert victim.is_file() and victim.name in again.written
    assert not (cat / "test-00009.tar").exists() and "test-00009.tar" in again.removed


def test_folder_with_files_in_a_shards_place_is_named(tmp_path: Path) -> None:
    cat = tmp_path / "ds" / "mug"
    first = write_category_shards("mug", models(tmp_path), cat, ST, 0, "h")
    victim = cat / first.shards["train"][0].name
    victim.unlink()
    victim.mkdir()
    (victim / "notes.txt").write_text("keep me")
    with pytest.raises(NotOurFiles, match=rf"{victim.name}: a folder with files in it"):
        write_category_shards("mug", models(tmp_path), cat, ST, 0, "h")
    assert (victim / "notes.txt").read_text() == "keep me"


# ---------------------------------------------------------------- 8: two writers of one category folder


def _write_in_child(root: str, n: int, out: "multiprocessing.Queue") -> None:
    try:
        for _ in range(n):
            write_category_shards("mug", models(Path(root)), Path(root) / "ds" / "mug", ST, 0, "h", lock_wait_s=60)
        out.put("ok")
    except Exception as exc:  # reported to the test, which names it
        out.put(f"{type(exc).__name__}: {exc}")


def test_two_processes_writing_one_category_both_succeed(tmp_path: Path) -> None:
    models(tmp_path)  # the stage folders, once
    ctx = multiprocessing.get_context("fork")
    q = ctx.Queue()
    procs = [ctx.Process(target=_write_in_child, args=(str(tmp_path), 5, q)) for _ in range(2)]
    for p in procs:
        p.start()
    results = [q.get(timeout=120) for _ in procs]
    for p in procs:
        p.join(timeout=30)
    assert results == ["ok", "ok"]
    write_category_shards("mug", models(tmp_path), tmp_path / "alone" / "mug", ST, 0, "h")
    assert files(tmp_path / "ds" / "mug") == files(tmp_path / "alone" / "mug")  # no staging, no lock left


def _hold_lock(cat: str, ready: "multiprocessing.Event", release: "multiprocessing.Event") -> None:
    """Hold the category lock with a staging folder in use, as a writing build does."""
    with category_lock(Path(cat)):
        staging = Path(cat) / f".staging-{socket.gethostname()}-{os.getpid()}-abcd1234"
        staging.mkdir()
        (staging / "train-00000.tar").write_bytes(b"half written")
        ready.set()
        release.wait(60)


def test_busy_category_names_the_other_writer(tmp_path: Path) -> None:
    cat = tmp_path / "ds" / "mug"
    cat.mkdir(parents=True)
    ctx = multiprocessing.get_context("fork")
    ready, release = ctx.Event(), ctx.Event()
    holder = ctx.Process(target=_hold_lock, args=(str(cat), ready, release))
    holder.start()
    try:
        assert ready.wait(30)
        with pytest.raises(CategoryBusy, match=rf"another build is writing .*mug \(pid {holder.pid} on .+\)"):
            write_category_shards("mug", models(tmp_path), cat, ST, 0, "h", lock_wait_s=0.5)
        assert not list_shards(cat)
        staging = cat / f".staging-{socket.gethostname()}-{holder.pid}-abcd1234"
        assert (staging / "train-00000.tar").read_bytes() == b"half written"  # the other build's, untouched
    finally:
        release.set()
        holder.join(timeout=30)
    assert not (cat / LOCK_FILE).exists()
    assert write_category_shards("mug", models(tmp_path), cat, ST, 0, "h", lock_wait_s=0.5).written


def test_lock_of_a_killed_holder_does_not_block(tmp_path: Path) -> None:
    cat = tmp_path / "ds" / "mug"
    cat.mkdir(parents=True)
    ctx = multiprocessing.get_context("fork")
    ready, release = ctx.Event(), ctx.Event()
    holder = ctx.Process(target=_hold_lock, args=(str(cat), ready, release))
    holder.start()
    assert ready.wait(30)
    os.kill(holder.pid, signal.SIGKILL)
    holder.join(timeout=30)
    assert (cat / LOCK_FILE).exists()  # left behind by the kill, but no longer locked
    assert write_category_shards("mug", models(tmp_path), cat, ST, 0, "h", lock_wait_s=0.5).written


def test_stale_staging_goes_other_dot_folders_stay(tmp_path: Path) -> None:
    cat = tmp_path / "ds" / "mug"
    (cat / ".staging-somehost-99999999-abcd1234").mkdir(parents=True)  # a killed run's
    (cat / ".staging-abcd_123").mkdir()  # an older build's name
    (cat / ".staging-notes").mkdir()  # not a name we give
    write_category_shards("mug", models(tmp_path), cat, ST, 0, "h")
    assert sorted(p.name for p in cat.iterdir() if p.name.startswith(".staging")) == [".staging-notes"]


# ---------------------------------------------------------------- 5: a category the source lost


def test_retire_removes_only_what_our_records_list(tmp_path: Path) -> None:
    cat = tmp_path / "ds" / "mug"
    write_category_shards("mug", models(tmp_path), cat, ST, 0, "h")
    write_json(cat / "category.json", {"category": "mug"})
    (cat / "notes.txt").write_text("mine")
    assert retire_category(cat) == ["notes.txt"]
    assert sorted(p.name for p in cat.iterdir()) == ["notes.txt"]
    (cat / "notes.txt").unlink()
    other = tmp_path / "ds" / "car"
    write_category_shards("car", models(tmp_path), other, ST, 0, "h")
    assert retire_category(other) == [] and not other.exists()


@pytest.fixture(scope="module")
def renamed(tmp_path_factory) -> dict:
    """A folder of mug + knife built, then knife renamed to blade and rebuilt; knife's folder in
    the dataset also holds a file of the user's."""
    root = tmp_path_factory.mktemp("renamed")
    src = root / "src"
    box(src / "mug" / "a.obj", (1.0, 0.6, 0.4))
    box(src / "knife" / "b.obj", (1.5, 0.2, 0.05))
    assert run_build(src, root)
    before = read_manifest(root / "ds")
    (root / "ds" / "knife" / "notes.txt").write_text("the user's")
    (src / "knife").rename(src / "blade")
    assert run_build(src, root)
    return {"root": root, "src": src, "before": before}


def test_renamed_category_leaves_manifest_and_totals(renamed: dict, tmp_path: Path) -> None:
    ds = renamed["root"] / "ds"
    assert sorted(renamed["before"]["categories"]) == ["knife", "mug"]
    m = read_manifest(ds)
    assert sorted(m["categories"]) == ["blade", "mug"] and m["totals"]["categories"] == 2
    assert m["totals"]["models_built"] == 2
    assert sorted(p.name for p in (ds / "knife").iterdir()) == ["notes.txt"]  # ours gone, the user's kept
    assert verify_dataset(ds) == []
    assert run_build(renamed["src"], tmp_path)  # a clean build of the renamed folder
    assert (tmp_path / "ds" / "manifest.json").read_bytes() == (ds / "manifest.json").read_bytes()


def test_removed_category_leaves_manifest_and_totals(renamed: dict) -> None:
    root, src, ds = renamed["root"], renamed["src"], renamed["root"] / "ds"
    shutil.rmtree(src / "blade")
    assert run_build(src, root)
    m = read_manifest(ds)
    assert list(m["categories"]) == ["mug"] and m["totals"]["categories"] == 1 and m["totals"]["models_built"] == 1
    assert not (ds / "blade").exists() and verify_dataset(ds) == []


def test_other_sources_categories_are_kept(tmp_path: Path) -> None:
    """Only categories built from this source (same source name) are retired."""
    box(tmp_path / "src" / "mug" / "a.obj", (1, 1, 1))
    frag_dir = tmp_path / "ds" / "knife"
    frag_dir.mkdir(parents=True)
    s = BuildSettings(source=str(tmp_path / "src"), work_dir=tmp_path / "work", dataset_dir=tmp_path / "ds")
    write_json(frag_dir / "category.json", {"category": "knife", "settings": {"source": "elsewhere"}})
    assert gone_categories(s) == []
    write_json(frag_dir / "category.json", {"category": "knife", "settings": {"source": "src"}})
    assert gone_categories(s) == ["knife"]


# ---------------------------------------------------------------- 9: a build that built nothing fails


@pytest.fixture(scope="module")
def all_broken(tmp_path_factory) -> dict:
    """The `luigi` command on a folder whose every mesh is broken (no renderer runs)."""
    root = tmp_path_factory.mktemp("broken")
    src = root / "src" / "mug"
    src.mkdir(parents=True)
    (src / "cut.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    (src / "empty.obj").write_bytes(b"")
    cmd = LUIGI + [
        "--source",
        str(root / "src"),
        "--models-per-category",
        "0",
        "--work-dir",
        str(root / "work"),
        "--dataset-dir",
        str(root / "ds"),
    ]
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    return {"root": root, "rc": r.returncode, "out": r.stdout + r.stderr}


def test_all_failed_category_fails_the_build_with_one_line(all_broken: dict) -> None:
    out = all_broken["out"]
    assert all_broken["rc"] == 30, out  # [retcode] task_failed
    lines = [ln for ln in out.splitlines() if ln.startswith("FAILED")]
    assert lines == ["FAILED BuildDataset: TooManyFailures: mug: no model built, 2 of 2 models failed"], out
    assert out.rstrip().endswith(f"see the FAILED lines above and {all_broken['root'] / 'work' / 'luigi.log'}")


def test_verify_fails_an_empty_category(all_broken: dict) -> None:
    ds = all_broken["root"] / "ds"
    assert verify_dataset(ds) == ["mug: no samples (2 of 2 models failed)"]
    r = subprocess.run(
        [sys.executable, "-m", "pipeline", "verify", str(ds)], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 1, r.stdout


def test_max_failed_fraction_one_still_fails_an_empty_category(all_broken: dict) -> None:
    s = BuildSettings(dataset_dir=all_broken["root"] / "ds")
    assert too_many_failures(s, ["mug"], 1.0) == ["mug: no model built, 2 of 2 models failed"]
    assert too_many_failures(s, ["mug"], 0.5) == ["mug: 2 of 2 models failed (100%) > --max-failed-fraction 0.5"]


LONG = (
    "repair failed verification: "
    + " ".join(f"word{i:03d}" for i in range(40))
    + " /a/very/long/path/that/must/stay/whole/"
    + "x" * 150
    + ".obj"
)


def test_long_failure_reason_is_wrapped_whole(tmp_path: Path) -> None:
    ds = tmp_path / "ds"
    write_json(
        ds / "manifest.json",
        {
            "checksum": "0" * 64,
            "categories": {
                "mug": {
                    "models_built": 1,
                    "models_failed": 1,
                    "splits": {s: {"samples": int(s == "train")} for s in ("train", "val", "test")},
                    "failed": [{"model_id": "bad", "stage": "prepare", "reason": LONG}],
                }
            },
        },
    )
    text = summary(BuildSettings(dataset_dir=ds), ["mug"])
    start = text.index("  failed mug/bad at prepare: ")
    block = text[start:].split("\nmanifest:")[0].splitlines()
    assert len(block) > 2 and all(len(ln) <= WIDTH or " " not in ln.strip() for ln in block)
    assert " ".join(ln.strip() for ln in block) == f"failed mug/bad at prepare: {LONG}"


def test_failed_task_line_is_wrapped_whole() -> None:
    out = io.StringIO()
    con = Console(out)

    class Task:
        category = "mug"

        @staticmethod
        def get_task_family() -> str:
            return "CategoryShards"

    con._failed(Task(), RuntimeError(LONG))
    assert (
        " ".join(ln.strip() for ln in out.getvalue().splitlines()) == f"FAILED CategoryShards mug: RuntimeError: {LONG}"
    )


_WARN_BUILD = """
import sys, warnings, luigi
from workflows.tasks import PrepareBatch
@PrepareBatch.event_handler(luigi.Event.START)
def warn(task):
    warnings.warn("invalid value encountered in divide", RuntimeWarning)  # as trimesh's numpy does
from workflows.make_dataset import main
sys.exit(main(sys.argv[1:]))
"""


def test_library_warnings_go_to_the_log_not_the_console(all_broken: dict, tmp_path: Path) -> None:
    root = all_broken["root"]
    r = subprocess.run(
        [
            sys.executable,
            "-c",
            _WARN_BUILD,
            "--source",
            str(root / "src"),
            "--models-per-category",
            "0",
            "--work-dir",
            str(tmp_path / "work"),
            "--dataset-dir",
            str(tmp_path / "ds"),
            "--workers",
            "1",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 1  # nothing built
    assert "RuntimeWarning" not in r.stdout + r.stderr, r.stdout + r.stderr
    assert "RuntimeWarning: invalid value encountered in divide" in (tmp_path / "work" / "luigi.log").read_text()


def _session_alive(sid: int) -> list[str]:
    """Command lines of the live (not zombie) processes of session ``sid``."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            fields = stat[stat.rindex(")") + 2 :].split()
            if int(fields[3]) == sid and fields[0] != "Z":
                out.append((d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace"))
        except (OSError, ValueError):
            continue
    return out


def test_second_build_refused_by_luigis_lock_exits_non_zero(tmp_path: Path) -> None:
    """A first `luigi` command holds the pid lock (it sleeps at start-up, before Luigi runs, and
    its pid is in the lock file as Luigi writes it); the same command again is turned away."""
    import luigi.lock

    box(tmp_path / "src" / "mug" / "a.obj", (1, 1, 1))
    cmd = LUIGI + [
        "--source",
        str(tmp_path / "src"),
        "--render-settings",
        EMBREE,
        "--work-dir",
        str(tmp_path / "work"),
        "--dataset-dir",
        str(tmp_path / "ds"),
        "--lock-pid-dir",
        str(tmp_path / "locks"),
    ]
    (tmp_path / "hang").mkdir()
    (tmp_path / "hang" / "sitecustomize.py").write_text("import time\ntime.sleep(120)\n")
    first = subprocess.Popen(
        cmd,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(tmp_path / "hang")},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        (tmp_path / "locks").mkdir()
        deadline = time.monotonic() + 10
        while not luigi.lock.getpcmd(first.pid).endswith(str(tmp_path / "locks")) and time.monotonic() < deadline:
            time.sleep(0.05)
        _, _, pid_file = luigi.lock.get_info(str(tmp_path / "locks"), first.pid)
        Path(pid_file).write_text(f"{first.pid}\n")
        r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    finally:
        first.kill()
        first.wait()
    out = r.stdout + r.stderr
    assert r.returncode == 45, out
    assert f"Pid(s) {{{first.pid}}} already running" in out
    assert "error: not started: the same build command is already running on this machine" in " ".join(out.split())
    assert not (tmp_path / "work").exists() and not (tmp_path / "ds").exists()


# ---------------------------------------------------------------- 8: killing the build kills its workers


def test_die_with_parent_only_arms_forked_processes() -> None:
    assert die_with_parent() is False  # the test process itself (workers=1 builds run here)
    ctx = multiprocessing.get_context("fork")
    q = ctx.Queue()
    p = ctx.Process(target=lambda: q.put(die_with_parent()))
    p.start()
    p.join(30)
    assert q.get(timeout=5) is True


@pytest.mark.slow  # a real --workers 2 build with Blender, killed mid-render (~15 s)
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_killing_the_luigi_process_ends_its_workers_and_blender(tmp_path: Path, sig: int) -> None:
    from pipeline.shapes import generate

    for i in range(4):
        generate("mug", i).write(tmp_path / "src" / "mug" / f"m{i}.obj")
    cmd = LUIGI + [
        "--source",
        str(tmp_path / "src"),
        "--views",
        "4",
        "--variants",
        "1",
        "--image-size",
        "256",
        "--out-size",
        "64",
        "--batch-size",
        "2",
        "--workers",
        "2",
        "--work-dir",
        str(tmp_path / "work"),
        "--dataset-dir",
        str(tmp_path / "ds"),
    ]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            alive = _session_alive(proc.pid)
            if sum("render.worker" in c for c in alive) >= 1 and len(alive) >= 4:  # luigi + 2 tasks + Blender
                break
            time.sleep(0.2)
        assert proc.poll() is None, "the build ended before it could be killed"
        os.kill(proc.pid, sig)
        proc.wait(30)
        # at once, not when the batch would have finished: an orphan renders on for many seconds
        deadline = time.monotonic() + 2
        while _session_alive(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert _session_alive(proc.pid) == []
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)


@pytest.mark.slow  # two whole builds at once (~40 s on 2 cores)
def test_two_luigi_builds_on_one_dataset_folder_both_succeed(tmp_path: Path) -> None:
    for name, ext in (("a", (1, 0.6, 0.4)), ("b", (0.4, 0.4, 1.2)), ("c", (1.0, 1.0, 0.3))):
        box(tmp_path / "src" / "mug" / f"{name}.obj", ext)
    base = LUIGI + [
        "--source",
        str(tmp_path / "src"),
        "--render-settings",
        EMBREE,
        "--views",
        "1",
        "--variants",
        "1",
        "--image-size",
        "64",
        "--out-size",
        "64",
        "--batch-size",
        "1",
        "--no-lock",
        "--dataset-dir",
        str(tmp_path / "ds"),
    ]
    procs = [
        subprocess.Popen(
            base + ["--work-dir", str(tmp_path / f"work{i}")],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for i in range(2)
    ]
    outs = [p.communicate(timeout=300)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], "\n".join(o[-3000:] for o in outs)
    assert verify_dataset(tmp_path / "ds") == []
    r = subprocess.run(
        base[:-2] + ["--work-dir", str(tmp_path / "work0"), "--dataset-dir", str(tmp_path / "alone")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout[-3000:]
    assert files(tmp_path / "ds") == files(tmp_path / "alone")
