"""The import rules docs/architecture.md states, read from the package's source (ast): solvers
take their types from clothsim.model, never import the builder, the compile step or the scene
layer, and do not reach the builder or the compile step even through another module; the core
types import no builder or solver.

(The scene layer is reached through ``clothsim.mold``: ``mold.load`` reads the scene's typed mold
specs, so any import of the mold package loads ``clothsim.config``; that edge is the mold
package's, not a solver's.)"""

import ast
from pathlib import Path

import clothsim

PKG = Path(clothsim.__file__).parent

# what no solver may import itself
BUILDER_AND_SCENE = {"clothsim.grid", "clothsim.compile", "clothsim.config"}
# what no solver may reach even through another clothsim module
BUILDER = {"clothsim.grid", "clothsim.compile"}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PKG.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """The clothsim modules a file imports anywhere in it (module level or inside functions,
    TYPE_CHECKING blocks included), resolved to absolute names; ``from X import y`` counts as
    importing X and X.y (y may be a submodule)."""
    mod = _module_name(path)
    package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            out.add(target)
            out.update(f"{target}.{a.name}" for a in node.names)
    return {m for m in out if m == "clothsim" or m.startswith("clothsim.")}


def _graph() -> dict[str, set[str]]:
    files = {_module_name(p): p for p in PKG.rglob("*.py")}
    return {m: {t for t in _imports(p) if t in files} for m, p in files.items()}


def _reach(graph, start: str) -> dict[str, str]:
    """Every module ``start`` imports, directly or through others: {module: the module that
    imports it on one such path}."""
    seen = {start: ""}
    todo = [start]
    while todo:
        m = todo.pop()
        for t in graph[m]:
            if t not in seen:
                seen[t] = m
                todo.append(t)
    return seen


def _path(seen, target):
    chain = [target]
    while seen[chain[-1]]:
        chain.append(seen[chain[-1]])
    return " <- ".join(chain)


def test_the_import_reader_sees_imports():
    """The reader resolves relative imports, function-level ones included (a check that finds
    nothing proves nothing)."""
    g = _graph()
    assert "clothsim.model" in g["clothsim.solvers.newton.sequencing"]
    assert "clothsim.lattice" in g["clothsim.solvers.paper"]  # inside the package's top level
    assert "clothsim.grid" in g["clothsim.compile"]
    assert "clothsim.config" in g["clothsim.simulation"]  # imported inside a function
    assert "clothsim.solvers.newton.linalg" in g["clothsim.solvers.newton.iteration"]


def _solvers(g):
    out = [m for m in g if m == "clothsim.solvers" or m.startswith("clothsim.solvers.")]
    assert len(out) > 10
    return out


def test_solvers_never_import_the_builder_compile_or_config():
    g = _graph()
    bad = [f"{m} imports {t}" for m in _solvers(g) for t in sorted(g[m] & BUILDER_AND_SCENE)]
    assert not bad, "\n".join(bad)


def test_solvers_do_not_reach_the_builder_through_other_modules():
    g = _graph()
    bad = []
    for m in _solvers(g):
        seen = _reach(g, m)
        bad += [_path(seen, t) for t in sorted(BUILDER & set(seen))]
    assert not bad, "solvers reach the builder:\n" + "\n".join(bad)


def test_solvers_take_the_core_types_from_model():
    """Where a solver names Model, State or SpringFamily it imports them from clothsim.model."""
    bad = []
    for p in (PKG / "solvers").rglob("*.py"):
        for node in ast.walk(ast.parse(p.read_text(), str(p))):
            if isinstance(node, ast.ImportFrom):
                names = {a.name for a in node.names} & {"Model", "State", "SpringFamily", "Placement"}
                if names and not (node.module or "").endswith("model"):
                    bad.append(f"{p.relative_to(PKG)}:{node.lineno}")
    assert not bad, bad


def test_the_core_types_import_no_builder_or_solver():
    g = _graph()
    for core in ("clothsim.model", "clothsim.lattice"):
        assert not g[core] & BUILDER_AND_SCENE
        seen = _reach(g, core)
        bad = [_path(seen, t) for t in sorted(seen) if t in BUILDER or t.startswith("clothsim.solvers")
               or t in {"clothsim.simulation", "clothsim.results", "clothsim.initial"}]
        assert not bad, bad


def test_no_test_module_imports_another():
    """Issue 29 item 5: shared test helpers live in helper modules (conftest.py, viewer_util.py,
    browser_util.py), never in a test module another test imports (that ran its tests' module
    code twice and tied unrelated files together)."""
    import ast
    from pathlib import Path

    bad = []
    for f in sorted((Path(__file__).resolve().parent).glob("*.py")):
        for node in ast.walk(ast.parse(f.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            bad += [f"{f.name} imports {n}" for n in names if n.split(".")[-1].startswith("test_")]
    assert not bad, "\n".join(bad)


def test_only_conftest_starts_a_browser():
    """Issue 29 item 5: Chromium is started in one place, conftest.py's ``browser`` fixture (one
    per test module); the test modules launched it themselves in nine places (four module
    fixtures, four test bodies and a helper, each with its own copy of the set-up)."""
    import ast
    from pathlib import Path

    bad = []
    for f in sorted((Path(__file__).resolve().parent).glob("test_*.py")):
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module == "playwright.sync_api":
                bad.append(f"{f.name}:{node.lineno} imports playwright.sync_api")
            if isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", "")) == "launch":
                bad.append(f"{f.name}:{node.lineno} calls launch()")
    assert not bad, "\n".join(bad)
