"""The friction benchmark's rows (clothsim/bench/friction.py, ``python app.py bench --friction``):
a capstan row measures a frictional load step and the frictionless solve in seconds and work
units and the tension ratio's error against e^(mu phi); the table shows both and their ratio."""

from __future__ import annotations

import math

import pytest

from clothsim.bench.friction import capstan_table, capstan_row, table
from clothsim.cli import build_parser


def test_the_bench_command_has_the_friction_table():
    args = build_parser().parse_args(["bench", "--friction", "--quick", "--out", "x"])
    assert args.friction and args.quick


@pytest.mark.slow
def test_a_capstan_row_and_its_table():
    r = capstan_row(20)
    assert r["steps"] == 20 and r["slip"] > 0 and r["stick"] == 0
    assert 5e-3 < r["capstan_error"] < 3e-2  # 1.7e-2 at 20 divisions (docs/method/friction.md)
    assert r["ratio"] == pytest.approx(math.exp(0.3 * r["phi"]) * (1 + r["capstan_error"]))
    assert 0 < r["ref_pass_s"] < r["free_s"] and r["step_mean_s"] > 0
    lines = table([r])
    assert "WU" in lines[2] and f"{r['step_mean_s'] / r['free_s']:.2f}" in lines[2]
    assert f"{r['capstan_error']:+.1e}" in capstan_table([r])[2]
