"""arvcas: the Haidou-1 ARV and its manipulator as CasADi graphs, compiled to C."""

__version__ = "0.1.0"
