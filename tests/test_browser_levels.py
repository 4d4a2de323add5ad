"""The measuring levels in a real headless Chromium (see test_browser.py): a compression tube on
a leg from a size chart (B, C, D circular, tests/test_levels.py's), relaxed in the viewer; the
levels' rings are drawn round the leg (orange pixels that go when 'Show measuring levels' is
off), their labels read the girth and the girth mean, and the pressure profile plot under the
convergence plot draws its curve. The screenshot is docs/guide/viewer_levels.png.

Without /usr/bin/chromium these tests skip locally and fail in CI (``CI`` set)."""

from __future__ import annotations

import pytest

pytest.importorskip("viser")
pytest.importorskip("playwright")

from browser_util import close_notifications, pixels_js, poll, wait_for_render  # noqa: E402

from clothsim.config import load_scene  # noqa: E402
from clothsim.viewer import ViewerApp  # noqa: E402

from conftest import ROOT  # noqa: E402
from viewer_util import free_port  # noqa: E402

TUBE = ROOT / "configs" / "tube_on_leg_cone.yaml"
LEG = ("mold={leg: {levels: {B: {girth_cm: 22, height_cm: 2}, C: {girth_cm: 24.5, height_cm: 8},"
       " D: {girth_cm: 23.5, height_cm: 14}}}}")
SHOT = ROOT / "docs" / "guide" / "viewer_levels.png"

# the rings' orange (panels/levels.py: (240, 140, 0)), any shade
ORANGE_JS = pixels_js("r > 180 && g > 90 && g < 190 && b < 80 && r > g + 50")

# coloured (non-grey) pixels drawn in the n-th uPlot chart's canvas (0: convergence, 1: profile)
PLOT_INK_JS = """(n) => {
  const c = document.querySelectorAll('.uplot canvas')[n];
  if (!c) return -1;
  const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  let k = 0;
  for (let i = 0; i < d.length; i += 4) {
    const r = d[i], g = d[i+1], b = d[i+2];
    if (d[i+3] > 0 && Math.max(r, g, b) - Math.min(r, g, b) > 60) k++;
  }
  return k;
}"""


@pytest.mark.slow
def test_levels_rings_and_profile_plot_in_the_page(browser):
    over = [LEG, "constraints.1.displacement=[0, 0, 0]", "levels={radius: 0.008}", "profiles=[]"]
    app = ViewerApp(load_scene(TUBE, over), port=free_port())
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    try:
        page.goto(app.url)
        wait_for_render(page, min_pixels=2000, timeout=90)
        close_notifications(page)
        lv = app.panels["levels"]
        page.get_by_role("button", name="Start").click()
        assert poll(lambda: app.sim.status == "converged", timeout=600), app.sim.status
        assert poll(lambda: lv.read_at == app.sim.state.iteration, timeout=120)
        b = next(r for r in lv.view["levels"]["levels"] if r["level"] == "B")
        labels = [h.text for h in lv._nodes if hasattr(h, "text")]
        assert f"B 22.0 cm · {b['mean_mmhg']:.1f} mmHg" in labels, labels
        page.get_by_text("Pressure profile (girth mean)").first.wait_for(timeout=30_000)
        page.get_by_role("cell", name="C", exact=True).first.wait_for(timeout=30_000)
        shown = poll(lambda: page.evaluate(ORANGE_JS) > 100 and page.evaluate(ORANGE_JS), timeout=60)
        ink = poll(lambda: page.evaluate(PLOT_INK_JS, 1) > 200 and page.evaluate(PLOT_INK_JS, 1), timeout=30)
        plot = page.locator(".uplot").nth(1)
        plot.scroll_into_view_if_needed()
        close_notifications(page)
        SHOT.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SHOT))
        page.get_by_label("Show measuring levels").uncheck()
        hidden = poll(lambda: page.evaluate(ORANGE_JS) < (shown or 0) / 4 and page.evaluate(ORANGE_JS) + 1,
                      timeout=30)
        print(f"ring pixels: {shown} shown, {hidden - 1 if hidden else None} hidden; profile ink {ink}; "
              f"B {b['mean_mmhg']:.2f} mmHg")
        assert shown and hidden and ink
    finally:
        page.close()
        app.close()
