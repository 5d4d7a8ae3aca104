"""arvcas: underwater vehicle-manipulator systems as CasADi graphs, compiled to C.

Entry points: :class:`Run` (a closed-loop run described; ``.compile()`` gives a :class:`CompiledRun`
with ``simulate``, ``batch`` and ``many``), the thin wrappers :func:`simulate`, :func:`simulate_batch`,
:func:`simulate_many`, :func:`default_gains`; :func:`compiled` (the plant functions backed by compiled
C as CasADi Functions) and :func:`dynamics` (the same, and their Jacobians, on NumPy arrays at C speed);
:class:`Controller` and :func:`register_controller` for a control law of your own; :func:`load_system`
(a vehicle, its thrusters and its arm described by a file, docs/system-file.md).
"""

from arvcas._version import __version__

from arvcas.build.dynamics import compiled, dynamics  # noqa: E402
from arvcas.sim.run import CompiledRun, Run  # noqa: E402
from arvcas.sim.simulation import Result, default_gains, simulate, simulate_batch, simulate_many  # noqa: E402
from arvcas.controllers import Controller, Gain, register as register_controller  # noqa: E402
from arvcas.system import System, load_system, params  # noqa: E402  (arvcas.params: the parameter loader)

__all__ = ["__version__", "Run", "CompiledRun", "Result", "compiled", "dynamics", "simulate", "simulate_batch",
           "simulate_many", "default_gains", "Controller", "Gain", "register_controller", "System", "load_system",
           "params"]
