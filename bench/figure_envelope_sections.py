"""Cross-sections of the source, the raw Manifold envelope and the pulled-back one, side by side.

    .venv/bin/python bench/figure_envelope_sections.py [--out docs/images/envelope_sections.png]

For a few procedural models (the bench corpus of ``bench_pipeline.py``) it cuts each surface with
one plane across a thin part (knife blade, mug wall, airplane wing, guitar body) and draws the
cuts: source in black, the envelope at resolution 5000 (the earlier default) in red, the
envelope at resolution 2500 pulled back (``pull_to_source`` 0.9, the default since) in blue. The
training targets are sampled on the envelope, so the gap between black and colour is how much
thicker the network's targets are than the drawn object.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_pipeline import write_corpus  # noqa: E402  (this folder is on the path when run as a script)

from pipeline.prepare.watertight import make_watertight, pull_to_source  # noqa: E402
from pipeline.sources.mesh_io import load_mesh  # noqa: E402

# category, model index in the corpus, plane axis, plane offset (source frame), zoom box half-size
CUTS = [
    ("knife", 0, 2, -0.4, 0.08),
    ("mug", 0, 1, 0.5, 0.55),
    ("airplane", 0, 0, 0.6, 0.15),
    ("guitar", 0, 1, 0.0, 0.35),
]
STYLES = [
    ("source", "black", 1.6),
    ("Manifold 5000 (before)", "tab:red", 1.0),
    ("Manifold 2500 pulled 0.9 (now)", "tab:blue", 1.0),
]


def section_segments(vertices: np.ndarray, faces: np.ndarray, axis: int, offset: float) -> np.ndarray:
    """(n, 2, 2) segments of the mesh cut by the plane x[axis] = offset, in the other two axes."""
    normal = np.eye(3)[axis]
    segments = trimesh.intersections.mesh_plane(
        trimesh.Trimesh(vertices, faces, process=False), normal, normal * offset
    )
    keep = [i for i in range(3) if i != axis]
    return np.asarray(segments)[:, :, keep]


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_envelope"))
    ap.add_argument("--out", type=Path, default=Path("docs/images/envelope_sections.png"))
    args = ap.parse_args()
    write_corpus(args.work, 1 + max(c[1] for c in CUTS))
    fig, axes = plt.subplots(1, len(CUTS), figsize=(4.2 * len(CUTS), 4.6))
    for ax, (category, index, axis, offset, half) in zip(axes, CUTS):
        path = sorted((args.work / "corpus" / category).glob("*.ply"))[index]
        v, f = load_mesh(path, 1 << 30)
        old = make_watertight(v, f, 5000, 0)
        wv, wf = make_watertight(v, f, 2500, 0)
        new = (pull_to_source(wv, wf, v, f, 0.9), wf)
        cuts = [section_segments(mv, mf, axis, offset) for mv, mf in [(v, f), old, new]]
        for (label, colour, width), seg in zip(STYLES, cuts):
            for a, b in seg:
                ax.plot([a[0], b[0]], [a[1], b[1]], color=colour, lw=width)
            ax.plot([], [], color=colour, lw=width, label=label)
        centre = cuts[0].reshape(-1, 2).mean(axis=0)  # the source's cut
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_aspect("equal")
        ax.set_title(f"{category} {path.stem}: cut at {'xyz'[axis]} = {offset}")
        ax.tick_params(labelsize=7)
    axes[0].legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
