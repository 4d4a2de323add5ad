"""The report's table per measuring level.

With ``levels.csv`` in the result folder (written by the leg's measuring levels: a row per level
with its name, height, girth, the garment's reduction there and the pressure's girth mean and
four sides, anterior, posterior, medial and lateral, in mmHg) the table is that file, read
tolerantly: columns in any order, names in any case with or without a unit (``girth``,
``girth_m``, ``girth_cm``, ``girth [cm]``, ``mean_mmHg``, ``Anterior (mmHg)``, ``reduction_pct``;
``height_cm`` the height the standard measures from, ``z_m`` the level's coordinate), extra
columns ignored, empty or
``n/a`` cells shown as n/a. A cell that is neither empty nor a number is refused naming the file,
line and column (the report never pastes it into the page). Girths in cm or mm (by the header, or
a value above 3 without a unit) are turned into metres; a reduction of at most 1 everywhere is a
fraction and is shown in per cent.

Without it, the table is built from the run's profiles (summary.json, the numbers of
profiles.csv): a row per slice, with the girth of the body there (the perimeter of the convex hull
of the body's section inside the garment's, as a tape measures it) and the girth mean, least and
greatest pressure. Every row shows its pressure as a percentage of the first (B) and the first
row its class under each standard the run used (a compression class is specified at B).
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
from pathlib import Path

import numpy as np

from ..fileio import excerpt, read_text

SIDES = ("anterior", "posterior", "medial", "lateral")
#: largest levels.csv read [bytes] (a row per level: a few hundred bytes)
LEVELS_LIMIT = 2 * 2**20


def _key(header: str) -> tuple[str | None, str]:
    """(the column's meaning or None, its unit: 'cm', 'mm', 'percent' or '') of a header cell."""
    h = header.strip().lower()
    unit = "cm" if re.search(r"\bcm\b|_cm\b", h) else "mm" if re.search(r"\bmm\b|_mm\b", h) else ""
    if "%" in h or "percent" in h or "pct" in h:
        unit = "percent"
    name = re.sub(r"[\[(].*?[\])]", "", h)
    name = re.sub(r"[^a-z]+", "_", name).strip("_")
    for side in SIDES:
        if side in name:
            return side, unit
    if name.startswith("level") or name in ("name", "point"):
        return "level", unit
    if "mean" in name:
        return "mean", unit
    if name in ("z", "z_m"):
        return "z", unit
    if "height" in name:
        return "height", unit
    if "girth" in name or "circumference" in name:
        return "girth", unit
    if "reduction" in name:
        return "reduction", unit
    return None, unit


def read_levels(path: Path, error=ValueError) -> list[dict] | None:
    """levels.csv's rows as [{level, height [m], z [m], girth [m], reduction [%], mean,
    anterior, ...}] (None where a cell is empty; height: the file's height, else its z; z: the
    level's coordinate along the limb's axis, ``z_m``, where the profile is drawn), or None when the folder has no levels.csv. ``error``: the
    exception class raised (``file:line: ...``)."""
    if not os.path.lexists(path):
        return None
    text = read_text(path, error, limit=LEVELS_LIMIT)
    lines = [(n, ln) for n, ln in enumerate(text.splitlines(), 1) if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        return []
    first_no, first = lines[0]
    header = next(csv.reader([first]))
    cols = [_key(h) for h in header]
    names = [c[0] for c in cols]
    for need in ("level", "mean"):
        if need not in names:
            raise error(f"{path}:{first_no}: no '{need}' column (the header is {excerpt(first, 80)}; "
                        f"levels.csv has level, height, girth, reduction, mean and the four sides in mmHg)")
    rows = []
    for n, ln in lines[1:]:
        cells = next(csv.reader([ln]))
        row: dict = {"level": None, "height": None, "z": None, "girth": None, "reduction": None, "mean": None,
                     **{s: None for s in SIDES}}
        for (key, unit), h, cell in zip(cols, header, cells):
            if key is None or row.get(key) is not None:
                continue
            cell = cell.strip()
            if key == "level":
                row["level"] = cell
                continue
            if cell.lower() in ("", "n/a", "na", "nan", "-", "none", "null"):
                continue
            try:
                v = float(cell)
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                raise error(f"{path}:{n}: {excerpt(h.strip(), 40, quote=False)} is not a number ({excerpt(cell)})")
            if key in ("girth", "height", "z"):
                v = v / 100.0 if unit == "cm" else v / 1000.0 if unit == "mm" else v
            row[key] = v
            row.setdefault("_units", {})[key] = unit
        rows.append(row)
    girths = [r["girth"] for r in rows if r["girth"] is not None and not r.get("_units", {}).get("girth")]
    if girths and max(girths) > 3.0:    # no unit and above 3: centimetres
        for r in rows:
            if r["girth"] is not None and not r.get("_units", {}).get("girth"):
                r["girth"] /= 100.0
    red = [r for r in rows if r["reduction"] is not None]
    if red and all(r.get("_units", {}).get("reduction") != "percent" for r in red) and \
            max(abs(r["reduction"]) for r in red) <= 1.0:
        for r in red:
            r["reduction"] *= 100.0
    for r in rows:
        r.pop("_units", None)
        if r["height"] is None:
            r["height"] = r["z"]
    return rows


def body_girth(body_v: np.ndarray, body_f: np.ndarray, pos: np.ndarray, faces: np.ndarray, axis, h: float):
    """The body's girth [m] at height h along ``axis``: the perimeter of the convex hull of the
    body's section points that lie inside the garment's section (its convex hull grown by 1 cm);
    None when either section is missing."""
    import shapely
    from shapely.geometry import MultiPoint

    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    e1 = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)

    def cut(V, F):
        if not len(F):
            return np.zeros((0, 3))
        E = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1), axis=0)
        d = V @ a - h
        da, db = d[E[:, 0]], d[E[:, 1]]
        m = (da * db < 0) & np.isfinite(da) & np.isfinite(db)
        t = (da[m] / (da[m] - db[m]))[:, None]
        on = V[np.abs(d) <= 1e-12]   # vertices in the plane (a ring of a mesh cut at its height)
        return np.concatenate([V[E[m, 0]] + t * (V[E[m, 1]] - V[E[m, 0]]), on])

    g = cut(np.asarray(pos, float), np.asarray(faces))
    b = cut(np.asarray(body_v, float), np.asarray(body_f))
    if len(g) < 3 or len(b) < 3:
        return None
    hull = MultiPoint(np.c_[g @ e1, g @ e2]).convex_hull.buffer(0.01)
    bxy = np.c_[b @ e1, b @ e2]
    inside = shapely.contains_xy(hull, bxy[:, 0], bxy[:, 1])
    if inside.sum() < 3:
        return None
    shape = MultiPoint(bxy[inside]).convex_hull
    return float(shape.length) if shape.geom_type == "Polygon" else None


def levels_from_profiles(profiles: list[dict], body_v, body_f, pos, faces) -> list[dict]:
    """Rows of the table from the profiles' slices (see the module docstring)."""
    rows = []
    for pf in profiles:
        for s in pf["slices"]:
            if s["mean_mmhg"] is None:
                continue
            try:
                girth = body_girth(body_v, body_f, pos, faces, pf.get("axis") or (0, 0, 1), s["height_m"])
            except Exception:  # noqa: BLE001 (a section that cannot be measured: n/a)
                girth = None
            rows.append({"level": f"{pf['name']} {s['height_m']:.3f} m", "height": s["height_m"], "girth": girth,
                         "reduction": None, "mean": s["mean_mmhg"], "min": s["min_mmhg"], "max": s["max_mmhg"]})
        break   # the first profile (the limb's)
    return rows


def classify_with(mmhg: float, standards: list[dict]) -> list[tuple[str, str]]:
    """[(standard, class)] of a pressure under the standards of scene_summary (dicts); the class
    tables as clothsim.compression.standards states them."""
    from .spec import ClassBand, Standard
    from .standards import classify

    out = []
    for s in standards:
        std = Standard(name=str(s["name"]), site=str(s.get("site", "")), source=str(s.get("source", "")),
                       classes=[ClassBand(name=str(c["name"]), min=c["min"], max=c.get("max")) for c in s["classes"]])
        out.append((std.name, classify(mmhg, std)))
    return out


def levels_csv_text(rows: list[dict]) -> str:
    """The rows as CSV (for tests and exports)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["level", "height_m", "girth_m", "reduction_percent", "mean_mmhg", *(f"{s}_mmhg" for s in SIDES)])
    for r in rows:
        w.writerow([r["level"], *("" if r.get(k) is None else f"{r[k]:.6g}"
                                  for k in ("height", "girth", "reduction", "mean", *SIDES))])
    return buf.getvalue()
