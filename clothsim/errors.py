"""The errors users see. Kept apart so every layer can raise them without importing the scene."""


class SceneError(ValueError):
    """A scene is invalid. ``str(err)`` is the user-facing message: ``file:line: field: what``."""
