"""The package's version (pyproject.toml's ``version``), in a module of its own so that modules
of the package read it without importing the package's ``__init__`` (which imports the
simulation, and so most of the package: results.py reading ``clothsim.__version__`` made a circle)."""

__version__ = "0.1.0"
