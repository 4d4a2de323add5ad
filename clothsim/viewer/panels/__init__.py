"""One module per GUI panel. A panel builds its widgets once (``build``), shows the draft's values
in them (``sync``; not counted as edits) and turns a user's edit into a task posted to the update
loop (through :meth:`clothsim.viewer.server.ViewerApp.on`), which runs the matching typed operation
of :class:`clothsim.viewer.draft.SceneDraft` or of the simulation. Callbacks never touch the
simulation or the scene themselves."""

from __future__ import annotations


class Panel:
    """Base of the panels: ``app`` is the :class:`~clothsim.viewer.server.ViewerApp` (post, on,
    quiet, err, draft, sim and the ``gui`` dict of handles)."""

    def __init__(self, app):
        self.app = app
        self.gui = app.gui

    def build(self, gui) -> None:  # pragma: no cover - every panel overrides it
        raise NotImplementedError

    def sync(self) -> None:
        """Show the draft's values (called inside ``app.quiet()``)."""
