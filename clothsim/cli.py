"""Headless commands: run, sweep, bench, fit, report, view (the default).

Exit status: 0 converged (or all runs converged), 1 stopped without converging (or some runs
did not converge), 2 bad input (or an --out another run, fit or sweep is writing), 130
interrupted (Ctrl+C; SIGTERM too for run, fit and sweep; a run keeps the state it reached, a fit
the tries it finished).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import math
import os
import signal
import sys
import threading
import time
import warnings
from pathlib import Path

from . import simulation
from .compression.levels import levels_lines
from .compression.fit import (FitError, FitInterrupted, FitResult, fit, fit_info, fitted_lines, parse_target,
                              parse_vary, write_outputs)
from .compression.report import ReportError, write_report
from .config import SceneError, load_scene
from .fileio import FolderLock, OutputError, atomic_write_bytes, check_out_dir, describe_write_error
from .material import MaterialError, MaterialWarning
from .mold import MoldError
from .records import outputs_markdown
from .diagnostics import gathered_rows_warning
from .results import strict_json
from .sweep import main as sweep_main

DEFAULT_SCENE = Path(__file__).resolve().parent.parent / "configs" / "thermoform.yaml"


def _progress_printer(stream, every_s: float = 0.2):
    last = [0.0]
    width = 28

    def cb(prog):
        now = time.perf_counter()
        if now - last[0] < every_s:
            return False
        last[0] = now

        r = prog.residual
        frac = 0.0 if not math.isfinite(r) or r <= 0 else min(1.0, max(0.0, 1 - math.log10(max(r, 1e-30)) / 20))
        bar = "#" * int(frac * width)
        stream.write(f"\r[{bar:<{width}}] it {prog.iteration:>8d}  ||V||inf {r:10.3e} N  "
                     f"{prog.iterations_per_s:9.1f} it/s  contact {prog.contact_count:6d}  {prog.method}")
        stream.flush()
        return False

    return cb


def _stage_printer(stream):
    """Start-up progress: one line per stage on stream (``start-up: model built (N nodes),
    1.2 s``), so a big lattice's start-up is not silent."""
    def on_stage(text: str, seconds: float) -> None:
        stream.write(f"start-up: {text}, {seconds:.1f} s\n")
        stream.flush()

    return on_stage


#: a seam open by more than this share of its shorter side's length after a run is reported as
#: not closed (a sewn seam closes to about 1e-7 m)
SEAM_OPEN_WARN = 0.01


def cmd_run(args) -> int:
    stop: list[str] = []  # the signal that asked the run to stop (SIGINT, SIGTERM)
    # from the solve to the last file written: a signal while the summary is worked out or the
    # files written (seconds on a big sheet) must not lose the finished result either; the --out
    # lock (taken before the solve) is held until the last file is written
    with _stop_on_signals(stop), contextlib.ExitStack() as held:
        return _cmd_run(args, stop, held)


def _cmd_run(args, stop: list[str], held: contextlib.ExitStack) -> int:
    if args.out is not None and not args.out.strip():
        print("error: --out: empty folder name (omit --out to write nothing)", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else None
    # with --json, standard output carries the JSON alone: the human lines go to standard error
    say = functools.partial(print, file=sys.stderr) if args.json else print
    try:
        scene = load_scene(args.scene, args.set)
        if out is not None:  # before the solve: a bad --out must not cost a whole run
            check_out_dir(out)
            # one command per folder: a second run into it is refused at once (two mixed their files)
            held.enter_context(FolderLock(out, "run"))
        show = sys.stderr.isatty() or args.progress
        cb = _progress_printer(sys.stderr) if (show and not args.quiet) else None

        def callback(progress):
            # a first Ctrl+C (or SIGTERM) stops the run at its next iteration and keeps the state
            # it reached (written with --out, status "stopped"); a second one ends it at once
            r = cb(progress) if cb is not None else None
            return True if stop else r

        result = simulation.solve(scene, callback=callback, on_stage=_stage_printer(sys.stderr) if cb else None)
    except (SceneError, MoldError, MaterialError, OutputError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if cb is not None:
        sys.stderr.write("\n")
    s = result.summary()
    if out is not None:
        before = _file_stamps(out)
        try:
            result.save(out, ply_field=args.color)
        except OSError as exc:  # a full disk, the folder removed meanwhile, ...
            print(f"error: {describe_write_error(exc, out)} ({s['status']} after {s['iterations']} iterations); "
                  f"{_left_behind(out, before)}", file=sys.stderr)
            return 2
    line = (f"{s['status']}: {s['iterations']} iterations, ||V||_inf = {s['residual']:.3e} N "
            f"(relative {s['relative_residual']:.1e}), energy {s['energy']:.6e} J, "
            f"{s['wall_time_s']:.3f} s relaxing + {s['startup_s']:.2f} s start-up, solver {s['solver']}, "
            f"{s['contact_count']} contact nodes")
    say(line)
    _print_pressure(s, result.model.mold is not None, say)
    _print_compression(s, say)
    if result.model.mold is not None and not s["contact_count"] and s["status"] == "converged":
        say("  warning: no node touches the mold: the sheet does not reach it, or a garment narrower than the "
            "form closed beside it (its probes read no pressure)")
    interrupted = bool(stop) and s["status"] == "stopped"  # a signal during the last batch: converged
    if interrupted:
        say(f"  interrupted ({stop[0]}): stopped after {s['iterations']} iterations; the state reached is kept"
            + (" (written below)" if out is not None else ""))
    elif s["status"] != "converged":
        say(f"  {s['message']}")
    if s["undetermined_nodes"]:
        say(f"  note: {s['undetermined_nodes']} nodes are held only by slack springs (their position is not unique)")
    if s.get("min_weft_extent_ratio", 1.0) < 0.5:
        say(f"  note: the sheet's narrowest weft extent is {s['min_weft_extent_ratio']:.0%} of its rest width "
            f"(it gathers: nothing holds its width)")

    if gathered_rows_warning(s):
        say(gathered_rows_warning(s))
    if "max_seam_gap_m" in s:
        say(f"  seams: open by at most {s['max_seam_gap_m']:.2e} m")
        for n, r in enumerate(s.get("seams") or []):
            if r["ease_pct"] > 0.01:  # an eased seam: say how much its longer side gathers
                say(f"  seam {n}: sides {r['a_length_m']:.4g} m and {r['b_length_m']:.4g} m, ease "
                    f"{r['ease_pct']:.1f} % (the longer side gathers), open by at most {r['max_gap_m']:.2e} m")
            shorter = min(r["a_length_m"], r["b_length_m"])  # 0 for a tack (two single nodes)
            if shorter > 0.0 and r["max_gap_m"] > SEAM_OPEN_WARN * shorter:
                say(f"  warning: seam {n} is open by up to {r['max_gap_m']:.3g} m, "
                    f"{r['max_gap_m'] / shorter:.0%} of its shorter side: it did not "
                    f"close (are its sides held apart, or its ease too large to gather?)")
    if s.get("gathered_contact_nodes"):
        say(f"  note: {s['gathered_contact_nodes']} contact nodes sit where the sheet has gathered to under 1% of its "
            f"area: their load is a line load (contact_force, N); their pressure is inf and left out of the peak"
            + (f"; line load up to {s['contact_line_load_n_per_m']:.4g} N/m along the rope"
               if s.get("contact_line_load_n_per_m") is not None else ""))
    if out is not None:
        written = _written_files(out, before)
        say(f"  wrote {out}/" + ", ".join(written))
    if args.json:
        print(strict_json(s))
    if interrupted:
        return 130
    return 0 if result.converged else 1


@contextlib.contextmanager
def _stop_on_signals(stop: list, kept: str = "the state reached is kept"):
    """While in the block, SIGINT and SIGTERM append their name to ``stop`` (the run's callback
    then stops it at its next iteration, and a run already finished writes its files); a second
    signal ends the process at once with the signal's default action (a KeyboardInterrupt raised
    from the handler could land in a finalizer and be ignored). Only in the main thread
    (elsewhere signals cannot be handled): there nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        if stop:
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        stop.append(signal.Signals(signum).name)
        # os.write, not print: the handler may run inside a buffered write to stderr
        os.write(2, f"\n{stop[0]}: stopping; {kept} (again to quit at once)\n".encode())
    old = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


def _file_stamps(out: Path) -> dict[str, tuple[int, int]]:
    """{name: (inode, mtime_ns)} of the files in ``out`` (empty if it does not exist yet)."""
    stamps = {}
    try:
        for f in out.iterdir():
            try:
                st = f.stat()
            except OSError:
                continue
            stamps[f.name] = (st.st_ino, st.st_mtime_ns)
    except OSError:
        pass
    return stamps


def _written_files(out: Path, before: dict[str, tuple[int, int]]) -> list[str]:
    """The files of ``out`` that a save wrote (new, or replaced since ``before``: every result file
    is written to a temporary name and renamed over), in writing order."""
    after = _file_stamps(out)
    new = [n for n, st in after.items() if not n.startswith(".") and before.get(n) != st]
    return sorted(new, key=lambda n: (after[n][1], n))


def _left_behind(out: Path, before: dict) -> str:
    """What a failed save left in ``out``: the files it wrote before failing (each complete:
    written to a temporary name and renamed) and that summary.json is missing."""
    written = [n for n in _written_files(out, before) if n != "summary.json"]
    if not written:
        return "nothing was written and no summary.json (the folder holds no finished result)"
    return (f"written before it failed: {', '.join(written)}; no summary.json, so the folder does not count as a "
            f"finished result (result.npz's positions can start a rerun: initial.file)"
            if "result.npz" in written else
            f"written before it failed: {', '.join(written)}; no summary.json, so the folder does not count as a "
            f"finished result")


def _print_pressure(s: dict, has_mold: bool, say=print) -> None:
    """The contact pressure a run reached: the peak a sensor disc reads (mmHg and Pa, and the
    node peak beside it), when the scene has a mold."""
    mmhg, pa = s.get("max_sensor_pressure_mmhg"), s.get("max_sensor_pressure_pa")
    if not has_mold or mmhg is None or pa is None:
        return  # no mold, or every loaded node gathered (the line load is reported below)
    node = s.get("max_contact_pressure_mmhg")
    say(f"  pressure: peak {mmhg:.2f} mmHg ({pa:.1f} Pa) on a sensor disc of radius "
        f"{1000 * s.get('sensor_radius_m', 0.005):.3g} mm"
        + (f"; {node:.2f} mmHg at a single node" if node is not None and mmhg > 0 else ""))


def _print_compression(s: dict, say=print) -> None:
    """The probes (name, pressure, contact fraction, class, note) and each profile's gradient
    check of a run summary, when the scene asks for them, through ``say`` (print)."""
    probes = s.get("probes") or []
    if probes:
        w = max(len(p["name"]) for p in probes)
        say("  probes (normal force on the sensor disc / its area):")
        for p in probes:
            cls = "; ".join(f"{k}: {v}" for k, v in (p.get("classes") or {}).items())
            say(f"    {p['name']:<{w}}  {p['pressure_mmhg']:8.2f} mmHg  contact fraction {p['contact_fraction']:.2f}"
                + (f"  {cls}" if cls else "") + (f"  ({p['note']})" if p.get("note") else ""))
    for pf in s.get("profiles") or []:
        say(f"  profile {pf['name']}: {pf['gradient'].get('note', '')}")
    if s.get("levels"):
        for line in levels_lines(s["levels"]):
            say(line)


def cmd_view(args) -> int:
    from .viewer import main as viewer_main

    return viewer_main(args)


def cmd_outputs(args) -> int:
    """``python app.py outputs``: the field list (clothsim.records) as a table: output, unit, meaning."""

    rows = [[c.strip().strip("`").replace("\\|", "|") for c in line.strip("|").split(" | ")]
            for line in outputs_markdown().splitlines()[2:]]
    w0, w1 = max(len(r[0]) for r in rows), max(len(r[1]) for r in rows)
    print(f"{'output':<{w0}}  {'unit':<{w1}}  meaning")
    for name, unit, doc in rows:
        print(f"{name:<{w0}}  {unit:<{w1}}  {doc}")
    return 0


def cmd_sweep(args) -> int:
    return sweep_main(args)


def cmd_bench(args) -> int:
    if getattr(args, "friction", False):
        from .bench.friction import main as friction_main

        return friction_main(args)
    from .bench import main as bench_main

    return bench_main(args)


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be a positive finite number (got {text})")
    return v


def _port(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 1 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"must be between 1 and 65535 (got {v})")
    return v


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1 (got {v})")
    return v


COMMANDS = ("run", "view", "sweep", "bench", "fit", "report", "outputs")


def cmd_fit(args) -> int:
    """Inverse sizing (clothsim.compression.fit): exit 0 fitted, 1 not within tolerance, 2 bad
    input or an unreachable target, 130 interrupted (SIGINT or SIGTERM: the tries finished so far
    are kept in fit.csv)."""
    stop: list[str] = []
    with _stop_on_signals(stop, "the tries finished so far are kept"), contextlib.ExitStack() as held:
        return _cmd_fit(args, stop, held)


def _cmd_fit(args, stop: list[str], held: contextlib.ExitStack) -> int:
    def log(t):
        vals = ", ".join(f"{x:.8g}" for x in t.values)
        reads = ", ".join(f"{p:.3f} mmHg ({r:+.3f})" for p, r in zip(t.readings_mmhg, t.residuals_mmhg))
        print(f"  try {vals}: {reads}  {t.time_s:.2f} s  {t.status}", file=sys.stderr, flush=True)

    try:
        varies = [parse_vary(v) for v in args.vary]
        targets = [parse_target(t) for t in args.target]
        if args.out:  # before the solves: a bad --out must not cost a whole fit
            check_out_dir(args.out)
            held.enter_context(FolderLock(args.out, "fit"))
        res = fit(args.scene, varies, targets, overrides=args.set, tol_mmhg=args.tol, max_solves=args.max_solves,
                  log=None if args.quiet else log, stop=stop)
    except FitInterrupted as exc:
        return _fit_interrupted(args, exc, varies, targets)
    except (FitError, SceneError, MoldError, MaterialError, OutputError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(("fitted: " if res.converged else "not fitted: ") + res.message)

    for line in fitted_lines(res, varies, targets):
        print(line)
    print(res.tries_csv(varies, targets), end="")
    if args.out:
        before = _file_stamps(Path(args.out))
        try:
            out = write_outputs(res, args.out, varies, targets)
        except OSError as exc:  # a full disk, the folder removed meanwhile, ...
            print(f"error: {describe_write_error(exc, args.out)}; {_left_behind(Path(args.out), before)}",
                  file=sys.stderr)
            return 2
        print(f"  wrote {out}/fitted.yaml, fit.csv, fit.json and the fitted run's result files")
    return 0 if res.converged else 1


def _fit_interrupted(args, exc, varies, targets) -> int:
    """A signal stopped the fit: the tries it finished go to standard output and, with --out, to
    fit.csv and fit.json (each written atomically); exit 130."""
    res = FitResult(False, f"{exc}; not fitted", [], [], tries=exc.tries)
    print(f"not fitted: {res.message}")
    text = res.tries_csv(varies, targets)
    print(text, end="")
    wrote = ""
    if args.out:
        out = Path(args.out)
        info = {**fit_info(res, varies, targets), "interrupted": exc.name}
        try:
            atomic_write_bytes(out / "fit.csv", text.encode())
            atomic_write_bytes(out / "fit.json", strict_json(info).encode())
        except OSError as err:
            print(f"error: {describe_write_error(err, out)}", file=sys.stderr)
            return 2
        wrote = f"; wrote {out}/fit.csv and fit.json"
    print(f"interrupted ({exc.name}): {len(exc.tries)} finished tries kept{wrote}", file=sys.stderr)
    return 130


def cmd_report(args) -> int:
    try:
        path = write_report(args.result_dir, args.out, pmax=args.pmax)
    except (ReportError, SceneError, MoldError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file the checks did not foresee (removed meanwhile, ...)
        print(f"error: {exc.filename or args.result_dir}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0


def add_compression_commands(sub) -> None:
    """The compression-engineering subcommands: fit and report."""
    f = sub.add_parser("fit", help="inverse sizing: find a field's value that gives target probe pressures",
                       description="Inverse sizing: vary scene fields (a panel width, a stretch, a material "
                                   "scale) until the scene's probes read the target pressures; writes the "
                                   "fitted scene and every try. Exit 0 fitted, 1 not within --tol, 2 bad input "
                                   "or a target out of reach, 130 interrupted (the tries so far are kept).")
    f.add_argument("scene", help="scene YAML file with probes")
    f.add_argument("--vary", action="append", required=True, metavar="FIELD[=LO:HI]",
                   help="a scene field to vary (a --set path; one the file omits starts from its default, "
                        "e.g. fabric.warp.scale from 1), with optional bounds (default: start value +-30%%), "
                        "e.g. --vary fabric.size.0=0.2:0.3")
    f.add_argument("--target", action="append", required=True, metavar="PROBE=VALUE",
                   help="a probe's target pressure, e.g. --target ankle=20mmHg (units mmHg, Pa, kPa), or a "
                        "measuring level's girth mean, e.g. --target B=27.5mmHg")
    f.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="override a scene field")
    f.add_argument("--tol", type=_positive_float, default=0.1,
                   help="tolerance on each target [mmHg], positive and finite (default 0.1)")
    f.add_argument("--max-solves", type=_positive_int, default=12, help="most solves to spend, at least 1 (default 12)")
    f.add_argument("--out", help="folder for fitted.yaml, fit.csv, fit.json and the fitted run's results")
    f.add_argument("--quiet", action="store_true", help="do not print each try")
    f.set_defaults(func=cmd_fit)

    r = sub.add_parser("report", help="write a self-contained HTML report of a result folder",
                       description="Write a self-contained HTML report (pressure map on the body, probes, "
                                   "levels, profile and gradient, material, assumptions, run summary) of a "
                                   "folder written by run --out or fit --out, from the folder alone (it can "
                                   "be moved or mailed); the page opens in any browser without a server.")
    r.add_argument("result_dir", help="a folder written by run --out or fit --out")
    r.add_argument("--out", help="HTML file to write (default RESULT_DIR/report.html)")
    r.add_argument("--pmax", type=_positive_float, default=None,
                   help="top of the pressure map's colour scale [mmHg], positive and finite (default: the 98th "
                        "percentile of the contact nodes' pressure, rounded up; the report states it)")
    r.set_defaults(func=cmd_report)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="clothsim", description=__doc__.splitlines()[0],
        epilog="Without a command, or with a scene file first (python app.py configs/x.yaml), the viewer "
               "opens. Exit status: 0 converged, 1 not converged, 2 bad input, 130 interrupted (the state "
               "reached is kept).")
    sub = p.add_subparsers(dest="command")

    r = sub.add_parser("run", help="relax a scene headless and write its results",
                       description="Relax a scene headless, print its summary (the pressure peak and probes "
                                   "included) and, with --out, write its result files (the folder is locked "
                                   "while the run writes it).")
    r.add_argument("scene", help="scene YAML file")
    r.add_argument("--out", help="output folder (result.npz, summary.json, history.csv, sheet.ply, scene.yaml)")
    r.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override a scene field, e.g. --set solver.C=3 --set fabric.divisions=[80,80]")
    r.add_argument("--color", choices=["strain", "pressure"], default="strain", help="sheet.ply colouring (default: %(default)s)")
    r.add_argument("--progress", action="store_true", help="show the progress bar even when not on a terminal")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--json", action="store_true", help="print the summary as JSON")
    r.set_defaults(func=cmd_run)

    v = sub.add_parser("view", help="open the browser viewer (default command)",
                       description="Open the browser viewer on a scene (the default command).")
    v.add_argument("scene", nargs="?", default=str(DEFAULT_SCENE),
                   help="scene YAML file (default: configs/thermoform.yaml)")
    v.add_argument("--host", default="127.0.0.1",
                   help="address to serve on (default: %(default)s, this machine only)")
    v.add_argument("--port", type=_port, default=8080,
                   help="port to serve on; the next free one is taken if busy (default: %(default)s)")
    v.add_argument("--upload-limit-mb", type=_positive_float, default=200.0,
                   help="largest mold or table upload accepted [MB] (default: %(default)s)")
    v.add_argument("--no-browser", action="store_true", help="do not open a browser tab")
    v.set_defaults(func=cmd_view)

    s = sub.add_parser("sweep", help="run a parameter sweep",
                       description="Run every combination of a sweep file's parameters; finished runs "
                                   "are kept, so rerunning the same command continues an interrupted sweep.")
    s.add_argument("sweep", help="sweep YAML file (see README: Parameter sweeps)")
    s.add_argument("--out", required=True,
                   help="output folder: one folder per run, summary.csv and plots/ (locked while the sweep runs)")
    s.add_argument("--workers", type=_positive_int, default=None,
                   help="worker processes (default: the number of CPUs)")
    s.add_argument("--dask", default=None,
                   help="'local' for a Dask LocalCluster or a scheduler address tcp://host:port "
                        "(default: local worker processes, no Dask)")
    s.add_argument("--force", action="store_true", help="rerun finished runs too")
    s.add_argument("--skip-errors", action="store_true",
                   help="do not retry runs that ended in status 'error' (they are retried by default)")
    s.set_defaults(func=cmd_sweep)

    o = sub.add_parser("outputs", help="list the outputs a run reports and a sweep accepts, with their units",
                       description="Every field of a run's results (clothsim.records: summary.json, the "
                                   "friction report, stages, probes, the sweep worker's extras) with its "
                                   "unit and meaning: the names a sweep file's outputs: takes.")
    o.set_defaults(func=cmd_outputs)

    b = sub.add_parser("bench", help="speed-against-error benchmark",
                       description="Time every solver against its error on the benchmark scenes.")
    b.add_argument("--quick", action="store_true", help="small grids and short caps (about a minute)")
    b.add_argument("--out", default=str(Path("results") / "bench"),
                   help="folder for benchmarks.md and speed_vs_error.png (default: %(default)s; the "
                        "repository's copies are in docs/benchmarks/)")
    b.add_argument("--scans", action="store_true",
                   help="only the scan campaign (the torso band on the scanned bodies, newton alone): "
                        "writes benchmarks_scans.md")
    b.add_argument("--surface", choices=("faceted", "smooth"), default="faceted",
                   help="the scanned bodies' contact surface in the scan campaign (default: %(default)s)")
    b.add_argument("--garments", action="store_true",
                   help="only the panel scenes (a 40k-node circle and four sewn panels on the sphere cap) "
                        "beside the 201^2 square: writes benchmarks_garments.md")
    b.add_argument("--repeat", type=int, default=None,
                   help="with --garments: rounds of fresh processes, each running every scene once; the best "
                        "and the median of the rounds' ratios to the square reported (default: "
                        "bench.GARMENT_REPEAT, 5)")
    b.add_argument("--friction", action="store_true",
                   help="only the friction benchmark: a frictional load step against the frictionless solve "
                        "(capstan, tube on a cone, the stocking with friction; --quick leaves the stocking "
                        "out) and the capstan's error against the lattice size: writes benchmarks_friction.md")
    b.set_defaults(func=cmd_bench)
    add_compression_commands(sub)
    return p


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Our own warnings (implausible tables, a mold in millimetres, mold files' dropped triangles)
    as one ``warning: ...`` line, no source location."""
    if issubclass(category, MaterialWarning) or "clothsim" in str(filename):
        # once per command: a scene is validated again when it is resolved, copied or written
        # (a table's warning came 2 or 3 times)
        if str(message) not in _shown:
            _shown.add(str(message))
            print(f"warning: {message}", file=sys.stderr)
    else:
        _default_showwarning(message, category, filename, lineno, file, line)


_default_showwarning = warnings.showwarning
_shown: set[str] = set()  # the warnings this command has printed


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser()
    # view is the default command: no command, an option first or a scene file first
    if not argv or argv[0] not in (*COMMANDS, "-h", "--help"):
        argv = ["view", *argv]
    args = parser.parse_args(argv)
    _shown.clear()
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        try:
            return int(args.func(args) or 0)
        except KeyboardInterrupt:  # Ctrl+C before a command's own handler is in place
            print("\ninterrupted", file=sys.stderr)
            return 130
        except MemoryError:  # past the estimate (clothsim.compile.check_memory): a clear refusal
            print(f"error: {args.command}: out of memory (the scene needs more memory than this process "
                  f"may use: the machine's, or a ulimit -v or cgroup limit); use fewer divisions",
                  file=sys.stderr)
            return 2


if __name__ == "__main__":
    sys.exit(main())
