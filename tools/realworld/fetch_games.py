"""Fetch free game meshes from Debian and write them as a folder source, in the procedural /
ShapeNet frame (y up, length along z, front toward -z): ``<out>/<category>/<model>.obj``.

    python tools/realworld/fetch_games.py --source torcs --out sources/games   # car/, 16 bodies
    python tools/realworld/fetch_games.py --source gl117 --out sources/games   # airplane/, 12 jets

* ``torcs``: the car bodies of the TORCS racing game (Debian ``torcs-data``, GPL-2+ / Free Art
  data), AC3D ``cars/<name>/<name>.acc`` triangle strips, thousands of disconnected pieces, no
  wheels (the game adds them); bodies under MIN_FACES triangles (none today) are left out.
* ``gl117``: the aircraft of the GL-117 flight game (Debian ``gl-117-data``, GPL-2), 3DS
  ``models/gl-*.3ds`` and ``transp*.3ds`` (600-1,200 triangles, wings single sheets) but the
  game's logo model ``gl-117.3ds`` and ``transp2.3ds`` (a copy of ``transp1.3ds``): 12.

The package is downloaded with ``apt-get download`` (nothing installed, no root needed; where the
machine has no package lists, lists of its own are fetched first) into a temporary folder, or
read from ``--deb``; only the wanted members
are read out of it (``dpkg-deb --fsys-tarfile``), the formats are parsed here (game_formats.py:
no assimp). ``<out>/<category>/COPYRIGHT.debian`` is the package's copyright file. Exit status 3
when the package cannot be fetched (no network, no apt lists), with the reason on stderr.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import re
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # game_formats beside this script
from game_formats import read_3ds, read_ac3d, write_obj  # noqa: E402

CANNOT_FETCH = 3
MIN_FACES = 500
# Game frames to the project's, as rows applied to column vectors.
# AC3D (TORCS): y up, the front toward +x  ->  front toward -z: (x, y, z) -> (z, y, -x).
AC3D_TO_PROJECT = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], float)
# 3DS (GL-117): z up, the nose toward -y  ->  y up, nose toward -z: (x, y, z) -> (y, z, x).
MAX3DS_TO_PROJECT = np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]], float)


@dataclasses.dataclass(frozen=True)
class Game:
    package: str
    category: str
    member: re.Pattern  # path inside the package; group 1 names the model
    read: Callable[[bytes], tuple[np.ndarray, np.ndarray]]
    rotation: np.ndarray
    model_prefix: str = ""
    exclude: tuple[str, ...] = ()


GAMES = {
    "torcs": Game(
        "torcs-data",
        "car",
        re.compile(r"usr/share/games/torcs/cars/([^/]+)/\1\.acc"),
        lambda b: read_ac3d(b.decode("latin-1")),
        AC3D_TO_PROJECT,
    ),
    "gl117": Game(
        "gl-117-data",
        "airplane",
        re.compile(r"usr/share/games/gl-117/models/((?:gl-|transp)[^/]*)\.3ds"),
        read_3ds,
        MAX3DS_TO_PROJECT,
        model_prefix="gl117_",
        exclude=("gl-117",),
    ),
}


class CannotFetch(RuntimeError):
    """The package could not be downloaded or read: the caller skips, nothing is wrong here."""


def _apt(args: list[str], folder: Path) -> subprocess.CompletedProcess:
    try:
        return subprocess.run(["apt-get", *args], cwd=folder, capture_output=True, text=True, timeout=900)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise CannotFetch(f"apt-get {' '.join(args)}: {exc}") from None


def download(package: str, folder: Path) -> Path:
    """``apt-get download`` into ``folder``; the .deb's path. Where the machine's package lists
    do not know the package (an image with its lists removed), lists of its own are fetched into
    ``folder`` first: no root, nothing of the system's changed."""
    run = _apt(["download", package], folder)
    if run.returncode != 0:
        lists = folder / "apt-lists"
        (lists / "partial").mkdir(parents=True, exist_ok=True)
        own = ["-o", f"Dir::State::Lists={lists}", "-o", "Debug::NoLocking=1"]
        update = _apt([*own, "update"], folder)
        run = _apt([*own, "download", package], folder) if update.returncode == 0 else update
    debs = sorted(folder.glob(f"{package}_*.deb"))
    if run.returncode != 0 or not debs:
        reason = (run.stderr.strip().splitlines() or ["no .deb written"])[-1]
        raise CannotFetch(f"apt-get download {package} failed ({run.returncode}): {reason}")
    return debs[0]


def deb_members(deb: Path, wanted: Callable[[str], bool]) -> Iterator[tuple[str, bytes]]:
    """(path, bytes) of the package's files for which ``wanted(path)``, streamed (torcs-data is
    a third of a gigabyte packed: nothing else is written out)."""
    try:
        proc = subprocess.Popen(["dpkg-deb", "--fsys-tarfile", str(deb)], stdout=subprocess.PIPE)
    except OSError as exc:
        raise CannotFetch(f"dpkg-deb: {exc}") from None
    try:
        with tarfile.open(fileobj=proc.stdout, mode="r|") as tar:
            for info in tar:
                name = info.name.removeprefix("./")
                if info.isfile() and wanted(name):
                    yield name, tar.extractfile(info).read()
    finally:
        proc.stdout.close()
        if proc.wait() != 0:
            raise CannotFetch(f"dpkg-deb --fsys-tarfile {deb.name} failed ({proc.returncode})")


def convert(game: Game, deb: Path, out: Path) -> list[str]:
    """Write the game's models as OBJs under ``out/<category>``; the model names, sorted. A file
    identical to one before it (GL-117's transp2 is transp1) is left out: a build would reject
    it as a duplicate, not a mesh it cannot prepare."""
    folder = out / game.category
    folder.mkdir(parents=True, exist_ok=True)
    copyright_file = f"usr/share/doc/{game.package}/copyright"
    members = dict(deb_members(deb, lambda p: p == copyright_file or bool(game.member.fullmatch(p))))
    if copyright_file in members:
        (folder / "COPYRIGHT.debian").write_bytes(members.pop(copyright_file))
    written, seen = [], {}
    for name, data in sorted(members.items()):
        model = game.member.fullmatch(name).group(1)
        if model in game.exclude:
            continue
        digest = hashlib.sha256(data).hexdigest()
        if digest in seen:
            print(f"skip {name}: the same file as {seen[digest]}", file=sys.stderr)
            continue
        seen[digest] = name
        try:
            vertices, faces = game.read(data)
        except ValueError as exc:
            print(f"skip {name}: {exc}", file=sys.stderr)
            continue
        if len(faces) < MIN_FACES:
            print(f"skip {name}: {len(faces)} triangles < {MIN_FACES}", file=sys.stderr)
            continue
        write_obj(folder / f"{game.model_prefix}{model}.obj", vertices @ game.rotation.T, faces)
        written.append(game.model_prefix + model)
    return sorted(written)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--source", choices=sorted(GAMES), required=True)
    ap.add_argument("--out", type=Path, required=True, help="source root: models go to OUT/CATEGORY/")
    ap.add_argument("--deb", type=Path, help="an already downloaded .deb of the source's package")
    a = ap.parse_args(argv)
    game = GAMES[a.source]
    try:
        with tempfile.TemporaryDirectory() as tmp:
            deb = a.deb or download(game.package, Path(tmp))
            models = convert(game, deb, a.out)
    except CannotFetch as exc:
        print(f"cannot fetch {a.source}: {exc}", file=sys.stderr)
        return CANNOT_FETCH
    print(f"{len(models)} models -> {a.out / game.category}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
