"""The documentation site builds with MkDocs in strict mode (every page in the nav, no broken
link or anchor), its reference pages are generated from the code, and the README's links lead to
files that exist."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

pytest.importorskip("mkdocs")


def test_site_builds_strict_with_generated_reference(tmp_path):
    site = tmp_path / "site"
    out = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(site)],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    scene = (site / "reference" / "scene" / "index.html").read_text()
    from clothsim.config import Scene, SolverSettings

    # every top-level scene field and every solver field is listed (generated, not hand-kept)
    for name in list(Scene.model_fields) + list(SolverSettings.model_fields):
        assert f"<code>{name}</code>" in scene, name
    cli = (site / "reference" / "cli" / "index.html").read_text()
    for command in ("run", "view", "sweep", "bench", "fit", "report"):
        assert f"clothsim {command}" in cli
    assert "--max-solves" in cli or "--vary" in cli


def test_readme_is_a_quick_start_whose_links_exist():
    text = (ROOT / "README.md").read_text()
    lines = text.splitlines()
    assert len(lines) <= 250
    # the two commands come first
    code = text.split("```bash", 1)[1].split("```", 1)[0]
    assert "python app.py" in code and "python -m pytest" in code
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text):
        if re.match(r"[a-z]+://", target):
            continue
        assert (ROOT / target).exists(), target
