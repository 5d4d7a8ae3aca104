"""Result files: the HDF5 layout of one closed-loop run, in one place.

:func:`write_result` stores a :class:`arvcas.sim.simulation.Result`; :func:`read_result` gives it back,
field for field (arrays bit for bit).

Layout (``format = "arvcas-result"``, ``format_version = 2``)
------------------------------------------------------------
One dataset per traced signal of the run (:mod:`arvcas.sim.signals`: the signals every run has, then
the controller's own), one row per controller sample ``t_k = k h``, ``k = 0..N`` (float64), each with
the signal's attributes ``units``, ``description``, ``columns`` (comma-separated column names) and,
where a frame matters, ``frame`` (``{n}`` NED inertial, ``{b}`` body at the COB). The root attribute
``signals`` lists them in order. Format version 1 files (a fixed list of datasets) are read too.

Root attributes: ``format``, ``format_version``, ``controller``, ``chat`` and ``rmse`` (6 each,
eq. 42-43; with ``chat_units``, ``rmse_units``, ``dofs``), ``seed``, ``gains`` and ``gain_names``,
``config`` (the scenario file's text), ``params`` and ``param_names``, ``uncertainty`` ([C, D, g, arm]
factors), ``phase`` (disturbance phases, rad), ``h`` (s), ``ok``, ``t_fail`` (s; NaN when ok),
``status`` (one sentence), ``arvcas_version``, ``casadi_version``, ``created`` (ISO 8601, UTC) and
``meta`` (JSON text of ``Result.meta``). ``params``/``param_names``, ``uncertainty`` and ``phase``
are absent when the Result has none.

Writing is atomic, through :func:`arvcas.util.files.atomic_write` (temporary name in the target
directory, fsync, ``os.replace``): an interrupted write leaves any previous file untouched and no
partial file under the final name; an existing file arvcas did not write is not replaced.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
from collections.abc import Callable
from pathlib import Path

import casadi as ca
import h5py
import numpy as np

from arvcas.controllers import gains as gains_mod
from arvcas.util import files
from arvcas.system.params import SCHEMA as PARAM_SCHEMA
from arvcas.sim.signals import Signal
from arvcas.sim.simulation import Result

__all__ = ["ResultsError", "write_result", "read_result", "check_dir", "FORMAT", "FORMAT_VERSION"]

FORMAT = "arvcas-result"
FORMAT_VERSION = 2
_V1_DATASETS = ("t", "eta", "nu", "eta_hat", "eta_ref", "tau_cmd", "thrust", "s", "k1", "k2", "f_hat", "f_true", "q",
                "payload")

_DOFS = "x, y, z, phi, theta, psi"

_ROOT_ARRAYS_OPTIONAL = {"params": "params_vector", "uncertainty": "uncertainty", "phase": "phase",
                         "chat_delivered": "chat_delivered"}


class ResultsError(ValueError):
    """A result file cannot be written or read (one line, naming the path)."""


# ---------------------------------------------------------------------------------------------
# writing


def check_dir(d, what: str | None = None) -> Path:
    """``d`` after checking that it is an existing, writable directory (:func:`arvcas.util.files.check_dir`)."""
    return files.check_dir(d, what, ResultsError)


def _check_target(path: Path) -> Path:
    """The final path, after checking that its directory exists and is writable (before any work)."""
    return files.target(path, str(path), ResultsError)


def _series(result: Result, sig: Signal, n: int | None) -> np.ndarray:
    name, width = sig.name, sig.width
    a = np.asarray(result.series[name], dtype=float)
    if isinstance(width, str):  # one column per thruster / per joint of the system
        width = a.shape[1] if a.ndim == 2 else 0
    want = (a.shape[0],) if width == 1 else (a.shape[0], width)
    if a.ndim == 0 or a.shape != want or (n is not None and a.shape[0] != n):
        exp = f"({n if n is not None else 'N+1'}{'' if width == 1 else f', {width}'})"
        raise ResultsError(f"Result.{name}: expected shape {exp}, got {a.shape}")
    return a


def _vector(result: Result, attr: str, n: int | None, where: str) -> np.ndarray:
    a = np.asarray(getattr(result, attr), dtype=float).ravel()
    if n is not None and a.shape != (n,):
        raise ResultsError(f"Result.{where}: expected {n} values, got shape {a.shape}")
    return a


def _status(result: Result) -> str:
    if result.ok:
        return f"completed: {len(result.t)} controller samples to t = {float(result.t[-1]):g} s without divergence"
    return (f"diverged at t = {result.t_fail:g} s (non-finite state or |eta - eta_ref| beyond the scenario's "
            f"limits); samples after t_fail repeat the last valid state and are not meaningful")


def _collect(result: Result) -> tuple[dict[str, np.ndarray], dict[str, object]]:
    """Validate the Result and turn it into (datasets, root attributes); raises ResultsError."""
    if not isinstance(result, Result):
        raise ResultsError(f"write_result: expected arvcas.sim.simulation.Result, got {type(result).__name__}")
    try:
        gains_mod.check_controller(result.controller)
    except ValueError as e:
        raise ResultsError(f"Result.controller: {e}") from None
    if "t" not in result.series:
        raise ResultsError("Result: has no 't' series")
    n = len(np.asarray(result.t))
    sigs = {s.name: s for s in result.signals}
    for name in result.series:
        if name not in sigs:
            raise ResultsError(f"Result: series {name!r} has no signal description (units, frame)")
    data = {name: (_series(result, sig, n), sig) for name, sig in sigs.items()}
    gain_names = gains_mod.gain_names(result.controller)
    attrs: dict[str, object] = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "controller": result.controller,
        "signals": np.array(list(data), dtype=object),
        "dofs": np.array(_DOFS.split(", "), dtype=object),
        "chat": _vector(result, "chat", 6, "chat"),
        "chat_units": "N (x, y, z), N m (phi, theta, psi) per controller sample; eq. 42 on tau_cmd",
        "rmse": _vector(result, "rmse", 6, "rmse"),
        "rmse_units": "m (x, y, z), rad (phi, theta, psi); eq. 43 on eta - eta_ref",
        "seed": int(result.seed),
        "gains": _vector(result, "gains", len(gain_names), "gains"),
        "gain_names": np.array(gain_names, dtype=object),
        "config": str(result.config_text),
        "h": float(result.h),
        "ok": bool(result.ok),
        "t_fail": float("nan") if result.t_fail is None else float(result.t_fail),
        "arvcas_version": str(result.version),
        "casadi_version": ca.__version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }
    if not result.ok and result.t_fail is None:
        raise ResultsError("Result: ok is False but t_fail is None")
    attrs["status"] = _status(result)
    if result.params_vector is not None:
        p = _vector(result, "params_vector", None, "params_vector")
        names = list(result.meta.get("param_names") or PARAM_SCHEMA)  # another system's run names its own
        if p.shape != (len(names),):
            raise ResultsError(f"Result.params_vector: expected {len(names)} values "
                               f"(the system's parameter names), got {p.shape}")
        attrs["params"] = p
        attrs["param_names"] = np.array(names, dtype=object)
    if result.uncertainty is not None:
        attrs["uncertainty"] = _vector(result, "uncertainty", 4, "uncertainty")
    if result.phase is not None:
        attrs["phase"] = _vector(result, "phase", 6, "phase")
    if result.chat_delivered is not None:
        attrs["chat_delivered"] = _vector(result, "chat_delivered", 6, "chat_delivered")
        attrs["chat_delivered_units"] = ("N (x, y, z), N m (phi, theta, psi) per controller sample; eq. 42 on the "
                                         "thrusters' delivered body wrench")
    try:
        attrs["meta"] = json.dumps(result.meta, sort_keys=True, allow_nan=True)
    except (TypeError, ValueError) as e:
        raise ResultsError(f"Result.meta: not JSON-serialisable ({e})") from None
    return data, attrs


def _put(f: h5py.File, name: str, data: np.ndarray, sig: Signal) -> None:
    """One dataset with its signal's attributes (the writer's unit of work)."""
    ds = f.create_dataset(name, data=data, dtype="f8")
    ds.attrs["units"] = sig.units
    ds.attrs["description"] = sig.description
    ds.attrs["columns"] = ", ".join(sig.column_names(data.shape[1] if data.ndim == 2 else 1))
    if sig.frame:
        ds.attrs["frame"] = sig.frame


def atomic_write(path, write: Callable[[Path], None], kind: str | None = None) -> Path:
    """:func:`arvcas.util.files.atomic_write` with errors as :class:`ResultsError`; ``kind``: the file's
    ``format`` (an HDF5 file), else as files.atomic_write's."""
    return files.atomic_write(path, write, ResultsError, kind)


def write_result(result: Result, path) -> Path:
    """Write ``result`` to the HDF5 file ``path`` atomically; returns the path.

    The directory must exist and be writable; an existing file is replaced only once the new one is
    complete on disk. Raises :class:`ResultsError` (one line) before any work when it cannot.
    """
    path = _check_target(Path(path))
    data, attrs = _collect(result)

    def fill(tmp: Path) -> None:
        with files.new_hdf5(tmp) as f:
            for k, v in attrs.items():
                f.attrs[k] = v
            for name, (arr, sig) in data.items():
                _put(f, name, arr, sig)
            f.flush()

    return atomic_write(path, fill, FORMAT)


# ---------------------------------------------------------------------------------------------
# reading


def _str(v) -> str:
    return v.decode("utf-8") if isinstance(v, bytes) else str(v)


def _strs(v) -> list[str]:
    return [_str(x) for x in np.asarray(v).ravel()]


def read_result(path) -> Result:
    """Read a file written by :func:`write_result` back into a :class:`Result`.

    Raises :class:`ResultsError` (one line, naming the path) for a missing file, a file that is not
    HDF5, not an arvcas result (no or another ``format`` attribute, newer ``format_version``), or
    damaged (truncated, missing datasets, inconsistent shapes).
    """
    path = Path(path)
    if not path.exists():
        raise ResultsError(f"{path}: no such file")
    if not path.is_file():
        raise ResultsError(f"{path}: not a regular file")
    try:
        with open(path, "rb") as fh:
            sig = fh.read(8)
    except OSError as e:
        raise ResultsError(f"{path}: cannot read ({e.strerror})") from None
    if sig != b"\x89HDF\r\n\x1a\n":
        raise ResultsError(f"{path}: not an HDF5 file")
    try:
        with h5py.File(path, "r") as f:
            return _read(f, path)
    except ResultsError:
        raise
    except (OSError, KeyError, ValueError, TypeError, RuntimeError) as e:
        msg = " ".join(str(e).split()) or type(e).__name__
        raise ResultsError(f"{path}: damaged or truncated HDF5 file ({msg})") from None


def _read(f: h5py.File, path: Path) -> Result:
    a = f.attrs
    fmt = _str(a["format"]) if "format" in a else None
    if fmt != FORMAT:
        what = "no 'format' attribute" if fmt is None else f"format is '{fmt}'"
        raise ResultsError(f"{path}: not an arvcas result file ({what}, expected '{FORMAT}')")
    ver = int(a.get("format_version", -1))
    if not 1 <= ver <= FORMAT_VERSION:
        raise ResultsError(f"{path}: format_version {ver} is not supported (this arvcas reads 1..{FORMAT_VERSION})")
    names = _strs(a["signals"]) if ver >= 2 else list(_V1_DATASETS)
    missing = [k for k in names if k not in f]
    if missing:
        raise ResultsError(f"{path}: damaged result file: missing dataset(s) {', '.join(missing)}")
    cols = {k: np.array(f[k][()], dtype=float) for k in names}
    if "t" not in cols:
        raise ResultsError(f"{path}: damaged result file: no dataset 't'")
    n = cols["t"].shape[0]
    sigs = []
    for k in names:
        if cols[k].ndim not in (1, 2) or cols[k].shape[0] != n:
            raise ResultsError(f"{path}: damaged result file: dataset {k} has shape {cols[k].shape}, expected ({n}, ...)")
        at = f[k].attrs
        try:
            sigs.append(Signal(k, 1 if cols[k].ndim == 1 else cols[k].shape[1], _str(at["units"]),
                               _str(at.get("frame", "")), _str(at["columns"]), _str(at["description"]), None))
        except KeyError as e:
            raise ResultsError(f"{path}: damaged result file: dataset {k} lacks its attribute {e}") from None
    controller = _str(a["controller"])
    gains = np.array(a["gains"], dtype=float)
    try:
        expect_names = gains_mod.gain_names(controller)
    except ValueError:
        raise ResultsError(f"{path}: unknown controller '{controller}'") from None
    if _strs(a["gain_names"]) != expect_names:
        raise ResultsError(f"{path}: gain_names do not match controller '{controller}' of this arvcas version")
    opt = {}
    for key, field in _ROOT_ARRAYS_OPTIONAL.items():
        opt[field] = np.array(a[key], dtype=float) if key in a else None
    meta = json.loads(_str(a["meta"])) if "meta" in a else {}
    if opt["params_vector"] is not None:
        names = _strs(a["param_names"])
        if names != list(meta.get("param_names") or PARAM_SCHEMA):
            raise ResultsError(f"{path}: param_names differ from this arvcas version's parameter schema"
                               f"{'' if 'system' not in meta else ' of system ' + str(meta['system'])}")
    t_fail = float(a["t_fail"])
    ok = bool(a["ok"])
    return Result(
        controller=controller, gains=gains, seed=int(a["seed"]), series=cols, signals=tuple(sigs),
        chat=np.array(a["chat"], dtype=float), rmse=np.array(a["rmse"], dtype=float),
        ok=ok, t_fail=None if ok or math.isnan(t_fail) else t_fail,
        config_text=_str(a["config"]), h=float(a["h"]), version=_str(a["arvcas_version"]),
        meta=meta,
        **opt,
    )
