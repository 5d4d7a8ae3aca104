"""A URDF arm in a system file (docs/system-file.md form 3), read by Pinocchio's URDF reader.

Why Pinocchio: it reads URDF with urdfdom, the ROS reference parser, it is maintained, and it merges
the bodies of fixed joints into their moving parent (parallel-axis theorem, frames placed) — the one
step of reading an arm that is easy to get wrong. It is also arvcas's independent reference for the
multibody tests, so the URDF path adds no new library. It is heavy (about 480 MB installed), so it is
the optional extra ``arvcas[urdf]``; the shipped systems need it not (their arms are written in the
file, forms 1 and 2). Pinocchio checks little (it takes prismatic joints, links without inertials and
indefinite tensors), so the raw XML is checked here first with the standard library: joint types on
the chain, an inertial on every moving link, the joint count.

The arm is the subtree of the URDF below ``base_link`` (a whole robot's URDF may be named: what is not
below the base is not read). The chain runs from ``base_link`` to ``tool_link``; every other joint of
the subtree must be fixed or *locked*: a gripper's fingers, a camera's pan joint. A locked joint
(``[arm.lock]``, or a joint whose limits admit one position, as uuv_simulator writes its "fixed"
sensor joints) is frozen at its angle and its body merged into its parent by Pinocchio's
``buildReducedModel`` (the parallel-axis theorem, frames placed). The base link's own inertial, and
whatever is rigid on it, is not part of the arm (:class:`ArmChain` reports it: ``base_mass``): the
vehicle's numbers must include it (``arvcas import-system`` adds it; docs/system-file.md).

:func:`convert` turns the ``[arm]`` of a form-3 document into the chain form (2), every number with a
source naming the URDF file and the joint or link it came from; :func:`arm_chain` does the same for a
parsed URDF and numbers already in SI (the importers of other tools' descriptions use it).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from dataclasses import dataclass
from typing import Any

import numpy as np

from arvcas.system import config, systemfile

__all__ = ["convert", "arm_chain", "subtree", "parse", "ArmChain", "SUPPORTED_JOINTS", "LOCKABLE_JOINTS"]

SUPPORTED_JOINTS = ("revolute", "continuous", "fixed")
LOCKABLE_JOINTS = ("revolute", "continuous", "prismatic")
_HYDRO_KEYS = ("volume", "cob", "drag_diameter", "drag_from", "drag_to", "Cd")
LOCKED_PREFIX = "locked joint "  # the name of a locked joint inside arvcas's copy of the URDF
_ARM_KEYS = ("urdf", "base_link", "tool_link", "tool_offset", "lock", "mount", "stow", "hydro", "trim")
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


def refuse_dtd(text, where: str, error) -> None:
    """Refuse (``error``, one line) XML with a document type declaration: a ``<!DOCTYPE>``, and with it
    every entity declaration, internal or external, is found by expat before any tree is built, so no
    entity is ever expanded (the "billion laughs" and external-entity attacks; defusedxml's
    ``forbid_dtd``). URDF, xacro and package.xml files have no DTD."""
    import xml.parsers.expat as expat

    class _DTD(Exception):
        pass

    def refuse(*_args):
        raise _DTD

    scan = expat.ParserCreate()
    scan.StartDoctypeDeclHandler = refuse
    scan.EntityDeclHandler = refuse
    scan.ExternalEntityRefHandler = refuse
    try:
        scan.Parse(text, True)
    except _DTD:
        raise error(f"{where}: has a document type declaration (<!DOCTYPE ...>); arvcas reads XML without one "
                    f"(it expands no entities)") from None
    except expat.ExpatError as e:
        raise error(f"{where}: malformed XML: {e}") from None


def parse(text: str, where: str, error) -> ET.Element:
    """The ``<robot>`` element of a URDF's text, parsed with no DTD (:func:`refuse_dtd`); one-line errors
    naming ``where``."""
    refuse_dtd(text, where, error)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise error(f"{where}: malformed XML: {e}") from None
    if root.tag != "robot":
        raise error(f"{where}: the root element is <{root.tag}>, a URDF has <robot>")
    return root


def limits(j: ET.Element) -> tuple[float, float] | None:
    """A joint's ``<limit lower upper>`` (None: no limit element, or no numbers there)."""
    lim = j.find("limit")
    if lim is None:
        return None
    try:
        return float(lim.get("lower", "0")), float(lim.get("upper", "0"))
    except ValueError:
        return None


def single_position(j: ET.Element) -> float | None:
    """The one position of a revolute or prismatic joint whose limits admit only one (lower == upper: how
    uuv_simulator writes a sensor's or an arm's anchor joint that Gazebo must not merge), else None."""
    lim = limits(j) if j.get("type") in ("revolute", "prismatic") else None
    return lim[0] if lim is not None and lim[0] == lim[1] else None


def subtree(root: ET.Element, base: str, where: str, error) -> ET.Element:
    """A URDF ``<robot>`` of ``base`` and the links below it with their joints, ``base`` its root."""
    links = {e.get("name"): e for e in root.findall("link")}
    if base not in links:
        raise error(f"{where}: link '{base}' is not in the URDF (links: {', '.join(list(links)[:12])})")
    below: dict[str, list[ET.Element]] = {}
    for j in root.findall("joint"):
        p, c = j.find("parent"), j.find("child")
        if p is None or c is None:
            raise error(f"{where}: joint '{j.get('name')}' has no <parent> or <child>")
        below.setdefault(p.get("link"), []).append(j)
    keep, joints, todo = {base}, [], [base]
    while todo:
        for j in below.get(todo.pop(), []):
            child = j.find("child").get("link")
            if child in keep:
                raise error(f"{where}: link '{child}' is reached twice (joint '{j.get('name')}'): not a tree")
            if child not in links:
                raise error(f"{where}: joint '{j.get('name')}' leads to link '{child}', which is not in the URDF")
            keep.add(child)
            joints.append(j)
            todo.append(child)
    out = ET.Element("robot", {"name": root.get("name", "arm")})
    out.extend(e for e in root.findall("link") if e.get("name") in keep)
    out.extend(joints)
    return out


def _chain(root: ET.Element, base: str, tool: str, locks: dict, where: str,
           error) -> tuple[list[ET.Element], dict[str, float]]:
    """The joints from ``base`` to ``tool`` in order and the locked joints' positions; the URDF (the
    subtree of ``base``) checked along the way. ``locks``: joint name -> (SI position, its key)."""
    links = {e.get("name"): e for e in root.findall("link")}
    if tool not in links:
        raise error(f"{where}: link '{tool}' is not below '{base}' (links below it: "
                    f"{', '.join(list(links)[:12])})")
    by_child = {j.find("child").get("link"): j for j in root.findall("joint")}
    path = []
    cur = tool
    while cur != base:
        j = by_child[cur]
        path.append(j)
        cur = j.find("parent").get("link")
    path.reverse()
    joints = {j.get("name"): j for j in root.findall("joint")}
    for name, (_, key) in locks.items():
        if name not in joints:
            raise error(f"{key}: no joint '{name}' below '{base}'{config.closest(name, joints)}")
    locked: dict[str, float] = {}
    for name, j in joints.items():
        kind = j.get("type")
        if name in locks:
            q, key = locks[name]
            if kind not in LOCKABLE_JOINTS:
                raise error(f"{key}: joint '{name}' is {kind}: only {', '.join(LOCKABLE_JOINTS)} joints are locked")
            lim = limits(j) if kind != "continuous" else None
            if lim is not None and not lim[0] - 1e-12 <= q <= lim[1] + 1e-12:
                raise error(f"{key}: {q:g} is outside joint '{name}''s limits [{lim[0]:g}, {lim[1]:g}]")
            locked[name] = q
        elif single_position(j) is not None:
            locked[name] = single_position(j)
    for name, j in joints.items():
        kind = j.get("type")
        if kind == "fixed" or name in locked:
            continue
        if kind not in SUPPORTED_JOINTS:
            raise error(f"{where}: joint '{name}' is of type '{kind}': supported joint types are "
                        f"{', '.join(SUPPORTED_JOINTS)} (a {', '.join(LOCKABLE_JOINTS)} joint may be locked: "
                        f"[arm.lock])")
        if j not in path:
            raise error(f"{where}: joint '{name}' moves a branch off the chain {base} -> {tool} (a gripper's "
                        f"finger?): lock it at a position ([arm.lock]), or end the chain there (tool_link)")
        if j.find("mimic") is not None:
            raise error(f"{where}: joint '{name}' mimics joint '{j.find('mimic').get('joint')}': a chain joint "
                        f"moves on its own; lock it ([arm.lock])")
    moving = [j for j in path if j.get("type") != "fixed" and j.get("name") not in locked]
    if len(moving) > systemfile.MAX_JOINTS:
        raise error(f"{where}: {len(moving)} revolute joints from {base} to {tool}, at most "
                    f"{systemfile.MAX_JOINTS} are supported")
    for j in moving:
        child = j.find("child").get("link")
        if links[child].find("inertial") is None:
            raise error(f"{where}: link '{child}' (moved by joint '{j.get('name')}') has no <inertial>: every "
                        f"moving link needs its mass and inertia")
    return path, locked


@dataclass(frozen=True)
class ArmChain:
    """An arm read from a URDF: ``arm``, the chain form's tables (``joint<i>``, ``link<i>``, ``tool``, entries
    ``{value, unit, source}``); ``joints``, the moving joints' names; ``locked``, the locked joints and their
    positions; ``base_mass``, ``base_com`` and ``base_inertia`` (about the com, base frame), the base link and
    everything rigid on it (fixed and locked joints), which are not part of the arm."""

    arm: dict
    joints: tuple[str, ...]
    locked: dict
    base_mass: float
    base_com: np.ndarray
    base_inertia: np.ndarray


def arm_chain(root: ET.Element, base: str, tool: str, fname: str, where: str, error, *, locks: dict | None = None,
              hydro: dict | None = None, tool_offset: tuple | None = None, hydro_where: str = "") -> ArmChain:
    """The arm of the URDF ``root`` from ``base`` to ``tool`` in the chain form (docs/system-file.md form 2).

    ``locks``: joint name -> (SI position, the key that gave it, for messages); ``hydro``: link name ->
    {key: (SI value, source)} with keys of :data:`_HYDRO_KEYS`, vectors in the link's frame; the entries of
    the links merged into one body add up (volumes; the centre of buoyancy is their volume-weighted mean;
    at most one drag segment); ``tool_offset``: (point in ``tool``'s frame, source). ``fname`` names the
    URDF in sources, ``where`` in messages, ``hydro_where`` the file of the hydro entries.
    """
    sub = subtree(root, base, where, error)
    chain, locked = _chain(sub, base, tool, locks or {}, where, error)
    try:
        import pinocchio as pin
    except ImportError:
        raise error(f"{hydro_where or where}: reading a URDF arm needs Pinocchio: pip install 'arvcas[urdf]'") from None
    for j in sub.findall("joint"):  # a locked joint becomes a frame: unnamed, it cannot clash with a link's
        if j.get("name") in locked:
            j.set("name", f"{LOCKED_PREFIX}{j.get('name')}")
    try:
        model = pin.buildModelFromXML(ET.tostring(sub, encoding="unicode"))
    except Exception as e:  # noqa: BLE001 (urdfdom's own message, one line)
        raise error(f"{where}: Pinocchio could not read it: {' '.join(str(e).split())}") from None
    if locked:
        q0 = pin.neutral(model)
        ids = [model.getJointId(LOCKED_PREFIX + n) for n in locked]
        for jid, q in zip(ids, locked.values()):
            jm = model.joints[jid]
            q0[jm.idx_q:jm.idx_q + jm.nq] = [math.cos(q), math.sin(q)] if jm.nq == 2 else [q]
        model = pin.buildReducedModel(model, ids, q0)
    moving = [j.get("name") for j in chain if j.get("type") != "fixed" and j.get("name") not in locked]
    names = list(model.names)[1:]
    if names != moving:
        raise error(f"{where}: the URDF's moving joints {names} are not the chain {base} -> {tool} {moving}: "
                    f"only a serial arm rooted at '{base}' is supported")
    out: dict[str, Any] = {}
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
            raise error(f"{where}: joint '{jname}': <axis xyz> must be three numbers, not all zero")
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
        lsrc = f"{fname}: inertials of the body moved by joint '{jname}' (fixed and locked children merged by Pinocchio)"
        out[f"link{i}"] = {
            "mass": _entry(I.mass, "kg", lsrc), "com": _entry(I.lever, "m", lsrc),
            "inertia": _entry([Ic[0, 0], Ic[1, 1], Ic[2, 2], Ic[0, 1], Ic[0, 2], Ic[1, 2]], "kg*m^2", lsrc),
            "volume": _entry(0.0, "m^3", "no [arm.hydro] entry for this body: no buoyancy"),
            "cob": _entry(I.lever, "m", "no [arm.hydro] entry: at the centre of mass"),
        }
    _merge_hydro(pin, model, moving, out, hydro or {}, fname, hydro_where or where, error)
    tf = model.frames[model.getFrameId(tool, pin.FrameType.BODY)]
    if not moving or model.names[tf.parentJoint] != moving[-1]:
        raise error(f"{where}: tool link '{tool}' does not move with the last joint")
    t = tf.placement.translation
    tsrc = f"{fname}: origin of link '{tool}'"
    if tool_offset is not None:
        t = tf.placement.act(np.asarray(tool_offset[0], dtype=float))
        tsrc = f"{tool_offset[1]} (the point in link '{tool}' of {fname}, moved into the frame of the last joint)"
    out["tool"] = {"x": _entry(t[0], "m", tsrc), "y": _entry(t[1], "m", tsrc), "z": _entry(t[2], "m", tsrc)}
    I0 = model.inertias[0]
    return ArmChain(out, tuple(moving), dict(locked), float(I0.mass), np.array(I0.lever),
                    np.array(I0.inertia))


def _merge_hydro(pin, model, moving: list[str], out: dict, hydro: dict, fname: str, where: str, error) -> None:
    """``[arm.hydro.<link>]`` (SI) moved into the frame of the joint that moves the link, per body summed."""
    bodies: dict[int, list] = {}
    for lname, h in hydro.items():
        key = f"arm.hydro.{lname}"
        if not model.existFrame(lname, pin.FrameType.BODY):
            raise error(f"{where}: {key}: '{lname}' is not a link of {fname} below the arm's base")
        fr = model.frames[model.getFrameId(lname, pin.FrameType.BODY)]
        jid = fr.parentJoint
        if jid == 0 or model.names[jid] not in moving:
            raise error(f"{where}: {key}: '{lname}' does not move with a joint of the arm (its buoyancy and drag "
                        f"belong to the vehicle)")
        bodies.setdefault(moving.index(model.names[jid]) + 1, []).append((lname, fr.placement, h))
    for i, entries in bodies.items():
        link = out[f"link{i}"]
        names = ", ".join(f"'{n}'" for n, _, _ in entries)

        def moved(src: str, lname: str) -> str:
            return f"{src} ({lname}, moved into the frame of joint {i})"

        vols = [(n, X, h) for n, X, h in entries if "volume" in h]
        if vols:
            link["volume"] = _entry(sum(h["volume"][0] for _, _, h in vols), "m^3",
                                    "; ".join(moved(h["volume"][1], n) for n, _, h in vols))
        cobs = [(n, X, h) for n, X, h in entries if "cob" in h]
        if len(entries) == 1 and cobs:
            n, X, h = cobs[0]
            link["cob"] = _entry(X.act(h["cob"][0]), "m", moved(h["cob"][1], n))
        elif len(entries) > 1:
            lack = [n for n, _, h in vols if h["volume"][0] > 0 and "cob" not in h]
            if lack:
                raise error(f"{where}: arm.hydro.{lack[0]}: links {names} are one body of the arm; each that has "
                            f"a volume needs its cob (their centre of buoyancy is the volume-weighted mean)")
            V = sum(h["volume"][0] for _, _, h in vols)
            if V > 0:
                c = sum(h["volume"][0] * X.act(h["cob"][0]) for _, X, h in vols) / V
                link["cob"] = _entry(c, "m", "volume-weighted mean of " + "; ".join(
                    moved(h["cob"][1], n) for n, _, h in vols if h["volume"][0] > 0))
        drags = [(n, X, h) for n, X, h in entries if any(k in h for k in ("drag_diameter", "drag_from", "drag_to"))]
        for n, X, h in drags:
            if not all(k in h for k in ("drag_diameter", "drag_from", "drag_to")):
                raise error(f"{where}: arm.hydro.{n}: a drag segment needs drag_diameter, drag_from and drag_to "
                            f"(or none)")
        if len(drags) > 1:
            raise error(f"{where}: arm.hydro: links {', '.join(repr(n) for n, _, _ in drags)} are one body of the "
                        f"arm and each has a drag segment: give one segment per body")
        for n, X, h in drags:
            link["drag_diameter"] = _entry(h["drag_diameter"][0], "m", moved(h["drag_diameter"][1], n))
            for k in ("drag_from", "drag_to"):
                link[k] = _entry(X.act(h[k][0]), "m", moved(h[k][1], n))
        cds = [(n, h) for n, _, h in entries if "Cd" in h]
        if len(cds) > 1:
            raise error(f"{where}: arm.hydro: links {', '.join(repr(n) for n, _ in cds)} are one body and each "
                        f"gives Cd: give one")
        for n, h in cds:
            link["Cd"] = _entry(h["Cd"][0], "1", moved(h["Cd"][1], n))


_HYDRO_DIMS = {"volume": ("volume", None), "cob": ("length", 3), "drag_diameter": ("length", None),
               "drag_from": ("length", 3), "drag_to": ("length", 3), "Cd": ("1", None)}


def convert(doc: dict, path: Path, error) -> dict:
    """``doc`` with its ``[arm]`` URDF (form 3) replaced by the chain form (2); ``error`` one line."""
    where = str(path)
    arm = dict(doc["arm"])
    for k in ("urdf", "base_link", "tool_link"):
        if not isinstance(arm.get(k), str):
            raise error(f"{where}: arm.{k}: expected a string (docs/system-file.md form 3)")
    extra = [k for k in arm if k not in _ARM_KEYS]
    if extra:
        raise error(f"{where}: arm.{extra[0]}: not a key of a URDF arm (allowed: {', '.join(_ARM_KEYS)})"
                    f"{config.closest(extra[0], _ARM_KEYS)}")
    upath = systemfile.rel_path(path, arm["urdf"])
    uwhere = str(upath)
    from arvcas.util.files import read_text

    root = parse(read_text(upath, "URDF file", error), uwhere, error)
    kinds = {j.get("name"): j.get("type") for j in root.findall("joint")}
    lock = arm.get("lock", {})
    if not isinstance(lock, dict):
        raise error(f"{where}: arm.lock: expected a table of joint names (\"name\" = {{ value, unit, source }})")
    locks = {}
    for name, e in lock.items():
        key = f"arm.lock.{name}"
        dim = "length" if kinds.get(name) == "prismatic" else "angle"
        locks[name] = (_si(e, key, dim, None, where, error), f"{where}: {key}")
    hydro = arm.get("hydro", {})
    if not isinstance(hydro, dict):
        raise error(f"{where}: arm.hydro: expected tables [arm.hydro.<link name>]")
    hyd = {}
    for lname, h in hydro.items():
        key = f"arm.hydro.{lname}"
        if not isinstance(h, dict):
            raise error(f"{where}: {key}: expected a table")
        bad = [k for k in h if k not in _HYDRO_KEYS]
        if bad:
            raise error(f"{where}: {key}.{bad[0]}: unknown key (allowed: {', '.join(_HYDRO_KEYS)})"
                        f"{config.closest(bad[0], _HYDRO_KEYS)}")
        hyd[lname] = {k: (_si(e, f"{key}.{k}", *_HYDRO_DIMS[k], where, error), e.get("source", ""))
                      for k, e in h.items()}
    offset = None
    if "tool_offset" in arm:
        e = arm["tool_offset"]
        offset = (_si(e, "arm.tool_offset", "length", 3, where, error), e.get("source", ""))
    fname = Path(arm["urdf"]).name
    got = arm_chain(root, arm["base_link"], arm["tool_link"], fname, uwhere, error, locks=locks, hydro=hyd,
                    tool_offset=offset, hydro_where=where)
    out = {k: v for k, v in arm.items() if k in ("mount", "stow", "trim")}
    out.update(got.arm)
    new = dict(doc)
    new["arm"] = out
    return new
