"""The browser viewer (viser), split by job:

- :mod:`.server`: :class:`ViewerApp`, the viser server and its one update loop;
- :mod:`.draft`: :class:`SceneDraft`, the edited scene with typed edit operations, and scene
  files (the scene + files zip, opening an uploaded scene) (no viser);
- :mod:`.panels`: one module per GUI panel (run, view, solver, constraints, material,
  fabric & mold, probes and the click readout, files);
- :mod:`.pick`: the node under a click, its readout, the probes' readings and rings (no viser);
- :mod:`.render` (scene nodes, camera), :mod:`.glb` (GLB writer, colour map) and :mod:`.fields`
  (per-node fields): rendering;
- :mod:`.plot`: the residual plot;
- :mod:`.command`: ``clothsim view``.

The core never imports this package. Importing it does not import viser: ``ViewerApp`` and
``main`` are loaded on first use, so that the draft and the rendering helpers work (and are
tested) where viser is not installed.
"""

from .draft import SceneDraft, parse_table_text, table_text

__all__ = ["ViewerApp", "SceneDraft", "main", "parse_table_text", "table_text"]


def __getattr__(name: str):
    if name == "ViewerApp":
        from .server import ViewerApp

        return ViewerApp
    if name == "main":
        from .command import main

        return main
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
