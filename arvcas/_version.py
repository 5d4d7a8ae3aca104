"""The package's version, in a module that imports nothing: every layer may read it (pyproject.toml takes it
from here) without running the package's ``__init__``, which imports the layers themselves."""

__version__ = "0.1.0"
