"""Helpers for the browser tests: a real headless Chromium (Debian's ``chromium`` package) driven by
Playwright's sync API, with the flags that give software WebGL2 (see docs/develop/viser.md).

Never run ``playwright install`` here: the client comes from pip, the browser from apt."""

from __future__ import annotations

import os
import re
import shutil
import time
from pathlib import Path

import pytest

from clothsim.records import OUTPUT_FIELDS

CHROMIUM = os.environ.get("CLOTHSIM_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]

# JavaScript: copy the largest canvas (the 3D view; viser keeps its drawing buffer) into a 2D
# canvas and count pixels that differ from the corner pixel (the background).
COUNT_JS = """() => {
  const cs = [...document.querySelectorAll('canvas')];
  if (!cs.length) return {w: 0, h: 0, n: 0};
  const c = cs.reduce((a, b) => (a.width * a.height >= b.width * b.height ? a : b));
  const w = c.width, h = c.height;
  if (!w || !h) return {w, h, n: 0};
  const o = document.createElement('canvas'); o.width = w; o.height = h;
  const ctx = o.getContext('2d'); ctx.drawImage(c, 0, 0);
  const d = ctx.getImageData(0, 0, w, h).data;
  const r0 = d[0], g0 = d[1], b0 = d[2];
  let n = 0, colored = 0;
  for (let i = 0; i < d.length; i += 4) {
    const dr = Math.abs(d[i] - r0), dg = Math.abs(d[i+1] - g0), db = Math.abs(d[i+2] - b0);
    if (dr + dg + db > 30) {
      n++;
      const mx = Math.max(d[i], d[i+1], d[i+2]), mn = Math.min(d[i], d[i+1], d[i+2]);
      if (mx - mn > 40) colored++;
    }
  }
  return {w, h, n, colored};
}"""


def require_chromium():
    """Skip without a browser locally; fail in CI (the CI image must have it)."""
    if Path(CHROMIUM).exists():
        return
    if os.environ.get("CI"):
        pytest.fail(f"{CHROMIUM} is missing in CI: install Debian's chromium package")
    pytest.skip(f"{CHROMIUM} not installed")


#: Playwright's timeout for every action of a page [ms] (its default, 30 s, was exceeded by clicks
#: in a clean-clone CI run at load average 6-8; a passing run never waits for it)
PAGE_TIMEOUT_MS = 120_000


def launch(playwright):
    """Debian's Chromium, headless; its pages wait up to PAGE_TIMEOUT_MS for every action."""
    browser = playwright.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
    new_page = browser.new_page

    def page_with_timeout(*args, **kwargs):
        page = new_page(*args, **kwargs)
        page.set_default_timeout(PAGE_TIMEOUT_MS)
        return page

    browser.new_page = page_with_timeout
    return browser


def offline_page(browser, **kwargs):
    """(page, refused): a new page of ``browser`` (``kwargs`` to ``new_page``) on which every
    request but file: and data: URLs is refused and its URL appended to ``refused``: a report
    that opens offline leaves it empty."""
    page = browser.new_page(**kwargs)
    refused = []

    def block(route):
        if not route.request.url.startswith(("file:", "data:")):
            refused.append(route.request.url)
            route.abort()
        else:
            route.continue_()

    page.route("**/*", block)
    return page, refused


# JavaScript: every image of the page, decoded and drawn into a canvas: its size, how many pixels
# are not near-white (n) and how many are coloured (a channel spread over 60)
IMAGES_JS = """() => [...document.images].map(img => {
  const c = document.createElement('canvas'); c.width = img.naturalWidth; c.height = img.naturalHeight;
  if (!img.complete || !c.width) return {alt: img.alt, w: 0, h: 0, n: 0, colored: 0};
  const ctx = c.getContext('2d'); ctx.drawImage(img, 0, 0);
  const d = ctx.getImageData(0, 0, c.width, c.height).data;
  let n = 0, colored = 0;
  for (let i = 0; i < d.length; i += 4) {
    if (d[i] + d[i+1] + d[i+2] < 720) n++;
    const mx = Math.max(d[i], d[i+1], d[i+2]), mn = Math.min(d[i], d[i+1], d[i+2]);
    if (mx - mn > 60) colored++;
  }
  return {alt: img.alt, w: c.width, h: c.height, n, colored};
})"""


def canvas_pixels(page) -> dict:
    return page.evaluate(COUNT_JS)


def wait_for_render(page, min_pixels: int = 2000, timeout: float = 60.0) -> dict:
    """Wait until the 3D canvas shows something (the first software-rendered frame takes 7-10 s
    while shaders compile)."""
    t0 = time.time()
    last = {}
    while time.time() - t0 < timeout:
        last = canvas_pixels(page)
        if last.get("n", 0) >= min_pixels:
            return last
        page.wait_for_timeout(500)
    return last


def open_viewer(browser, url: str, min_pixels: int = 2000):
    """A 1400 x 900 page of ``browser`` on the viewer at ``url``, its 3D view drawn (at least
    ``min_pixels`` pixels, waiting up to 90 s) and its notifications closed; the page is closed
    if any of that fails."""
    page = browser.new_page(viewport={"width": 1400, "height": 900})
    try:
        page.goto(url)
        wait_for_render(page, min_pixels=min_pixels, timeout=90)
        close_notifications(page)
    except BaseException:
        page.close()
        raise
    return page


def close_notifications(page) -> None:
    for b in page.locator(".mantine-Notification-closeButton").all():
        try:
            b.click(timeout=1000)
        except Exception:
            pass


def status_text(page) -> str:
    """The status line (the markdown holding 'residual ... N'). On a cold start the page shows
    "Compiling kernels" first and the status line only when the kernels are ready (half a minute
    or more on a loaded 2-core machine): wait up to 90 s for it."""
    loc = page.locator("p", has_text=re.compile(r"iteration \d+ · residual")).first
    return loc.inner_text(timeout=90_000)


def shown_residual(page) -> float:
    res = OUTPUT_FIELDS["residual"]  # the status line names it as the field list does
    m = re.search(re.escape(res.label) + r" ([0-9.eE+-]+|n/a) " + re.escape(res.unit), status_text(page))
    assert m, "no residual in the status line"
    return float(m.group(1)) if m.group(1) != "n/a" else float("nan")


def shown_iteration(page) -> int:
    m = re.search(r"iteration (\d+)", status_text(page))
    return int(m.group(1))


def text_area_for(page, label: str):
    """The textarea of a viser text input labelled ``label`` (they have no id: find the row holding
    the label, then its textarea or input)."""
    lab = page.locator("label", has_text=label).first
    target = lab.get_attribute("for")
    if target:
        el = page.locator(f"[id='{target}']")
        if el.count():
            return el.first
    row = lab.locator("xpath=ancestor::div[.//textarea or .//input][1]")
    ta = row.locator("textarea")
    return ta.first if ta.count() else row.locator("input").first


def have_browser() -> bool:
    return Path(CHROMIUM).exists() or shutil.which("chromium") is not None


def pixels_js(test: str) -> str:
    """A JavaScript function for ``page.evaluate``: how many pixels of the largest canvas (the 3D
    view) pass ``test``, a JavaScript condition on the pixel's ``r``, ``g``, ``b`` (0-255)."""
    return """() => {
  const c = [...document.querySelectorAll('canvas')].reduce((a, b) => (a.width * a.height >= b.width * b.height ? a : b));
  const o = document.createElement('canvas'); o.width = c.width; o.height = c.height;
  const ctx = o.getContext('2d'); ctx.drawImage(c, 0, 0);
  const d = ctx.getImageData(0, 0, c.width, c.height).data;
  let n = 0;
  for (let i = 0; i < d.length; i += 4) {
    const r = d[i], g = d[i+1], b = d[i+2];
    if (""" + test + """) n++;
  }
  return n;
}"""


def free_port() -> int:
    """A free TCP port on 127.0.0.1."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def poll(fn, timeout=30.0, every=0.2):
    """fn() until it is truthy or ``timeout`` [s] has passed; its last value."""
    t0 = time.time()
    while time.time() - t0 < timeout:
        v = fn()
        if v:
            return v
        time.sleep(every)
    return fn()
