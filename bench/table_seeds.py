"""Every seed of every category's recipe, one markdown row each, from the raw result files.

The quality table in BENCHMARKS.md shows seed 0; this prints the table of all the seeds measured
beside it, so a reader sees at a glance which goals hold at every seed instead of reading them
out of prose. Each row reads `bench/results/eval_<TAG>.json` (`train evaluate`, one drawing),
`response_<TAG>.json` (`bench/probe_sketch_response.py`) and, where it exists, `eval_<TAG>_v4.json`
(`evaluate --views 4`: four drawings of each test model). A file that is missing leaves its cell
empty rather than failing the table.

Usage: python bench/table_seeds.py [--results bench/results]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

# category -> the raw files' tag of its recipe at each seed measured (BENCHMARKS.md's quality table)
RECIPE_RUNS: dict[str, tuple[str, ...]] = {
    "airplane": ("airplane_v3_fold_s0", "airplane_v3_fold_s1", "airplane_v3_fold_s2"),
    "bathtub": ("bathtub_2000_6k_s0", "bathtub_2000_6k_s1", "bathtub_2000_6k_s2"),
    "bottle": ("bottle_1000_rep", "bottle_1000_s1"),
    "car": ("car_1000_race", "car_1000_race_s1"),
    "guitar": ("guitar_1000_wch3_s0", "guitar_1000_wch3_s1"),
    "gun": ("gun_1000_fold_s0", "gun_1000_fold_s1"),
    "knife": ("knife_1000_6k_s0", "knife_1000_6k_s1", "knife_1000_6k_s2"),
    "mug": ("mug_1000_fold_s0", "mug_1000_fold_s1", "mug_1000_fold_s2"),
}
# The quality goals (BENCHMARKS.md): L_Ch this far below template and blind, at most this many
# crossing pairs a shape, a response ratio at least this.
GOAL_VS_TEMPLATE = -40.0
GOAL_VS_BLIND = -25.0
GOAL_PAIRS = 0.5
GOAL_RESPONSE = 2.0

HEADER = (
    "| category | seed | test shapes | vs template / blind | four drawings vs blind | pairs per shape "
    "| CAD-clean | response ratio | goals met | raw TAG |\n"
    "|---|---:|---:|---:|---:|---:|---:|---:|---|---|"
)


def _load(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.is_file() else None


def vs(evaluation: dict, baseline: str) -> float:
    """The network's L_Ch against ``baseline``'s ('template' or 'blind'), in percent: the ratio of
    the means, as `evaluate`'s ``chamfer_vs_*`` keys, which files written before those keys lack."""
    return 100.0 * (evaluation["model"]["chamfer"] / evaluation[baseline]["chamfer"] - 1.0)


def seed_of(tag: str) -> int:
    """The seed a tag names (``…_s1`` → 1); a tag without one is seed 0."""
    last = tag.rsplit("_", 1)[-1]
    return int(last[1:]) if last[:1] == "s" and last[1:].isdigit() else 0


def _pct(x: float) -> str:
    return f"{x:.1f} %".replace("-", "\u2212")  # the docs' minus sign


def goals_met(evaluation: dict, response: dict | None) -> str:
    """Which of the four goals a run meets, in the quality table's words (a run without a
    response file says so rather than counting the goal as missed)."""
    met = {
        "template": vs(evaluation, "template") <= GOAL_VS_TEMPLATE,
        "blind": vs(evaluation, "blind") <= GOAL_VS_BLIND,
        "pairs": evaluation["model"]["intersecting_pairs"] <= GOAL_PAIRS,
        "response": response is not None and response["ratio_models_to_variants"] >= GOAL_RESPONSE,
    }
    if all(met.values()):
        return "all four"
    said = ", ".join(k for k, ok in met.items() if ok) or "none"
    return said if response is not None else f"{said} (no response file)"


def row(category: str, tag: str, results: Path) -> str | None:
    """One run's markdown row, or None when its evaluation is not in ``results``."""
    evaluation = _load(results / f"eval_{tag}.json")
    if evaluation is None:
        return None
    response = _load(results / f"response_{tag}.json")
    four = _load(results / f"eval_{tag}_v4.json")
    model = evaluation["model"]
    checked = evaluation.get("cad_checked", 0)
    cad = f"{round(model['cad_clean'] * checked)} of {checked}" if checked else ""
    cells = [
        category,
        str(seed_of(tag)),
        str(evaluation["samples"]),
        f"{_pct(vs(evaluation, 'template'))} / {_pct(vs(evaluation, 'blind'))}",
        _pct(vs(four, "blind")) if four else "",
        f"{model['intersecting_pairs']:.2f}",
        cad,
        f"{response['ratio_models_to_variants']:.1f}" if response else "",
        goals_met(evaluation, response),
        f"`{tag}`",
    ]
    return "| " + " | ".join(cells) + " |"


def table(results: Path) -> str:
    """The markdown table of every recipe run whose evaluation is in ``results``."""
    rows = [r for cat, tags in RECIPE_RUNS.items() for t in tags if (r := row(cat, t, results))]
    return "\n".join([HEADER, *rows])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", type=Path, default=Path(__file__).parent / "results")
    print(table(ap.parse_args().results))


if __name__ == "__main__":
    main()
