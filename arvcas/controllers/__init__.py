"""Controllers: each law is an object (:class:`Controller`) in one module, found by name in one registry.

- :mod:`.base`: :class:`Controller`, :class:`Gain`, :func:`register`, :func:`get`;
- :mod:`.gains`: flat gain vectors (names, defaults from the system's gain table, validation);
- the paper's laws: :mod:`.proposed` (modified AGSTA + ATD + RESO), :mod:`.agsta` (the baseline),
  :mod:`.traditional` (the zigzagging law of Fig. 10), :mod:`.implicit` (implicit GSTA step), all
  built on :mod:`.smc`; and :mod:`.pid` (a per-DOF PID baseline);
- building blocks, pure functions over any CasADi type: :mod:`.atd` (eq. 12-13), :mod:`.reso`
  (eq. 14-16), :mod:`.gsta` (eq. 18-21 and the adaptive laws).

A controller of your own: subclass :class:`Controller`, declare ``name``, ``gains``, ``state``,
``signals`` and ``defaults`` (or ``defaults_block``), implement ``initial`` and ``step``, and call
:func:`register` (docs/adding-a-controller.md); or leave the module to the plugin loader (``--plugin FILE.py``,
a study's ``plugins``, an entry point of the group ``arvcas.controllers``: docs/plugins.md).
"""

from arvcas.controllers.base import (Controller, ControllerError, Gain, accepted, aliases, available, canonical, get,
                                     names, register, unregister)
from arvcas.controllers import proposed, agsta, traditional, implicit, pid, ardusub  # noqa: F401,E402  (registers them)

__all__ = ["Controller", "ControllerError", "Gain", "available", "get", "names", "register", "unregister", "aliases",
           "canonical", "accepted"]
