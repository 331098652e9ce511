"""The browser testbed for real: `python -m train serve` in a subprocess, Debian's Chromium driven
headless by Playwright draws on the sketchpad and uploads a file, the page answers with the 3D
view, the STEP downloaded through the browser is a valid solid for OpenCASCADE, and the page's
verdict is the one `predict` prints. Runs in the serve env: `make test-serve` (part of
`make test-slow`)."""

import re
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

pytestmark = pytest.mark.slow
pytest.importorskip("playwright", reason="the serve env has playwright: make test-serve")
pytest.importorskip("gradio", reason="the serve env has gradio: make test-serve")

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import box_sketch, camera  # noqa: E402
from test_serve_session import tiny_checkpoint  # noqa: E402

from pipeline.core.atomic import read_json  # noqa: E402
from train.export.kernel_check import step_file_verdict  # noqa: E402
from train.predict import predict  # noqa: E402
from train.serve.browser import make_cad, running_server  # noqa: E402

CHROMIUM = "/usr/bin/chromium"


@pytest.mark.skipif(not Path(CHROMIUM).is_file(), reason="no Chromium: make browser")
def test_the_page_turns_a_drawing_and_an_upload_into_a_valid_step(tmp_path):
    ck = tiny_checkpoint(tmp_path)
    sketch = tmp_path / "box.png"
    cv2.imwrite(str(sketch), box_sketch(np.array([1, 0.3, 0.2]) / 1.06, camera(30, 20, 256), 256, 3))
    with running_server([str(ck)], tmp_path / "serve") as url:
        assert url.startswith("http://127.0.0.1:")  # the page listens on this machine only
        drawn = make_cad(url, tmp_path / "drawn", screenshot=tmp_path / "serve.png", chromium=CHROMIUM)
        uploaded = make_cad(url, tmp_path / "uploaded", [str(sketch)], chromium=CHROMIUM)
    for res in (drawn, uploaded):
        assert set(res["files"]) == {"patches.stp", "patches.igs", "mesh.obj", "quads.obj"}
        step = res["files"]["patches.stp"]
        interferences, solid = step_file_verdict(step)
        assert solid, f"{step}: not a valid solid for OpenCASCADE"
        # the request's folder on the server: the same STEP, and predict on its view says the same
        folder = Path(re.search(r"folder: (\S+)", res["verdict"]).group(1))
        assert step.read_bytes() == (folder / "patches.stp").read_bytes()
        ref = predict(ck, [folder / "view_0.png"], tmp_path / f"predict-{folder.name}")
        line = "prediction is clean" if ref["clean"] else "NOT CLEAN: " + "; ".join(ref["problems"])
        assert line in res["verdict"]
        assert ref["clean"] <= (interferences == 0)
    # the drawing reached the network as strokes, the upload as the file's own bytes
    drawn_folder = Path(re.search(r"folder: (\S+)", drawn["verdict"]).group(1))
    seen = cv2.imread(str(drawn_folder / "input.png"), cv2.IMREAD_GRAYSCALE)
    assert 0.01 < (seen < 128).mean() < 0.5
    up_folder = Path(re.search(r"folder: (\S+)", uploaded["verdict"]).group(1))
    assert (up_folder / "view_0.png").read_bytes() == sketch.read_bytes()
    assert (tmp_path / "serve.png").stat().st_size > 10_000
    assert not drawn["mirror_box"]  # the knife's template does not mirror: no tick box


@pytest.mark.skipif(not Path(CHROMIUM).is_file(), reason="no Chromium: make browser")
def test_the_pages_mirror_average_box_is_predicts_flag(tmp_path):
    ck = tiny_checkpoint(tmp_path, "car")  # the car's template mirrors
    with running_server([str(ck)], tmp_path / "serve") as url:
        res = make_cad(url, tmp_path / "got", chromium=CHROMIUM, mirror_average=True)
    assert res["mirror_box"]
    folder = Path(re.search(r"folder: (\S+)", res["verdict"]).group(1))
    assert read_json(folder / "prediction.json")["mirror_average"]
    predict(ck, [folder / "view_0.png"], tmp_path / "ref", mirror_average=True)
    assert np.array_equal(np.load(tmp_path / "ref" / "patches.npy"), np.load(folder / "patches.npy"))
