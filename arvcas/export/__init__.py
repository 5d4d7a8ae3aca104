"""The controller of a run for other programs: ``arvcas export-controller`` (:mod:`.controller`: the
EKF, reference, law and allocation of a compiled run's controller sample as a standalone C library,
its files rendered from ``arvcas/build/templates/controller/``) and the check that such a package is
the run's controller (:mod:`.closeloop`: it closed around the plant over the run's scenario).

This package sits above :mod:`arvcas.sim` (the controller's graph is the run's own,
:func:`arvcas.sim.closedloop.controller_functions`) and below the command line; the plant's C
(``arvcas export-c``), the FMU and the text of every generated file are in :mod:`arvcas.build`.
"""
