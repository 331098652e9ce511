"""The testbed without its web page: checkpoints loaded once, a person's views in, CAD files out.

Each request runs ``train.predict.predict_run`` (the same normalization, network call, exports and
kernel verdict as ``python -m train predict``) in a folder of its own under ``out``, which keeps
the views as they were given, so ``python -m train predict --sketch FOLDER/view_0.png`` redoes
it. Only the page's 3D view (``view.glb``) is added.
"""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from pipeline.core.atomic import write_bytes
from pipeline.core.settings_io import setting
from train.data import param_mirror
from train.errors import UsageError
from train.export.units import CadFileSettings, CadUnits
from train.fit import TrainedRun, load_run
from train.mirror_average import mirror_averaged
from train.predict import predict_run, verdict_line
from train.serve.view_mesh import write_view_glb

# What a request folder holds for the page to offer: key -> file name.
DOWNLOADS = {
    "step": "patches.stp",
    "iges": "patches.igs",
    "obj": "mesh.obj",
    "quads": "quads.obj",
}
# Image file signatures, to keep an upload's own suffix on its copy.
_MAGIC = {b"\x89PNG": ".png", b"\xff\xd8\xff": ".jpg", b"RIFF": ".webp", b"II*\x00": ".tif", b"MM\x00*": ".tif"}


@dataclasses.dataclass(frozen=True)
class ServeSettings(CadFileSettings):
    """``python -m train serve``: one flag per field."""

    checkpoint: tuple[str, ...] = setting(
        help="one or more checkpoint.pt / best.pt (several: --checkpoint A B; the page offers a choice)"
    )
    host: str = setting("127.0.0.1", "address to listen on; 127.0.0.1 keeps the page to this machine")
    port: int = setting(7860, "port to listen on")
    out: str = setting("serve-out", "folder of the predictions, one subfolder per request")


@dataclasses.dataclass(frozen=True)
class ServeResult:
    """One request's outcome: its folder, the files to offer, and the kernel's verdict."""

    folder: Path
    files: dict[str, Path]  # DOWNLOADS' keys + "glb" (the 3D view), "input" (what the network saw), "json"
    clean: bool
    problems: list[str]
    crossing_patches: list[int]  # patches the kernel names: members of interfering pairs and folded ones
    prediction: dict  # prediction.json

    @property
    def verdict(self) -> str:
        """The line ``python -m train predict`` prints for the same result."""
        return verdict_line(self.clean, self.problems)


def checkpoint_labels(paths: Sequence[str | Path]) -> list[str]:
    """Short distinct names for the page's chooser: ``run/best.pt``, longer only where needed."""
    paths = [Path(p).resolve() for p in paths]
    for depth in range(2, max((len(p.parts) for p in paths), default=2) + 1):
        labels = ["/".join(p.parts[-depth:]) for p in paths]
        if len(set(labels)) == len(labels):
            return labels
    raise UsageError(f"--checkpoint: a file is named twice ({', '.join(map(str, paths))})")


def view_bytes(view: bytes | np.ndarray | str | Path) -> tuple[bytes, str]:
    """(image file bytes, suffix) of a view: file bytes as given, a file's contents, or an array
    (H, W), (H, W, 3) RGB or (H, W, 4) RGBA, uint8, as image widgets hand them over) as PNG."""
    if isinstance(view, (str, Path)):
        path = Path(view)
        if not path.is_file():
            raise UsageError(f"{path}: no such sketch file")
        view = path.read_bytes()
    if isinstance(view, bytes):
        suffix = next((s for magic, s in _MAGIC.items() if view.startswith(magic)), ".img")
        return view, suffix
    img = np.asarray(view)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3, 4)):
        raise UsageError(f"a drawing as an array must be uint8 (H, W[, 1|3|4]), not {img.dtype} {img.shape}")
    if img.ndim == 3 and img.shape[2] >= 3:  # OpenCV writes BGR(A)
        img = cv2.cvtColor(img, cv2.COLOR_RGBA2BGRA if img.shape[2] == 4 else cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise UsageError(f"a drawing of shape {img.shape} cannot be encoded as PNG")
    return buf.tobytes(), ".png"


def has_strokes(img: np.ndarray) -> bool:
    """Whether an RGB(A) drawing from the page's sketchpad has any mark on it (an untouched pad
    is transparent or white; it is left out rather than reported as a blank sketch)."""
    img = np.asarray(img)
    if img.ndim == 2:
        return bool((img < 200).any())
    dark = img[..., :3].min(axis=-1) < 200
    if img.shape[2] == 4:
        dark &= img[..., 3] > 16
    return bool(dark.any())


class ServeSession:
    """Checkpoints loaded once (``load_run``: weights-only unpickling, no code runs) and the
    predictions made with them."""

    def __init__(self, checkpoints: Sequence[str | Path], out: str | Path, units: CadUnits = CadUnits()) -> None:
        if not checkpoints:
            raise UsageError("--checkpoint: give at least one checkpoint")
        self.runs: dict[str, TrainedRun] = {
            label: load_run(path) for label, path in zip(checkpoint_labels(checkpoints), checkpoints)
        }
        self.out = Path(out)
        self.units = units
        # label -> the run through MirrorAverage, for templates that mirror (made once: the check is not free)
        self._mirrored: dict[str, TrainedRun] = {
            label: mirror_averaged(run) for label, run in self.runs.items() if param_mirror(run.template) is not None
        }

    @property
    def labels(self) -> list[str]:
        return list(self.runs)

    def run(self, label: str | None = None) -> TrainedRun:
        if label is None:
            return next(iter(self.runs.values()))
        if label not in self.runs:
            raise UsageError(f"no checkpoint {label!r}; loaded: {', '.join(self.runs)}")
        return self.runs[label]

    def mirrors(self, label: str | None = None) -> bool:
        """Whether the checkpoint's template mirrors its parameters (the page's mirror-average toggle)."""
        self.run(label)  # an unknown label is an error naming the loaded ones
        return (label or self.labels[0]) in self._mirrored

    def parts(self, label: str | None = None) -> list[str]:
        """The optional parts of the checkpoint's template (the page's toggles)."""
        return list(self.run(label).template.part_names)

    def predict(
        self,
        views: Sequence[bytes | np.ndarray | str | Path],
        label: str | None = None,
        parts: dict[str, bool] | None = None,
        mirror_average: bool = False,
    ) -> ServeResult:
        """Predict from one or more views of one object into a new folder under ``out``; a
        failure (no drawing, a wrong part, a template without a mirror) leaves no folder behind.
        ``mirror_average``: as ``predict --mirror-average``."""
        if not views:
            raise UsageError("no drawing: draw on the sketchpad or upload one or more views")
        run = self.run(label)
        if mirror_average:
            run = self._mirrored.get(label or self.labels[0]) or mirror_averaged(run)  # the latter refuses by name
        self.out.mkdir(parents=True, exist_ok=True)
        folder = Path(tempfile.mkdtemp(prefix=time.strftime("%Y%m%d-%H%M%S-"), dir=self.out))
        try:
            paths = []
            for k, view in enumerate(views):
                data, suffix = view_bytes(view)
                paths.append(folder / f"view_{k}{suffix}")
                write_bytes(paths[-1], data)
            res = predict_run(run, paths, folder, parts, self.units)
            kernel = res["cad_kernel"]
            crossing = sorted({i for pair in kernel["patch_pairs"] for i in pair} | set(kernel["folded_patches"]))
            glb = write_view_glb(folder / "quads.obj", crossing, folder / "view.glb")
        except BaseException:
            shutil.rmtree(folder, ignore_errors=True)
            raise
        files = {k: folder / name for k, name in DOWNLOADS.items()}
        files.update(glb=glb, input=folder / "input.png", json=folder / "prediction.json")
        return ServeResult(folder, files, bool(res["clean"]), list(res["problems"]), crossing, res)
