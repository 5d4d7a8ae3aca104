"""The ``ardusub`` controller's gains as an ArduSub parameter file (``arvcas export-controller --format
ardusub-params``): the ``.param`` format QGroundControl and MAVProxy load, one ``NAME value`` per line,
comments after ``#`` (docs/ardusub.md "Out to the vehicle").

The header says the system, the front and member, its objectives and the date. Every value is checked
against ArduSub's range (``arvcas/data/ardusub_params.toml``, from ArduSub's parameter metadata): a value
outside it is refused with one line, never clipped. The x and y slots of the gain vector (no ArduSub
parameter) are not written.
"""

from __future__ import annotations

import datetime
import re
from pathlib import Path

import numpy as np

from arvcas.controllers import ardusub

__all__ = ["ParamFileError", "MARK", "param_values", "param_text", "write_param_file", "read_param_file",
           "default_name"]

MARK = "# ArduSub parameters written by arvcas"  # the first line of every file this module writes
_LINE = re.compile(r"^([A-Z][A-Z0-9_]{0,15})[ ,\t]+([-+0-9.eE]+)\s*(#.*)?$")


class ParamFileError(ValueError):
    """One-line error about an ArduSub parameter file or a value for it."""


def param_values(gains) -> dict[str, float]:
    """ArduSub parameter name -> value of an ``ardusub`` gain vector (the x, y slots left out); a value outside
    ArduSub's range is refused (ParamFileError naming the parameter, its value and the range)."""
    g = np.asarray(gains, dtype=float).ravel()
    slots = ardusub.slot_names()
    if g.shape != (len(slots),):
        raise ParamFileError(f"ardusub-params: expected {len(slots)} gains of controller ardusub, got {g.size}")
    table = ardusub.params()["param"]
    out = {}
    for name, v in zip(slots, g):
        if name is None:
            continue
        lo, hi = table[name]["range"]
        if not (np.isfinite(v) and lo <= v <= hi):
            raise ParamFileError(f"ardusub-params: {name} = {v:.6g} is outside ArduSub's range [{lo:g}, {hi:g}] "
                                 f"(arvcas/data/ardusub_params.toml); refused, not clipped")
        out[name] = float(v)
    return out


def param_text(values: dict[str, float], header: dict[str, str]) -> str:
    """The file's text: the header's ``key: value`` lines as comments, then ``NAME value`` lines (sorted by name,
    as ArduPilot's own parameter files)."""
    lines = [MARK]
    for k, v in header.items():
        for part in str(v).splitlines() or [""]:
            lines.append(f"# {k}: {part}")
    lines += [f"{n} {_fmt(values[n])}" for n in sorted(values)]
    return "\n".join(lines) + "\n"


def _fmt(v: float) -> str:
    s = f"{v:.7g}"
    return s if ("e" in s or "." in s) else s + ".0"


def default_name(system: str) -> str:
    return f"{system}_ardusub.param"


def write_param_file(path, gains, *, system: str, front: str, member: str, objectives: str, force: bool = False,
                     date: str | None = None) -> Path:
    """Write the gains' parameter file at ``path``; refuses a value outside ArduSub's ranges (before writing) and a
    file arvcas did not write (or any existing file without ``force``)."""
    values = param_values(gains)
    path = Path(path)
    if path.exists():
        first = path.read_text(errors="replace").splitlines()[:1]
        if first != [MARK]:
            raise ParamFileError(f"{path}: exists and was not written by arvcas; not replaced")
        if not force:
            raise ParamFileError(f"{path}: exists (pass --force to replace it)")
    header = {"system": system, "front": front, "member": member, "objectives": objectives,
              "date": date or datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
              "controller": "arvcas ardusub (ArduSub ALT_HOLD / STABILIZE gains; docs/ardusub.md); other ArduSub "
                            "parameters are left as they are on the vehicle"}
    path.write_text(param_text(values, header))
    return path


def read_param_file(path) -> dict[str, float]:
    """``NAME -> value`` of a ``.param`` file (QGroundControl / MAVProxy format: ``NAME value`` or ``NAME,value``,
    ``#`` comments); a line of another form is refused with its number."""
    out = {}
    for i, line in enumerate(Path(path).read_text().splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        m = _LINE.match(s)
        if m is None:
            raise ParamFileError(f"{path}:{i}: not 'NAME value': {line!r}")
        out[m.group(1)] = float(m.group(2))
    return out
