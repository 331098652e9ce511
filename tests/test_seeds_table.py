"""BENCHMARKS.md's table of every recipe seed is what `bench/table_seeds.py` makes of the raw files."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _table_seeds():
    spec = importlib.util.spec_from_file_location("table_seeds", ROOT / "bench" / "table_seeds.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_benchmarks_holds_the_table_the_raw_files_make() -> None:
    table = _table_seeds().table(ROOT / "bench" / "results")
    assert table.count("\n") >= 2 + 8, "one row per category at least"
    assert table in (ROOT / "BENCHMARKS.md").read_text(), "rerun bench/table_seeds.py and paste its table"


def _evaluation(model: float, blind: float, template: float, pairs: float = 0.0) -> dict:
    return {
        "samples": 10,
        "cad_checked": 4,
        "model": {"chamfer": model, "intersecting_pairs": pairs, "cad_clean": 0.75},
        "blind": {"chamfer": blind},
        "template": {"chamfer": template},
    }


def test_a_row_says_which_goals_hold(tmp_path: Path) -> None:
    ts = _table_seeds()
    (tmp_path / "eval_x_s2.json").write_text(json.dumps(_evaluation(0.07, 0.1, 0.2)))
    (tmp_path / "response_x_s2.json").write_text(json.dumps({"ratio_models_to_variants": 3.0}))
    (tmp_path / "eval_y.json").write_text(json.dumps(_evaluation(0.08, 0.1, 0.2, pairs=0.6)))
    met = ts.row("x", "x_s2", tmp_path)
    assert "| x | 2 | 10 | −65.0 % / −30.0 % |" in met and "| 3 of 4 |" in met and "all four" in met
    short = ts.row("y", "y", tmp_path)
    assert "| y | 0 |" in short and "| template (no response file) |" in short
    assert ts.row("z", "z_s1", tmp_path) is None
