"""Speed benchmark: plant functions, the closed loop, compiling and the sections listed below.

:func:`run` measures everything in one process and writes ``bench.json`` (every figure, with the
machine it was measured on) and ``bench.md`` (the tables) to an output directory. ``arvcas bench``
is its command line; ``benchmarks/run.py`` and ``python -m arvcas.bench`` call the same.

One module per section: :mod:`~arvcas.bench.common` (settings, the required keys, timing and machine
state), :mod:`~arvcas.bench.plant` (1), :mod:`~arvcas.bench.closed_loop` (2),
:mod:`~arvcas.bench.targets` (2b: the targets of the default plant step), :mod:`~arvcas.bench.compiling` (3),
:mod:`~arvcas.bench.startup` (4), :mod:`~arvcas.bench.systems` (5),
:mod:`~arvcas.bench.identification` (6), :mod:`~arvcas.bench.controller` (7: the exported
controller's time per step), :mod:`~arvcas.bench.lanes` (8: lockstep lanes against one run at a time,
the 40,000-run study), :mod:`~arvcas.bench.cost` (9: cost against run length, batch size and arm joints),
:mod:`~arvcas.bench.runner` (:func:`run`: every section in one process, and :func:`write`) and
:mod:`~arvcas.bench.report` (``bench.md``).

Rules (STYLE, the guide): speed is measured here, never asserted in a test. Every time is the median
of repeated measurements (``median``, ``min``, ``max``, ``n`` in the JSON; full mode: n >= 5). Every
comparison is a ratio against a baseline measured in the same run: CasADi's VM evaluating the same
graph, one thread for the batch, the current default optimisation level for the compile sweep.

What is measured:

1. Plant functions, each of the five public SX Functions and the two Jacobians
   (:data:`arvcas.build.dynamics.NAMES`): (a) single calls from C, by a small driver generated here,
   compiled with codegen's flags, that ``dlopen``\\ s the very library :func:`arvcas.compiled` loads
   and loops over 256 varying input sets; (b) ``f.map(N)`` of the compiled external called from
   Python, per evaluation; (c) the same SX Function in CasADi's VM, single calls from Python and
   ``map(N)``; (d) :func:`arvcas.dynamics` on NumPy arrays, single calls and one batch of N rows (1
   thread, all cores), and the compiled Function called on NumPy arrays; (e) the same C driver on the
   library ``arvcas export-c`` writes, built by its Makefile; (f) for vehicle_rhs, a hand-written
   NumPy implementation (the yardstick; arvcas has none), single and vectorised over N rows.
   Instructions per second = ``f.n_instructions()`` / time.
2. Closed loop: the compiled 100 s run (metrics only, with trace, and :func:`simulate`), the same
   MX run in the VM, :func:`simulate_batch` with 1 and 2 threads; instructions per controller
   sample = the sum over the sub-functions the step calls (controller, ``h/h_plant`` RK4 substeps,
   the divergence check and finalize's branch for a running run).
3. Compiling: cold (fresh temporary ``ARVCAS_CACHE``) and warm (disk hit) builds of ``uvms_rhs`` and
   of the run; a sweep over ``-O0..-O3`` of compile time against run speed, which decides the
   default optimisation level.
7. The exported controller (``arvcas export-controller``): ns per ``step`` from a C driver linking
   the export's own library, for the proposed law, AGSTA and PID on each system with a scenario.
8. Lockstep lanes (:mod:`arvcas.sim.lockstep`): batches on one thread W runs at a time against one at
   a time, alternated, outputs compared to the bit, with running, mixed and diverging members; a
   40,000-run study on 2 threads: its runs alone, and ``run_study`` end to end.
9. Cost against work (:mod:`~arvcas.bench.cost`): Haidou-1's run time against its length (10-1000 s) and
   against the batch size (1-100,000 runs, one at a time and in lockstep), and per controller sample, CasADi
   instructions and cold compile time against the arm's joints (0-7, generated system files); a line with
   intercept fitted to each series and where it holds; the figures and a README in ``<out>/cost/``.

Interference: the load average before and after, and the share of the machine's CPU time used by
other processes while measuring (from ``/proc/stat`` minus this process and its children), are
recorded; ``wait_load`` waits for a quiet machine before starting.

Units: keys end in ``_s`` (seconds), ``_us`` (microseconds) or ``_ns`` (nanoseconds); ``rtf`` is
simulated time over wall time; ``ratio_*`` and ``*_speedup`` are dimensionless.
"""

from __future__ import annotations

from arvcas.bench.common import CONTROLLER, REQUIRED_KEYS, RUN_TIME_TOLERANCE, BenchError, Settings
from arvcas.bench.compiling import _recommend
from arvcas.bench.report import render_markdown
from arvcas.bench.runner import run, write

__all__ = ["BenchError", "Settings", "run", "write", "render_markdown", "REQUIRED_KEYS"]
