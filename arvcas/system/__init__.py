"""The parameters-and-systems layer: a system file read into its structure and its numbers.

- :mod:`~arvcas.system.config`: the one strict loader (TOML tables -> typed frozen dataclasses, units
  checked, closest-name hints) for system, scenario and study files; :mod:`~arvcas.system.tomlfile`
  reads their text with one-line errors;
- :mod:`~arvcas.system.systemfile`: a system file's *structure* (what shapes the compiled code);
- :mod:`~arvcas.system.params`: its *numbers* (:class:`~arvcas.system.params.Params`, SI, with units
  and sources), checked physical;
- :mod:`~arvcas.system.urdf`: a URDF arm read by Pinocchio (a gripper's joints locked);
- :mod:`~arvcas.system.uuv`: a uuv_simulator / Gazebo description imported as a system file (docs/importing.md);
- :mod:`~arvcas.system.loader`: :class:`System` and :func:`load_system` (shipped systems by name).

This layer uses none above it (docs/architecture.md) but the model's matrices in the physical check.
"""

from arvcas.system.loader import DEFAULT, SHIPPED, UNSET, System, load_system, renamed_system, resolve, result_ref, shipped

__all__ = ["System", "SHIPPED", "load_system", "shipped", "resolve", "DEFAULT", "UNSET", "renamed_system", "result_ref"]
