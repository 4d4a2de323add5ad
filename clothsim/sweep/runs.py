"""Run folders: a finished run is a folder holding summary.json (written last); summary.csv is
rebuilt from the folders, so an interrupted sweep keeps every finished run and resumes."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

from ..fileio import FolderLock, OutputError, atomic_write_bytes, check_free_space
from ..records import flatten
from .spec import Run, Sweep, SweepError

FINISHED_FILE = "summary.json"


def _atomic_write(path: Path, data: bytes) -> None:
    atomic_write_bytes(path, data)


def write_run(out: Path, payload: dict) -> None:
    """Write a worker's files into out/<run_id>/, each atomically, summary.json last."""
    d = out / payload["run_id"]
    d.mkdir(parents=True, exist_ok=True)
    check_free_space(out, sum(len(b) for b in payload["files"].values()))
    # an older result must not look finished while the new files replace it
    for stale in (FINISHED_FILE, "crashed.json", "error.txt"):
        (d / stale).unlink(missing_ok=True)
    for tmp in d.glob(".*.tmp*"):  # left by a write that was killed half-way
        tmp.unlink(missing_ok=True)
    files = payload["files"]
    for name, data in files.items():
        if name != FINISHED_FILE:
            _atomic_write(d / name, data)
    _atomic_write(d / "sweep_run.json", json.dumps(payload["record"], indent=2, default=str).encode())
    _atomic_write(d / FINISHED_FILE, files[FINISHED_FILE])


def write_crashed(out: Path, run: Run, message: str) -> None:
    d = out / run.run_id
    d.mkdir(parents=True, exist_ok=True)
    (d / FINISHED_FILE).unlink(missing_ok=True)
    _atomic_write(d / "crashed.json", json.dumps({"status": "crashed", "message": message}, indent=2).encode())


def finished(out: Path, run: Run, skip_errors: bool = True) -> bool:
    """True if out/<run_id> holds a complete run of this very scene (one that ended in status
    ``error`` counts only with skip_errors)."""
    d = out / run.run_id
    if not (d / FINISHED_FILE).is_file():
        return False
    try:
        rec = json.loads((d / "sweep_run.json").read_text())
    except (OSError, ValueError):
        return False
    if rec.get("scene_hash") != run.scene_hash:
        return False
    return skip_errors or _status(d) != "error"


def _status(d: Path) -> str | None:
    try:
        return json.loads((d / FINISHED_FILE).read_text()).get("status")
    except (OSError, ValueError, AttributeError):
        return None


class _FolderLock:
    """The sweep's lock on its output folder (clothsim.fileio.FolderLock, shared with run and
    fit: a run into a sweep's folder is refused too). Raises SweepError naming the holder."""

    def __init__(self, out: Path):
        self.lock = FolderLock(out, "sweep")

    def __enter__(self):
        try:
            self.lock.__enter__()
        except OutputError as exc:
            raise SweepError(str(exc)) from None
        return self

    def __exit__(self, *exc):
        self.lock.__exit__(*exc)


def read_row(out: Path, run: Run) -> dict:
    """The summary of one run from its folder: summary.json, the sweep worker's extras and the
    named outputs (clothsim.records.flatten: friction.KEY, stage:NAME.KEY, probe:NAME_SUFFIX;
    a fitting sweep's fit:PATH, fit_converged, fit_solves)."""
    d = out / run.run_id
    row: dict[str, Any] = {}
    try:
        summary = json.loads((d / FINISHED_FILE).read_text())
        row.update(summary)
        rec = json.loads((d / "sweep_run.json").read_text())
        row.update(rec.get("extra", {}))
        if isinstance(summary, dict):
            row.update(flatten(summary))
        fit = row.get("fit")
        if isinstance(fit, dict):  # a fitting sweep's run: fit:PATH, fit_converged, fit_solves
            for path, value in (fit.get("fields") or {}).items():
                row[f"fit:{path}"] = value
            row["fit_converged"] = fit.get("converged")
            row["fit_solves"] = fit.get("solves")
    except (OSError, ValueError):
        try:
            row.update(json.loads((d / "crashed.json").read_text()))
        except (OSError, ValueError):
            row.update({"status": "pending", "message": "not run yet"})
    return row


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, tuple, dict)):
        return json.dumps(v)
    return str(v)


def build_summary(sweep: Sweep, out: Path) -> list[dict]:
    """Rebuild out/summary.csv from the run folders; returns the rows (dicts of raw values)."""
    outputs = [o for o in sweep.spec.outputs if o != "status"]
    header = ["run_id", *sweep.varied, "status", *outputs, "message"]
    rows = []
    for run in sweep.runs:
        r = read_row(out, run)
        row = {"run_id": run.run_id, **run.params, "status": r.get("status", "error")}
        for o in outputs:
            row[o] = r.get(o)
        row["message"] = "" if row["status"] == "converged" else (r.get("message") or "")
        rows.append(row)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for row in rows:
        w.writerow([_cell(row.get(h)) for h in header])
    _atomic_write(out / "summary.csv", buf.getvalue().encode())
    return rows
