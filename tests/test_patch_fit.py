"""The fit stage (``--fit-patches``): the category's template fitted to every prepared model, run
through Luigi at tiny settings (3 procedural knives, 2 batches, 20 Adam steps on 600 points, the
Embree renderer), its members read back by webdataset, byte-identical rebuilds, re-runs only on
a changed fit setting, a bad model failing only itself, and the export read by OpenCASCADE."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import luigi
import numpy as np
import pytest
import webdataset as wds

from pipeline.core import schema
from pipeline.core.fit_settings import PatchFitSettings
from pipeline.dataset.manifest import read_fragment, read_manifest
from pipeline.dataset.shards import list_shards
from pipeline.dataset.verify import verify_dataset
from workflows import BuildCategory, steps
from workflows.build_settings import BuildSettings

CATEGORY = "knife"
TINY = dict(
    category=CATEGORY,
    models_per_category=3,
    views=1,
    variants=1,
    image_size=64,
    out_size=64,
    batch_size=2,
    render_settings='{"backend": "embree"}',
    fit_patches=True,
    fit_settings='{"steps": 20, "points": 600}',
)


def build(root: Path, **kw) -> bool:
    params = {**TINY, "work_dir": str(root / "work"), "dataset_dir": str(root / "ds"), **kw}
    return luigi.build([BuildCategory(**params)], local_scheduler=True, workers=1, log_level="WARNING")


def settings(root: Path, **kw) -> BuildSettings:
    fields = {k: v for k, v in TINY.items() if k not in ("category", "render_settings", "fit_settings")}
    over = {"render_overrides": TINY["render_settings"], "fit_overrides": TINY["fit_settings"], **kw}
    return BuildSettings(**fields, **over, work_dir=root / "work", dataset_dir=root / "ds")


def fit_records(s: BuildSettings) -> dict[str, int]:
    return {p.parent.name: p.stat().st_mtime_ns for p in (s.stage_dir("fit") / CATEGORY).glob("*/record.json")}


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("fit")
    assert build(root)
    return root


def test_off_by_default_and_keys_unchanged_when_off() -> None:
    base, on = BuildSettings(), BuildSettings(fit_patches=True)
    assert not base.fit_patches and "fit" not in base.manifest_settings()
    assert "fit" not in base.stages() and "fit" in on.stages()
    # only the shards (and what records them) change when the stage is on; upstream keys stay
    assert on.augment_key() == base.augment_key() and on.shards_key() != base.shards_key()
    # fit settings given while the stage is off change nothing
    assert BuildSettings(fit_overrides='{"steps": 5}').shards_key() == base.shards_key()
    assert BuildSettings(fit_overrides='{"steps": 5}').category_settings_hash() == base.category_settings_hash()


def test_settings_checked() -> None:
    assert PatchFitSettings(templates=("knife=sphere54",)).template_for("knife") == "sphere54"
    assert PatchFitSettings().template_for("mug") == "mug"
    with pytest.raises(ValueError, match="CATEGORY=TEMPLATE"):
        PatchFitSettings(templates=("knife",))
    with pytest.raises(ValueError, match="steps"):
        PatchFitSettings(steps=0)
    with pytest.raises(ValueError, match="collision"):
        PatchFitSettings(collision=-1.0)


def test_the_collision_weight_reaches_the_fit(monkeypatch) -> None:
    from train.objective import Objective
    from train.patch_fit import Target, fit_targets
    from train.templates import load_template

    seen = []
    real = Objective.batch_terms

    def spy(self, params, batch, st, weights, training=True):
        seen.append(weights.collision)
        return real(self, params, batch, st, weights, training)

    monkeypatch.setattr(Objective, "batch_terms", spy)
    pts = np.random.default_rng(0).normal(size=(300, 6)).astype(np.float32)
    tpl = load_template("sphere24")
    fit_targets(tpl, [Target("a", pts)], PatchFitSettings(steps=2, points=300), 0, "x")
    fit_targets(tpl, [Target("a", pts)], PatchFitSettings(steps=2, points=300, collision=3.0), 0, "x")
    assert seen[:2] == [0.0, 0.0] and 3.0 in seen  # the fit's own steps carry the weight


def test_fit_members_in_shards_read_by_webdataset(built: Path) -> None:
    shards = [str(p) for p in list_shards(built / "ds" / CATEGORY)]
    samples = list(wds.WebDataset(shards, shardshuffle=False, empty_check=False).decode())
    assert len(samples) == 3
    frag = read_fragment(built / "ds" / CATEGORY)
    assert frag["models_failed"] == 0 and verify_dataset(built / "ds") == []
    for s in samples:
        info, params = s[schema.FIT_MEMBER], s[schema.FIT_PARAMS_MEMBER]
        assert set(info) == set(schema.FIT_FIELDS)
        assert params.dtype == np.float32 and params.ndim == 1 and np.isfinite(params).all()
        assert info["template"] == CATEGORY and info["steps"] == 20 and info["points"] == 600
        assert 0 < len(info["active_patches"]) <= info["patches"]
        # the fit moved the template towards the model
        assert info["chamfer_fitted"] < 0.8 * info["chamfer_template"], info
    summary = frag[schema.FRAGMENT_FIT]
    assert summary["models"] == 3 and summary["chamfer_fitted"] < summary["chamfer_template"]
    assert read_manifest(built / "ds")["categories"][CATEGORY][schema.FRAGMENT_FIT] == summary
    assert read_manifest(built / "ds")["categories"][CATEGORY]["settings"]["fit"]["steps"] == 20
    # the stage's cost is kept in the work folder, not in the manifest
    s = settings(built)
    docs = [json.loads(p.read_text()) for p in sorted((s.stage_dir("fit") / CATEGORY / "_batches").glob("*.json"))]
    assert len(docs) == 2 and all(d["cpu_seconds"] > 0 for d in docs)


def test_rebuild_elsewhere_is_byte_identical(built: Path, tmp_path: Path) -> None:
    # in one batch of 3 where the first build had 2 + 1: a model's fit is its own (sum loss)
    assert build(tmp_path, batch_size=3)
    a, b = list_shards(built / "ds" / CATEGORY), list_shards(tmp_path / "ds" / CATEGORY)
    assert [p.name for p in a] == [p.name for p in b]
    assert all(x.read_bytes() == y.read_bytes() for x, y in zip(a, b))
    assert read_manifest(built / "ds")["checksum"] == read_manifest(tmp_path / "ds")["checksum"]


def test_reruns_only_when_its_settings_change(built: Path) -> None:
    s = settings(built)
    before = fit_records(s)
    prepared = sorted((s.stage_dir("prepare") / CATEGORY).glob("*/record.json"))
    prep_mtimes = [p.stat().st_mtime_ns for p in prepared]
    assert len(before) == 3
    assert build(built)
    assert fit_records(s) == before  # nothing re-fitted
    assert build(built, fit_settings='{"steps": 10, "points": 600}')
    other = settings(built, fit_overrides='{"steps": 10, "points": 600}')
    assert other.stage_dir("fit") != s.stage_dir("fit") and len(fit_records(other)) == 3
    assert fit_records(s) == before and [p.stat().st_mtime_ns for p in prepared] == prep_mtimes
    assert read_fragment(built / "ds" / CATEGORY)[schema.FRAGMENT_FIT]["steps"] == 10
    assert build(built)  # back to the first settings: found again under their key
    assert fit_records(s) == before and read_fragment(built / "ds" / CATEGORY)[schema.FRAGMENT_FIT]["steps"] == 20


def test_bad_model_fails_only_itself(built: Path, tmp_path: Path) -> None:
    s = settings(tmp_path, fit_overrides='{"steps": 3, "points": 600}')
    lst = {"category": CATEGORY, "models": [{"model_id": m, "work_id": m} for m in ("00000", "00001")]}
    prep = settings(built).stage_dir("prepare")
    # this build's prepare folder: a copy of the module build's, with one model's samples broken
    import shutil

    shutil.copytree(prep, s.stage_dir("prepare"))
    np.save(s.stage_dir("prepare") / CATEGORY / "00001" / schema.SAMPLES_FILE, np.zeros((10, 5), np.float32))
    steps._write_batch(s, "prepare", lst, 0, [{**m, "stage": "prepare", "status": "ok"} for m in lst["models"]], 0.0)
    doc = steps.fit_step(s, lst, 0)
    status = {m["model_id"]: (m["status"], m.get("error", {}).get("reason", "")) for m in doc["models"]}
    assert status["00000"][0] == "ok"
    assert status["00001"][0] == "failed" and "surface samples" in status["00001"][1]


def one_model_batch(built: Path, root: Path, fit_overrides: str) -> tuple[BuildSettings, dict]:
    """Settings under ``root`` and a one-model listing whose prepare batch is done (copied from
    ``built``), ready for ``steps.fit_step``."""
    import shutil

    s = settings(root, fit_overrides=fit_overrides)
    lst = {"category": CATEGORY, "models": [{"model_id": "00000", "work_id": "00000"}]}
    shutil.copytree(settings(built).stage_dir("prepare"), s.stage_dir("prepare"))
    steps._write_batch(s, "prepare", lst, 0, [{**m, "stage": "prepare", "status": "ok"} for m in lst["models"]], 0.0)
    return s, lst


def test_a_template_edited_during_a_batch_leaves_it_to_fit_again(built: Path, tmp_path: Path, monkeypatch) -> None:
    """The fit key holds the template files' content: a template edited while a batch fits moves
    the key, and the batch is marked done beside its models, not under the new key (where the
    shards would find it done and its models missing, as a 2,000-bathtub build once did)."""
    monkeypatch.chdir(tmp_path)  # ./templates/ (a fit's user templates) is this test's own
    s, lst = one_model_batch(built, tmp_path / "b", '{"steps": 3, "points": 600}')
    before = s.stage_dir("fit")
    real = steps._run_fit_job

    def fit_then_edit(*args):
        answer = real(*args)
        Path("templates").mkdir()
        Path("templates/mine.json").write_text("{}")  # a user's template saved mid-batch
        return answer

    monkeypatch.setattr(steps, "_run_fit_job", fit_then_edit)
    doc = steps.fit_step(s, lst, 0)
    assert doc["models"][0]["status"] == "ok"
    assert s.stage_dir("fit") != before  # the key moved
    marker = steps.batch_path(s, "fit", lst, 0)
    assert (before / marker.relative_to(s.stage_dir("fit"))).exists()  # done where its model is
    assert (before / CATEGORY / "00000" / "record.json").exists()
    assert not marker.exists()  # under the new key: not done, so Luigi fits it again


def test_the_fit_loads_the_template_its_key_names(built: Path, tmp_path: Path, monkeypatch) -> None:
    """The fit stage reads the template once: a template file edited after the stage keyed its
    folder, as the fit process starts, is not what that folder's fits are made from."""
    from train.patch_fit import template_sha256
    from train.templates import load_template, save_template

    monkeypatch.chdir(tmp_path)
    save_template(load_template(CATEGORY), "mine.json")
    want = template_sha256(load_template("mine.json"))
    s, lst = one_model_batch(built, tmp_path / "b", '{"steps": 3, "points": 600, "templates": ["knife=mine.json"]}')
    keyed = s.stage_dir("fit")
    real = steps._run_fit_job

    def edit_then_fit(*args):
        save_template(load_template("sphere24"), "mine.json")  # saved over as the process starts
        return real(*args)

    monkeypatch.setattr(steps, "_run_fit_job", edit_then_fit)
    assert steps.fit_step(s, lst, 0)["models"][0]["status"] == "ok"
    record = json.loads((keyed / CATEGORY / "00000" / schema.RECORD).read_text())
    assert record["template_sha256"] == want  # the key's content, not the sphere saved over it
    assert record["patches"] == load_template(CATEGORY).num_patches


def test_a_template_snapshot_is_the_content_its_key_holds(tmp_path: Path, monkeypatch) -> None:
    from train.templates import BUILTIN
    from workflows.build_settings import TEMPLATE_DIRS, template_fingerprints, template_snapshot

    monkeypatch.chdir(tmp_path)
    prints = template_fingerprints(())
    assert template_snapshot(CATEGORY, prints) == (TEMPLATE_DIRS[0] / f"{CATEGORY}.json").read_bytes()
    for name in BUILTIN:  # built in code: no file to read, even where one of that name lies
        Path("templates").mkdir(exist_ok=True)
        Path("templates", f"{name}.json").write_text("{}")
        assert template_snapshot(name, template_fingerprints(())) is None
    with pytest.raises(ValueError, match=rf"{CATEGORY}\.json: the template changed"):
        template_snapshot(CATEGORY, {**prints, f"builtin/{CATEGORY}.json": "0" * 64})


def test_fit_isolates_a_model_whose_fit_raises() -> None:
    from train.patch_fit import Target, _fit_isolating
    from train.templates import load_template

    rng = np.random.default_rng(0)
    pts = rng.normal(size=(200, 6)).astype(np.float32)
    good, bad = Target("a", pts), Target("b", pts[:, :5])  # five columns: the objective cannot read it
    out = _fit_isolating(load_template("sphere24"), [good, bad], PatchFitSettings(steps=2, points=200), 0, "x")
    assert not isinstance(out[0], Exception) and isinstance(out[1], Exception)


def test_export_fit_writes_a_step_opencascade_reads(built: Path, tmp_path: Path, capsys) -> None:
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer

    from train.cli import main
    from train.export.cad_view import read_cad

    out = tmp_path / "fit"
    assert (
        main(
            [
                "export-fit",
                "--dataset",
                str(built / "ds"),
                "--category",
                CATEGORY,
                "--model",
                "00000",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    info = json.loads((out / "export.json").read_text())
    shape = read_cad(out / "patches.stp")
    faces, exp = 0, TopExp_Explorer(shape, TopAbs_FACE)
    while exp.More():
        faces += 1
        exp.Next()
    assert faces == info["patches"] and info["chamfer_fitted"] < info["chamfer_template"]
    assert (out / "patches.igs").stat().st_size and (out / "quads.obj").stat().st_size
    # a model that is not there: one line naming the folder
    assert (
        main(["export-fit", "--dataset", str(built / "ds"), "--category", CATEGORY, "--model", "zz", "--out", str(out)])
        == 2
    )
    assert "no model 'zz'" in capsys.readouterr().err


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
