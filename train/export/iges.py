"""IGES 5.3 writer and reader for bicubic patches as Rational B-Spline Surfaces (entity 128).

Each patch is written exactly: degree 3 x 3, all weights 1, as a B-spline of ``SPANS`` (4)
uniform spans in each direction (knots 0,0,0,0,¼,½,¾,1,1,1,1, 7 x 7 control points): the bicubic
Bézier net with knots inserted, which is the same surface (each new control point is a blossom
value of the Bézier net, de Casteljau with the knots as parameters). Why not the single-span
form (4 x 4, knots 0,0,0,0,1,1,1,1): OpenCASCADE's sewing, which is what CAD programs built on it
run on an IGES of loose faces, seeds its projection of one edge onto its neighbour from a few
samples per span, and on a single-span edge that doubles back (a strongly bent prediction) it
lands on the wrong branch and leaves two identical edges unsewn at any tolerance; 2 spans did
not cure every measured case, 4 did (``tests/test_cad_tolerances.py``). The file has the
fixed-format sections Start (S), Global (G), Directory Entry (D, two lines per entity),
Parameter Data (P) and Terminate (T), each record 80 columns with the section letter in column 73
and the sequence number in 74-80. Coordinates are model coordinates × ``CadUnits.factor``, and the
Global section declares the matching unit (flag + name), so CAD programs open the file at the
chosen size. The surfaces stand alone (no shared edges): ``patches.stp`` carries the sewn solid.
The reader parses that structure back (for round-trip checks
and for loading exported files) without any CAD library.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.core.atomic import write_bytes
from pipeline.core.errors import ModelError
from train.export.units import CadUnits

SPANS = 4  # uniform spans per direction: see the module docstring
_KNOTS = (0.0,) * 4 + tuple(k / SPANS for k in range(1, SPANS)) + (1.0,) * 4
# A fixed timestamp keeps the file byte-identical across runs (the standard requires one).
_DATE = "20210101.000000"


def _real(x: float) -> str:
    return f"{float(x):.17E}".replace("E", "D")  # 'D' marks double precision; 17 digits round-trips


def _hollerith(text: str) -> str:
    return f"{len(text)}H{text}"


def _records(tokens: list[str], width: int) -> list[str]:
    """Pack delimited tokens into lines of at most ``width`` columns without splitting a token."""
    lines, cur = [], ""
    for tok in tokens:
        if len(cur) + len(tok) > width:
            lines.append(cur)
            cur = ""
        cur += tok
    if cur:
        lines.append(cur)
    return lines


def _delimited(values: list[str]) -> list[str]:
    return [v + "," for v in values[:-1]] + [values[-1] + ";"]


def _blossom(ctrl: np.ndarray, us: tuple[float, float, float]) -> np.ndarray:
    """Blossom of cubic Bézier control points ``(4, ...)`` at ``us``: de Casteljau with one
    parameter per level (at equal parameters it is the curve point)."""
    pts = np.asarray(ctrl, dtype=np.float64)
    for u in us:
        pts = (1.0 - u) * pts[:-1] + u * pts[1:]
    return pts[0]


def bspline_control(net: np.ndarray) -> np.ndarray:
    """Control points ``(n, n, 3)`` over ``_KNOTS`` of the bicubic net ``(4, 4, 3)`` (i along s, j
    along t): the same surface. Control point i of a cubic B-spline is the blossom at knots
    i+1..i+3, so the ends stay the net's and no fitting is involved."""
    triples = [tuple(_KNOTS[i + 1 : i + 4]) for i in range(len(_KNOTS) - 4)]
    along_s = np.stack([_blossom(net, u) for u in triples])  # (n, 4, 3)
    return np.stack([_blossom(along_s.transpose(1, 0, 2), u) for u in triples], axis=1)


def entity128_params(net: np.ndarray) -> list[str]:
    """Parameter list of one bicubic net (4, 4, 3), ``net[i, j]`` with i along u (s), j along v (t)."""
    ctrl = bspline_control(net)
    n = ctrl.shape[0] - 1  # upper index of the control points in each direction
    params = ["128", str(n), str(n), "3", "3", "0", "0", "1", "0", "0"]
    params += [_real(k) for k in _KNOTS] * 2
    params += [_real(1.0)] * (n + 1) ** 2
    for j in range(n + 1):  # the first index (u) varies fastest
        for i in range(n + 1):
            params += [_real(c) for c in ctrl[i, j]]
    params += [_real(0.0), _real(1.0), _real(0.0), _real(1.0)]
    return params


def iges_text(nets: np.ndarray, name: str = "patches.igs", units: CadUnits = CadUnits()) -> str:
    """IGES text of model-frame nets ``(P, 4, 4, 3)``, written × ``units.factor`` in ``units``."""
    nets = np.asarray(nets, dtype=np.float64) * units.factor
    flag, unit_name = units.iges
    extent = float(np.abs(nets).max()) if nets.size else 1.0
    start = ["sketch2patch: Coons patches as exact bicubic NURBS (entity 128)"]
    glob = [
        "1H,",
        "1H;",
        _hollerith("sketch2patch"),
        _hollerith(name),
        _hollerith("sketch2patch"),
        _hollerith("0.1.0"),
        "32",
        "38",
        "6",
        "308",
        "15",
        _hollerith("sketch2patch"),
        "1.0",
        str(flag),
        _hollerith(unit_name),
        "1",
        _real(1e-3 * units.factor),
        _hollerith(_DATE),
        _real(1e-9 * units.factor),
        _real(extent),
        "",
        "",
        "11",
        "0",
        _hollerith(_DATE),
    ]
    d_lines: list[str] = []
    p_lines: list[str] = []
    for k, net in enumerate(nets):
        de = 2 * k + 1
        chunk = _records(_delimited(entity128_params(net)), 64)
        first_p = len(p_lines) + 1
        p_lines += [f"{c:<64} {de:>7}" for c in chunk]
        fields1 = [128, first_p, 0, 0, 0, 0, 0, 0]
        d_lines.append("".join(f"{v:>8}" for v in fields1) + "00000000")
        fields2 = ["128", "0", "0", str(len(chunk)), "0", "", "", "PATCH", str(k)]
        d_lines.append("".join(f"{v:>8}" for v in fields2))
    sections = [("S", start), ("G", _records(_delimited(glob), 72)), ("D", d_lines), ("P", p_lines)]
    out = []
    for letter, lines in sections:
        out += [f"{line:<72}{letter}{n:>7}" for n, line in enumerate(lines, 1)]
    counts = "".join(f"{letter}{len(lines):>7}" for letter, lines in sections)
    out.append(f"{counts:<72}T{1:>7}")
    return "\n".join(out) + "\n"


def write_iges(path: str | Path, nets: np.ndarray, units: CadUnits = CadUnits()) -> None:
    """Write model-frame bicubic nets (P, 4, 4, 3) as an IGES file in ``units`` (atomically)."""
    write_bytes(path, iges_text(nets, Path(path).name, units).encode("ascii"))


def _float(tok: str) -> float:
    return float(tok.strip().replace("D", "E").replace("d", "e"))


def read_iges(path: str | Path) -> list[dict]:
    """The entity-128 surfaces of an IGES file: dicts with degrees, knots, weights (n_u, n_v),
    control points (n_u, n_v, 3) and parameter ranges."""
    lines = Path(path).read_text().splitlines()
    if not lines or any(len(line) != 80 for line in lines):
        raise ModelError(path, "not a fixed-format IGES file (records must be 80 columns)")
    d = [line for line in lines if line[72] == "D"]
    p = {int(line[73:80]): line for line in lines if line[72] == "P"}
    surfaces = []
    for k in range(0, len(d), 2):
        etype, pstart = int(d[k][0:8]), int(d[k][8:16])
        count = int(d[k + 1][24:32])
        if etype != 128:
            continue
        text = "".join(p[pstart + n][:64] for n in range(count))
        toks = text.split(";")[0].split(",")
        k1, k2, m1, m2 = (int(t) for t in toks[1:5])
        nu, nv = k1 + 1, k2 + 1
        vals = [_float(t) for t in toks[10:]]
        ku, kv = nu + m1 + 1, nv + m2 + 1
        s_knots, t_knots = vals[:ku], vals[ku : ku + kv]
        pos = ku + kv
        w = np.array(vals[pos : pos + nu * nv]).reshape(nv, nu).T
        pos += nu * nv
        ctrl = np.array(vals[pos : pos + 3 * nu * nv]).reshape(nv, nu, 3).transpose(1, 0, 2)
        pos += 3 * nu * nv
        surfaces.append(
            {
                "degree": (m1, m2),
                "knots": (np.array(s_knots), np.array(t_knots)),
                "weights": w,
                "control": ctrl,
                "range": tuple(vals[pos : pos + 4]),
            }
        )
    return surfaces


def bspline_basis(knots: np.ndarray, degree: int, x: np.ndarray) -> np.ndarray:
    """(..., n) values of the n = len(knots) − degree − 1 B-spline basis functions at ``x``
    (Cox–de Boor; the last span is closed so that x = knots[-1] is inside it)."""
    knots = np.asarray(knots, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)[..., None]
    lo, hi = knots[:-1], knots[1:]
    last = np.arange(len(lo)) == np.nonzero(hi > lo)[0][-1]
    basis = ((x >= lo) & ((x < hi) | (last & (x <= hi)))).astype(np.float64)
    for d in range(1, degree + 1):
        left_den, right_den = knots[d:-1] - knots[: -d - 1], knots[d + 1 :] - knots[1:-d]
        left = np.divide(
            x - knots[: -d - 1],
            left_den,
            out=np.zeros(np.broadcast_shapes(x.shape, left_den.shape)),
            where=left_den > 0,
        )
        right = np.divide(
            knots[d + 1 :] - x,
            right_den,
            out=np.zeros(np.broadcast_shapes(x.shape, right_den.shape)),
            where=right_den > 0,
        )
        basis = left * basis[..., :-1] + right * basis[..., 1:]
    return basis


def eval_surface(surface: dict, s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Evaluate a parsed rational B-spline surface at parameters inside its knot range."""
    (du, dv), (ku, kv) = surface["degree"], surface["knots"]
    bu, bv = bspline_basis(ku, du, s), bspline_basis(kv, dv, t)
    w = surface["weights"]
    num = np.einsum("...i,...j,ij,ijk->...k", bu, bv, w, surface["control"])
    den = np.einsum("...i,...j,ij->...", bu, bv, w)
    return num / den[..., None]
