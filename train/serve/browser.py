"""The testbed driven as a person drives it: a real server, headless Chromium (Debian's, through
Playwright), a drawing or an upload, the 3D view, the STEP downloaded through the page.

Used by the slow browser test and for the README's screenshot::

    .venv-serve/bin/python -m train.serve.browser --checkpoint RUN/best.pt --sketch S.png \\
        --screenshot docs/images/serve.png

Needs the serve extra (``make serve-env``: playwright) and ``/usr/bin/chromium`` (``make browser``).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

from pipeline.core.settings_io import add_arguments, from_args, setting
from train.errors import UsageError

# Chromium in a closed network: without the background-networking flags its own connections are
# refused and it stalls; a fresh profile each time.
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)
VIEWPORT = {"width": 1400, "height": 1000}
# a box's edges in sketchpad fractions: what the browser test draws with the mouse
BOX_STROKES = (
    ((0.30, 0.40), (0.62, 0.30), (0.78, 0.42), (0.46, 0.52), (0.30, 0.40)),
    ((0.30, 0.40), (0.30, 0.62), (0.46, 0.74), (0.78, 0.64), (0.78, 0.42)),
    ((0.46, 0.52), (0.46, 0.74)),
)


@dataclasses.dataclass(frozen=True)
class BrowserSettings:
    """``python -m train.serve.browser``: serve, make CAD once through the page, save what came back."""

    checkpoint: tuple[str, ...] = setting(help="checkpoint(s) to serve")
    sketch: tuple[str, ...] = setting((), "views to upload (none: draw a box on the sketchpad with the mouse)")
    downloads: str = setting("serve-out/browser", "folder for the files downloaded through the page")
    screenshot: str | None = setting(None, "save a screenshot of the page with its result here (PNG)")
    mirror_average: bool = setting(False, "tick the page's mirror average (templates that mirror: airplane, car)")
    chromium: str = setting("/usr/bin/chromium", "the Chromium executable (Debian's package)")
    timeout: float = setting(300.0, "seconds to wait for the server and for the prediction")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def running_server(checkpoints: list[str], out: str | Path, timeout: float = 300.0) -> Iterator[str]:
    """``python -m train serve`` in a subprocess (this interpreter: the serve env) on a free port
    of 127.0.0.1; yields its URL once the page answers, stops it afterwards."""
    port = free_port()
    log = tempfile.NamedTemporaryFile("w+", prefix="serve-", suffix=".log", delete=False)
    cmd = [sys.executable, "-m", "train", "serve", "--checkpoint", *map(str, checkpoints)]
    cmd += ["--port", str(port), "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=Path(__file__).resolve().parents[2])
    url = f"http://127.0.0.1:{port}/"
    try:
        deadline = time.monotonic() + timeout
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"the server exited ({proc.returncode}): {Path(log.name).read_text()[-2000:]}")
            with contextlib.suppress(OSError):
                with urllib.request.urlopen(url, timeout=5) as r:
                    if r.status == 200:
                        break
            if time.monotonic() > deadline:
                raise TimeoutError(f"no page at {url} after {timeout:g} s: {Path(log.name).read_text()[-2000:]}")
            time.sleep(0.5)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()
        os.unlink(log.name)


def draw_box(page) -> None:
    """Pick the sketchpad's brush and draw :data:`BOX_STROKES` with the mouse."""
    page.locator("#sketchpad button[aria-label='Brush']").click()
    box = page.locator("#sketchpad canvas").last.bounding_box()
    side = min(box["width"], box["height"])  # the drawing area is the canvas's centred square
    x0, y0 = box["x"] + (box["width"] - side) / 2, box["y"] + (box["height"] - side) / 2
    for stroke in BOX_STROKES:
        pts = [(x0 + fx * side, y0 + fy * side) for fx, fy in stroke]
        page.mouse.move(*pts[0])
        page.mouse.down()
        for p in pts[1:]:
            page.mouse.move(*p, steps=12)
        page.mouse.up()


def make_cad(
    url: str,
    downloads: str | Path,
    sketches: list[str] = (),
    screenshot: str | Path | None = None,
    chromium: str = "/usr/bin/chromium",
    timeout: float = 300.0,
    mirror_average: bool = False,
) -> dict:
    """Open the page, upload ``sketches`` (or draw a box), tick the mirror average if asked, press
    Make CAD, wait for the 3D view, download every offered file through the browser. Returns
    {"verdict": text, "files": {name: path}, "mirror_box": whether the page showed the tick box}."""
    from playwright.sync_api import sync_playwright

    if not Path(chromium).is_file():
        raise UsageError(f"{chromium}: no Chromium (make browser: apt-get install chromium)")
    downloads = Path(downloads)
    downloads.mkdir(parents=True, exist_ok=True)
    profile = tempfile.mkdtemp(prefix="chromium-profile-")
    try:
        with sync_playwright() as pw:
            ctx = pw.chromium.launch_persistent_context(
                profile,
                executable_path=chromium,
                args=list(CHROMIUM_FLAGS),
                headless=True,
                viewport=VIEWPORT,
                accept_downloads=True,
            )
            try:
                page = ctx.new_page()
                page.set_default_timeout(timeout * 1000)
                page.goto(url, wait_until="networkidle")
                if sketches:
                    page.locator("#uploads input[type=file]").set_input_files([str(s) for s in sketches])
                    for name in {Path(s).name for s in sketches}:  # uploaded: the page offers it back
                        page.locator(f"#uploads a[download='{name}']").wait_for()
                else:
                    draw_box(page)
                box = page.locator("#mirror-average input[type=checkbox]")
                mirror_box = box.count() > 0 and box.is_visible()
                if mirror_average:
                    if not mirror_box:
                        raise UsageError("the page offers no mirror average for this checkpoint's template")
                    box.check()
                page.locator("#make-cad").click()
                page.locator("#model3d canvas").wait_for()
                links = page.locator("#downloads a[download]")
                links.first.wait_for()
                files = {}
                for i in range(links.count()):
                    with page.expect_download() as info:
                        links.nth(i).click()
                    d = info.value
                    files[d.suggested_filename] = downloads / d.suggested_filename
                    d.save_as(files[d.suggested_filename])
                verdict = page.locator("#verdict").inner_text()
                if screenshot is not None:
                    page.wait_for_timeout(1500)  # the 3D view's first frames
                    Path(screenshot).parent.mkdir(parents=True, exist_ok=True)
                    page.screenshot(path=str(screenshot), full_page=True)
            finally:
                ctx.close()
    finally:
        shutil.rmtree(profile, ignore_errors=True)
    return {"verdict": verdict, "files": files, "mirror_box": mirror_box}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m train.serve.browser", description=__doc__.split("\n\n")[0])
    add_arguments(parser, BrowserSettings)
    s = from_args(BrowserSettings, parser.parse_args(argv))
    out = Path(s.downloads)
    with running_server(list(s.checkpoint), out / "server", s.timeout) as url:
        res = make_cad(url, out, list(s.sketch), s.screenshot, s.chromium, s.timeout, s.mirror_average)
    print(res["verdict"])
    print("downloaded: " + " ".join(str(p) for p in res["files"].values()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
