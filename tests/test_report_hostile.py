"""``python app.py report`` on a result folder someone else wrote (issue 28 items 3 and 7).

A result folder is mailed around: its summary.json may hold markup where a number belongs, its
history.csv may be a FIFO or a link to /dev/zero. The report refuses a non-number in a number's
place (exit 2, ``summary.json: KEY: ...``), shows every string escaped (checked in a real headless
Chromium: no dialog fires, no element is injected) and reads the folder's files through the same
input checks as scene files (clothsim.fileio)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest

import clothsim
from clothsim.config import load_scene

from conftest import ROOT, cli_main

SLEEVE = ROOT / "configs" / "class2_sleeve.yaml"


@pytest.fixture(scope="module")
def sleeve_run(tmp_path_factory):
    """A result folder with probes, profiles and classes (the class II sleeve, 34 x 16)."""
    out = tmp_path_factory.mktemp("sleeve") / "run"
    clothsim.solve(load_scene(SLEEVE)).save(out)
    return out


def _copy(src, dst, edit=None):
    shutil.copytree(src, dst)
    if edit is not None:
        p = dst / "summary.json"
        s = json.loads(p.read_text())
        edit(s)
        p.write_text(json.dumps(s))
    return dst


def _set(s, key, value):
    *head, last = key
    for k in head:
        s = s[k]
    s[last] = value


PAYLOADS = ["<script>alert(1)</script>", "<img src=x id=inj2 onerror=alert(2)>", "'\"><svg id=inj3 onload=alert(3)>",
            "</pre></p><b id=inj4>x</b>"]


def _hostile_strings(s):
    """Markup in every string the page shows (and a mathtext-breaking name)."""
    p0, p1, p2, p3 = PAYLOADS
    s["name"] = f"sleeve $20_$30 {p0}"
    s["status"], s["solver"], s["clothsim_version"] = p1, p2, p3
    s["max_contact_pressure_mmhg"] = None
    s["contact_pressure_note"] = p0
    for pr in s["probes"]:
        pr["name"], pr["note"] = p1, p2
        pr["classes"] = {p3: p0}
    s["classes"]["probe"] = p1
    for r in s["classes"]["results"]:
        r["standard"], r["class"], r["source"] = p2, p3, p0
    for pf in s["profiles"]:
        pf["name"] = f"leg $1_$2 {p1}"
        pf["gradient"]["note"] = p2


def _hostile_scene_summary(d):
    """Markup in the strings of result.npz's scene summary (the report's Scene section)."""
    import numpy as np

    with np.load(d / "result.npz") as z:
        arrays = {k: z[k] for k in z.files}
    scene = json.loads(str(arrays["scene_summary"]))
    scene["name"], scene["garment"], scene["body"] = PAYLOADS[3], PAYLOADS[0], PAYLOADS[1]
    scene["stages"] = [PAYLOADS[2]]
    scene["files"] = [{"field": PAYLOADS[0], "file": PAYLOADS[1], "sha256": PAYLOADS[2]}]
    scene["materials"][0]["direction"] = PAYLOADS[3]
    scene["standards"][0]["classes"][0]["name"] = PAYLOADS[2]
    arrays["scene_summary"] = np.array(json.dumps(scene))
    np.savez_compressed(d / "result.npz", **arrays)


def _hostile_numbers(s):
    """The issue's case: markup where the status line's numbers belong."""
    s["iterations"] = "<script>alert(1)</script>"
    s["contact_count"] = "<img src=x id=inj5 onerror=alert(2)>"
    s["node_count"] = "<svg id=inj6 onload=alert(3)>"


INJECTED_JS = """() => ({
  scripts: document.querySelectorAll('script').length,
  injected: [...document.querySelectorAll('[id^=inj]')].map(e => e.id),
  handlers: [...document.querySelectorAll('*')].filter(e => [...e.attributes].some(a => a.name.startsWith('on')))
              .map(e => e.tagName),
  h1: document.querySelector('h1') ? document.querySelector('h1').textContent : null,
  probe: [...document.querySelectorAll('#probes td')].map(e => e.textContent)[0] || null,
  scene: document.querySelector('#scene') ? document.querySelector('#scene').textContent : '',
})"""


def _open_in_chromium(browser, pages: dict) -> dict:
    """{name: what each report.html did in a real headless Chromium}: the dialogs it opened
    (alert() from injected script or handlers), its script elements, the elements with an id
    starting 'inj' and the elements carrying an on* handler, and a few texts."""
    seen = {}
    for name, f in pages.items():
        page = browser.new_page()
        dialogs = []

        def on_dialog(dlg, dialogs=dialogs):
            dialogs.append(dlg.message)
            dlg.dismiss()

        page.on("dialog", on_dialog)
        page.route("**/*", lambda route: route.continue_() if route.request.url.startswith(("file:", "data:"))
                   else route.abort())
        page.goto(f.as_uri())
        page.wait_for_load_state("load")
        page.wait_for_timeout(500)   # an onerror / onload handler fires after the load
        seen[name] = {"dialogs": dialogs, **page.evaluate(INJECTED_JS)}
        page.close()
    return seen


def _assert_inert(seen: dict) -> None:
    for name, got in seen.items():
        assert got["dialogs"] == [] and got["scripts"] == 0, (name, got)
        assert got["injected"] == [] and got["handlers"] == [], (name, got)


def test_markup_in_number_fields_never_runs_in_chromium(tmp_path, capsys, sleeve_run, browser):
    """Issue 28 item 3: markup in summary.json's iterations, contact_count and node_count ran as
    script (Chromium fired three alerts). A non-number there is refused: exit 2, naming the file
    and key, and no report file (so nothing to open); any page written is opened in Chromium."""
    d = _copy(sleeve_run, tmp_path / "numbers", _hostile_numbers)
    rc, err = cli_main(capsys, "report", str(d))
    page = d / "report.html"
    _assert_inert(_open_in_chromium(browser, {"numbers": page} if page.exists() else {}))
    assert rc == 2 and f"{d / 'summary.json'}: iterations: not a number (got a string" in err, err
    assert not page.exists()


def test_markup_in_string_fields_is_shown_as_text_in_chromium(tmp_path, capsys, sleeve_run, browser):
    """Markup in every string the page shows (names, status, notes, classes, the scene summary in
    result.npz: its name, garment, body, stages, files, materials and class names) is HTML-escaped:
    Chromium shows it as text, runs nothing, injects nothing."""
    d = _copy(sleeve_run, tmp_path / "strings", _hostile_strings)
    _hostile_scene_summary(d)
    rc, err = cli_main(capsys, "report", str(d))
    assert rc == 0, err
    got = _open_in_chromium(browser, {"strings": d / "report.html"})
    _assert_inert(got)
    got = got["strings"]
    assert got["h1"] == f"clothsim report: sleeve $20_$30 {PAYLOADS[0]}"   # the text, escaped
    assert got["probe"] == PAYLOADS[1]
    assert PAYLOADS[3] in got["scene"] and PAYLOADS[0] in got["scene"] and PAYLOADS[1] in got["scene"]


@pytest.mark.parametrize("key, value", [
    (("iterations",), "<b>12</b>"),
    (("iterations",), True),
    (("iterations",), 12.5),
    (("contact_count",), "3"),
    (("node_count",), [1]),
    (("residual",), "1e-9"),
    (("max_contact_pressure_mmhg",), "abc"),    # a ValueError traceback before
    (("probes", 0, "pressure_mmhg"), "<i>25</i>"),
    (("probes", 0, "radius_m"), "0.01"),
    (("probes", 0, "center", 1), "x"),
    (("probes", 0), "probe"),
    (("classes", "pressure_mmhg"), {"a": 1}),
    (("profiles", 0, "slices", 0, "mean_mmhg"), "25"),
    (("profiles", 0, "slices", 0, "height_m"), None),
])
def test_a_non_number_in_a_number_field_is_refused_naming_the_key(tmp_path, capsys, sleeve_run, key, value):
    d = _copy(sleeve_run, tmp_path / "run", lambda s: _set(s, key, value))
    rc, err = cli_main(capsys, "report", str(d))
    name = "".join(f"[{k}]" if isinstance(k, int) else f".{k}" for k in key).lstrip(".")
    assert rc == 2 and f"{d / 'summary.json'}: {name}: " in err, err
    assert not (d / "report.html").exists()


def test_deep_json_and_a_history_without_its_columns_refused(tmp_path, capsys, sleeve_run):
    """Issue 28 item 7: 100k-deep JSON (RecursionError) and a history.csv without an `iteration`
    column (ValueError) ended in tracebacks."""
    d = _copy(sleeve_run, tmp_path / "deep")
    (d / "summary.json").write_text("[" * 100_000 + "]" * 100_000)
    rc, err = cli_main(capsys, "report", str(d))
    assert rc == 2 and f"{d / 'summary.json'}: JSON nested too deeply" in err, err
    d = _copy(sleeve_run, tmp_path / "nocol")
    (d / "history.csv").write_text("step,residual_N\n1,2\n")
    rc, err = cli_main(capsys, "report", str(d))
    assert rc == 2 and f"{d / 'history.csv'}:1: no 'iteration' column" in err, err
    d = _copy(sleeve_run, tmp_path / "badcell")
    (d / "history.csv").write_text("iteration,residual_N,energy_J,elapsed_s\n0,1.0,0,0\n1,<b>,0,0\n")
    rc, err = cli_main(capsys, "report", str(d))
    assert rc == 2 and f"{d / 'history.csv'}:3: residual_N is not a number ('<b>')" in err, err
    assert not any((tmp_path / n / "report.html").exists() for n in ("deep", "nocol", "badcell"))


def _report_subprocess(d):
    """The report command in a fresh process, bounded: 60 s and 3 GB of address space (main hung
    on a FIFO and read /dev/zero into 5.5 GB)."""
    def limit():
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, 3 * 2**30))

    try:
        r = subprocess.run([sys.executable, str(ROOT / "app.py"), "report", str(d)], capture_output=True, text=True,
                           timeout=120, cwd=ROOT, preexec_fn=limit)
    except subprocess.TimeoutExpired:
        pytest.fail(f"report {d} still running after 120 s")
    assert "Traceback" not in r.stderr, r.stderr[-2000:]
    return r.returncode, r.stderr


@pytest.mark.slow
def test_a_fifo_or_device_in_a_result_folder_refused(tmp_path, sleeve_run):
    """Issue 28 item 7: a FIFO history.csv hung the report; a history.csv linked to /dev/zero was
    read (5.5 GB). Both are refused as not regular files, as a scene file would be; so is a link
    to a file outside the folder, and a FIFO in summary.json's place."""
    d = _copy(sleeve_run, tmp_path / "fifo")
    (d / "history.csv").unlink()
    os.mkfifo(d / "history.csv")
    rc, err = _report_subprocess(d)
    assert rc == 2 and f"{d / 'history.csv'}: not a regular file" in err, err
    d = _copy(sleeve_run, tmp_path / "zero")
    (d / "history.csv").unlink()
    (d / "history.csv").symlink_to("/dev/zero")
    rc, err = _report_subprocess(d)
    assert rc == 2 and f"{d / 'history.csv'}: not a regular file" in err, err
    d = _copy(sleeve_run, tmp_path / "fifo_summary")
    (d / "summary.json").unlink()
    os.mkfifo(d / "summary.json")
    rc, err = _report_subprocess(d)
    assert rc == 2 and f"{d / 'summary.json'}: not a regular file" in err, err
    outside = tmp_path / "elsewhere.json"
    outside.write_text((sleeve_run / "summary.json").read_text())
    d = _copy(sleeve_run, tmp_path / "link")
    (d / "summary.json").unlink()
    (d / "summary.json").symlink_to(outside)
    rc, err = _report_subprocess(d)
    assert rc == 2 and f"{d / 'summary.json'}: is a link to a file outside its folder" in err, err
    assert not any((tmp_path / n / "report.html").exists() for n in ("fifo", "zero", "fifo_summary", "link"))


def test_a_result_npz_declaring_more_than_the_scene_needs_refused(tmp_path, capsys, sleeve_run):
    """A 200 kB result.npz can declare 200 MB of positions (a zip bomb): the arrays' declared sizes
    are held to the scene's node count before anything is decompressed."""
    import numpy as np

    d = _copy(sleeve_run, tmp_path / "bomb")
    np.savez_compressed(d / "result.npz", positions=np.zeros((25_000_000,)), in_contact=np.zeros(1, bool))
    assert (d / "result.npz").stat().st_size < 1_000_000
    rc, err = cli_main(capsys, "report", str(d))
    assert rc == 2 and f"{d / 'result.npz'}: positions holds 200,000,128 bytes, more than the scene's" in err, err
    np.savez_compressed(d / "result.npz", positions=np.zeros((7, 3)), in_contact=np.zeros(7, bool))
    rc, err = cli_main(capsys, "report", str(d))
    assert rc == 2 and f"{d / 'result.npz'}: positions (7, 3) and in_contact (7,) do not hold the scene's" in err, err
    assert not (d / "report.html").exists()
