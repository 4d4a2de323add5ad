"""The stocking's report (configs/garments/stocking.yaml, issue 31 item 5) in a real headless
Chromium (Debian's chromium, Playwright; see browser_util): written from a moved copy of the
result folder, it opens from a file with every network request refused and no console error,
every image decodes and is drawn, the pressure map's colour scale reaches its stated top and the
headline holds more than a single node. The top of the page (headline and pressure map) is saved
as docs/guide/report.png, the picture of the docs' Report section (docs/guide/compression.md)."""

from __future__ import annotations

import json
import os
import shutil

import pytest

pytest.importorskip("playwright")


import clothsim  # noqa: E402
from clothsim.config import load_scene  # noqa: E402

from browser_util import IMAGES_JS, offline_page  # noqa: E402
from conftest import ROOT  # noqa: E402

SCREENSHOT = ROOT / "docs" / "guide" / "report.png"


@pytest.mark.browser
@pytest.mark.slow
def test_stocking_report_in_chromium(tmp_path, browser):
    from clothsim.cli import main

    res = clothsim.solve(load_scene(ROOT / "configs" / "garments" / "stocking.yaml"))
    res.save(tmp_path / "run")
    out = tmp_path / "mailed" / "stocking"
    shutil.copytree(tmp_path / "run", out)       # the report reads the folder alone, wherever it is
    assert main(["report", str(out)]) == 0
    page_file = out / "report.html"
    s = json.loads((out / "summary.json").read_text())
    errors = []
    page, requests = offline_page(browser, viewport={"width": 1360, "height": 1000})
    try:
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(page_file.as_uri())
        page.wait_for_load_state("load")
        imgs = page.evaluate(IMAGES_JS)
        scale = page.eval_on_selector("#map-pressure", "f => ({lo: +f.dataset.lo, hi: +f.dataset.hi, "
                                                       "top: +f.dataset.topTick})")
        headline = page.eval_on_selector_all("#headline div", "els => els.map(e => e.textContent)")
        levels = page.eval_on_selector_all("#levels tr", "els => els.length")
        box = page.eval_on_selector("#map-pressure", "f => { const r = f.getBoundingClientRect(); "
                                                     "return r.bottom + window.scrollY; }")
        shot = tmp_path / "report.png"
        page.screenshot(path=str(shot), clip={"x": 0, "y": 0, "width": 1360, "height": box + 12},
                        full_page=True)
    finally:
        page.close()
    assert not requests and not errors, (requests, errors)
    alts = [i["alt"] for i in imgs]
    assert alts[:2] == ["pressure map: front, side and top views", "profile plot"], alts
    assert {"material curves", "convergence plot", "warp strain map: front, side and top views"} <= set(alts)
    for i in imgs:
        assert i["w"] > 300 and i["h"] > 300 and i["n"] > 0.02 * i["w"] * i["h"], i   # loaded and drawn
    pressure = next(i for i in imgs if i["alt"].startswith("pressure map"))
    assert pressure["colored"] > 20_000, pressure
    # the scale: from 0 to its top tick, which covers the 95th percentile; the single-node peak
    # (85 mmHg on the faceted leg) is stated, not the scale
    assert scale["lo"] == 0 and scale["top"] == scale["hi"] < s["max_contact_pressure_mmhg"]
    text = " ".join(headline)
    assert "probe ankle" in text and "girth mean" in text and "single-node peak" in text
    assert f"{s['classes']['pressure_mmhg']:.1f} mmHg" in text
    assert levels > 5
    assert shot.stat().st_size > 50_000
    if os.environ.get("CLOTHSIM_SCREENSHOT"):    # the docs' picture, refreshed on request
        tmp = SCREENSHOT.with_suffix(".png.tmp")
        tmp.write_bytes(shot.read_bytes())
        os.replace(tmp, SCREENSHOT)
