"""Piecewise-linear tension tables: validation, evaluation, energy integral, CSV import.

Why tension per width: fabric strip tests (EN 14704-1, KES-FB1, ASTM D5035) report force per
width [N/m] against engineering strain, and a knit's "thickness" is ill defined. A table given as
stress [Pa] is converted once, with the fabric thickness, to tension per width
``T = sigma * thickness``; from then on a spring's axial force is ``T(strain) * width`` where width
is its tributary width [m] (paper, Fig. 3: the associated area is thickness x width).

Conventions: strain is engineering strain ``l / l0 - 1``; the table starts at strain 0,
strictly increasing strain, non-negative non-decreasing values; beyond the last point the last
segment is extended; at zero or negative strain a tension-only spring is slack (zero force).

The tables are packed for the numba kernels as flat arrays (see :class:`TablePack`).
"""

from __future__ import annotations

import csv
import io
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .fileio import excerpt, fmt_beyond, read_text
from .kernels import table_eval


class MaterialError(ValueError):
    """A material table is invalid; the message names what is wrong (and the file/line for CSV)."""


class MaterialWarning(UserWarning):
    """A material table is valid but implausible (e.g. strains typed as percent)."""


#: largest table value accepted: tension per width [N/m] and stress [Pa]. A 1 mm steel sheet
#: (E = 200 GPa) has 2e8 N/m per unit strain, so no fabric comes near; with coordinates bounded
#: by 1e6 m (clothsim.config.COORD_MAX) spring forces stay below about 1e15 N and their squares
#: (energies, norms) far from float overflow (1.8e308), where 1e308 would overflow at once.
TENSION_MAX = 1e9
STRESS_MAX = 1e12
VALUE_MAX = {"tension": (TENSION_MAX, "N/m"), "stress": (STRESS_MAX, "Pa")}
#: a table strain above this (500 %) suggests percent typed as a fraction: warn
STRAIN_WARN = 5.0


def warn_implausible_strain(strain, where: str) -> None:
    """Warn (MaterialWarning) if the largest strain exceeds STRAIN_WARN; ``where`` names the
    file or field (``fabric.warp.strain``)."""
    m = max((float(x) for x in strain), default=0.0)
    if m > STRAIN_WARN:
        warnings.warn(MaterialWarning(
            f"{where}: {m:g} ({m * 100:g} %) is implausible for a fabric: was a percentage typed as a "
            f"strain? (strain is a fraction, 0.3 = 30 %; a CSV header 'strain [%]' reads percent)"), stacklevel=2)


def _bad(message: str, index: int | None = None) -> MaterialError:
    """A MaterialError whose ``index`` is the table point it is about (None: the whole table)."""
    exc = MaterialError(message)
    exc.index = index
    return exc


def check_table(strain, value, value_name: str = "stress", shown=None) -> None:
    """Raise MaterialError (message without field prefix) if (strain, value) is not a valid table;
    its ``index`` is the offending point (None for the whole table), so a CSV reader can name the
    line. shown: (strain, value) as the user wrote them (a CSV's cells), quoted in the messages
    instead of the numbers.

    The messages are part of the user interface (tests check them verbatim)."""
    strain = list(strain)
    value = list(value)
    s_txt, v_txt = (list(shown[0]), list(shown[1])) if shown is not None else (strain, value)
    if len(strain) != len(value):
        raise _bad(f"strain and {value_name} have different lengths ({len(strain)} and {len(value)})")
    if len(strain) < 2:
        raise _bad(f"needs at least 2 points (got {len(strain)})")
    for name, seq, txt in (("strain", strain, s_txt), (value_name, value, v_txt)):
        for k, x in enumerate(seq):
            if not math.isfinite(float(x)):
                raise _bad(f"{name}: must be finite (got {txt[k]})", k)
    if float(strain[0]) != 0.0:
        raise _bad(f"strain: must start at 0 (got {s_txt[0]})", 0)
    for k in range(1, len(strain)):
        if not float(strain[k]) > float(strain[k - 1]):
            raise _bad(f"strain: must be strictly increasing ({s_txt[k]} after {s_txt[k - 1]})", k)
    for k, x in enumerate(value):
        if float(x) < 0.0:
            raise _bad(f"{value_name}: must be non-negative (got {v_txt[k]})", k)
    if value_name in VALUE_MAX:
        hi, unit = VALUE_MAX[value_name]
        for k, x in enumerate(value):
            if float(x) > hi:
                raise _bad(f"{value_name}: at most {hi:.0e} {unit} (got {fmt_beyond(x, hi)} {unit})", k)
    for k in range(1, len(value)):
        if float(value[k]) < float(value[k - 1]):
            raise _bad(f"{value_name}: must be non-decreasing ({v_txt[k]} after {v_txt[k - 1]})", k)


#: the units a CSV table's header may name in brackets or parentheses (``tension [kN/m]``), as
#: factors to the table's own units: tension per width to N/m (strip tests report N per 5 cm or
#: per 50 mm strip: EN ISO 13934-1; cN/cm and gf/cm in knit data sheets), stress to Pa, strain to a
#: fraction. Matched without regard to spaces, and to case except in m and M (milli and mega: mPa
#: is not MPa, and is refused)
CSV_UNITS = {
    "tension": {"N/m": 1.0, "kN/m": 1e3, "N/mm": 1e3, "N/cm": 100.0, "cN/cm": 1.0, "mN/mm": 1.0,
                "N/5cm": 20.0, "N/50mm": 20.0, "N/25mm": 40.0, "N/in": 1.0 / 0.0254,
                "lbf/in": 4.4482216152605 / 0.0254, "gf/cm": 9.80665e-3 / 1e-2, "kgf/cm": 9.80665 / 1e-2,
                "kgf/m": 9.80665},
    "stress": {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6, "GPa": 1e9, "N/m2": 1.0, "N/m^2": 1.0, "N/mm2": 1e6,
               "N/mm^2": 1e6, "psi": 6894.757293168},
    "strain": {"%": 0.01, "-": 1.0, "1": 1.0, "m/m": 1.0, "mm/mm": 1.0},
}


def _csv_unit(cell: str, name: str, source: str, line: int) -> float:
    """The factor of a header cell ``name [unit]`` (``CSV_UNITS[name]``; 1 with no unit); an unknown
    unit or text that is not a bracketed unit raises MaterialError naming the file and line."""
    rest = cell.strip()[len(name):].strip()
    if not rest:
        return 1.0
    units = CSV_UNITS[name]
    known = ", ".join(units)
    if len(rest) >= 2 and (rest[0], rest[-1]) in (("[", "]"), ("(", ")")):
        unit = "".join(rest[1:-1].split()).replace("\u00b2", "2")
        for k, f in units.items():
            if unit == k:
                return f
        for k, f in units.items():
            # any case (KN/m, n/mm), but m and M as written: mPa is not MPa
            if unit.lower() == k.lower() and all(a == b for a, b in zip(unit, k) if b in "mM"):
                return f
        near = next((k for k in units if unit.lower() == k.lower()), None)
        if near is not None:
            raise MaterialError(f"{source}:{line}: {name}: unit {excerpt(rest[1:-1].strip())}: write it {near} "
                                f"(m and M are milli and mega, or metre)")
        raise MaterialError(f"{source}:{line}: {name}: unknown unit {excerpt(rest[1:-1].strip())} (known: {known})")
    raise MaterialError(f"{source}:{line}: {name}: write the unit in brackets after the name, e.g. "
                        f"'{name} [{next(iter(units))}]' (got {excerpt(cell.strip())}; known units: {known})")


def read_table_csv(path: Path) -> tuple[np.ndarray, np.ndarray, str]:
    """Read a two-column CSV table ``strain,<stress|tension>``.

    The header names the second column: ``stress`` (Pa) or ``tension`` (N/m); a unit in brackets or
    parentheses after a name converts the column (``CSV_UNITS``: ``tension [kN/m]``, ``tension
    [N/5cm]``, ``stress [MPa]``, ``strain [%]``); an unknown unit is an error. Returns (strain,
    value, kind) with kind "stress" or "tension", in the table's units (fraction, Pa or N/m).
    Errors name the file and the line; the file must be a regular UTF-8 file of at most 10 MB.
    A largest strain above 500 % warns (MaterialWarning: percent typed as a fraction?).
    """
    path = Path(path)
    text = read_text(path, MaterialError, encoding="utf-8-sig")
    return parse_table_csv(text, str(path))


def _cells(row: list[str]) -> list[str]:
    """A CSV row without its trailing empty cells (a spreadsheet's ``0,0,``)."""
    row = list(row)
    while row and not row[-1].strip():
        row.pop()
    return row


def _csv_number(cell: str) -> float:
    """A CSV cell's number: what float() reads, but not with the underscores Python allows
    between digits (``1_5`` would read as 15: a typo, or a locale's separator)."""
    if "_" in cell:
        raise ValueError(cell)
    return float(cell)


def parse_table_csv(text: str, source: str = "<csv>") -> tuple[np.ndarray, np.ndarray, str]:
    """Parse CSV text as in :func:`read_table_csv` (used for browser uploads too)."""
    rows = [r for r in csv.reader(io.StringIO(text))]
    numbered = [(n + 1, _cells(r)) for n, r in enumerate(rows) if r and any(c.strip() for c in r)]
    numbered = [(n, r) for n, r in numbered if not r[0].lstrip().startswith("#")]
    if not numbered:
        raise MaterialError(f"{source}: empty table")
    line, header = numbered[0]
    if len(header) < 2:
        raise MaterialError(f"{source}:{line}: header needs two columns: strain,stress or strain,tension")
    if len(header) > 2:
        raise MaterialError(f"{source}:{line}: header has {len(header)} columns; a table has two: "
                            f"strain,stress or strain,tension")
    h0 = header[0].strip().lower()
    h1 = header[1].strip().lower()
    if not h0.startswith("strain"):
        raise MaterialError(f"{source}:{line}: first column must be 'strain' (got {excerpt(header[0].strip())})")
    if h1.startswith("stress"):
        kind = "stress"
    elif h1.startswith("tension"):
        kind = "tension"
    else:
        raise MaterialError(
            f"{source}:{line}: second column must be 'stress' [Pa] or 'tension' [N/m] (got {excerpt(header[1].strip())})"
        )
    scale0 = _csv_unit(header[0], "strain", source, line)
    scale1 = _csv_unit(header[1], kind, source, line)
    strain, value, lines, s_txt, v_txt = [], [], [], [], []
    for line, row in numbered[1:]:
        if len(row) != 2:
            raise MaterialError(f"{source}:{line}: expected two columns, got {len(row)}")
        try:
            s = _csv_number(row[0])
            v = _csv_number(row[1])
        except ValueError:
            raise MaterialError(f"{source}:{line}: not a number: {excerpt(','.join(row), 40, quote=False)}") from None
        if not (math.isfinite(s) and math.isfinite(v)):
            raise MaterialError(f"{source}:{line}: must be finite: {excerpt(','.join(row), 40, quote=False)}")
        strain.append(s / 100.0 if scale0 == 0.01 else s * scale0)  # percent divided, as it always was
        value.append(v * scale1)
        lines.append(line)
        s_txt.append(row[0].strip())
        v_txt.append(row[1].strip())
    try:
        check_table(strain, value, kind, shown=(s_txt, v_txt))
    except MaterialError as exc:
        at = f":{lines[exc.index]}" if getattr(exc, "index", None) is not None else ""
        raise MaterialError(f"{source}{at}: {exc}") from None
    warn_implausible_strain(strain, f"{source}: strain")
    return np.asarray(strain, float), np.asarray(value, float), kind


@dataclass(frozen=True)
class Table:
    """One validated tension table.

    strain: (P,) engineering strain, strain[0] == 0.
    tension: (P,) tension per width [N/m] at those strains.
    compression: if True the first segment is extended to negative strain (used for the optional
        bending/shear springs, which resist compression); otherwise the spring is slack below 0.
    """

    strain: np.ndarray
    tension: np.ndarray
    compression: bool = False

    @staticmethod
    def linear(stiffness: float, compression: bool = True) -> "Table":
        """T = stiffness * strain [N/m]; used for shear and bending springs."""
        return Table(np.array([0.0, 1.0]), np.array([0.0, float(stiffness)]), compression)

    def evaluate(self, strain):
        """Tension [N/m] at the given strains (numpy, for tests and plots)."""
        pack = TablePack.from_tables([self])
        strain = np.atleast_1d(np.asarray(strain, float))
        out = np.empty_like(strain)

        for n, s in enumerate(strain):
            out[n] = table_eval(pack.x, pack.y, pack.cum, pack.start, pack.compression, 0, s)[0]
        return out


@dataclass(frozen=True)
class TablePack:
    """Several tables concatenated for numba.

    x, y: concatenated strains and tensions [N/m]; start: (n+1,) offsets; cum: energy integral
    int_0^x T ds at each breakpoint [N/m]; compression: (n,) bool as uint8.
    """

    x: np.ndarray
    y: np.ndarray
    cum: np.ndarray
    start: np.ndarray
    compression: np.ndarray

    @staticmethod
    def from_tables(tables: list[Table]) -> "TablePack":
        xs, ys, cums, starts, comp = [], [], [], [0], []
        for t in tables:
            x = np.asarray(t.strain, float)
            y = np.asarray(t.tension, float)
            c = np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(x))])
            xs.append(x)
            ys.append(y)
            cums.append(c)
            starts.append(starts[-1] + len(x))
            comp.append(1 if t.compression else 0)
        return TablePack(
            np.concatenate(xs),
            np.concatenate(ys),
            np.concatenate(cums),
            np.asarray(starts, np.int64),
            np.asarray(comp, np.uint8),
        )
