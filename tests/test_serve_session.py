"""The browser testbed's core without a browser or gradio: a tiny trained checkpoint, a person's
views in (file bytes, a sketchpad's RGBA array), predict's files and verdict out."""

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import trimesh

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import box_sketch, camera, tiny_run, write_fixture_shards  # noqa: E402

from pipeline.core.atomic import read_json
from train.errors import UsageError
from train.export.kernel_check import step_file_verdict
from train.fit import FitSettings, fit
from train.predict import predict
from train.serve.session import ServeSession, checkpoint_labels, has_strokes, view_bytes
from train.serve.view_mesh import CROSSING_COLOR, read_patch_obj, write_view_glb


def tiny_checkpoint(root: Path, category: str = "knife") -> Path:
    """Two steps of training on the category's template (the knife's is small: the full export
    stays fast)."""
    torch.set_num_threads(1)
    shards = write_fixture_shards(root / "ds", category, n_points=600, size=32)
    out = root / "run"
    s = FitSettings(
        **tiny_run(shards, out, category=category, template=category, max_views=2, log_every=1, checkpoint_every=100)
    )
    fit(s, progress=False)
    return out / "checkpoint.pt"


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    return tiny_checkpoint(tmp_path_factory.mktemp("ck"))


def drawing(size: int = 96) -> np.ndarray:
    """A box drawn black on white, as a person's PNG would hold it."""
    return box_sketch(np.array([1, 0.3, 0.2]) / 1.06, camera(30, 20, size), size, 2)


def test_a_view_gives_predicts_files_and_verdict(checkpoint, tmp_path):
    bed = ServeSession([checkpoint], tmp_path / "serve")
    ok, png = cv2.imencode(".png", drawing())
    res = bed.predict([png.tobytes()])
    for key in ("step", "iges", "obj", "quads", "glb", "input", "json"):
        assert res.files[key].is_file() and res.files[key].stat().st_size > 0, key
    assert res.files["step"].parent == res.folder and res.folder.parent == tmp_path / "serve"
    assert (res.folder / "view_0.png").read_bytes() == png.tobytes()  # the view kept as it came
    interferences, solid = step_file_verdict(res.files["step"])  # read back from disk by OpenCASCADE
    assert solid and res.prediction["step"] == "solid"
    assert (interferences == 0) == res.clean
    # the same sketch through `predict`: the same numbers, the same verdict line
    ref = predict(checkpoint, [res.folder / "view_0.png"], tmp_path / "pred")
    assert np.array_equal(np.load(tmp_path / "pred" / "patches.npy"), np.load(res.folder / "patches.npy"))
    assert ref["clean"] == res.clean and ref["problems"] == res.problems
    assert ref["cad_kernel"] == res.prediction["cad_kernel"]
    assert read_json(res.files["json"])["clean"] == res.clean
    assert res.verdict == ("prediction is clean" if ref["clean"] else "NOT CLEAN: " + "; ".join(ref["problems"]))
    crossing = {i for pair in ref["cad_kernel"]["patch_pairs"] for i in pair} | set(ref["cad_kernel"]["folded_patches"])
    assert res.crossing_patches == sorted(crossing)


def test_a_sketchpad_array_is_read_like_the_same_drawing_as_a_file(checkpoint, tmp_path):
    """A sketchpad hands over RGBA strokes on a transparent canvas: the network must see what it
    sees for the black-on-white PNG of the same strokes."""
    bed = ServeSession([checkpoint], tmp_path / "serve")
    grey = drawing()
    rgba = np.zeros((*grey.shape, 4), np.uint8)  # black ink, its coverage in alpha
    rgba[..., 3] = 255 - grey
    assert has_strokes(rgba) and not has_strokes(np.zeros_like(rgba)) and not has_strokes(np.full_like(rgba, 255))
    a = bed.predict([rgba])
    b = bed.predict([cv2.imencode(".png", grey)[1].tobytes()])
    seen_a, seen_b = (cv2.imread(str(r.files["input"]), cv2.IMREAD_GRAYSCALE) for r in (a, b))
    assert np.abs(seen_a.astype(int) - seen_b.astype(int)).max() <= 1
    assert a.folder != b.folder
    # RGB order in, OpenCV's BGR order in the file: a red stroke stays red
    red = np.zeros((8, 8, 3), np.uint8)
    red[..., 0] = 255
    assert cv2.imdecode(np.frombuffer(view_bytes(red)[0], np.uint8), cv2.IMREAD_COLOR)[0, 0].tolist() == [0, 0, 255]


def test_part_toggles_and_two_views(checkpoint, tmp_path):
    bed = ServeSession([checkpoint], tmp_path / "serve")
    assert bed.parts() == ["guard", "pommel"]
    full = bed.predict([drawing()])
    both = bed.predict([drawing(), drawing(80)], parts={"guard": False, "pommel": True})
    assert len(read_json(both.files["json"])["input"]) == 2
    ref = predict(
        checkpoint, [both.folder / "view_0.png", both.folder / "view_1.png"], tmp_path / "p", {"guard": False}
    )
    assert both.prediction["patches"] == ref["patches"] < full.prediction["patches"]


def test_a_failed_request_leaves_no_folder(checkpoint, tmp_path):
    bed = ServeSession([checkpoint], tmp_path / "serve")
    with pytest.raises(UsageError, match="no drawing found"):
        bed.predict([np.full((64, 64), 255, np.uint8)])
    with pytest.raises(UsageError, match="no such optional part"):
        bed.predict([drawing()], parts={"turbine": False})
    with pytest.raises(UsageError, match="no drawing"):
        bed.predict([])
    assert list((tmp_path / "serve").iterdir()) == []


def test_the_mirror_average_toggle_is_predicts_flag(checkpoint, tmp_path):
    """The page's toggle gives what `predict --mirror-average` gives, says so in prediction.json,
    and is refused by name, before any folder, for a template whose parameters do not mirror."""
    knife = ServeSession([checkpoint], tmp_path / "serve")
    assert not knife.mirrors()
    with pytest.raises(UsageError, match="knife.*mirror-average"):
        knife.predict([drawing()], mirror_average=True)
    assert not list((tmp_path / "serve").glob("*"))
    car_ck = tiny_checkpoint(tmp_path / "car", "car")
    car = ServeSession([car_ck], tmp_path / "serve")
    assert car.mirrors()
    plain = car.predict([drawing()])
    averaged = car.predict([drawing()], mirror_average=True)
    assert averaged.prediction["mirror_average"] and not plain.prediction["mirror_average"]
    ref = predict(car_ck, [averaged.folder / "view_0.png"], tmp_path / "pred", mirror_average=True)
    assert ref["mirror_average"]
    got = np.load(averaged.folder / "patches.npy")
    assert np.array_equal(np.load(tmp_path / "pred" / "patches.npy"), got)
    assert not np.allclose(np.load(plain.folder / "patches.npy"), got)  # the toggle changes the answer


def test_the_3d_view_colours_the_crossing_patches(checkpoint, tmp_path):
    res = ServeSession([checkpoint], tmp_path / "serve").predict([drawing()])
    _, tris, patch = read_patch_obj(res.files["quads"])
    assert set(patch) == set(range(res.prediction["patches"]))
    glb = write_view_glb(res.files["quads"], [0, 3], tmp_path / "v.glb")
    mesh = trimesh.load(glb, force="mesh")
    assert len(mesh.faces) == len(tris)
    red = (mesh.visual.vertex_colors[mesh.faces[:, 0], :3] == np.round(255 * np.array(CROSSING_COLOR))).all(axis=1)
    assert np.array_equal(red, np.isin(patch, [0, 3]))


def test_checkpoints_get_short_distinct_labels(tmp_path):
    a, b = tmp_path / "knife" / "best.pt", tmp_path / "mug" / "best.pt"
    assert checkpoint_labels([a, b]) == ["knife/best.pt", "mug/best.pt"]
    assert checkpoint_labels([tmp_path / "x" / "r" / "best.pt", tmp_path / "y" / "r" / "best.pt"]) == [
        "x/r/best.pt",
        "y/r/best.pt",
    ]
    with pytest.raises(UsageError, match="named twice"):
        checkpoint_labels([a, a])


def test_serve_without_gradio_is_a_one_line_error(checkpoint, capsys):
    try:
        import gradio  # noqa: F401
    except ModuleNotFoundError:
        pass
    else:
        pytest.skip("gradio is installed here (the serve env)")
    from train.cli import main

    assert main(["serve", "--checkpoint", str(checkpoint)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "make serve" in err[0] and "pip install -e .[serve]" in err[0]
