"""Cold start (issue 14, item 4): the first ``python app.py`` compiles about 30 s of numba kernels.
The viewer serves its page at once with a "compiling kernels (first run only)" note, builds the
model, the panels and the kernels in a start-up thread, and starts the relaxation when they are
ready. Tested in a real headless Chromium with a warm-up hook that blocks (a slow compile
simulated), and through the command line (the URL printed at once, a scene that cannot be built
still exits 2). The time to the first frame on a truly cold cache is measured by
scripts/cold_start.py (docs/benchmarks/benchmarks.md), not here."""

from __future__ import annotations

import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

pytest.importorskip("viser")

from viewer_util import free_port, small_scene, wait_for  # noqa: E402
from clothsim.viewer import ViewerApp  # noqa: E402
from clothsim.viewer.server import STARTUP_NOTE  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def test_background_start_serves_at_once_and_starts_when_warm():
    """Without a browser: the constructor returns before the warm-up ends, with the note on the
    page; the relaxation starts only once the warm-up returns, then runs to convergence."""
    gate = threading.Event()
    entered = threading.Event()

    def slow_warm(sim):
        entered.set()
        gate.wait(60)

    t0 = time.perf_counter()
    a = ViewerApp(small_scene(), port=free_port(), background=True, autostart=True, warm=slow_warm)
    try:
        assert time.perf_counter() - t0 < 10
        assert a._startup_note is not None and STARTUP_NOTE in a._startup_note.content
        assert entered.wait(60) and not a.ready.is_set()
        time.sleep(0.5)
        assert a.sim.status == "idle" and a.sim.state.iteration == 0
        gate.set()
        assert a.ready.wait(30) and a.startup_error is None and a._startup_note is None
        assert wait_for(lambda: a.sim.state.iteration > 0, 60)
        assert a.sim.wait(120) == "converged"
    finally:
        gate.set()
        a.close()


def test_background_start_reports_a_scene_that_cannot_be_built(tmp_path):
    """A mold that fails to load in the start-up thread is shown on the page and kept in
    ``startup_error``; ``view`` then exits 2 with the message, no traceback."""
    d = yaml.safe_load((ROOT / "configs" / "sphere_cap.yaml").read_text())
    (tmp_path / "bad.stl").write_bytes(b"solid x\nthis is not an stl\n")
    d["mold"] = {"path": str(tmp_path / "bad.stl")}
    scene = tmp_path / "s.yaml"
    scene.write_text(yaml.safe_dump(d))
    r = subprocess.run([sys.executable, str(ROOT / "app.py"), "view", str(scene), "--port", str(free_port()),
                        "--no-browser"], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 2 and "bad.stl" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert "clothsim viewer: http://127.0.0.1:" in r.stdout  # the page was served first


def test_view_prints_its_url_before_the_kernels_are_ready():
    """``view`` prints the URL at once (the page is served while the model is built and the
    kernels compile), then says when it is ready."""
    proc = subprocess.Popen([sys.executable, str(ROOT / "app.py"), "view", str(ROOT / "configs" / "sphere_cap.yaml"),
                             "--port", str(free_port()), "--no-browser"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        t0 = time.time()
        line = ""
        while "clothsim viewer:" not in line and time.time() - t0 < 60:
            line = proc.stdout.readline()  # viser's own banner comes first
        assert "clothsim viewer:" in line and time.time() - t0 < 30, time.time() - t0
        err = ""
        while "ready in" not in err and time.time() - t0 < 300:
            err += proc.stderr.readline()
        # "compiling kernels" on a cold numba cache only, "loading ..." on a warm one (issue 28.20)
        assert ("compiling kernels (first start" in err or "loading the compiled kernels" in err) and "ready in" in err, err
    finally:
        proc.terminate()
        proc.wait(30)


# --------------------------------------------------------------------------- in Chromium
# (the `browser` fixture, Debian's Chromium: tests/conftest.py)
@pytest.mark.slow
def test_browser_shows_compiling_note_until_kernels_ready(browser):
    """Issue 14, item 4 in Chromium: while the (simulated slow) warm-up runs, the page shows the
    "Compiling kernels (first run only)" note and the relaxation has not started; once it returns
    the note goes and the status line shows the relaxation running on its own (no Start)."""
    from browser_util import close_notifications, shown_iteration

    gate = threading.Event()

    def slow_warm(sim):
        gate.wait(120)

    a = ViewerApp(small_scene(), port=free_port(), background=True, autostart=True, warm=slow_warm)
    page = browser.new_page(viewport={"width": 1400, "height": 900})
    try:
        page.goto(a.url)
        page.get_by_text(STARTUP_NOTE).first.wait_for(timeout=60_000)
        assert not a.ready.is_set()
        page.wait_for_timeout(1500)
        assert page.get_by_text(STARTUP_NOTE).count() >= 1 and not a.ready.is_set()
        gate.set()
        assert a.ready.wait(60)
        page.get_by_text(STARTUP_NOTE).first.wait_for(state="detached", timeout=120_000)
        close_notifications(page)
        t0 = time.time()
        it = 0
        while it == 0 and time.time() - t0 < 60:
            try:
                it = shown_iteration(page)
            except Exception:  # the status line is not there yet
                pass
            page.wait_for_timeout(300)
        assert it > 0, re.sub(r"\s+", " ", page.inner_text("body"))[:400]
    finally:
        gate.set()
        page.close()
        a.close()


def test_startup_note_says_compiling_only_on_a_cold_cache():
    """Issue 28 item 20: the page said "Compiling kernels (first run only)" on every start; it
    says compiling only when numba's cache holds no kernels of this version, loading otherwise."""
    from clothsim.viewer.server import _startup_html

    cold, warm = _startup_html(3.0, cached=False), _startup_html(3.0, cached=True)
    assert STARTUP_NOTE in cold and STARTUP_NOTE in warm
    assert "compiling" in cold and "compiling" not in warm and "cache" in warm
