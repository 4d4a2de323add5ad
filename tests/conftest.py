"""Shared test helpers: small scenes built from dicts."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

STRIP = {
    "name": "strip",
    "fabric": {
        "size": [0.10, 0.02],
        "divisions": [10, 2],
        "thickness": 0.0005,
        "warp": {"strain": [0, 0.1, 0.3, 0.6, 1.0], "stress": [0, 5.0e4, 2.0e5, 8.0e5, 3.0e6]},
        "weft": {"strain": [0, 0.1, 0.3, 0.6, 1.0], "tension": [0, 12, 55, 140, 300]},
    },
    "constraints": [
        {"nodes": "left", "axes": "xyz"},
        {"nodes": "right", "axes": "xyz", "displacement": [0.03, 0, 0]},
    ],
    "initial": {"perturb": 0.0005, "seed": 1},
    "solver": {"method": "paper", "C": 2.0, "e": 1e-8, "max_iterations": 200000},
}


def scene_dict(base=STRIP, **changes):
    """A deep copy of base with dotted-path changes applied (values as in --set)."""
    from clothsim.config import apply_overrides

    return apply_overrides(copy.deepcopy(base), changes)


def make_scene(base=STRIP, **changes):
    from clothsim.config import scene_from_dict

    return scene_from_dict(scene_dict(base, **changes))


def solver_methods():
    """Every concrete solver method (auto excluded)."""
    from clothsim.config import SOLVER_METHODS

    return [m for m in SOLVER_METHODS if m != "auto"]


@pytest.fixture
def root():
    return ROOT


def cli_main(capsys, *argv) -> tuple[int, str]:
    """(exit status, stderr) of the command line (``app.py`` with ``argv``) run in this process;
    an argparse refusal's SystemExit gives its status. Its stderr never holds a traceback."""
    from clothsim import cli

    try:
        rc = cli.main(list(argv))
    except SystemExit as exc:
        rc = exc.code
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return rc, err


@pytest.fixture(scope="module")
def browser():
    """Debian's Chromium, headless, through Playwright (``browser_util.launch``: software WebGL,
    generous action timeouts): one per test module, closed after it. Without /usr/bin/chromium
    the test skips locally and fails in CI (``CI`` set). The one place a test starts a browser."""
    pytest.importorskip("playwright")
    from browser_util import launch, require_chromium

    require_chromium()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = launch(p)
        try:
            yield b
        finally:
            b.close()


#: fixtures that start Debian's Chromium: a test using one is a browser test
BROWSER_FIXTURES = {"browser"}


def pytest_collection_modifyitems(config, items):
    """The `browser` marker on every test that drives a real Chromium: the test_browser* modules
    and any test using a browser fixture (tests that launch one themselves carry the marker in
    their file). The fast subset is ``python -m pytest -m "not slow and not browser"``."""
    for item in items:
        if item.module.__name__.startswith("test_browser") or BROWSER_FIXTURES & set(item.fixturenames):
            item.add_marker(pytest.mark.browser)
