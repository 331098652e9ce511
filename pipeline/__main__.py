"""Dataset commands: `python -m pipeline verify <dataset-dir>` and `python -m pipeline preview <dataset-dir> --out DIR`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pipeline.core.schema import MANIFEST


def _verify(args: argparse.Namespace) -> int:
    from pipeline.dataset.verify import verify_dataset

    problems = verify_dataset(Path(args.dataset_dir))
    for p in problems:
        print(f"MISMATCH {p}")
    if problems:
        print(f"FAILED: {len(problems)} problem(s) in {args.dataset_dir}")
        return 1
    print(f"OK: every shard in {args.dataset_dir} matches {MANIFEST}")
    return 0


def _preview(args: argparse.Namespace) -> int:
    from pipeline.sheets.dataset import write_previews

    refused: list[str] = []
    for path in write_previews(Path(args.dataset_dir), Path(args.out), args.max_models, args.categories, refused):
        print(path)
    for line in refused:  # a manifest naming paths outside the dataset: nothing written for it
        print(f"REFUSED {line}", file=sys.stderr)
    return 1 if refused else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pipeline", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    v = sub.add_parser("verify", help="re-check every shard against manifest.json; exit 1 on any mismatch")
    v.add_argument("dataset_dir")
    v.set_defaults(func=_verify)
    p = sub.add_parser("preview", help="write a contact-sheet PNG per category from the shards")
    p.add_argument("dataset_dir")
    p.add_argument("--out", required=True, help="folder for <category>.png (odd names: a safe slug + hash)")
    p.add_argument("--max-models", type=int, default=16, help="rows (models) per sheet")
    p.add_argument("--categories", nargs="*", default=None, help="only these categories")
    p.set_defaults(func=_preview)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
