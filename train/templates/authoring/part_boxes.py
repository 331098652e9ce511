"""Per-part bounding boxes → the cuboid collection a template is built from.

Labels lose their side and instance suffixes ("wing_l", "engine0_r" → "wing", "engine") so a
part and its mirror image share a label. Mugs are refined as the paper describes: the cup's box
becomes four walls and a bottom (an interior void open at the top) and the handle's box becomes
three bars that close a loop with the cup wall (a hole in the handle), so the template has genus 1.
Bathtubs likewise: the paper builds them from five cuboids, the tub's box becomes a floor and four
walls, so the template has the basin (a closed box cannot: a Coons patch spanning the rim is
fixed by its boundary curves and cannot dip into the basin, so training folds it in).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from pipeline.core.schema import part_family as base_label
from train.templates.authoring.lattice import Box, CuboidLike

WALL = 0.12  # cup wall thickness, fraction of the cup's half-width
BOTTOM = 0.12  # cup bottom thickness, fraction of its height
BAR = 0.25  # handle bar thickness, fraction of the handle's reach / height
# bathtub wall / floor (procedural tubs: wall 0.04–0.09 on half-widths 0.28–0.55, floor ~ 1/5 of the height)
TUB_WALL = 0.18
TUB_BOTTOM = 0.2
# category -> (part label whose box becomes floor + four walls, wall fraction, bottom fraction)
HOLLOW = {"mug": ("cup", WALL, BOTTOM), "bathtub": ("tub", TUB_WALL, TUB_BOTTOM)}


def category_boxes(category: str, cuboids: Sequence[CuboidLike]) -> list[Box]:
    boxes = [Box(base_label(c.label), np.asarray(c.lo, float), np.asarray(c.hi, float)) for c in cuboids]
    if category in HOLLOW:
        label, wall, bottom = HOLLOW[category]
        boxes = [h for b in boxes for h in (hollow_box(b, wall, bottom) if b.label == label else [b])]
    if category == "mug":
        boxes = _handles(boxes)
    return boxes


def _handles(boxes: list[Box]) -> list[Box]:
    """Each handle box becomes a three-bar loop against the cup (its walls already hollowed)."""
    cups = [b for b in boxes if b.label == "cup"]
    if not cups:
        return boxes
    cup = Box("cup", np.min([b.lo for b in cups], 0), np.max([b.hi for b in cups], 0))
    out = [b for b in boxes if b.label != "handle"]
    for h in (b for b in boxes if b.label == "handle"):
        out += handle_loop(h, cup)
    return out


def hollow_box(box: Box, wall: float, bottom: float) -> list[Box]:
    """Bottom slab plus four walls: the union is ``box`` with a void open at the top (y up).
    ``wall``: thickness as a fraction of the smaller horizontal half-extent; ``bottom``: of the height."""
    lo, hi, label = box.lo, box.hi, box.label
    w = wall * 0.5 * min(hi[0] - lo[0], hi[2] - lo[2])
    b = bottom * (hi[1] - lo[1])
    return [
        Box(label, lo.copy(), np.array([hi[0], lo[1] + b, hi[2]])),
        Box(label, lo.copy(), np.array([lo[0] + w, hi[1], hi[2]])),
        Box(label, np.array([hi[0] - w, lo[1], lo[2]]), hi.copy()),
        Box(label, lo.copy(), np.array([hi[0], hi[1], lo[2] + w])),
        Box(label, np.array([lo[0], lo[1], hi[2] - w]), hi.copy()),
    ]


def handle_loop(handle: Box, cup: Box) -> list[Box]:
    """Top bar, bottom bar and outer bar: with the cup wall they enclose the handle's hole."""
    lo, hi = handle.lo.copy(), handle.hi.copy()
    # The handle sticks out of the cup along the horizontal axis where it reaches farthest.
    reach = [hi[0] - cup.hi[0], cup.lo[0] - lo[0], hi[2] - cup.hi[2], cup.lo[2] - lo[2]]
    k = int(np.argmax(reach))
    axis, outward = (0, 2)[k // 2], 1 if k % 2 == 0 else -1
    wall = cup.hi[axis] if outward > 0 else cup.lo[axis]
    if reach[k] <= 0:
        return [handle]
    # Start the bars inside the wall so they overlap it; the outer bar sits at the far end.
    if outward > 0:
        lo[axis] = min(lo[axis], wall - 0.5 * WALL * (cup.hi[axis] - cup.lo[axis]) * 0.5)
    else:
        hi[axis] = max(hi[axis], wall + 0.5 * WALL * (cup.hi[axis] - cup.lo[axis]) * 0.5)
    t_out = BAR * reach[k]
    t_y = BAR * (hi[1] - lo[1])
    top = Box("handle", np.array([lo[0], hi[1] - t_y, lo[2]]), hi.copy())
    bottom = Box("handle", lo.copy(), np.array([hi[0], lo[1] + t_y, hi[2]]))
    o_lo, o_hi = lo.copy(), hi.copy()
    if outward > 0:
        o_lo[axis] = hi[axis] - t_out
    else:
        o_hi[axis] = lo[axis] + t_out
    return [top, bottom, Box("handle", o_lo, o_hi)]
