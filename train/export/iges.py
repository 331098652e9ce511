"""IGES 5.3 writer and reader for bicubic patches as Rational B-Spline Surfaces (entity 128).

Each patch is written exactly: degree 3 x 3, 4 x 4 control points, all weights 1, knots
0,0,0,0,1,1,1,1 in both directions (a Bézier patch is a single-span B-spline). The file has the
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
from train.export.bicubic import bernstein3
from train.export.units import CadUnits

_KNOTS = (0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0)
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


def entity128_params(net: np.ndarray) -> list[str]:
    """Parameter list of one bicubic net (4, 4, 3), ``net[i, j]`` with i along u (s), j along v (t)."""
    params = ["128", "3", "3", "3", "3", "0", "0", "1", "0", "0"]
    params += [_real(k) for k in _KNOTS] * 2
    params += [_real(1.0)] * 16
    for j in range(4):  # the first index (u) varies fastest
        for i in range(4):
            params += [_real(c) for c in net[i, j]]
    params += [_real(0.0), _real(1.0), _real(0.0), _real(1.0)]
    return params


def iges_text(nets: np.ndarray, name: str = "patches.igs", units: CadUnits = CadUnits()) -> str:
    """IGES text of model-frame nets ``(P, 4, 4, 3)``, written × ``units.factor`` in ``units``."""
    nets = np.asarray(nets, dtype=np.float64) * units.factor
    flag, unit_name = units.iges
    extent = float(np.abs(nets).max()) if nets.size else 1.0
    start = ["sketch2patch: Coons patches as exact bicubic NURBS (entity 128)"]
    glob = [
        "1H,", "1H;", _hollerith("sketch2patch"), _hollerith(name), _hollerith("sketch2patch"),
        _hollerith("0.1.0"), "32", "38", "6", "308", "15", _hollerith("sketch2patch"), "1.0", str(flag),
        _hollerith(unit_name), "1", _real(1e-3 * units.factor), _hollerith(_DATE), _real(1e-9 * units.factor), _real(extent), "",
        "", "11", "0", _hollerith(_DATE),
    ]  # fmt: skip
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
            {"degree": (m1, m2), "knots": (np.array(s_knots), np.array(t_knots)), "weights": w,
             "control": ctrl, "range": tuple(vals[pos : pos + 4])}
        )  # fmt: skip
    return surfaces


def eval_surface(surface: dict, s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Evaluate a parsed single-span bicubic rational surface at parameters in [0, 1]."""
    if surface["degree"] != (3, 3) or any(not np.allclose(k, _KNOTS) for k in surface["knots"]):
        raise ValueError("only single-span bicubic surfaces (Bézier knots) are supported")
    bu, bv = bernstein3(s), bernstein3(t)
    w = surface["weights"]
    num = np.einsum("...i,...j,ij,ijk->...k", bu, bv, w, surface["control"])
    den = np.einsum("...i,...j,ij->...", bu, bv, w)
    return num / den[..., None]
