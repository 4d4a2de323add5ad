"""Seams in the viewer in a real headless Chromium (see tests/test_browser.py for the set-up):
the orange threads of a seam of unequal node counts are drawn in the 3D view, and the status
line lists the seam's widest gap and ease.

Without /usr/bin/chromium these tests skip locally and fail in CI (``CI`` set)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

pytest.importorskip("viser")
pytest.importorskip("playwright")

from browser_util import free_port, open_viewer, pixels_js, poll, status_text  # noqa: E402

from clothsim.config import load_scene  # noqa: E402
from clothsim.viewer import ViewerApp  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent

# pixels of the seam threads' orange (255, 140, 0), lit or blended: any shade with r >> g >> b
ORANGE_JS = pixels_js("r > 150 && g > 0.35 * r && g < 0.75 * r && b < 0.35 * g")


@pytest.mark.slow
def test_unequal_seam_threads_and_gap_list_in_chromium(browser):
    """configs/garments/eased_seam.yaml started 3 cm open (its upper panel moved up): the 23
    threads (one per sewn node) show as orange pixels in the page, which go when the threads
    are hidden; after Start the status line in the page lists 'seam 0: widest gap ... m (ease
    10.0 %)' with the gap closed below 1e-5 m."""
    scene = load_scene(ROOT / "configs" / "garments" / "eased_seam.yaml",
                       ["panels.1.placement.transform.translate=[-0.005,0.08,0]"])
    app = ViewerApp(scene, port=free_port())
    try:
        page = open_viewer(browser, app.url)
        try:
            assert app.renderer.h_seams is not None and len(app.renderer.h_seams.points) == 23
            shown = poll(lambda: page.evaluate(ORANGE_JS) > 200 and page.evaluate(ORANGE_JS), timeout=30)
            app.renderer.h_seams.visible = False
            hidden = poll(lambda: page.evaluate(ORANGE_JS) < (shown or 0) / 4 and page.evaluate(ORANGE_JS) + 1,
                           timeout=30)
            print(f"orange pixels: {shown} with the seam threads, {hidden and hidden - 1} without")
            assert shown and hidden and hidden - 1 < shown / 4
            app.renderer.h_seams.visible = True
            page.get_by_role("button", name="Start").click()
            text = poll(lambda: "converged" in status_text(page) and "seam 0" in status_text(page)
                         and status_text(page), timeout=90)
            assert text, status_text(page)
            m = re.search(r"seam 0: widest gap ([0-9.eE+-]+) m \(ease 10\.0 %\)", text)
            assert m, text
            assert float(m.group(1)) < 1e-5
        finally:
            page.close()
    finally:
        app.close()
