"""Figure: validation L_Ch against the step for several runs on one dataset, with the template's and
the sketch-blind baseline's L_Ch on the same split as lines (how close the network gets to the
blind baseline, and when it stops moving).

Usage: .venv/bin/python bench/figure_curves.py --run LABEL=RUN_DIR [--run ...] \\
       --baselines EVAL_VAL.json --out docs/images/curves_<category>.png [--title TEXT]
``EVAL_VAL.json`` is ``python -m train evaluate --split val --out EVAL_VAL.json`` of one of the
runs: the template line is the same for every run on the dataset, the blind line is that run's
own mean output (another run's blind baseline differs by a few per cent).
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from pipeline.core.atomic import atomic_path  # noqa: E402


def validation_curve(run_dir: Path) -> list[tuple[int, float]]:
    """(step, validation L_Ch) from a run's log.csv."""
    with open(run_dir / "log.csv") as f:
        return [(int(r["step"]), float(r["val_chamfer"])) for r in csv.DictReader(f) if r.get("val_chamfer")]


def figure(runs: list[tuple[str, Path]], baselines: dict, out: Path, title: str) -> None:
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for label, run_dir in runs:
        curve = validation_curve(run_dir)
        ax.plot(*zip(*curve), lw=1.2, marker=".", ms=3, label=label)
    for key, style in (("template", ":"), ("blind", "--")):
        value = baselines[key]["chamfer"]
        ax.axhline(value, color="k", ls=style, lw=1, label=f"{key} ({baselines['split']}): {value:.4f}")
    goal = 0.75 * baselines["blind"]["chamfer"]
    ax.axhline(goal, color="tab:red", ls="-.", lw=1, label=f"goal, 25 % below blind: {goal:.4f}")
    ax.set_xlabel("step")
    ax.set_ylabel(f"L_Ch ({baselines['split']} split)")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=110, metadata={"Software": None})
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", action="append", required=True, metavar="LABEL=RUN_DIR")
    ap.add_argument("--baselines", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--title", default="")
    a = ap.parse_args()
    runs = [(spec.split("=", 1)[0], Path(spec.split("=", 1)[1])) for spec in a.run]
    figure(runs, json.loads(a.baselines.read_text()), a.out, a.title)
    print(a.out)


if __name__ == "__main__":
    main()
