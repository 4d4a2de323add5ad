"""Time to the first drawn frame of ``python app.py view`` on a cold numba cache, in a real
headless Chromium (Debian's package, through Playwright).

    python scripts/cold_start.py [--scene configs/thermoform.yaml] [--warm]

NUMBA_CACHE_DIR points at an empty temporary folder (``--warm``: a second start on the same
folder), the viewer starts in a subprocess, the browser (started beforehand) opens its URL as
soon as it is printed, and the script prints, in seconds from the process start: the URL printed,
the page showing the "compiling kernels" note, the first 3D frame drawn (canvas pixels), and the
relaxation running (the status line's iteration above 0)."""

from __future__ import annotations

import argparse
import os
import re
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cpu_s(pid: int) -> float:
    """CPU time [s] (user + system) the process has used so far (load-independent, unlike wall time)."""
    f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


def one_start(browser, scene: str, cache: str, root: Path, frame_only: bool = False) -> dict:
    from browser_util import canvas_pixels, close_notifications

    env = {**os.environ, "NUMBA_CACHE_DIR": cache, "PYTHONPATH": str(root)}
    port = free_port()
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, str(root / "app.py"), "view", scene, "--port", str(port),
                             "--no-browser"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            cwd=root, env=env)
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
        deadline = t0 + 600
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
        proc.terminate()
        proc.wait(30)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default=str(ROOT / "configs" / "thermoform.yaml"))
    ap.add_argument("--root", default=str(ROOT), help="the checkout to start (to compare with another)")
    ap.add_argument("--warm", action="store_true", help="also a second start on the now warm cache")
    ap.add_argument("--frame-only", action="store_true", help="stop at the first frame (a viewer that "
                    "does not start the relaxation by itself)")
    args = ap.parse_args()
    from browser_util import launch
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory(prefix="numba-cold-") as cache, sync_playwright() as p:
        browser = launch(p)
        try:
            runs = [("cold", one_start(browser, args.scene, cache, Path(args.root), args.frame_only))]
            if args.warm:
                runs.append(("warm", one_start(browser, args.scene, cache, Path(args.root), args.frame_only)))
        finally:
            browser.close()
    for kind, r in runs:
        print(kind, "  ".join(f"{k} {v:.1f}" for k, v in r.items()))


if __name__ == "__main__":
    main()
