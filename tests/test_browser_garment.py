"""Pattern panels in the viewer in a real headless Chromium (see tests/test_browser.py for the
set-up): the two-panel DXF sleeve (configs/garments/sleeve_dxf.yaml) shows each panel's outline
as magenta pixels that go when *Show panel outlines* is unticked in the View tab, and the Fabric &
mold tab lists the panels (the table and the placement's panel chooser).

Without /usr/bin/chromium these tests skip locally and fail in CI (``CI`` set)."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("viser")
pytest.importorskip("playwright")

from browser_util import free_port, open_viewer, pixels_js, poll  # noqa: E402

from clothsim.config import load_scene  # noqa: E402
from clothsim.viewer import ViewerApp  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent

# pixels of the outlines' magenta (220, 0, 220), lit or blended: red and blue high, green far
# below both (the sheet's viridis map, the seams' orange, the constrained nodes' red and the
# grey mold never are)
MAGENTA_JS = pixels_js("r > 120 && b > 120 && g < 0.45 * Math.min(r, b)")


@pytest.mark.slow
def test_panel_outlines_and_panel_list_in_chromium(browser):
    app = ViewerApp(load_scene(ROOT / "configs" / "garments" / "sleeve_dxf.yaml"), port=free_port())
    try:
        page = open_viewer(browser, app.url)
        try:
            assert app.renderer.h_outlines is not None
            assert len(app.renderer.h_outlines.points) == int(app.sim.model.topology.boundary.sum())
            shown = poll(lambda: page.evaluate(MAGENTA_JS) > 200 and page.evaluate(MAGENTA_JS), timeout=30)
            # untick "Show panel outlines" in the View tab (the page, not the server)
            page.get_by_role("tab", name="View").click()
            page.get_by_text("Show panel outlines").first.click()
            hidden = poll(lambda: page.evaluate(MAGENTA_JS) < (shown or 0) / 10 and page.evaluate(MAGENTA_JS) + 1,
                           timeout=30)
            print(f"magenta pixels: {shown} with the outlines, {hidden and hidden - 1} without")
            assert shown and hidden and hidden - 1 < shown / 10
            assert app.gui["show_outlines"].value is False and app.renderer.h_outlines.visible is False
            # the panel list: the table and the placement's chooser in the Fabric & mold tab
            page.get_by_role("tab", name="Fabric & mold").click()
            page.get_by_text("Pattern panels").first.wait_for(timeout=20_000)
            table = page.locator("table", has_text="panel").first
            text = table.inner_text(timeout=20_000)
            assert "front" in text and "back" in text, text
            page.get_by_text("Garment panels").first.wait_for(timeout=20_000)
            assert page.get_by_text("Wrap radius [m]").first.is_visible()
        finally:
            page.close()
    finally:
        app.close()
