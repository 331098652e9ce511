"""Dataset commands: `python -m pipeline verify <dataset-dir>` and `python -m pipeline preview <dataset-dir> --out DIR`."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from pipeline.core.schema import MANIFEST
from pipeline.core.settings_io import add_arguments, from_args, setting


@dataclasses.dataclass(frozen=True)
class VerifySettings:
    dataset_dir: str = setting(help="the dataset folder (holds manifest.json)", positional=True)


@dataclasses.dataclass(frozen=True)
class PreviewSettings:
    dataset_dir: str = setting(help="the dataset folder (holds manifest.json)", positional=True)
    out: str = setting(help="folder for <category>.png (odd names: a safe slug + hash)")
    max_models: int = setting(16, "rows (models) per sheet")
    categories: tuple[str, ...] = setting((), "only these categories (default: all)")

    def __post_init__(self) -> None:
        if self.max_models < 1:
            raise ValueError(f"max_models must be >= 1, got {self.max_models}")


def _verify(args: VerifySettings) -> int:
    from pipeline.dataset.verify import verify_dataset

    problems = verify_dataset(Path(args.dataset_dir))
    for p in problems:
        print(f"MISMATCH {p}")
    if problems:
        print(f"FAILED: {len(problems)} problem(s) in {args.dataset_dir}")
        return 1
    print(f"OK: every shard in {args.dataset_dir} matches {MANIFEST}")
    return 0


def _preview(args: PreviewSettings) -> int:
    from pipeline.sheets.dataset import write_previews

    refused: list[str] = []
    for path in write_previews(
        Path(args.dataset_dir), Path(args.out), args.max_models, list(args.categories) or None, refused
    ):
        print(path)
    for line in refused:  # a manifest naming paths outside the dataset: nothing written for it
        print(f"REFUSED {line}", file=sys.stderr)
    return 1 if refused else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pipeline", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    commands = {
        "verify": (VerifySettings, _verify, "re-check every shard against manifest.json; exit 1 on any mismatch"),
        "preview": (PreviewSettings, _preview, "write a contact-sheet PNG per category from the shards"),
    }
    for name, (cls, _, help_) in commands.items():
        add_arguments(sub.add_parser(name, help=help_), cls)
    args = parser.parse_args(argv)
    cls, run, _ = commands[args.command]
    try:
        settings = from_args(cls, args)
    except ValueError as exc:
        parser.error(str(exc))
    return run(settings)


if __name__ == "__main__":
    sys.exit(main())
