"""Tension tables: evaluation, energy integral, validation messages, CSV import."""

import numpy as np
import pytest

from clothsim.kernels import table_eval
from clothsim.material import MaterialError, Table, TablePack, check_table, parse_table_csv, read_table_csv

X = np.array([0.0, 0.1, 0.3, 0.6, 1.0])
Y = np.array([0.0, 12.0, 55.0, 140.0, 300.0])


def _eval(pack, t, s):
    return table_eval(pack.x, pack.y, pack.cum, pack.start, pack.compression, t, s)


def test_table_eval_matches_linear_interpolation_and_extrapolation():
    """T(s) equals numpy.interp inside the table, the last segment extended beyond it, and 0 at
    and below zero strain (tension only)."""
    pack = TablePack.from_tables([Table(X, Y)])
    slope_last = (Y[-1] - Y[-2]) / (X[-1] - X[-2])
    for s in np.linspace(-0.5, 2.0, 101):
        T, dT, W = _eval(pack, 0, s)
        if s <= 0:
            assert T == 0 and dT == 0 and W == 0
        elif s <= 1.0:
            assert T == pytest.approx(np.interp(s, X, Y), rel=1e-12, abs=1e-12)
        else:
            assert T == pytest.approx(Y[-1] + slope_last * (s - 1.0), rel=1e-12)


def test_energy_integral_is_the_integral_of_tension():
    """W(s) = int_0^s T: compared with a fine trapezoid rule, across breakpoints and beyond."""
    pack = TablePack.from_tables([Table(X, Y)])
    for s in (0.05, 0.1, 0.25, 0.6, 0.99, 1.7):
        fine = np.linspace(0, s, 20001)
        T = np.interp(fine, X, Y) if s <= 1.0 else np.where(
            fine <= 1.0, np.interp(fine, X, Y), Y[-1] + (Y[-1] - Y[-2]) / 0.4 * (fine - 1.0))
        ref = np.trapezoid(T, fine)
        assert _eval(pack, 0, s)[2] == pytest.approx(ref, rel=1e-6)


def test_derivative_of_tension_by_finite_differences():
    """dT/ds equals the finite-difference slope away from breakpoints."""
    pack = TablePack.from_tables([Table(X, Y)])
    h = 1e-7
    for s in (0.05, 0.2, 0.45, 0.8, 1.5):
        fd = (_eval(pack, 0, s + h)[0] - _eval(pack, 0, s - h)[0]) / (2 * h)
        assert _eval(pack, 0, s)[1] == pytest.approx(fd, rel=1e-6)


def test_compression_table_extends_first_segment():
    """A compression-resisting linear table (shear/bending springs) gives T = k s for s < 0."""
    pack = TablePack.from_tables([Table.linear(20.0)])
    T, dT, W = _eval(pack, 0, -0.1)
    assert (T, dT, W) == pytest.approx((-2.0, 20.0, 0.1))


@pytest.mark.parametrize(
    "strain, value, message",
    [
        ([0, 0.1], [0, 1, 2], "strain and stress have different lengths (2 and 3)"),
        ([0], [0], "needs at least 2 points (got 1)"),
        ([0, float("nan")], [0, 1], "strain: must be finite (got nan)"),
        ([0, 0.1], [0, float("inf")], "stress: must be finite (got inf)"),
        ([0.01, 0.1], [0, 1], "strain: must start at 0 (got 0.01)"),
        ([0, 0.3, 0.3], [0, 1, 2], "strain: must be strictly increasing (0.3 after 0.3)"),
        ([0, 0.3, 0.2], [0, 1, 2], "strain: must be strictly increasing (0.2 after 0.3)"),
        ([0, 0.1], [0, -1], "stress: must be non-negative (got -1)"),
        ([0, 0.1, 0.2], [0, 2, 1], "stress: must be non-decreasing (1 after 2)"),
    ],
)
def test_validation_messages(strain, value, message):
    """Each table rule rejects bad input with its exact message."""
    with pytest.raises(MaterialError) as exc:
        check_table(strain, value, "stress")
    assert str(exc.value) == message


def test_csv_import_tension_and_percent(tmp_path):
    """A CSV with header 'strain [%],tension [N/m]' gives strains /100 and tensions as given."""
    p = tmp_path / "knit.csv"
    p.write_text("# EN 14704-1 strip, course direction\nstrain [%],tension [N/m]\n0,0\n10,12\n30,55\n")
    strain, value, kind = read_table_csv(p)
    assert kind == "tension"
    np.testing.assert_allclose(strain, [0, 0.1, 0.3])
    np.testing.assert_allclose(value, [0, 12, 55])


def test_csv_import_stress_in_mpa():
    strain, value, kind = parse_table_csv("strain,stress [MPa]\n0,0\n0.5,1.5\n", "x.csv")
    assert kind == "stress"
    np.testing.assert_allclose(value, [0, 1.5e6])


@pytest.mark.parametrize(
    "text, message",
    [
        ("", "x.csv: empty table"),
        ("strain,force\n0,0\n", "x.csv:1: second column must be 'stress' [Pa] or 'tension' [N/m] (got 'force')"),
        ("strain,tension\n0,0\n0.1,abc\n", "x.csv:3: not a number: 0.1,abc"),
        ("strain,tension\n0,0\n0.1\n", "x.csv:3: expected two columns, got 1"),
        ("strain,tension\n0,0\n0.1,nan\n", "x.csv:3: must be finite: 0.1,nan"),
        ("strain,tension\n0,0\n0.1,5\n0.1,6\n", "x.csv:4: strain: must be strictly increasing (0.1 after 0.1)"),
        # units and rows (a kN/m table read as N/m was 1000 times too soft, with no error)
        ("strain,tension [furlongs]\n0,0\n", "x.csv:1: tension: unknown unit 'furlongs' (known: N/m, kN/m, "),
        ("strain,stress [mPa]\n0,0\n", "x.csv:1: stress: unit 'mPa': write it MPa (m and M are milli and mega"),
        ("strain,stress [mpa]\n0,0\n", "x.csv:1: stress: unit 'mpa': write it MPa"),
        ("strain,tension N/m\n0,0\n", "x.csv:1: tension: write the unit in brackets after the name, e.g. "
                                     "'tension [N/m]' (got 'tension N/m'"),
        ("strain [ratio],tension\n0,0\n", "x.csv:1: strain: unknown unit 'ratio' (known: %, -"),
        ("strain,tension,extra\n0,0,1\n", "x.csv:1: header has 3 columns; a table has two"),
        ("strain,tension\n0,0\n0.1,5,7\n", "x.csv:3: expected two columns, got 3"),
        ("strain,tension\n0,0\n0.2,10\n0.1,20\n", "x.csv:4: strain: must be strictly increasing (0.1 after 0.2)"),
        ("strain,tension\n0,0\n0.1,-1\n", "x.csv:3: tension: must be non-negative (got -1)"),
        ("strain,tension\n0,0\n0.1,5\n0.2,4\n", "x.csv:4: tension: must be non-decreasing (4 after 5)"),
        ("strain,tension\n0.1,0\n0.2,4\n", "x.csv:2: strain: must start at 0 (got 0.1)"),
        ("strain,tension [kN/m]\n0,0\n0.1,2e6\n", "x.csv:3: tension: at most 1e+09 N/m (got 2e+09 N/m)"),
    ],
)
def test_csv_errors_name_file_and_line(text, message):
    """Every refusal names the file and line (long messages checked by their start)."""
    with pytest.raises(MaterialError) as exc:
        parse_table_csv(text, "x.csv")
    assert str(exc.value).startswith(message)


@pytest.mark.parametrize(
    "header, factor",
    [("tension", 1.0), ("tension [N/m]", 1.0), ("tension [kN/m]", 1e3), ("tension (N/mm)", 1e3),
     ("tension [N/cm]", 100.0), ("tension [cN/cm]", 1.0), ("tension [N/5 cm]", 20.0),
     ("tension [N/50mm]", 20.0), ("Tension [KN/m]", 1e3), ("tension [gf/cm]", 0.980665)],
)
def test_csv_tension_units_convert(header, factor):
    """A tension unit in the header converts the column to N/m (a kN/m table read as N/m would be
    1000 times too soft, with no error: found by a hostile-input pass)."""
    strain, value, kind = parse_table_csv(f"strain,{header}\n0,0\n0.1,10\n0.3,50\n", "x.csv")
    assert kind == "tension"
    np.testing.assert_allclose(value, np.array([0.0, 10.0, 50.0]) * factor, rtol=1e-12)


@pytest.mark.parametrize("header, factor", [("stress", 1.0), ("stress [Pa]", 1.0), ("stress [kPa]", 1e3),
                                            ("stress [MPa]", 1e6), ("stress [N/mm2]", 1e6)])
def test_csv_stress_units_convert(header, factor):
    strain, value, kind = parse_table_csv(f"strain,{header}\n0,0\n0.5,2\n", "x.csv")
    assert kind == "stress"
    np.testing.assert_allclose(value, [0.0, 2.0 * factor], rtol=1e-12)


def test_csv_trailing_empty_cells_are_allowed():
    """A spreadsheet's export with an empty third column (``0,0,``) is a two-column table."""
    strain, value, _ = parse_table_csv("strain,tension,\n0,0,\n0.1,10,\n", "x.csv")
    np.testing.assert_allclose(value, [0.0, 10.0])
