import pytest
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
    assert cells[5] == "450" and cells[6] == "1.50" and cells[10] == "450, 470"


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


def test_run_pair_alternates_the_scenes_and_pairs_neighbours(monkeypatch):
    """``run_pair`` solves base and scene alternately (base, scene, scene, base, ...) in one
    process, after one warm-up solve each, and pairs each solve with its neighbour."""
    import clothsim.solvers as solvers

    class _S:
        def model_copy(self, update):
            return self

        def copy(self):
            return self

    loads, warm, order = [], [], []
    monkeypatch.setattr(bench, "_load", lambda c, *a: loads.append(c.name) or (c.name, _S(), _S()))
    monkeypatch.setattr(solvers, "solve", lambda m, s, st, **k: warm.append(m))
    t = {"b": iter([1.0, 1.1, 1.2, 1.3]), "c": iter([1.5, 1.6, None, 1.8])}
    monkeypatch.setattr(bench, "_cpu_to", lambda m, s, st: order.append(m) or next(t[m]))
    pairs = bench.run_pair(bench.Case("b", "x.yaml"), bench.Case("c", "y.yaml"), 4)
    assert loads == ["b", "c"] and warm == ["b", "c"]
    assert order == ["b", "c", "c", "b", "b", "c", "c", "b"]
    assert pairs == [[1.0, 1.5], [1.1, 1.6], [1.2, None], [1.3, 1.8]]


def test_same_process_ratios_skip_missing_pairs_and_failed_processes(monkeypatch):
    runs = iter([[[1.0, 1.5], [2.0, None]], RuntimeError("boom"), [[1.0, 1.2]]])

    def child(fn, base, case):
        r = next(runs)
        if isinstance(r, Exception):
            raise r
        return r

    monkeypatch.setattr(bench, "_in_child", child)
    log = []
    out = bench.same_process_ratios(bench.Case("b", "x.yaml"), [bench.Case("c", "y.yaml")], 3, log.append)
    assert out == {"c": [1.5, 1.2]}
    assert any("boom" in m for m in log)


def test_garment_report_gives_the_same_process_ratio(tmp_path):
    sq = dict(_row("sphere cap 201^2", 280.0), wu_runs=[280.0])
    ci = dict(_row("circle cap 40k", 400.0), wu_runs=[400.0], same_process_ratios=[1.3, 1.1, 1.2, 1.25])
    fo = dict(_row("four panels cap 40k", 400.0), wu_runs=[400.0])
    bench.write_garment_report([sq, ci, fo], tmp_path, 12.0)
    md = (tmp_path / "benchmarks_garments.md").read_text()
    cells = {}
    for s in md.splitlines():
        if s.startswith("| ") and not s.startswith("| scene"):
            c = [x.strip() for x in s.strip("|").split("|")]
            cells[c[0]] = c
    assert cells["circle cap 40k"][9] == "1.23 (1.10-1.30, 4)"
    assert cells["sphere cap 201^2"][9] == "1.00" and cells["four panels cap 40k"][9] == "-"


@pytest.mark.slow
def test_run_pair_times_two_real_scenes():
    """A real pair on small lattices: both reach 1e-7 N and every time is a positive CPU time."""
    base = bench.Case("sq", "configs/sphere_cap.yaml", ["fabric.divisions=[20,20]"], ("newton",), {"newton": 60})
    case = bench.Case("ci", "configs/garments/circle_cap.yaml", ["panels.0.divisions=[24,24]"], ("newton",),
                      {"newton": 60})
    pairs = bench.run_pair(base, case, 2)
    assert len(pairs) == 2
    assert all(t is not None and 0.0 < t < 60.0 for p in pairs for t in p)
