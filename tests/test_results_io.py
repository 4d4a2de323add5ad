"""Writing results: nothing mixed, nothing left behind (issue 15, items 10 and 13).

A run saved into a folder holding an earlier result replaces it as a set (summary.json removed
first, written last); a failed write (a full disk) leaves no temporary file and the command exits
2 with a one-line message; free space is checked before the first write."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
from collections import namedtuple

import pytest
import yaml

from conftest import cli_main, scene_dict

from clothsim import cli
from clothsim.config import load_scene


def _scene(tmp_path, **changes):
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(scene_dict(**changes), sort_keys=False))
    return p


def _fail_fsync_of(monkeypatch, name, exc):
    """Make the fsync of the temporary file of ``name`` raise exc (the file is half written)."""
    real = os.fsync

    def fsync(fd):
        if os.readlink(f"/proc/self/fd/{fd}").rsplit("/", 1)[-1].startswith(f".{name}.tmp"):
            raise exc
        return real(fd)

    monkeypatch.setattr(os, "fsync", fsync)


def test_run_into_a_folder_with_an_earlier_result_is_replaced_as_a_set(tmp_path, capsys, monkeypatch):
    """Run A finished in out/; run B dies right after replacing result.npz: out/ must not hold
    A's summary.json beside B's result.npz (it would look complete), nor a temporary file."""
    s = _scene(tmp_path)
    out = tmp_path / "out"
    rc, _ = cli_main(capsys, "run", str(s), "--out", str(out), "--quiet")
    assert rc == 0 and (out / "summary.json").is_file()
    _fail_fsync_of(monkeypatch, "history.csv", KeyboardInterrupt())  # killed half-way through
    assert cli.main(["run", str(s), "--out", str(out), "--quiet", "--set", "solver.C=3"]) == 130
    names = sorted(p.name for p in out.iterdir())
    assert "summary.json" not in names, names
    assert not [n for n in names if ".tmp" in n], names


def test_full_disk_during_the_write_exits_2_and_leaves_no_temp_file(tmp_path, capsys, monkeypatch):
    s = _scene(tmp_path)
    out = tmp_path / "out"
    _fail_fsync_of(monkeypatch, "sheet.ply", OSError(errno.ENOSPC, "No space left on device"))
    rc, err = cli_main(capsys, "run", str(s), "--out", str(out), "--quiet")
    assert rc == 2
    assert f"--out {out}: the disk is full (No space left on device)" in err
    names = sorted(p.name for p in out.iterdir())
    assert "summary.json" not in names and not [n for n in names if ".tmp" in n], names
    # it said "nothing partial was left behind" while result.npz and history.csv stayed: it now
    # names exactly what was written (issue 28.11)
    assert "nothing partial" not in err
    assert "written before it failed: result.npz, history.csv; no summary.json" in err, err
    assert [n for n in names if not n.startswith(".")] == ["history.csv", "result.npz"]


def test_free_space_checked_before_writing(tmp_path, capsys, monkeypatch):
    s = _scene(tmp_path)
    out = tmp_path / "out"
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**6, 10**6 - 1000, 1000))
    rc, err = cli_main(capsys, "run", str(s), "--out", str(out), "--quiet")
    assert rc == 2 and f"--out {out}: not enough free space" in err
    assert list(out.iterdir()) == []


@pytest.fixture
def tiny_tmpfs(tmp_path):
    """A real 1 MB tmpfs (needs root and mount permission, else skipped)."""
    mnt = tmp_path / "tiny"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], capture_output=True)
    if r.returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


@pytest.mark.parametrize("space_check", [True, False])
def test_run_on_a_really_full_disk(tmp_path, capsys, monkeypatch, tiny_tmpfs, space_check):
    """On a 1 MB tmpfs a 160 x 160 run's files do not fit: exit 2, a clear message, no summary,
    no temporary file; also when the free-space check is fooled and a real write hits ENOSPC."""
    if not space_check:
        usage = namedtuple("usage", "total used free")
        monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**12, 0, 10**12))
    s = _scene(tmp_path, **{"fabric.divisions": [160, 160], "solver.e": 1e-3, "initial.perturb": 0.0})
    out = tiny_tmpfs / "out"
    rc, err = cli_main(capsys, "run", str(s), "--out", str(out), "--quiet")
    assert rc == 2, err
    assert ("not enough free space" if space_check else "the disk is full") in err, err
    names = sorted(p.name for p in out.iterdir())
    assert "summary.json" not in names and not [n for n in names if ".tmp" in n], names
    # the message names exactly the files that stayed (issue 28.11)
    left = [n for n in names if not n.startswith(".")]
    assert "nothing partial" not in err
    if left:
        assert f"written before it failed: {', '.join(sorted(left, key=err.index))}; no summary.json" in err, err
    else:
        assert "nothing was written" in err, err


def test_summary_written_last_and_strict(tmp_path):
    from clothsim.simulation import solve

    order = []
    import clothsim.results as results

    real = results.atomic_write_bytes

    def spy(path, data):
        order.append(path.name)
        return real(path, data)

    res = solve(load_scene(_scene(tmp_path)))
    results.atomic_write_bytes, saved = spy, results.atomic_write_bytes
    try:
        res.save(tmp_path / "out")
    finally:
        results.atomic_write_bytes = saved
    assert order[-1] == "summary.json" and len(order) == 5
    json.loads((tmp_path / "out" / "summary.json").read_text())


def test_an_earlier_results_extra_files_are_removed(tmp_path, capsys):
    """Run A (a scene with probes and profiles) wrote probes.csv, profiles.csv and profiles.png;
    run B (without) into the same folder must not leave them beside its own result. A file the
    result writer never writes is the user's and stays."""
    s = _scene(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    stale = ["probes.csv", "profiles.csv", "profiles.png", "summary.json", "sheet.ply"]
    for name in stale:
        (out / name).write_bytes(b"run A")
    (out / "notes.txt").write_text("mine")
    rc, _ = cli_main(capsys, "run", str(s), "--out", str(out), "--quiet")
    assert rc == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["history.csv", "notes.txt", "result.npz", "scene.yaml", "sheet.ply",
                     "summary.json"], names
    assert (out / "sheet.ply").read_bytes() != b"run A"
    assert json.loads((out / "summary.json").read_text())["status"] == "converged"


def test_files_of_result_names_in_a_folder_without_a_result_stay(tmp_path, capsys):
    """A run into a folder that holds no earlier result (no summary.json, no result.npz) leaves
    the user's files alone, even one named like a result file it does not write (a probes.csv of
    the user's own)."""
    s = _scene(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "probes.csv").write_text("the user's sensor readings")
    rc, _ = cli_main(capsys, "run", str(s), "--out", str(out), "--quiet")
    assert rc == 0
    assert (out / "probes.csv").read_text() == "the user's sensor readings"
    assert json.loads((out / "summary.json").read_text())["status"] == "converged"
