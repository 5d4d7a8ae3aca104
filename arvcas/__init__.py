"""arvcas: the Haidou-1 ARV and its manipulator as CasADi graphs, compiled to C.

Entry points: :func:`compiled` (the plant functions backed by compiled C), :func:`simulate`,
:func:`simulate_batch`, :func:`simulate_many` and :func:`default_gains` (the closed-loop experiment of
the paper's section 4, one compiled function per controller).
"""

__version__ = "0.1.0"

from arvcas.build.codegen import compiled  # noqa: E402
from arvcas.build.dynamics import dynamics  # noqa: E402
from arvcas.sim.simulation import Result, default_gains, simulate, simulate_batch, simulate_many  # noqa: E402

__all__ = ["__version__", "compiled", "dynamics", "simulate", "simulate_batch", "simulate_many", "default_gains", "Result"]
