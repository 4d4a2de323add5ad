"""The package's version (the one in pyproject.toml). Imports nothing, so any module can read it
at its top."""

__version__ = "0.1.0"
