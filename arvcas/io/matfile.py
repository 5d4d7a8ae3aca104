"""MATLAB ``.mat`` files (level 5, via :func:`scipy.io.savemat`) of results and fronts.

Variable names and shapes are what a MATLAB user of the paper's Simulink model expects: one row per
sample or per front member, one column per DOF, joint or thruster; scalars as 1x1; names as cell
arrays of char; text as char. Every file also holds

* ``arvcas``: a struct with ``format`` (``"arvcas-result"`` or ``"arvcas-front"``), ``format_version``,
  ``arvcas_version``, ``casadi_version``, ``created`` (ISO 8601, UTC);
* ``units`` and ``description``: structs with one char field per variable (``units.eta`` is
  ``'m, m, m, rad, rad, rad'``), and ``columns`` (the column names of each matrix).

A result (``.simulate``): ``t`` (N+1 x 1, s) and one (N+1 x width) matrix per traced signal
(``eta``, ``nu``, ``eta_hat``, ``eta_ref``, ``tau_cmd``, ``thrust``, ... : :mod:`arvcas.sim.signals`),
``chat``, ``rmse`` (1 x 6), ``gains`` (1 x n) with ``gain_names``, ``controller``, ``seed`` (int64: exact
up to 2**63), ``ok``, ``t_fail`` (NaN when ok), ``h``, ``params`` with ``param_names`` (the result's
system's), ``scenario`` (the scenario text).

A front (``front.h5``): ``F`` (f x 2: f_chat, f_rmse, docs/model.md §7), ``G`` (f x 1, the constraint:
> 0 diverged), ``gains`` (f x n, gain units) with ``gain_names``, ``X`` (f x n, log10 of the gains),
``chat``, ``rmse`` (f x 6 x K: member, DOF, draw), ``knee`` (1-based member index), ``table2_F``
(1 x 2), ``reference_point`` (1 x 2), ``hypervolume``, ``controller``, ``study``, ``seed`` and ``draw_seeds``
(int64).

Written atomically (:func:`arvcas.io.results.atomic_write`).
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

import casadi as ca
import numpy as np

from arvcas._version import __version__
from arvcas.controllers import gains as gains_mod
from arvcas.system.params import SCHEMA as PARAM_SCHEMA

__all__ = ["write_result_mat", "write_front_mat", "result_variables", "front_variables", "MatError"]


class MatError(ValueError):
    """One-line error about a .mat output."""


def _cell(names) -> np.ndarray:
    a = np.empty((1, len(names)), dtype=object)
    for i, n in enumerate(names):
        a[0, i] = str(n)
    return a


def _row(v) -> np.ndarray:
    return np.atleast_2d(np.asarray(v, dtype=float).ravel())


def _seed(v) -> np.ndarray:
    """Seeds as int64 (MATLAB reads them exactly; a double holds integers exactly only up to 2**53)."""
    return np.asarray(v, dtype=np.int64)


def _header(fmt: str) -> dict:
    return {"format": fmt, "format_version": 1.0, "arvcas_version": __version__, "casadi_version": ca.__version__,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")}


def result_variables(result) -> tuple[dict, dict, dict, dict]:
    """(variables, units, descriptions, columns) of a :class:`~arvcas.sim.simulation.Result`."""
    var, units, desc, cols = {}, {}, {}, {}
    for sig in result.signals:
        a = np.asarray(result.series[sig.name], dtype=float)
        var[sig.name] = a.reshape(-1, 1) if a.ndim == 1 else a
        units[sig.name], desc[sig.name] = sig.units, sig.description + (f" (frame {sig.frame})" if sig.frame else "")
        cols[sig.name] = _cell(sig.column_names(a.shape[1] if a.ndim == 2 else 1))
    var |= {"chat": _row(result.chat), "rmse": _row(result.rmse), "gains": _row(result.gains),
            "gain_names": _cell(gains_mod.gain_names(result.controller)), "controller": str(result.controller),
            "seed": _seed(result.seed), "ok": bool(result.ok),
            "t_fail": float("nan") if result.t_fail is None else float(result.t_fail), "h": float(result.h),
            "scenario": str(result.config_text)}
    units |= {"chat": "N (x, y, z), N m (phi, theta, psi) per controller sample (eq. 42)",
              "rmse": "m (x, y, z), rad (phi, theta, psi) (eq. 43)", "gains": ", ".join(gains_mod.gain_units(result.controller)),
              "t_fail": "s", "h": "s"}
    desc |= {"chat": "CHAT per DOF (eq. 42) on tau_cmd", "rmse": "RMSE per DOF (eq. 43) on eta - eta_ref",
             "gains": "the run's gain vector, DOF by DOF, in gain_names order", "t_fail": "time of divergence (NaN: none)",
             "h": "controller sampling period", "scenario": "the scenario's effective TOML text"}
    if result.params_vector is not None:
        names = list(result.meta.get("param_names") or PARAM_SCHEMA)  # another system's names, or Haidou-1's
        if len(names) != np.size(result.params_vector):
            raise MatError(f"the result's parameter vector has {np.size(result.params_vector)} entries but its "
                           f"system names {len(names)}: not written")
        var["params"] = _row(result.params_vector)
        var["param_names"] = _cell(names)
        units["params"] = "SI, see param_names and the parameter file"
        desc["params"] = "the model parameter vector p the run used"
    return var, units, desc, cols


def front_variables(front) -> tuple[dict, dict, dict, dict]:
    """(variables, units, descriptions, columns) of a :class:`~arvcas.tuning.front.Front`."""
    chat = np.transpose(np.asarray(front.chat, dtype=float), (1, 2, 0))  # (K, f, 6) -> member, DOF, draw
    rmse = np.transpose(np.asarray(front.rmse, dtype=float), (1, 2, 0))
    var = {"F": np.asarray(front.F, dtype=float), "G": np.asarray(front.G, dtype=float).reshape(front.F.shape[0], -1),
           "gains": np.asarray(front.gains, dtype=float), "X": np.asarray(front.X, dtype=float),
           "gain_names": _cell(front.names), "chat": chat, "rmse": rmse, "knee": float(front.knee() + 1),
           "table2_F": _row(front.table2_F), "reference_point": _row(front.reference_point),
           "hypervolume": float(front.hv), "controller": str(front.controller), "study": str(front.study_name),
           "seed": _seed(front.seed), "draw_seeds": np.atleast_2d(_seed(front.draw_seeds).ravel())}
    from arvcas.metrics.indices import defaults_name, norm_name

    units = {"F": f"1 (normalised by {norm_name(front.system)})", "G": "1", "gains": "gain units (see gain_names)",
             "X": "log10 of gain units", "chat": "N or N m per controller sample", "rmse": "m or rad",
             "table2_F": "1", "reference_point": "1", "hypervolume": "1"}
    desc = {"F": "objectives (f_chat, f_rmse) of each front member, docs/model.md §7",
            "G": "constraint: > 0 means the run diverged (infeasible)",
            "gains": "each member's gains", "X": "each member's decision variables: log10 of its gains",
            "chat": "per member, DOF and draw: CHAT (eq. 42)", "rmse": "per member, DOF and draw: RMSE (eq. 43)",
            "knee": "1-based index of the knee member (pymoo PseudoWeights 0.5, 0.5)",
            "table2_F": f"objectives of the {defaults_name(front.system)} on the same draws",
            "reference_point": "the study's hypervolume reference point", "hypervolume": "of F against reference_point"}
    cols = {"F": _cell(["f_chat", "f_rmse"]), "gains": _cell(front.names), "X": _cell(front.names)}
    if tuple(getattr(front, "objectives", ("chat", "rmse"))) != ("chat", "rmse"):  # docs/objectives.md
        from arvcas.metrics import objectives as objectives_mod

        cols["F"] = _cell(front.labels)
        units["F"] = units["table2_F"] = units["reference_point"] = ", ".join(
            objectives_mod.get(n).unit for n in front.objectives)
        desc["F"] = f"objectives ({', '.join(front.labels)}) of each front member, docs/objectives.md"
        desc["G"] = "constraints: > 0 means infeasible (the run diverged, or a study constraint is violated)"
    return var, units, desc, cols


def mat_kind(fmt: str) -> str:
    """The kind (:mod:`arvcas.util.files`) of a .mat file of format ``fmt`` (``arvcas-result``, ``arvcas-front``)."""
    return f"{fmt} (.mat)"


def _write(path, fmt: str, parts) -> Path:
    from scipy.io import savemat

    from arvcas.io.results import atomic_write

    path = Path(path)
    if path.suffix != ".mat":
        raise MatError(f"{path}: a MATLAB file must end in .mat")
    var, units, desc, cols = parts
    clash = sorted({"arvcas", "units", "description", "columns"} & set(var))
    if clash:
        raise MatError(f"{path}: variable names {clash} are reserved")
    doc = dict(var, arvcas=_header(fmt), units=units, description=desc, columns=cols)

    def fill(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            savemat(f, doc, long_field_names=True, do_compression=True, oned_as="row")

    return atomic_write(path, fill, mat_kind(fmt))


def write_result_mat(result, path) -> Path:
    """A result as a .mat file (see the module docstring); returns the path."""
    return _write(path, "arvcas-result", result_variables(result))


def write_front_mat(front, path) -> Path:
    """A front as a .mat file (see the module docstring); returns the path."""
    return _write(path, "arvcas-front", front_variables(front))
