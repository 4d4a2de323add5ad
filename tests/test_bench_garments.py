"""The benchmark's panel scenes (``app.py bench --garments``): each scene runs in several fresh
processes and the report gives the best run beside every run's work units. The runs themselves
are in the benchmark, not here."""

from clothsim import bench


def _row(case, wu7, wu9=None, total=100.0):
    return {"case": case, "nodes": 10, "status": "converged", "iterations": 2,
            "times": {"1e-07": wu7 and wu7 / 1000, "1e-09": None}, "times_wu": {"1e-07": wu7, "1e-09": wu9},
            "total_wu": total, "error_final": None}


def test_best_of_keeps_the_run_with_fewest_work_units(monkeypatch):
    """Three fresh runs of a scene: the one with the fewest work units to 1e-7 N is kept (a run
    that did not reach 1e-7 N ranks last) and every run's figure is listed in order."""
    runs = iter([_row("s", 380.0), _row("s", None, total=50.0), _row("s", 342.0)])
    calls = []
    monkeypatch.setattr(bench, "_in_child", lambda fn, *a: calls.append(a) or next(runs))
    best = bench._best_of(bench.Case("s", "x.yaml"), "newton", None, 3)
    assert len(calls) == 3
    assert best["times_wu"]["1e-07"] == 342.0
    assert best["wu_runs"] == [380.0, None, 342.0]


def test_garment_report_gives_ratio_to_the_square_and_every_run(tmp_path):
    rows = [dict(_row("sphere cap 201^2", 300.0), wu_runs=[320.0, 300.0]),
            dict(_row("circle cap 40k", 450.0), wu_runs=[450.0, 470.0])]
    bench.write_garment_report(rows, tmp_path, 12.0)
    md = (tmp_path / "benchmarks_garments.md").read_text()
    line = next(s for s in md.splitlines() if s.startswith("| circle cap 40k"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[5] == "450" and cells[6] == "1.50" and cells[9] == "450, 470"


def test_interleaved_runs_every_scene_once_per_round(monkeypatch):
    """Rounds of fresh processes, each round every scene in turn; the best per scene kept, with
    every round's work units and CPU seconds in round order."""
    wu = {"a": iter([300.0, 280.0, 310.0]), "b": iter([450.0, 400.0, 500.0])}
    order = []

    def child(fn, case, solver, ref):
        order.append(case.name)
        return dict(_row(case.name, next(wu[case.name])), ref_pass_s=0.002, solver=solver)

    monkeypatch.setattr(bench, "_in_child", child)
    rows = bench._interleaved([(bench.Case("a", "x.yaml"), "newton", None),
                               (bench.Case("b", "y.yaml"), "newton", None)], 3)
    assert order == ["a", "b", "a", "b", "a", "b"]
    assert [r["times_wu"]["1e-07"] for r in rows] == [280.0, 400.0]
    assert rows[1]["wu_runs"] == [450.0, 400.0, 500.0] and rows[1]["rounds"] == 3
    assert rows[1]["cpu_runs"] == [0.9, 0.8, 1.0]
    # round by round: 1.5, 1.4286, 1.6129 -> median 1.5
    r = bench.paired_ratios(rows[0], rows[1])
    assert len(r) == 3 and abs(sorted(r)[1] - 1.5) < 1e-12


def test_garment_report_gives_paired_medians(tmp_path):
    sq = dict(_row("sphere cap 201^2", 280.0), wu_runs=[300.0, 280.0, 310.0], cpu_runs=[0.6, 0.5, 0.6])
    ci = dict(_row("circle cap 40k", 400.0), wu_runs=[450.0, 400.0, None], cpu_runs=[0.8, 0.75, None])
    bench.write_garment_report([sq, ci], tmp_path, 12.0)
    md = (tmp_path / "benchmarks_garments.md").read_text()
    line = next(s for s in md.splitlines() if s.startswith("| circle cap 40k"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    # best 400 / 280; paired WU: 1.5, 1.4286 -> 1.46; paired s: 1.333, 1.5 -> 1.42
    assert cells[6] == "1.43" and cells[7] == "1.46" and cells[8] == "1.42"


def test_interleaved_keeps_a_failed_run_as_a_gap_in_its_round(monkeypatch):
    """A run that fails stays a None in its round, so the paired ratios still pair each round of
    a scene with the same round of the square."""
    wu = {"a": iter([300.0, 280.0, 310.0]), "b": iter([450.0, 500.0])}
    calls = {"b": 0}

    def child(fn, case, solver, ref):
        if case.name == "b":
            calls["b"] += 1
            if calls["b"] == 2:
                raise RuntimeError("boom")
        return dict(_row(case.name, next(wu[case.name])), ref_pass_s=0.002, solver=solver)

    monkeypatch.setattr(bench, "_in_child", child)
    log = []
    rows = bench._interleaved([(bench.Case("a", "x.yaml"), "newton", None),
                               (bench.Case("b", "y.yaml"), "newton", None)], 3, log.append)
    assert rows[1]["wu_runs"] == [450.0, None, 500.0] and rows[1]["rounds"] == 2
    assert rows[1]["cpu_runs"] == [0.9, None, 1.0]
    assert rows[1]["times_wu"]["1e-07"] == 450.0
    assert bench.paired_ratios(rows[0], rows[1]) == [1.5, 500.0 / 310.0]
    assert any("boom" in m for m in log)
