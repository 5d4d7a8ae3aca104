"""arvcas: the Haidou-1 ARV and its manipulator as CasADi graphs, compiled to C."""

__version__ = "0.1.0"

from .codegen import compiled  # noqa: E402  (the public entry to the compiled plant functions)
