"""The first start on a fresh install: ``run`` and the viewer's first drawn frame with an empty
numba cache, their wall and CPU seconds, and where the compile time goes, kernel by kernel.

    python scripts/cold_start.py [run|view|both] [--scene configs/thermoform.yaml] [--warm]
                                 [--top 25] [--json FILE]

Each start is a subprocess whose NUMBA_CACHE_DIR is a new empty temporary folder (``--warm``: a
second start on the same folder). ``run`` times ``python app.py run SCENE --quiet``; ``view``
starts ``python app.py view SCENE --no-browser``, opens its URL in Debian's headless Chromium
(through Playwright) as soon as it is printed, and times the page showing the "compiling
kernels" note, the first 3D frame drawn (canvas pixels) and the relaxation running (the status
line's iteration above 0).

The machine may be shared: beside every wall time the script gives the CPU seconds (user +
system) of the started process, which load does not inflate (much).

The per-kernel table comes from numba's event API (``numba.core.event``, the "numba:compile"
event, broadcast around each dispatcher's compilation, not around a load from the cache):
``self`` is a kernel's own compile time, nested compilations of the kernels it calls taken out,
``incl`` the time with them (counted where the compilation was started from Python, the root of
a nest), ``llvm`` the CPU seconds LLVM spent under its lock (optimisation and machine code) in
the kernel's own compilation. The sum of ``self`` is the compile time."""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


# ----------------------------------------------------------------------------- the child side
def _install_compile_table(path: str) -> None:
    """Record numba's compile events of this process; write the table to ``path`` at exit."""
    import atexit
    import threading

    from numba.core import event as ev

    t_start = time.perf_counter()
    rows: dict[str, dict] = {}
    stacks: dict[int, list] = {}  # per thread: [wall0, cpu0, child wall, child cpu, llvm cpu]
    llvm: dict[int, list] = {}  # per thread: the LLVM lock's start (cpu) stack

    def name_of(data) -> str:
        f = data["dispatcher"].py_func
        mod = f.__module__ or ""
        return (mod.removeprefix("clothsim.") + "." if mod.startswith("clothsim") else mod + ".") + f.__qualname__

    class Compile(ev.Listener):
        def on_start(self, event):
            stacks.setdefault(threading.get_ident(), []).append(
                [time.perf_counter(), time.thread_time(), 0.0, 0.0, 0.0])

        def on_end(self, event):
            st = stacks[threading.get_ident()]
            w0, c0, cw, cc, lc = st.pop()
            wall, cpu = time.perf_counter() - w0, time.thread_time() - c0
            if st:
                st[-1][2] += wall
                st[-1][3] += cpu
            r = rows.setdefault(name_of(event.data), {"compiles": 0, "self_s": 0.0, "self_cpu_s": 0.0,
                                                      "incl_s": 0.0, "llvm_cpu_s": 0.0, "first_at_s": None,
                                                      "signatures": []})
            r["compiles"] += 1
            r["self_s"] += wall - cw
            r["self_cpu_s"] += cpu - cc
            r["llvm_cpu_s"] += lc
            r["signatures"].append(", ".join(str(a) for a in event.data["args"]))
            if r["first_at_s"] is None:
                r["first_at_s"] = w0 - t_start
            if not st:
                r["incl_s"] += wall

    class Llvm(ev.Listener):
        def on_start(self, event):
            llvm.setdefault(threading.get_ident(), []).append(time.thread_time())

        def on_end(self, event):
            c0 = llvm[threading.get_ident()].pop()
            st = stacks.get(threading.get_ident())
            if st:
                st[-1][4] += time.thread_time() - c0

    ev.register("numba:compile", Compile())
    ev.register("numba:llvm_lock", Llvm())

    def dump():
        tmp = path + ".tmp"
        with open(tmp, "w") as f:
            json.dump(rows, f)
        os.replace(tmp, path)

    atexit.register(dump)


def child(table: str, argv: list[str]) -> int:
    _install_compile_table(table)
    sys.path.insert(0, os.getcwd())
    from clothsim.cli import main as cli_main

    return cli_main(argv)


# ----------------------------------------------------------------------------- the parent side
def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cpu_s(pid: int) -> float:
    """CPU time [s] (user + system) the process has used so far (load-independent, unlike wall time)."""
    f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


def _env(cache: str, root: Path) -> dict:
    return {**os.environ, "NUMBA_CACHE_DIR": cache, "PYTHONPATH": str(root)}


def _child_cmd(table: str, argv: list[str]) -> list[str]:
    return [sys.executable, str(Path(__file__).resolve()), "--child", table, "--", *argv]


def one_run(scene: str, cache: str, root: Path, table: str) -> dict:
    """``app.py run SCENE --quiet`` in a subprocess: wall and CPU seconds, its summary line."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(_child_cmd(table, ["run", scene, "--quiet"]), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, cwd=root, env=_env(cache, root))
    out = proc.stdout.read()
    _pid, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise RuntimeError(f"run exited with {proc.returncode}:\n{out}")
    r = {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime}
    m = re.search(r"([0-9.]+) s relaxing \+ ([0-9.]+) s start-up", out)
    if m:
        r["relax_s"], r["startup_s"] = float(m.group(1)), float(m.group(2))
    m = re.search(r"energy ([0-9.eE+-]+) J", out)
    if m:
        r["energy_J"] = float(m.group(1))
    return r


def one_view(browser, scene: str, cache: str, root: Path, table: str, frame_only: bool = False) -> dict:
    """``app.py view`` in a subprocess, its page in Chromium: seconds to the URL, the note, the
    first frame and the relaxation running, with the process's CPU seconds at the last two."""
    from browser_util import canvas_pixels, close_notifications

    port = free_port()
    t0 = time.perf_counter()
    proc = subprocess.Popen(_child_cmd(table, ["view", scene, "--port", str(port), "--no-browser"]),
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=root,
                            env=_env(cache, root))
    out: dict = {}
    page = None
    try:
        line = ""
        while "clothsim viewer:" not in line:
            line = proc.stdout.readline()
            if not line and proc.poll() is not None:
                raise RuntimeError("the viewer exited")
        out["url_s"] = time.perf_counter() - t0
        url = line.split("clothsim viewer:", 1)[1].split()[0]
        page = browser.new_page(viewport={"width": 1200, "height": 800})
        page.goto(url)
        deadline = t0 + 900
        while time.perf_counter() < deadline:
            body = page.inner_text("body")
            if "note_s" not in out and "Compiling kernels" in body:
                out["note_s"] = time.perf_counter() - t0
            if "frame_s" not in out and canvas_pixels(page).get("n", 0) >= 2000:
                out["frame_s"] = time.perf_counter() - t0
                out["frame_cpu_s"] = cpu_s(proc.pid)
                if frame_only:
                    break
            m = re.search(r"iteration (\d+) · residual", body)
            if "run_s" not in out and m and int(m.group(1)) > 0:
                out["run_s"] = time.perf_counter() - t0
                out["run_cpu_s"] = cpu_s(proc.pid)
            if "frame_s" in out and "run_s" in out:
                break
            close_notifications(page)
            page.wait_for_timeout(200)
    finally:
        if page is not None:
            page.close()
        proc.terminate()  # view stops on SIGTERM like on Ctrl+C (exit 0; the table is written)
        proc.wait(60)
    return out


def table_rows(path: str) -> list[tuple[str, dict]]:
    try:
        rows = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return []
    return sorted(rows.items(), key=lambda kv: -kv[1]["self_cpu_s"])


def print_table(rows: list[tuple[str, dict]], top: int) -> None:
    if not rows:
        print("  (nothing compiled)")
        return
    tot = {k: sum(r[k] for _, r in rows) for k in ("self_s", "self_cpu_s", "llvm_cpu_s")}
    n = sum(r["compiles"] for _, r in rows)
    print(f"  {len(rows)} kernels, {n} compilations: {tot['self_s']:.1f} s wall, {tot['self_cpu_s']:.1f} s CPU "
          f"({tot['llvm_cpu_s']:.1f} s of it in LLVM)")
    print(f"  {'self CPU s':>10} {'self s':>7} {'incl s':>7} {'LLVM s':>7} {'n':>3}  kernel")
    for name, r in rows[:top]:
        print(f"  {r['self_cpu_s']:10.2f} {r['self_s']:7.2f} {r['incl_s']:7.2f} {r['llvm_cpu_s']:7.2f} "
              f"{r['compiles']:3d}  {name}")
    if len(rows) > top:
        rest = rows[top:]
        print(f"  {sum(r['self_cpu_s'] for _, r in rest):10.2f} {sum(r['self_s'] for _, r in rest):7.2f} "
              f"{'':7} {sum(r['llvm_cpu_s'] for _, r in rest):7.2f} {sum(r['compiles'] for _, r in rest):3d}  "
              f"({len(rest)} more)")


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--child":
        return child(sys.argv[2], sys.argv[4:])
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", nargs="?", choices=("run", "view", "both"), default="both")
    ap.add_argument("--scene", default=str(ROOT / "configs" / "thermoform.yaml"))
    ap.add_argument("--root", default=str(ROOT), help="the checkout to start (to compare with another)")
    ap.add_argument("--warm", action="store_true", help="also a second start on the now warm cache")
    ap.add_argument("--frame-only", action="store_true", help="view: stop at the first frame")
    ap.add_argument("--top", type=int, default=25, help="rows of the per-kernel table (default 25)")
    ap.add_argument("--json", help="also write the figures and the full tables to this file")
    args = ap.parse_args()
    root = Path(args.root).resolve()
    scene = str(Path(args.scene).resolve())
    report: dict = {"scene": scene, "load_average": os.getloadavg()}
    with tempfile.TemporaryDirectory(prefix="numba-cold-") as tmp:
        kinds = ["cold"] + (["warm"] if args.warm else [])
        if args.what in ("run", "both"):
            cache = os.path.join(tmp, "run-cache")
            os.mkdir(cache)
            for kind in kinds:
                table = os.path.join(tmp, f"run-{kind}.json")
                r = one_run(scene, cache, root, table)
                r["kernels"] = dict(table_rows(table))
                report[f"run_{kind}"] = r
                print(f"run {kind}: wall {r['wall_s']:.1f} s, CPU {r['cpu_s']:.1f} s"
                      + (f" (start-up {r['startup_s']:.1f} s, relaxing {r['relax_s']:.1f} s)" if "relax_s" in r else ""),
                      flush=True)
                print_table(table_rows(table), args.top)
        if args.what in ("view", "both"):
            sys.path.insert(0, str(ROOT / "tests"))
            from browser_util import launch
            from playwright.sync_api import sync_playwright

            cache = os.path.join(tmp, "view-cache")
            os.mkdir(cache)
            with sync_playwright() as p:
                browser = launch(p)
                try:
                    for kind in kinds:
                        table = os.path.join(tmp, f"view-{kind}.json")
                        r = one_view(browser, scene, cache, root, table, args.frame_only)
                        rows = table_rows(table)
                        r["kernels"] = dict(rows)
                        report[f"view_{kind}"] = r
                        print(f"view {kind}: " + ", ".join(f"{k} {v:.1f}" for k, v in r.items() if k != "kernels"),
                              flush=True)
                        print_table(rows, args.top)
                finally:
                    browser.close()
    report["load_average_end"] = os.getloadavg()
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
