"""What a re-run costs before any work: the completeness check of a built category
(workflows.steps.category_problems) with sizes only (the default), every shard's sha256
(``--verify``), and, for scale, a full ``pipeline verify`` (reads every tar); and re-reading a
folder source's model list (workflows.listing): first time (every file hashed) vs cached.
Synthetic samples as in bench_shards.py; medians over repeats.
Run: OMP_NUM_THREADS=1 .venv/bin/python bench/bench_repair.py [--models 256] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from bench_shards import fake_model  # noqa: E402

from pipeline.dataset.manifest import category_fragment, write_fragment, write_manifest  # noqa: E402
from pipeline.dataset.shards import list_shards, write_category_shards  # noqa: E402
from pipeline.dataset.verify import verify_dataset  # noqa: E402
from workflows.build_settings import BuildSettings  # noqa: E402
from workflows.steps import category_problems  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--models", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        s = BuildSettings(
            shard_overrides='{"max_samples_per_shard": 16}', work_dir=root / "work", dataset_dir=root / "ds"
        )
        models = [fake_model(root / "work", "mug", f"{i:05d}") for i in range(a.models)]
        result = write_category_shards("mug", models, root / "ds" / "mug", s.shard_settings(), 0, "bench")
        write_fragment(
            root / "ds" / "mug",
            category_fragment("mug", result, s.manifest_settings(), s.category_settings_hash(), a.models, []),
        )
        write_manifest(root / "ds")
        lst = {"category": "mug", "key": "n16", "models": []}
        timings: dict[str, list[float]] = {
            "size check (default)": [],
            "sha256 check (--verify)": [],
            "pipeline verify": [],
        }
        for _ in range(a.repeats):
            for name, check in (
                ("size check (default)", lambda: category_problems(s, lst, False)),
                ("sha256 check (--verify)", lambda: category_problems(s, lst, True)),
                ("pipeline verify", lambda: verify_dataset(root / "ds")),
            ):
                t = time.perf_counter()
                assert check() == []
                timings[name].append(time.perf_counter() - t)
        total = sum(p.stat().st_size for p in list_shards(root / "ds" / "mug"))
        print(f"models={a.models} shards={len(list_shards(root / 'ds' / 'mug'))} bytes={total / 2**20:.1f} MiB")
        base = statistics.median(timings["size check (default)"])
        for name, ts in timings.items():
            m = statistics.median(ts)
            print(
                f"{name:<24} median {1000 * m:8.1f} ms  ({m / base:6.0f}x the size check, "
                f"{total / m / 2**20:7.0f} MiB/s)"
            )
        listing(root, a.models, a.repeats)


def listing(root: Path, n: int, repeats: int) -> None:
    """Model list of a folder of ``n`` 1 MiB files: hashed once, then found in the cache."""
    from workflows.listing import current_listing

    src = root / "src" / "mug"
    src.mkdir(parents=True)
    for i in range(n):
        (src / f"m{i:05d}.obj").write_bytes(i.to_bytes(4, "little") * (1 << 18))
    first, cached = [], []
    for r in range(repeats):
        s = BuildSettings(source=str(root / "src"), models_per_category=0, work_dir=root / f"lw{r}")
        t = time.perf_counter()
        current_listing(s, "mug")
        first.append(time.perf_counter() - t)
        t = time.perf_counter()
        current_listing(s, "mug")
        cached.append(time.perf_counter() - t)
    f, c = statistics.median(first), statistics.median(cached)
    print(
        f"model list of {n} files x 1 MiB: first run (sha256 of each) median {1000 * f:.0f} ms, "
        f"re-run (cached by size/mtime/inode) {1000 * c:.1f} ms ({f / c:.0f}x less)"
    )


if __name__ == "__main__":
    main()
