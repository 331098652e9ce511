"""Trust at the borders of ``python -m train`` (issue 31): a checkpoint never runs code, and
every user mistake is one line naming the flag or file, exit status 2, no traceback."""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import webdataset as wds

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import box_sketch, camera, tiny_run, write_fixture_shards  # noqa: E402

from pipeline.core.schema import POINTS_MEMBER
from train.cli import main
from train.errors import UsageError
from train.fit import FitSettings, fit, load_checkpoint, load_run, save_checkpoint
from train.model import SketchToPatches
from train.templates import load_template

REPO = Path(__file__).resolve().parents[1]


class WritesAFile:
    """Unpickling this calls ``Path.write_text``: what a crafted checkpoint would do."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return pathlib.Path.write_text, (self.marker, "code ran")


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """Shards, a one-step run (checkpoint.pt) and a sketch PNG."""
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("trust")
    ds = write_fixture_shards(root / "ds", n_points=400, size=32)
    run = root / "run"
    assert main(fit_argv(ds, run, "--steps", "1")) == 0  # as a user would: resumes below match it
    sketch = root / "sketch.png"
    cv2.imwrite(str(sketch), box_sketch(np.array([1, 0.3, 0.2]) / 1.06, camera(30, 20, 32), 32, 1))
    return {"root": root, "ds": ds, "run": run, "ckpt": run / "checkpoint.pt", "sketch": sketch}


def _settings(ds: Path, out: Path) -> dict:
    return tiny_run(ds, out, n_points=200, max_views=2, log_every=1, checkpoint_every=100, device="cpu")


def fit_argv(ds: Path, out: Path, *extra: str) -> list[str]:
    """``fit`` flags of a tiny CPU run like ``_settings``; ``extra`` flags override them."""
    return [
        "fit",
        "--dataset",
        str(ds),
        "--category",
        "knife",
        "--template",
        "sphere24",
        "--out",
        str(out),
        "--steps",
        "2",
        "--batch-size",
        "2",
        "--workers",
        "0",
        "--points",
        "200",
        "--image-size",
        "32",
        "--max-views",
        "2",
        "--encoder-width",
        "8",
        "--device",
        "cpu",
        "--w-collision",
        "0",
        "--no-progress",
        *extra,
    ]


def cli_error(capsys, argv: list[str]) -> str:
    """Run ``python -m train ARGV`` in-process; it must fail with status 2 and one line on stderr."""
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"python -m train {argv[0]}: error: "), lines[0]
    return lines[0]


def _evil_checkpoint(path: Path, marker: Path) -> Path:
    """A file shaped like a checkpoint whose pickle writes ``marker`` when loaded unsafely."""
    torch.save({"settings": WritesAFile(marker), "model": {}, "step": 0}, path)
    return path


# ---------------------------------------------------------------- checkpoints never run code


def test_every_command_refuses_a_checkpoint_that_would_run_code(world, tmp_path, capsys):
    marker = tmp_path / "MARKER"
    evil = _evil_checkpoint(tmp_path / "evil.pt", marker)
    sketch, ds = str(world["sketch"]), str(world["ds"])
    runs = {
        "predict": ["predict", "--checkpoint", str(evil), "--sketch", sketch, "--out", str(tmp_path / "p")],
        "evaluate": ["evaluate", "--checkpoint", str(evil), "--dataset", ds, "--out", str(tmp_path / "e.json")],
        "interpolate": [
            "interpolate",
            "--checkpoint",
            str(evil),
            "--sketch-a",
            sketch,
            "--sketch-b",
            sketch,
            "--out",
            str(tmp_path / "i"),
        ],
    }
    for name, argv in runs.items():
        line = cli_error(capsys, argv)
        assert "evil.pt: refused: it holds Python objects" in line and "only load checkpoints you trust" in line, name
    # fit resuming a run whose checkpoint.pt is the crafted file
    resume = tmp_path / "resume"
    resume.mkdir()
    shutil.copy(evil, resume / "checkpoint.pt")
    assert "checkpoint.pt: refused" in cli_error(capsys, fit_argv(world["ds"], resume))
    # ... and one whose checkpoint is fine but whose best.pt is the crafted file
    shutil.copytree(world["run"], tmp_path / "best")
    shutil.copy(evil, tmp_path / "best" / "best.pt")
    before = sorted(p.name for p in (tmp_path / "best").iterdir())
    assert "best.pt: refused" in cli_error(capsys, fit_argv(world["ds"], tmp_path / "best", "--val-every", "1"))
    assert not marker.exists()
    assert not any((tmp_path / n).exists() for n in ("p", "e.json", "i"))  # nothing written
    assert sorted(p.name for p in resume.iterdir()) == ["checkpoint.pt"]
    assert sorted(p.name for p in (tmp_path / "best").iterdir()) == before
    # the crafted file really does run code when loaded the old way: the test above means something
    torch.load(evil, weights_only=False)
    assert marker.read_text() == "code ran"


def test_the_command_line_refuses_it_with_exit_status_2(world, tmp_path):
    marker = tmp_path / "MARKER"
    evil = _evil_checkpoint(tmp_path / "evil.pt", marker)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "train",
            "predict",
            "--checkpoint",
            str(evil),
            "--sketch",
            str(world["sketch"]),
            "--out",
            str(tmp_path / "out"),
        ],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=120,
    )
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.count("\n") == 1 and res.stderr.startswith(f"python -m train predict: error: {evil}: refused")
    assert not marker.exists() and not (tmp_path / "out").exists()


def test_checkpoints_load_as_plain_data_new_and_old(world, tmp_path):
    ck = torch.load(world["ckpt"], weights_only=True)  # settings, template, optimizer: no pickled objects
    assert isinstance(ck["settings"], dict) and isinstance(ck["template_json"], dict)
    assert "exp_avg" in ck["optimizer"]["state"][0] and ck["optimizer"]["param_groups"][0]["fused"]
    # a checkpoint from before the template was stored, with a removed setting at its "off" value
    # and without the settings added since: loads, the template from its name
    old = {k: ck[k] for k in ("step", "val_chamfer", "model", "optimizer", "template", "num_params")}
    old["settings"] = {k: v for k, v in ck["settings"].items() if k not in ("ema", "clip_grad", "contrast")}
    old["settings"]["encoder_lr"] = None
    torch.save(old, tmp_path / "old.pt")
    run = load_run(tmp_path / "old.pt")
    assert run.step == 1 and run.template.num_patches == 24 and run.settings.encoder_width == 8


# ---------------------------------------------------------------- one line per user mistake

BAD_FLAGS = [
    (["--steps", "0"], "steps must be an integer >= 1, got 0 (--steps)"),
    (["--steps", "-5"], "steps must be an integer >= 1, got -5 (--steps)"),
    (["--image-size", "0"], "image_size must be an integer >= 1, got 0 (--image-size)"),
    (["--points", "0"], "n_points must be an integer >= 1, got 0 (--points)"),
    (["--max-views", "0"], "max_views must be an integer >= 1, got 0 (--max-views)"),
    (["--batch-size", "0"], "batch_size must be an integer >= 1, got 0 (--batch-size)"),
    (["--log-every", "0"], "log_every must be an integer >= 1, got 0 (--log-every)"),
    (["--lr", "0"], "lr must be a learning rate > 0, got 0.0 (--lr)"),
    (["--workers", "-1"], "workers must be an integer >= 0, got -1 (--workers)"),
    (["--template", "nosuch"], "error: nosuch: no built-in template, no "),
]


@pytest.mark.parametrize("flags,words", BAD_FLAGS, ids=[f[0][0] + f[0][1] for f in BAD_FLAGS])
def test_fit_names_the_bad_flag(world, tmp_path, capsys, flags, words):
    assert words in cli_error(capsys, fit_argv(world["ds"], tmp_path / "run", *flags))
    assert not (tmp_path / "run").exists()


def test_settings_checks_hold_for_library_callers_too(world, tmp_path):
    with pytest.raises(ValueError, match=r"^steps must be an integer >= 1, got 0 \(--steps\)$"):
        FitSettings(**{**_settings(world["ds"], tmp_path), "steps": 0})
    from train.data import DataSettings

    with pytest.raises(ValueError, match="DataSettings.eval_views must be an integer >= 1, got 0"):
        DataSettings(eval_views=0)


def test_evaluate_and_interpolate_name_the_bad_flag(world, tmp_path, capsys):
    ck, ds, sk = str(world["ckpt"]), str(world["ds"]), str(world["sketch"])
    ev = ["evaluate", "--checkpoint", ck, "--dataset", ds, "--out", str(tmp_path / "e.json")]
    assert cli_error(capsys, ev + ["--views", "0"]).endswith("views must be an integer >= 1, got 0 (--views)")
    assert cli_error(capsys, ev + ["--limit", "0"]).endswith("got 0 (--limit)")
    assert cli_error(capsys, ev + ["--tau", "-1"]).endswith("distances > 0, got [-1.0] (--tau)")
    it = ["interpolate", "--checkpoint", ck, "--sketch-a", sk, "--sketch-b", sk, "--out", str(tmp_path / "i")]
    line = cli_error(capsys, it + ["--steps", "0"])
    assert line.endswith("steps must be an integer >= 2 (the two ends included), got 0 (--steps)")
    pr = ["predict", "--checkpoint", ck, "--sketch", sk, "--out", str(tmp_path / "p")]
    assert cli_error(capsys, pr + ["--part", "guard=maybe"]).endswith("--part guard=maybe: use NAME=on or NAME=off")
    assert cli_error(capsys, pr + ["--part", "wing=off"]).endswith(
        "--part wing: the checkpoint's template (sphere24) has no such optional part; its optional parts: none"
    )
    assert cli_error(capsys, pr + ["--scale", "-1"]).endswith("--units/--scale: scale must be positive, got -1.0")
    assert not any((tmp_path / n).exists() for n in ("e.json", "i", "p"))


def test_an_out_path_that_is_a_file_is_named(world, tmp_path, capsys):
    ck, sk, taken = str(world["ckpt"]), str(world["sketch"]), tmp_path / "taken"
    taken.write_text("keep me")
    for argv in (
        ["predict", "--checkpoint", ck, "--sketch", sk, "--out", str(taken)],
        ["interpolate", "--checkpoint", ck, "--sketch-a", sk, "--sketch-b", sk, "--out", str(taken)],
        fit_argv(world["ds"], taken),
    ):
        assert cli_error(capsys, argv).endswith(f"{taken}: not a folder (--out)")
    assert taken.read_text() == "keep me"


def test_a_device_that_is_not_there_is_named(world, tmp_path, capsys):
    assert cli_error(capsys, fit_argv(world["ds"], tmp_path / "run", "--device", "gpu")).endswith(
        "--device gpu: not a device name (cpu, cuda, cuda:N)"
    )
    if not torch.cuda.is_available():
        assert cli_error(capsys, fit_argv(world["ds"], tmp_path / "run", "--device", "cuda")).endswith(
            "--device cuda: CUDA is not available on this machine (use --device cpu)"
        )
    assert not (tmp_path / "run").exists()


def _bad_checkpoints(world, d: Path) -> list[tuple[Path, str]]:
    """(file, words of its error): missing, empty, a folder, text, truncated, foreign."""
    (d / "empty.pt").write_bytes(b"")
    (d / "folder.pt").mkdir()
    (d / "notes.pt").write_text("hello\n")
    data = world["ckpt"].read_bytes()
    (d / "cut.pt").write_bytes(data[: len(data) // 2])
    torch.save({"state_dict": {}}, d / "foreign.pt")
    torch.save(torch.zeros(3), d / "tensor.pt")
    return [
        (d / "missing.pt", "missing.pt: no such checkpoint file"),
        (d / "empty.pt", "empty.pt: the checkpoint file is empty"),
        (d / "folder.pt", "folder.pt: no such checkpoint file (it is a folder)"),
        (d / "notes.pt", "notes.pt: not a readable checkpoint"),
        (d / "cut.pt", "cut.pt: not a readable checkpoint"),
        (d / "foreign.pt", "foreign.pt: not a sketch2patch checkpoint: missing 'settings'"),
        (d / "tensor.pt", "tensor.pt: not a sketch2patch checkpoint: missing 'settings'"),
    ]


def test_a_bad_checkpoint_file_is_named_by_every_command(world, tmp_path, capsys):
    sk, ds = str(world["sketch"]), str(world["ds"])
    for path, words in _bad_checkpoints(world, tmp_path):
        for argv in (
            ["predict", "--checkpoint", str(path), "--sketch", sk, "--out", str(tmp_path / "p")],
            ["evaluate", "--checkpoint", str(path), "--dataset", ds, "--out", str(tmp_path / "e.json")],
            [
                "interpolate",
                "--checkpoint",
                str(path),
                "--sketch-a",
                sk,
                "--sketch-b",
                sk,
                "--out",
                str(tmp_path / "i"),
            ],
        ):
            assert words in cli_error(capsys, argv), (path.name, argv[0])
    assert not any((tmp_path / n).exists() for n in ("e.json", "i", "p"))


def test_a_checkpoint_whose_weights_do_not_fit_is_named(world, tmp_path, capsys):
    ck = load_checkpoint(world["ckpt"])
    ck["settings"]["encoder_width"] = 16  # the saved weights are of width 8
    torch.save(ck, tmp_path / "odd.pt")
    line = cli_error(
        capsys,
        [
            "predict",
            "--checkpoint",
            str(tmp_path / "odd.pt"),
            "--sketch",
            str(world["sketch"]),
            "--out",
            str(tmp_path / "p"),
        ],
    )
    assert "odd.pt: its weights do not fit the network its settings describe" in line


def test_a_missing_or_unreadable_sketch_is_named(world, tmp_path, capsys):
    ck = str(world["ckpt"])
    (tmp_path / "notes.png").write_text("not an image")
    (tmp_path / "empty.png").write_bytes(b"")
    cases = [
        (tmp_path / "nope.png", "nope.png: no such sketch file"),
        (tmp_path, f"{tmp_path}: no such sketch file (it is a folder)"),
        (tmp_path / "notes.png", "notes.png: not a readable image (not a PNG, JPEG, WebP or TIFF file)"),
        (tmp_path / "empty.png", "empty.png: not a readable image (empty file)"),
    ]
    for path, words in cases:
        assert words in cli_error(
            capsys, ["predict", "--checkpoint", ck, "--sketch", str(path), "--out", str(tmp_path / "p")]
        )
        assert words in cli_error(
            capsys,
            [
                "interpolate",
                "--checkpoint",
                ck,
                "--sketch-a",
                str(world["sketch"]),
                "--sketch-b",
                str(path),
                "--out",
                str(tmp_path / "i"),
            ],
        )
    assert not (tmp_path / "p").exists() and not (tmp_path / "i").exists()


def test_a_missing_dataset_folder_or_category_is_named(world, tmp_path, capsys):
    line = cli_error(capsys, fit_argv(tmp_path / "nowhere", tmp_path / "run"))
    assert line.endswith(f"{tmp_path / 'nowhere'}: the dataset folder does not exist")
    line = cli_error(capsys, fit_argv(world["ds"], tmp_path / "run", "--category", "mug"))
    assert line.endswith("no train-*.tar shards: the dataset has no category 'mug' (its categories: knife)")
    ev = [
        "evaluate",
        "--checkpoint",
        str(world["ckpt"]),
        "--dataset",
        str(tmp_path / "nowhere"),
        "--out",
        str(tmp_path / "e.json"),
    ]
    assert cli_error(capsys, ev).endswith("nowhere: the dataset folder does not exist")
    assert not (tmp_path / "run").exists() and not (tmp_path / "e.json").exists()


def test_resuming_with_other_settings_names_them(world, tmp_path, capsys):
    shutil.copytree(world["run"], tmp_path / "run")
    line = cli_error(capsys, fit_argv(world["ds"], tmp_path / "run", "--lr", "1e-3", "--w-flat", "3"))
    assert "the run there has different settings (lr 0.0001 -> 0.001; weights.flat 2.0 -> 3.0)" in line
    assert line.endswith("resume with the same settings or use another --out")
    assert load_checkpoint(tmp_path / "run" / "checkpoint.pt")["step"] == 1  # untouched


def test_a_resume_with_nothing_left_to_do_prints_valid_json(world, tmp_path, capsys):
    shutil.copytree(world["run"], tmp_path / "run")
    assert main(fit_argv(world["ds"], tmp_path / "run", "--steps", "1")) == 0

    def no_nan(name: str):
        raise AssertionError(f"{name} in the output: not valid JSON")

    res = json.loads(capsys.readouterr().out, parse_constant=no_nan)
    assert res["step"] == 1 and res["last_loss"] is None


def test_a_diverging_run_stops_and_keeps_its_last_good_checkpoint(world, tmp_path, capsys):
    # at lr 1e12 the first update blows the weights up and step 2's loss is NaN
    line = cli_error(
        capsys, fit_argv(world["ds"], tmp_path / "run", "--lr", "1e12", "--steps", "6", "--checkpoint-every", "1")
    )
    assert "step 2: training diverged (the loss is nan" in line
    assert f"{tmp_path / 'run' / 'checkpoint.pt'} keeps step 1; try a lower --lr or --clip-grad" in line
    ck = load_checkpoint(tmp_path / "run" / "checkpoint.pt")
    assert ck["step"] == 1
    assert all(torch.isfinite(v).all() for v in ck["model"].values() if v.is_floating_point())


@pytest.mark.parametrize("workers", [0, 1])
def test_a_truncated_shard_met_in_training_is_named(world, tmp_path, capsys, workers):
    ds = tmp_path / "ds"
    shutil.copytree(world["ds"], ds)
    shard = ds / "knife" / "train-00001.tar"
    data = shard.read_bytes()
    shard.write_bytes(data[: len(data) // 2])
    # workers 1: the error comes back from a DataLoader worker, its message wrapped in a traceback
    line = cli_error(capsys, fit_argv(ds, tmp_path / "run", "--workers", str(workers)))
    assert line.endswith(f"{shard}: unreadable shard (ReadError: unexpected end of data)")


def test_a_bad_sample_met_in_evaluation_is_named(world, tmp_path, capsys):
    ds = tmp_path / "ds"
    shutil.copytree(world["ds"], ds)
    shard = ds / "knife" / "test-00000.tar"
    samples = list(wds.WebDataset([str(shard)], shardshuffle=False, empty_check=False))
    samples[1][POINTS_MEMBER] = b"not an array"  # a sample the writer got wrong
    with open(shard, "wb") as f, wds.TarWriter(f) as sink:
        for sample in samples:
            sink.write({k: v for k, v in sample.items() if k != "__url__"})
    ev = ["evaluate", "--checkpoint", str(world["ckpt"]), "--dataset", str(ds), "--out", str(tmp_path / "e.json")]
    line = cli_error(capsys, ev)
    assert f"error: {samples[1]['__key__']}: unreadable sample: " in line
    assert not (tmp_path / "e.json").exists()


def test_usage_errors_stay_value_errors_for_library_callers(world, tmp_path):
    shutil.copytree(world["run"], tmp_path / "run")
    with pytest.raises(ValueError, match="different settings"):
        fit(FitSettings(**{**_settings(world["ds"], tmp_path / "run"), "lr": 1e-3}), progress=False)
    assert issubclass(UsageError, ValueError)
    # a checkpoint saved directly (no fit) loads with the same safe loader
    t = load_template("sphere24")
    model = SketchToPatches(t.initial_params(), encoder_width=8)
    s = FitSettings(**{**_settings(world["ds"], tmp_path), "steps": 1})
    save_checkpoint(tmp_path / "direct.pt", model, torch.optim.Adam(model.parameters()), 0, s, t)
    assert load_run(tmp_path / "direct.pt").settings.encoder_width == 8
