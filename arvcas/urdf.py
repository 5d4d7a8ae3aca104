"""A URDF arm in a system file (docs/system-file.md form 3), read by Pinocchio's URDF reader.

Why Pinocchio: it reads URDF with urdfdom, the ROS reference parser, it is maintained, and it merges
the bodies of fixed joints into their moving parent (parallel-axis theorem, frames placed) — the one
step of reading an arm that is easy to get wrong. It is also arvcas's independent reference for the
multibody tests, so the URDF path adds no new library. It is heavy (about 480 MB installed), so it is
the optional extra ``arvcas[urdf]``; the shipped systems need it not (their arms are written in the
file, forms 1 and 2). Pinocchio checks little (it takes prismatic joints, links without inertials and
indefinite tensors), so the raw XML is checked here first with the standard library: joint types on
the chain, an inertial on every moving link, the joint count.

:func:`convert` turns the ``[arm]`` of a form-3 document into the chain form (2), every number with a
source naming the URDF file and the joint or link it came from.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from arvcas import config, systemfile

__all__ = ["convert", "SUPPORTED_JOINTS"]

SUPPORTED_JOINTS = ("revolute", "continuous", "fixed")
_HYDRO_KEYS = ("volume", "cob", "drag_diameter", "drag_from", "drag_to", "Cd")
CONTINUOUS_LIMIT = 100 * math.pi  # a continuous joint's limits: unbounded in practice


def _entry(value, unit: str, source: str) -> dict:
    v = [float(x) for x in value] if isinstance(value, (list, tuple, np.ndarray)) else float(value)
    return {"value": v, "unit": unit, "source": source}


def _si(entry: Any, key: str, dim: str, n: int | None, where: str, error) -> Any:
    """An entry ``{value, unit, source}`` of [arm.hydro.*] in SI (checked: unit of dimension ``dim``)."""
    if not isinstance(entry, dict) or "value" not in entry or "unit" not in entry:
        raise error(f"{where}: {key}: expected {{ value, unit, source }}")
    unit = entry["unit"]
    if unit == config.SI:
        fac = 1.0
    else:
        d, fac = config.UNITS.get(unit, (None, None))
        if d != dim:
            raise error(f"{where}: {key}: unit {unit!r} is not a unit of {dim} (allowed: "
                        f"{', '.join(u for u, (dd, _) in config.UNITS.items() if dd == dim)}, SI)")
    v = entry["value"]
    if n is None:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise error(f"{where}: {key}: expected a finite number, got {v!r}")
        return float(v) * fac
    if not isinstance(v, list) or len(v) != n or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                         and math.isfinite(x) for x in v):
        raise error(f"{where}: {key}: expected {n} finite numbers, got {v!r}")
    return np.array(v, dtype=float) * fac


def _chain(root: ET.Element, base: str, tool: str, where: str, error) -> list[ET.Element]:
    """The joints from ``base`` to ``tool``, in order; the URDF checked along the way."""
    links = {e.get("name"): e for e in root.findall("link")}
    for name in (base, tool):
        if name not in links:
            raise error(f"{where}: link '{name}' is not in the URDF (links: {', '.join(list(links)[:12])})")
    by_child = {}
    for j in root.findall("joint"):
        c = j.find("child")
        if c is not None:
            by_child[c.get("link")] = j
    path = []
    cur = tool
    while cur != base:
        j = by_child.get(cur)
        if j is None:
            raise error(f"{where}: link '{tool}' is not below '{base}' (no joint leads to '{cur}')")
        path.append(j)
        cur = j.find("parent").get("link")
    path.reverse()
    on_chain = {base} | {j.find("child").get("link") for j in path}
    for j in root.findall("joint"):
        parent = j.find("parent").get("link")
        kind = j.get("type")
        if kind not in SUPPORTED_JOINTS:
            if parent in on_chain or j in path:
                raise error(f"{where}: joint '{j.get('name')}' is of type '{kind}': supported joint types are "
                            f"{', '.join(SUPPORTED_JOINTS)}")
        elif kind != "fixed" and j not in path:
            raise error(f"{where}: joint '{j.get('name')}' moves a branch off the chain {base} -> {tool}: "
                        f"only serial arms are supported")
    moving = [j for j in path if j.get("type") != "fixed"]
    if len(moving) > systemfile.MAX_JOINTS:
        raise error(f"{where}: {len(moving)} revolute joints from {base} to {tool}, at most "
                    f"{systemfile.MAX_JOINTS} are supported")
    for j in moving:
        child = j.find("child").get("link")
        if links[child].find("inertial") is None:
            raise error(f"{where}: link '{child}' (moved by joint '{j.get('name')}') has no <inertial>: every "
                        f"moving link needs its mass and inertia")
    return path


def convert(doc: dict, path: Path, error) -> dict:
    """``doc`` with its ``[arm]`` URDF (form 3) replaced by the chain form (2); ``error`` one line."""
    where = str(path)
    arm = dict(doc["arm"])
    for k in ("urdf", "base_link", "tool_link"):
        if not isinstance(arm.get(k), str):
            raise error(f"{where}: arm.{k}: expected a string (docs/system-file.md form 3)")
    extra = [k for k in arm if k not in ("urdf", "base_link", "tool_link", "mount", "stow", "hydro", "trim")]
    if extra:
        raise error(f"{where}: arm.{extra[0]}: not a key of a URDF arm (allowed: urdf, base_link, tool_link, "
                    f"mount, stow, hydro, trim)")
    upath = systemfile.rel_path(path, arm["urdf"])
    uwhere = str(upath)
    from arvcas.io.files import read_text

    text = read_text(upath, "URDF file", error)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise error(f"{uwhere}: malformed XML: {e}") from None
    if root.tag != "robot":
        raise error(f"{uwhere}: the root element is <{root.tag}>, a URDF has <robot>")
    base, tool = arm["base_link"], arm["tool_link"]
    chain = _chain(root, base, tool, uwhere, error)
    try:
        import pinocchio as pin
    except ImportError:
        raise error(f"{where}: arm.urdf: reading a URDF needs Pinocchio: pip install 'arvcas[urdf]'") from None
    try:
        model = pin.buildModelFromXML(text)
    except Exception as e:  # noqa: BLE001 (urdfdom's own message, one line)
        raise error(f"{uwhere}: Pinocchio could not read it: {' '.join(str(e).split())}") from None
    moving = [j.get("name") for j in chain if j.get("type") != "fixed"]
    names = list(model.names)[1:]
    if names != moving:
        raise error(f"{uwhere}: the URDF's moving joints {names} are not the chain {base} -> {tool} {moving}: "
                    f"only a serial arm rooted at '{base}' is supported")
    fname = Path(arm["urdf"]).name
    out = {k: v for k, v in arm.items() if k in ("mount", "stow", "trim")}
    for i, jname in enumerate(moving, start=1):
        jid = model.getJointId(jname)
        M = model.jointPlacements[jid]
        jel = next(j for j in chain if j.get("name") == jname)
        ax = jel.find("axis")  # in the joint's frame (URDF default x)
        try:
            axis = np.array([float(x) for x in (ax.get("xyz") if ax is not None else "1 0 0").split()])
        except ValueError:
            axis = np.zeros(0)
        if axis.shape != (3,) or not np.isfinite(axis).all() or np.linalg.norm(axis) == 0:
            raise error(f"{uwhere}: joint '{jname}': <axis xyz> must be three numbers, not all zero")
        axis = axis / np.linalg.norm(axis)
        src = f"{fname}: joint '{jname}'"
        if jel.get("type") == "continuous":
            lo, hi, lsrc = -CONTINUOUS_LIMIT, CONTINUOUS_LIMIT, f"{src} (continuous: unbounded, 100 pi)"
        else:
            iq = model.idx_qs[jid]
            lo, hi, lsrc = float(model.lowerPositionLimit[iq]), float(model.upperPositionLimit[iq]), src + " <limit>"
        rpy = pin.rpy.matrixToRpy(M.rotation)
        out[f"joint{i}"] = {
            "x": _entry(M.translation[0], "m", src), "y": _entry(M.translation[1], "m", src),
            "z": _entry(M.translation[2], "m", src), "roll": _entry(rpy[0], "rad", src),
            "pitch": _entry(rpy[1], "rad", src), "yaw": _entry(rpy[2], "rad", src),
            "axis": _entry(axis, "1", src), "qmin": _entry(lo, "rad", lsrc), "qmax": _entry(hi, "rad", lsrc),
        }
        I = model.inertias[jid]
        Ic = np.asarray(I.inertia)
        lsrc = f"{fname}: inertials of the body moved by joint '{jname}' (fixed children merged by Pinocchio)"
        out[f"link{i}"] = {
            "mass": _entry(I.mass, "kg", lsrc), "com": _entry(I.lever, "m", lsrc),
            "inertia": _entry([Ic[0, 0], Ic[1, 1], Ic[2, 2], Ic[0, 1], Ic[0, 2], Ic[1, 2]], "kg*m^2", lsrc),
            "volume": _entry(0.0, "m^3", "no [arm.hydro] entry for this body: no buoyancy"),
            "cob": _entry(I.lever, "m", "no [arm.hydro] entry: at the centre of mass"),
        }
    hydro = arm.get("hydro", {})
    if not isinstance(hydro, dict):
        raise error(f"{where}: arm.hydro: expected tables [arm.hydro.<link name>]")
    done: dict[int, str] = {}
    for lname, h in hydro.items():
        key = f"arm.hydro.{lname}"
        if not model.existFrame(lname):
            raise error(f"{where}: {key}: '{lname}' is not a link of {fname}")
        fr = model.frames[model.getFrameId(lname)]
        jid = fr.parentJoint
        if jid == 0 or model.names[jid] not in moving:
            raise error(f"{where}: {key}: '{lname}' does not move with a joint of the arm (its buoyancy and drag "
                        f"belong to the vehicle)")
        i = moving.index(model.names[jid]) + 1
        if i in done:
            raise error(f"{where}: {key}: link {i} already has hydrodynamics from arm.hydro.{done[i]} (one "
                        f"entry per moving body)")
        done[i] = lname
        if not isinstance(h, dict):
            raise error(f"{where}: {key}: expected a table")
        bad = [k for k in h if k not in _HYDRO_KEYS]
        if bad:
            raise error(f"{where}: {key}.{bad[0]}: unknown key (allowed: {', '.join(_HYDRO_KEYS)})"
                        f"{config.closest(bad[0], _HYDRO_KEYS)}")
        X = fr.placement  # link frame -> joint frame
        link = out[f"link{i}"]
        src = lambda k: f"{h[k].get('source', '')} ({lname}, moved into the frame of joint {i})"  # noqa: E731
        if "volume" in h:
            link["volume"] = _entry(_si(h["volume"], key + ".volume", "volume", None, where, error), "m^3",
                                    src("volume"))
        if "cob" in h:
            link["cob"] = _entry(X.act(_si(h["cob"], key + ".cob", "length", 3, where, error)), "m", src("cob"))
        have = [k for k in ("drag_diameter", "drag_from", "drag_to") if k in h]
        if have and len(have) != 3:
            raise error(f"{where}: {key}: a drag segment needs drag_diameter, drag_from and drag_to (or none)")
        if have:
            link["drag_diameter"] = _entry(_si(h["drag_diameter"], key + ".drag_diameter", "length", None, where,
                                               error), "m", src("drag_diameter"))
            for k in ("drag_from", "drag_to"):
                link[k] = _entry(X.act(_si(h[k], f"{key}.{k}", "length", 3, where, error)), "m", src(k))
        if "Cd" in h:
            link["Cd"] = _entry(_si(h["Cd"], key + ".Cd", "1", None, where, error), "1", src("Cd"))
    tf = model.frames[model.getFrameId(tool)]
    if model.names[tf.parentJoint] != moving[-1] if moving else True:
        raise error(f"{uwhere}: tool link '{tool}' does not move with the last joint")
    t = tf.placement.translation
    tsrc = f"{fname}: origin of link '{tool}'"
    out["tool"] = {"x": _entry(t[0], "m", tsrc), "y": _entry(t[1], "m", tsrc), "z": _entry(t[2], "m", tsrc)}
    new = dict(doc)
    new["arm"] = out
    return new
