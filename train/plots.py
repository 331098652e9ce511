"""Loss-curve plots from a run's log.csv (matplotlib, headless)."""

from __future__ import annotations

import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from pipeline.core.atomic import atomic_path  # noqa: E402


def plot_losses(csv_path: str | Path, png_path: str | Path) -> None:
    """One panel per logged term (log scale), step on x; the validation Chamfer, logged every
    ``val_every`` steps, is drawn over the training Chamfer."""
    with open(csv_path) as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return
    # terms a run does not use (the contrastive term when off) are empty columns
    keys = [k for k in rows[0] if k not in ("step", "seconds", "val_chamfer") and any(r[k] for r in rows)]
    steps = [int(r["step"]) for r in rows]
    val = [(int(r["step"]), float(r["val_chamfer"])) for r in rows if r.get("val_chamfer")]
    cols = min(4, len(keys))
    rows_n = -(-len(keys) // cols)
    fig, axes = plt.subplots(rows_n, cols, figsize=(3.2 * cols, 2.6 * rows_n), squeeze=False)
    for ax in axes.flat[len(keys) :]:
        ax.axis("off")
    for ax, k in zip(axes.flat, keys):
        points = [(step, float(r[k])) for step, r in zip(steps, rows) if r[k]]
        vals = [v for _, v in points]
        ax.plot(*zip(*points), lw=1, label="train")
        if k == "chamfer" and val:
            ax.plot(*zip(*val), lw=1.2, marker=".", label="val")
            ax.legend(fontsize=7)
        if all(v > 0 for v in vals):
            ax.set_yscale("log")
        ax.set_title(k, fontsize=9)
        ax.set_xlabel("step", fontsize=8)
        ax.tick_params(labelsize=7)
    fig.tight_layout()
    with atomic_path(png_path) as tmp:
        fig.savefig(tmp, dpi=100, metadata={"Software": None})
    plt.close(fig)
