"""``python app.py report``: the HTML report in a real headless Chromium (Debian's ``chromium``,
Playwright's sync API; see browser_util). It opens from a file with every network request
refused, every image decodes and is not blank (the pressure, warp strain and weft strain maps each
from three views, with its colour bar), and its numbers equal summary.json."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("playwright")

import clothsim  # noqa: E402
from clothsim.config import load_scene  # noqa: E402

from browser_util import IMAGES_JS, offline_page  # noqa: E402
from conftest import ROOT  # noqa: E402


@pytest.mark.browser
@pytest.mark.slow
def test_report_opens_offline_with_images_and_the_summary_numbers(tmp_path, browser):
    from clothsim.cli import main

    scene = load_scene(ROOT / "configs" / "sewn_sleeve.yaml", [
        "probes=[{name: side, point: [0.06, 0, 0]}, {name: above, point: [0.06, 0, 0.12]}]",
        "profiles=[{name: leg, from: -0.03, to: 0.04, step: 0.01}]", "classes={probe: side}"])
    res = clothsim.solve(scene)
    out = tmp_path / "run"
    res.save(out)
    assert main(["report", str(out)]) == 0
    page_file = out / "report.html"
    text = page_file.read_text()
    assert "http://" not in text and "https://" not in text and "<script" not in text
    s = json.loads((out / "summary.json").read_text())
    page, requests = offline_page(browser)
    try:
        page.goto(page_file.as_uri())
        page.wait_for_load_state("load")
        imgs = page.evaluate(IMAGES_JS)
        figures = page.eval_on_selector_all("figure.map", """els => els.map(f => ({id: f.id,
            maps: [...f.querySelectorAll('img.map')].map(i => i.alt)}))""")
        cells = page.eval_on_selector_all("#probes td.mmhg", "els => els.map(e => e.textContent)")
        fracs = page.eval_on_selector_all("#probes td.frac", "els => els.map(e => e.textContent)")
        classes = page.eval_on_selector_all("#classes td", "els => els.map(e => e.textContent)")
        peak = page.text_content("#peak")
        version = page.text_content("#version")
        gradient = page.text_content("p.gradient")
    finally:
        page.close()
    assert not requests, requests
    # the pressure, warp strain and weft strain maps, each one image of three views with the body
    # and the colour bar
    maps = ["pressure map", "warp strain map", "weft strain map"]
    assert [f["id"] for f in figures] == ["map-pressure", "map-warp-strain", "map-weft-strain"]
    for f, m in zip(figures, maps):
        assert f["maps"] == [f"{m}: front, side and top views"], f
    by_alt = {i["alt"]: i for i in imgs}
    assert [i["alt"] for i in imgs] == [f"{m}: front, side and top views" for m in maps[:1]] + ["profile plot"] + [
        f"{m}: front, side and top views" for m in maps[1:]] + ["material curves", "convergence plot"]
    for i in imgs:
        assert i["h"] > 300 and i["w"] > 300, i
        assert i["n"] > 0.02 * i["w"] * i["h"], i  # drawn, not blank
    for m in maps:
        assert by_alt[f"{m}: front, side and top views"]["colored"] > 3000  # the sheet and the bar, coloured
    assert cells == [f"{p['pressure_mmhg']:.2f}" for p in s["probes"]]
    assert fracs == [f"{p['contact_fraction']:.3f}" for p in s["probes"]]
    assert classes[:2] == ["RAL-GZ 387", s["classes"]["results"][0]["class"]]
    assert peak == f"{s['max_contact_pressure_mmhg']:.2f}"
    assert version == s["clothsim_version"] == clothsim.__version__
    assert s["profiles"][0]["gradient"]["note"] in gradient
