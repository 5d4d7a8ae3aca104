"""The provenance attributes every ``arvcas.experiments`` file carries, and its HDF5 readers.

Files are written and directories checked by :mod:`arvcas.util.files` (errors as ``ResultsError``).
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

import casadi as ca
import h5py
import numpy as np

from arvcas._version import __version__
from arvcas.util import files
from arvcas.io.results import ResultsError, atomic_write

__all__ = ["atomic_write", "write_text", "write_figure", "write_result_dir", "stored_inputs", "provenance",
           "prepare_dir", "target", "str_attr", "check_format", "controller_sources", "require_controllers"]


def write_text(path: Path, text: str) -> Path:
    return files.write_text(path, text, ResultsError)


def write_figure(path: Path, fig, fmt: str | None = None) -> Path:
    from arvcas.io import style

    return style.write_figure(path, fig, fmt, ResultsError)


def write_result_dir(out_dir, stem: str, result, write_h5, markdown, plot, fmt: str = "png") -> dict[str, Path]:
    """``out_dir/<stem>.h5`` (``write_h5(result, path)``), ``<stem>.md`` (``markdown(result)``) and
    ``<stem>.<fmt>`` (``plot(result)``; png, pdf or svg), each written atomically; ``out_dir`` is created if
    missing. The figure's key in the returned dict is ``"figure"``."""
    out = prepare_dir(out_dir, f"--out {out_dir}")
    written = {"h5": write_h5(result, out / f"{stem}.h5"), "md": write_text(out / f"{stem}.md", markdown(result))}
    fig = plot(result)
    written["figure"] = write_figure(out / f"{stem}.{fmt}", fig, fmt)
    return written


def stored_inputs(path, config_text: str, params_vector, error: type[ValueError] = ResultsError, system: str = ""):
    """The scenario and parameters a result file at ``path`` stores, for re-running it.

    ``config_text``: the stored scenario file; ``params_vector``: the parameter values in the order of
    the system's parameters (``error`` is raised when they do not fit); ``system``: the stored system
    (a shipped name or a system file; "" for Haidou-1). Returns ``(cfg, params)``.
    """
    from arvcas.system.params import load as load_params
    from arvcas.sim import scenario
    from arvcas.system import load_system

    cfg = scenario.loads_scenario(config_text, f"{path} (stored scenario)")
    base = load_system(system).params if system else load_params()
    names = base.names()
    if params_vector.shape != (len(names),):
        raise error(f"{path}: stored params do not match the parameters of system {base.structure.name}")
    params = base.replace(dict(zip(names, params_vector.tolist())))
    return cfg, params


def system_ref(params) -> str:
    """How a result file names the system of ``params`` (:func:`arvcas.system.result_ref`)."""
    from arvcas.system import result_ref

    return result_ref(params)


def system_reference(params, cfg) -> tuple | None:
    """The objectives' per-DOF normalisation for another system: its AGSTA at its default gains on noise
    seed 0 with the scenario's factors and phases (docs/model.md §8); None for Haidou-1 (Table 3)."""
    if not system_ref(params):
        return None
    from arvcas.sim.simulation import compiled_run

    run = compiled_run("agsta", params, cfg)
    chat, rmse, ok, _ = run.many(run.default_gains(), [0], n_threads=1)
    return (tuple(chat[0]), tuple(rmse[0])) if ok[0] else None


def provenance() -> dict[str, str]:
    """Versions that decide the numbers (the run, the random streams) and the creation time."""
    return {
        "arvcas_version": __version__,
        "casadi_version": ca.__version__,
        "numpy_version": np.__version__,
        "h5py_version": h5py.__version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }


def controller_sources(controllers) -> str:
    """JSON ``{name: record}`` of the controllers defined outside the package
    (:func:`arvcas.controllers.base.provenance`: the plugin and the digest of its source); "" when none."""
    import json

    from arvcas.controllers.base import provenance

    recs = {c: r for c in controllers for r in [provenance(c)] if r}
    return json.dumps(recs, sort_keys=True) if recs else ""


def require_controllers(path, controllers, sources: str) -> None:
    """Before a file's runs are re-run: each controller is registered (an entry point of its name is
    loaded), or a one-line ResultsError saying which plugin to load (``sources``: the file's
    :func:`controller_sources`)."""
    import json

    from arvcas.controllers import base

    recs = json.loads(sources) if sources else {}
    for c in controllers:
        try:
            base.get(c)
        except base.ControllerError as e:
            if c not in recs:
                raise ResultsError(f"{path}: {e}") from None
            src, hint = base.describe_provenance(recs[c])
            raise ResultsError(f"{path}: controller '{c}' is not registered; it came from {src}: {hint}") from None


def prepare_dir(d, what: str) -> Path:
    """Create ``d`` if missing (its parent must exist) and check it is a writable directory."""
    return files.prepare_dir(d, what, ResultsError)


def target(path, what: str) -> Path:
    """An output file path whose directory exists and is writable (checked before any work)."""
    return files.target(path, what, ResultsError)


def str_attr(v) -> str:
    return v.decode("utf-8") if isinstance(v, bytes) else str(v)


def check_format(path: Path, f: h5py.File, fmt: str, version: int) -> None:
    got = str_attr(f.attrs["format"]) if "format" in f.attrs else None
    if got != fmt:
        what = "no 'format' attribute" if got is None else f"format is '{got}'"
        raise ResultsError(f"{path}: not an {fmt} file ({what})")
    ver = int(f.attrs.get("format_version", -1))
    if not 1 <= ver <= version:
        raise ResultsError(f"{path}: format_version {ver} is not supported (this arvcas reads 1..{version})")


def open_h5(path, fmt: str, version: int):
    """Open an HDF5 file for reading after checking existence and signature; returns h5py.File."""
    path = Path(path)
    if not path.exists():
        raise ResultsError(f"{path}: no such file")
    if not path.is_file():
        raise ResultsError(f"{path}: not a regular file")
    with open(path, "rb") as fh:
        sig = fh.read(8)
    if sig != b"\x89HDF\r\n\x1a\n":
        raise ResultsError(f"{path}: not an HDF5 file")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise ResultsError(f"{path}: damaged or truncated HDF5 file ({' '.join(str(e).split())})") from None
    try:
        check_format(path, f, fmt, version)
    except BaseException:
        f.close()
        raise
    return f


def h5_format(path) -> str | None:
    """The ``format`` attribute of an HDF5 file, or None if it is not HDF5 or has none."""
    return files.hdf5_format(path)
