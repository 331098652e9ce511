"""`predict`'s optional parts: `--list-parts` prints the checkpoint's template's parts, a wrong
`--part` names them and leaves no files, and no doc or help text shows a part no template has."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import box_sketch, camera  # noqa: E402

from train.cli import main
from train.fit import FitSettings, save_checkpoint
from train.model import SketchToPatches
from train.predict import SHIPPED_PARTS
from train.templates import DATA_DIR, load_template

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def knife(tmp_path_factory) -> tuple[str, str]:
    """A knife checkpoint (its zero output layer predicts the template) and a sketch."""
    d = tmp_path_factory.mktemp("parts")
    t = load_template("knife")
    model = SketchToPatches(t.initial_params(), encoder_width=8).eval()
    s = FitSettings(dataset="-", category="knife", template="knife", out=str(d), image_size=32, encoder_width=8)
    save_checkpoint(d / "checkpoint.pt", model, torch.optim.Adam(model.parameters()), 0, s, t)
    cv2.imwrite(str(d / "s.png"), box_sketch(np.array([1, 0.3, 0.2]) / 1.06, camera(30, 20, 32), 32, 1))
    return str(d / "checkpoint.pt"), str(d / "s.png")


def _error(capsys, argv: list[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_list_parts_prints_the_templates_parts_and_exits(knife, capsys) -> None:
    ck, _ = knife
    assert main(["predict", "--checkpoint", ck, "--list-parts"]) == 0
    out = capsys.readouterr().out
    assert "template knife" in out
    assert "guard: 5 patches, 1 closing patches when off" in out and "pommel: 5 patches" in out
    assert main(["predict", "--checkpoint", ck, "--list-parts", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data == {
        "template": "knife",
        "parts": {"guard": {"patches": 5, "closing_patches": 1}, "pommel": {"patches": 5, "closing_patches": 1}},
    }


def test_sketch_and_out_are_required_without_list_parts(knife, capsys) -> None:
    ck, _ = knife
    assert _error(capsys, ["predict", "--checkpoint", ck]).endswith("--sketch and --out required (or --list-parts)")


def test_a_wrong_part_names_the_templates_parts_and_leaves_no_files(knife, tmp_path, capsys) -> None:
    ck, sketch = knife
    out = tmp_path / "p"
    line = _error(
        capsys, ["predict", "--checkpoint", ck, "--sketch", sketch, "--out", str(out), "--part", "turbine=off"]
    )
    assert line.endswith(
        "--part turbine: the checkpoint's template (knife) has no such optional part; its optional parts: guard, pommel"
    )
    assert not out.exists()
    out.mkdir()  # an existing folder stays as it was
    _error(capsys, ["predict", "--checkpoint", ck, "--sketch", sketch, "--out", str(out), "--part", "guard=of"])
    assert list(out.iterdir()) == []


def _shipped_parts() -> dict[str, list[str]]:
    return {
        p.stem: load_template(p.stem).part_names
        for p in sorted(DATA_DIR.glob("*.json"))
        if load_template(p.stem).part_names
    }


def test_help_lists_the_shipped_templates_parts() -> None:
    """--help's list is the shipped templates' own (it is written out, so this keeps it in step)."""
    want = "; ".join(f"{c} {', '.join(parts)}" for c, parts in _shipped_parts().items())
    assert SHIPPED_PARTS == want


def test_docs_name_only_parts_that_a_template_has() -> None:
    """Every `--part NAME=on|off` in the docs and README names a part of a shipped template (the
    airplane's is `engine`; there is no `turbine`), except the chair's `arm`, a part of the
    template that docs/templates.md builds from a folder in the same section."""
    known = {p for parts in _shipped_parts().values() for p in parts} | {"arm"}
    used = {}
    for doc in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for name in re.findall(r"--part[ =]+([A-Za-z_][\w-]*)=(?:on|off)", doc.read_text()):
            used.setdefault(name, doc.name)
    assert used, "the docs show --part somewhere"
    assert {n: d for n, d in used.items() if n not in known} == {}
