"""A pattern upload in a real headless Chromium (Debian's ``chromium``, Playwright): the 89-byte SVG
of issue 28, item 1 (a cubic 10^20 px long, which froze every tab for minutes while memory grew to
3.7 GB) is refused on the page within seconds, and the page keeps answering: a valid DXF uploaded
next lists its pieces. Without /usr/bin/chromium these tests skip locally and fail in CI."""

from __future__ import annotations

import re

import pytest

pytest.importorskip("viser")
pytest.importorskip("playwright")

from browser_util import free_port, open_viewer, poll  # noqa: E402
from viewer_util import BOMB_SVG, SMALL, pattern_dxf  # noqa: E402

from clothsim.config import scene_from_dict  # noqa: E402
from clothsim.viewer import ViewerApp  # noqa: E402


@pytest.mark.slow
def test_hostile_svg_upload_refused_on_the_page_which_keeps_answering(tmp_path, browser):
    app = ViewerApp(scene_from_dict({**SMALL, "name": "browser-patterns"}), port=free_port())
    try:
        page = open_viewer(browser, app.url)
        try:
            page.get_by_role("tab", name="Fabric & mold").click()
            upload = f"#file_upload_{app.gui['pattern_upload']._impl.uuid}"
            bomb = tmp_path / "bomb.svg"
            bomb.write_bytes(BOMB_SVG)
            page.set_input_files(upload, files=[str(bomb)])
            page.get_by_text(re.compile(r"bomb\.svg: piece path1, <path>: .*beyond the bound of 1e\+06 m")) \
                .first.wait_for(timeout=30_000)
            good = tmp_path / "pieces.dxf"
            good.write_bytes(pattern_dxf())
            page.set_input_files(upload, files=[str(good)])
            assert poll(lambda: app.gui["pattern_piece"].options == ("FRONT", "BACK"), timeout=30), app.errors
            page.get_by_text(re.compile(r"pieces\.dxf \(\d+\)")).first.wait_for(timeout=20_000)
            assert app.errors["pattern"] == ""
        finally:
            page.close()
    finally:
        app.close()
