"""A uuv_simulator / Gazebo vehicle description imported as a system file (docs/importing.md).

uuv_simulator describes a vehicle by a URDF (usually xacro) in ROS's body frame, x forward, y left, z up
(FLU), with Gazebo plugins: the underwater-object plugin's Fossen model per link (``added_mass``,
``linear_damping``, ``linear_damping_forward_speed``, ``quadratic_damping``, ``volume``,
``center_of_buoyancy``; ``fluid_density``) and one thruster plugin per thruster (its joint's axis is the
thrust direction). arvcas's body frame is x forward, y starboard, z down (FRD). :func:`import_uuv` reads
such a description and writes the system file (docs/system-file.md) with the frame change done:

* ``T = diag(1, -1, -1)`` (a half turn about x, a proper rotation: ``T a x T b = T (a x b)``); positions,
  directions, centres and the inertia tensor change as ``r' = T r``, ``I' = T I T`` (Fossen's products
  ``Ixy = -I'[0,1] = ixy``, ``Ixz = -I'[0,2] = ixz``, ``Iyz = -I'[1,2] = -iyz`` from URDF's tensor elements);
  a thruster's column ``[d; r x d]`` becomes ``blkdiag(T, T)`` times it;
* the plugin's hydrodynamic matrices are taken as written: the plugin itself turns the link's FLU velocity
  into FRD (``HydrodynamicModel::ToNED``: y and z negated) before multiplying, and turns the force back, so
  its ``M_A`` and ``D`` are FRD matrices already (docs/importing.md §2 derives it).

The vehicle is the base link and every link rigid on it (fixed joints, joints whose limits admit one
position, the thrusters' propeller joints, joints locked with ``locks``), the arm's base link included:
their masses and inertias are summed about the base link's origin, the body origin. An arm (``arm_base``
to ``tool_link``) is read by :func:`arvcas.system.urdf.arm_chain` and written in the chain form (2), its
links' plugin volumes and centres of buoyancy as their buoyancy. What the format has no slot for is named
in the written file's header and in :attr:`Imported.notes`. Every number keeps a source naming the input
file and the element it came from.
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from arvcas.system import config, systemfile, urdf
from arvcas.system.rosfiles import ImportError_, rel_path, default_roots, expand, find_packages, read_max_thrust, read_tam

__all__ = ["import_uuv", "check_options", "Imported", "ImportError_", "T_FLU_FRD", "find_packages", "expand", "read_tam",
           "UNDERWATER_PLUGINS", "THRUSTER_PLUGINS"]

T_FLU_FRD = np.diag([1.0, -1.0, -1.0])  # ROS body (x fwd, y left, z up) -> arvcas body (x fwd, y stbd, z down)
UNDERWATER_PLUGINS = ("libuuv_underwater_object_ros_plugin.so", "libuuv_underwater_object_plugin.so")
THRUSTER_PLUGINS = ("libuuv_thruster_ros_plugin.so", "libuuv_thruster_plugin.so")
PLUGIN_DENSITY = 1028.0  # UnderwaterObjectPlugin.cc's fluidDensity when <fluid_density> is absent
SDF_GRAVITY = 9.8  # SDF's default world <gravity> 0 0 -9.8: uuv_simulator's worlds set none
_DOF = "XYZKMN"
_VEL = "uvwpqr"


@dataclass(frozen=True)
class Imported:
    """The result of an import: the system file's ``text``, its ``name``, what was not imported (``notes``),
    the thrusters' ``names`` and their allocation matrix in the description's own FLU frame (``B_flu``,
    6 x n, columns ``[d; r x d]``) for comparison with uuv_simulator's TAM.yaml, the links of the vehicle's
    body and the arm's moving joints (in the order of ``q``)."""

    text: str
    name: str
    notes: tuple[str, ...]
    thrusters: tuple[str, ...]
    B_flu: np.ndarray
    vehicle_links: tuple[str, ...] = field(default=())
    arm_joints: tuple[str, ...] = field(default=())


# ---- geometry ---------------------------------------------------------------------------------------------


def _floats(text: str | None, n: int, what: str, error) -> np.ndarray:
    try:
        v = np.array([float(x) for x in (text or "").split()])
    except ValueError:
        v = np.zeros(0)
    if v.shape != (n,) or not np.isfinite(v).all():
        raise error(f"{what}: expected {n} numbers, got {text!r}")
    return v


def _rpy(r, p, y) -> np.ndarray:
    """Rz(y) Ry(p) Rx(r) (URDF)."""
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _axis_angle(axis: np.ndarray, q: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(q) * K + (1 - math.cos(q)) * K @ K


def matrix_rpy(R: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) with R = Rz(yaw) Ry(pitch) Rx(roll)."""
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    if abs(R[2, 0]) < 1 - 1e-12:
        return math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])
    return math.atan2(-R[1, 2], R[1, 1]), pitch, 0.0  # gimbal lock: yaw folded into roll


def _origin(el: ET.Element | None, what: str, error) -> tuple[np.ndarray, np.ndarray]:
    """(R, p) of an ``<origin xyz rpy>`` (absent: identity)."""
    if el is None:
        return np.eye(3), np.zeros(3)
    p = _floats(el.get("xyz", "0 0 0"), 3, f"{what} <origin xyz>", error)
    r = _floats(el.get("rpy", "0 0 0"), 3, f"{what} <origin rpy>", error)
    return _rpy(*r), p


def _inertial(link: ET.Element, where: str, error) -> tuple[float, np.ndarray, np.ndarray]:
    """(mass, com, tensor about the com) of a link in its own frame; (0, 0, 0) without ``<inertial>``."""
    el = link.find("inertial")
    if el is None:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    name = link.get("name")
    R, c = _origin(el.find("origin"), f"{where}: link '{name}' <inertial>", error)
    try:
        m = float(el.find("mass").get("value"))
        a = {k: float(el.find("inertia").get(k, "0")) for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")}
    except (AttributeError, TypeError, ValueError):
        raise error(f"{where}: link '{name}' <inertial>: needs <mass value> and <inertia ixx .. iyz>") from None
    I = np.array([[a["ixx"], a["ixy"], a["ixz"]], [a["ixy"], a["iyy"], a["iyz"]], [a["ixz"], a["iyz"], a["izz"]]])
    return m, c, R @ I @ R.T


# ---- the description --------------------------------------------------------------------------------------


@dataclass
class _Robot:
    root: ET.Element
    where: str  # for messages
    src: str  # for sources
    links: dict
    joints: dict
    by_parent: dict
    parent_joint: dict  # child link -> joint
    underwater: dict  # link name -> <link> block of the underwater-object plugin
    density: tuple[float, str]
    thrusters: list  # (id, joint name, link name, plugin element)


def _robot(text: str, where: str, src: str, error) -> _Robot:
    root = urdf.parse(text, where, error)
    links = {e.get("name"): e for e in root.findall("link")}
    joints = {e.get("name"): e for e in root.findall("joint")}
    by_parent: dict[str, list] = {}
    parent_joint = {}
    for j in joints.values():
        p, c = j.find("parent"), j.find("child")
        if p is None or c is None or p.get("link") not in links or c.get("link") not in links:
            raise error(f"{where}: joint '{j.get('name')}': <parent link> and <child link> must name links of "
                        f"the URDF")
        by_parent.setdefault(p.get("link"), []).append(j)
        parent_joint[c.get("link")] = j
    underwater, density, thrusters = {}, None, []
    for g in root.findall("gazebo"):
        for pl in g.findall("plugin"):
            fn = pl.get("filename", "")
            if fn in UNDERWATER_PLUGINS:
                d = pl.findtext("fluid_density")
                if d is not None:
                    try:
                        density = (float(d), f"{src}: <plugin {pl.get('name')}> <fluid_density>")
                    except ValueError:
                        raise error(f"{where}: <plugin {pl.get('name')}> <fluid_density>: not a number: {d!r}") \
                            from None
                for lk in pl.findall("link"):
                    underwater[lk.get("name")] = lk
            elif fn in THRUSTER_PLUGINS:
                try:
                    tid = int(pl.findtext("thrusterID", "").strip())
                except ValueError:
                    raise error(f"{where}: thruster plugin '{pl.get('name')}': <thrusterID> must be an integer") \
                        from None
                jn = (pl.findtext("jointName") or "").strip()
                ln = (pl.findtext("linkName") or "").strip()
                if jn not in joints or joints[jn].find("child").get("link") != ln:
                    raise error(f"{where}: thruster plugin '{pl.get('name')}': <jointName> '{jn}' is not a joint "
                                f"of the URDF leading to <linkName> '{ln}'")
                thrusters.append((tid, jn, ln, pl))
    if density is None:
        density = (PLUGIN_DENSITY, "uuv_simulator's UnderwaterObjectPlugin default (no <fluid_density> in "
                                   f"{src})")
    ids = [t[0] for t in thrusters]
    if len(set(ids)) != len(ids):
        raise error(f"{where}: two thruster plugins have the same <thrusterID>")
    return _Robot(root, where, src, links, joints, by_parent, parent_joint, underwater, density, sorted(thrusters))


def _root_link(r: _Robot) -> str:
    roots = [n for n in r.links if n not in r.parent_joint]
    return roots[0] if len(roots) == 1 else ""


def _joint_pose(j: ET.Element, q: float, where: str, error) -> tuple[np.ndarray, np.ndarray]:
    """(R, p) of the child in the parent frame at position q."""
    R, p = _origin(j.find("origin"), f"{where}: joint '{j.get('name')}'", error)
    if j.get("type") in ("fixed",) or q == 0.0:
        return R, p
    ax = _floats((j.find("axis").get("xyz") if j.find("axis") is not None else "1 0 0"), 3,
                 f"{where}: joint '{j.get('name')}' <axis xyz>", error)
    if j.get("type") == "prismatic":
        return R, p + R @ (ax / np.linalg.norm(ax) * q)
    return R @ _axis_angle(ax, q), p


@dataclass
class _Body:
    """The vehicle body: its links with their pose in the base link's frame (FLU), summed mass properties."""

    poses: dict  # link -> (R, p)
    via: dict  # link -> how it is attached (for sources)
    mass: float = 0.0
    first: np.ndarray = field(default_factory=lambda: np.zeros(3))
    second: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))  # tensor about the origin


def _vehicle(r: _Robot, base: str, arm_base: str | None, locks: dict, error) -> _Body:
    """The links rigid on ``base`` (the arm's stop at its first moving joints) and their mass properties."""
    thruster_joints = {t[1] for t in r.thrusters}
    body = _Body({base: (np.eye(3), np.zeros(3))}, {base: "the base link"})
    arm_sub = set()
    if arm_base is not None:
        sub = urdf.subtree(r.root, arm_base, r.where, error)
        arm_sub = {e.get("name") for e in sub.findall("joint")}
    todo = [base]
    while todo:
        parent = todo.pop()
        Rp, pp = body.poses[parent]
        for j in r.by_parent.get(parent, []):
            name, kind, child = j.get("name"), j.get("type"), j.find("child").get("link")
            single = urdf.single_position(j)
            if kind == "fixed":
                q, how = 0.0, f"fixed joint '{name}'"
            elif single is not None:
                q, how = single, f"joint '{name}', one position"
            elif name in locks:
                q, how = locks[name][0], f"joint '{name}' locked at {locks[name][0]:g}"
            elif name in thruster_joints:
                q, how = 0.0, f"thruster joint '{name}'"
            elif name in arm_sub:
                continue  # the arm's first moving joint: the arm begins
            else:
                hint = "" if arm_base is None else f" or below the arm's base '{arm_base}'"
                raise error(f"{r.where}: joint '{name}' ({kind}) moves link '{child}' on the vehicle: it is no "
                            f"thruster's and not in the arm{hint}; lock it (--lock {name}=POSITION) or import "
                            f"it as the arm (--arm-base)")
            R, p = _joint_pose(j, q, r.where, error)
            body.poses[child] = (Rp @ R, pp + Rp @ p)
            body.via[child] = how
            todo.append(child)
    if arm_base is not None and arm_base not in body.poses:
        raise error(f"{r.where}: the arm's base link '{arm_base}' is not rigid on the vehicle's base link '{base}' "
                    f"(a moving joint lies between them)")
    for name, (R, p) in body.poses.items():
        m, c, Ic = _inertial(r.links[name], r.where, error)
        if m == 0.0:
            continue
        cb = p + R @ c
        body.mass += m
        body.first += m * cb
        body.second += R @ Ic @ R.T + m * (cb @ cb * np.eye(3) - np.outer(cb, cb))
    return body


# ---- writing ----------------------------------------------------------------------------------------------


def _q(s: str) -> str:
    return json.dumps(s, ensure_ascii=False)


def _num(x: float) -> str:
    x = float(x)
    if x == 0.0:
        x = 0.0  # no "-0.0" in the file
    return repr(x)


def _e(value, unit: str, source: str) -> str:
    v = "[" + ", ".join(_num(x) for x in value) + "]" if np.ndim(value) else _num(value)
    return f"{{ value = {v}, unit = {_q(unit)}, source = {_q(source)} }}"


def _entry_line(key: str, entry: dict) -> str:
    return f"{key} = {_e(entry['value'], entry['unit'], entry['source'])}"


def _comment(text: str, width: int = 100) -> list[str]:
    out, line = [], "#"
    for w in " ".join(text.split()).split(" "):
        if len(line) + 1 + len(w) > width and line != "#":
            out.append(line)
            line = "#  "
        line += " " + w
    return out + [line]


def _hydro_vector(lk: ET.Element, tag: str, where: str, error) -> np.ndarray | None:
    t = lk.find("hydrodynamic_model").findtext(tag) if lk.find("hydrodynamic_model") is not None else None
    if t is None:
        return None
    try:
        v = np.array([float(x) for x in t.split()])
    except ValueError:
        v = np.zeros(0)
    if v.size not in (6, 36) or (tag == "added_mass" and v.size != 36) or not np.isfinite(v).all():
        n = "36" if tag == "added_mass" else "6 or 36"
        raise error(f"{where}: <link {lk.get('name')}> <{tag}>: expected {n} numbers")
    return v.reshape(6, 6) if v.size == 36 else np.diag(v)


def _volume(r: _Robot, lk: ET.Element, where: str, error) -> tuple[float, np.ndarray, str, str]:
    """(volume, centre of buoyancy in the link frame, their sources) of a plugin's <link> block."""
    name = lk.get("name")
    blk = f"{r.src}: <plugin uuv_plugin> <link {name}>"
    nb = (lk.findtext("neutrally_buoyant") or "0").strip().lower() in ("1", "true")
    if lk.find("metacentric_width") is not None:
        raise error(f"{where}: <link {name}>: a surface vessel (metacentric_width ...): arvcas models a submerged "
                    f"vehicle only")
    if nb:
        m = _inertial(r.links[name], where, error)[0]
        V, vsrc = m / r.density[0], f"{blk} <neutrally_buoyant> 1: V = m / rho of the link's <inertial>"
    else:
        try:
            V = float(lk.findtext("volume"))
        except (TypeError, ValueError):
            raise error(f"{where}: <link {name}> <volume>: expected a number") from None
        vsrc = f"{blk} <volume>"
    cob = lk.findtext("center_of_buoyancy")
    c = _floats(cob, 3, f"{where}: <link {name}> <center_of_buoyancy>", error) if cob else np.zeros(3)
    csrc = f"{blk} <center_of_buoyancy>" if cob else f"{blk}: no <center_of_buoyancy> (the plugin's default, the " \
                                                      f"link origin)"
    return V, c, vsrc, csrc


def check_options(arm_base, tool_link, tool_offset, stow, max_thrust, thruster_manager, gravity,
                  error=ImportError_) -> None:
    """The options of an import that contradict each other or are out of range (named as on the command line)."""
    if (tool_link is None) != (arm_base is None):
        raise error("--arm-base and --tool-link go together (the arm runs from one to the other)")
    if arm_base is None and (tool_offset is not None or stow is not None):
        raise error(f"{'--tool-offset' if tool_offset is not None else '--stow'}: describes an arm: only with "
                    f"--arm-base and --tool-link")
    if gravity is not None and not (math.isfinite(gravity) and gravity > 0):
        raise error(f"--gravity: expected a positive number of m/s^2, got {gravity!r}")
    if max_thrust is not None and not (math.isfinite(max_thrust) and max_thrust > 0):
        raise error(f"--max-thrust: expected a positive number of N, got {max_thrust!r}")
    if max_thrust is not None and thruster_manager is not None:
        raise error("--max-thrust: the thrust limit is given twice (also --thruster-manager): give one")


def import_uuv(description: str | Path, *, name: str | None = None, base_link: str | None = None,
               arm_base: str | None = None, tool_link: str | None = None, tool_offset=None,
               locks: dict[str, float] | None = None, stow=None, max_thrust: float | None = None,
               thruster_manager: str | Path | None = None, gravity: float | None = None,
               ros_paths=(), xacro_args: dict[str, str] | None = None, cite: str = "",
               error=ImportError_) -> Imported:
    """A uuv_simulator vehicle (a URDF or xacro file, or a description package's folder) as a system file.

    ``arm_base`` / ``tool_link``: import the arm between them (the chain form; joints off the chain, e.g.
    fingers, locked with ``locks``: joint name -> (position in rad or m, what gave it), which also holds
    any other joint of the vehicle); ``tool_offset``: the tool point in
    ``tool_link``'s frame (m); ``stow``: the arm's stow pose (rad; default the zero pose, clipped to the
    limits). Thrust limits: the thruster plugins' ``thrustMin``/``thrustMax``, else ``max_thrust`` (N),
    else ``thruster_manager.yaml``'s ``max_thrust``. ``gravity`` (m/s^2): the world's (default 9.8, SDF's).
    ``ros_paths``: folders holding the ROS packages that ``$(find ...)`` names. ``cite`` is put before every
    source (e.g. the repository and commit). Every input is checked before any work; faults are one line.
    """
    check_options(arm_base, tool_link, tool_offset, stow, max_thrust, thruster_manager, gravity, error)
    if name is not None and not systemfile.NAME_RE.match(name):
        raise error(f"--name {name!r}: must match [a-z][a-z0-9_]* (it names compiled code and files)")
    path = _description_file(Path(description), error)
    locks = dict(locks or {})
    roots = [Path(p) for p in ros_paths] or default_roots(path)
    for rp in roots:
        if not rp.is_dir():
            raise error(f"--ros-path {rp}: not a directory")
    rel = rel_path(path)
    src = (f"{cite}, " if cite else "") + rel
    packages = find_packages(roots, error) if path.suffix == ".xacro" or ".xacro" in path.name else {}
    text, includes = expand(path, packages, xacro_args or {}, error)
    r = _robot(text, str(path), src + (" (xacro)" if includes or path.suffix == ".xacro" else ""), error)
    src = r.src
    base = base_link or _root_link(r)
    if base not in r.links:
        raise error(f"{path}: base link {base!r} is not a link of the URDF{config.closest(base or '', r.links)}"
                    if base else f"{path}: the URDF has several root links: name the vehicle's with --base-link")
    if base not in r.underwater:
        raise error(f"{path}: link '{base}' has no block in a uuv underwater-object plugin ({UNDERWATER_PLUGINS[0]}): "
                    f"no hydrodynamic model to import")
    for j, (v, _) in locks.items():
        if j not in r.joints:
            raise error(f"--lock {j}: no joint '{j}' in {path.name}{config.closest(j, r.joints)}")
    if arm_base is not None:
        for lk in (arm_base, tool_link):
            if lk not in r.links:
                raise error(f"{path}: link {lk!r} is not in the URDF{config.closest(lk, r.links)}")
    n_thr = len(r.thrusters)
    if n_thr < 6:
        raise error(f"{path}: {n_thr} thruster plugins ({THRUSTER_PLUGINS[0]}): arvcas needs at least 6 thrusters "
                    f"that produce every wrench (fins and rudders are not modelled)")
    limits = _thrust_limits(r, max_thrust, thruster_manager, error)

    body = _vehicle(r, base, arm_base, locks, error)
    notes: list[str] = []
    lines: list[str] = []
    T = T_FLU_FRD
    # --- mass properties (FLU about the base link's origin) -> FRD
    m = body.mass
    if m <= 0:
        raise error(f"{path}: link '{base}' and the links rigid on it have no mass (<inertial>)")
    cg = T @ (body.first / m)
    I = T @ body.second @ T
    massive = [n for n in body.poses if _inertial(r.links[n], r.where, error)[0] > 0]
    msrc = (f"{src}: <inertial> of '{base}'" + (f" and the {len(massive) - 1} links rigid on it (this file's header)"
                                               if len(massive) > 1 else "") + ", summed about its origin")
    # --- buoyancy: the plugin blocks of the vehicle's links
    V, first, vsrcs = 0.0, np.zeros(3), []
    for ln, (R, p) in body.poses.items():
        if ln in r.underwater:
            v, c, vs, cs = _volume(r, r.underwater[ln], str(path), error)
            V += v
            first += v * (T @ (p + R @ c))
            vsrcs.append(f"{vs}; {cs}" if ln != base else vs)
    cb = first / V if V > 0 else np.zeros(3)
    shapes = [f"'{n}' ({r.underwater[n].findtext('hydrodynamic_model/type', '').strip()})" for n in body.poses
              if n != base and n in r.underwater and r.underwater[n].find("hydrodynamic_model") is not None]
    if shapes:
        notes.append("the hydrodynamic models of " + ", ".join(shapes) + ", rigid on the vehicle: their volumes and "
                     "centres of buoyancy join the vehicle's")
    bsrc = "; ".join(vsrcs)
    cobsrc = f"{src}: <center_of_buoyancy> of the plugin blocks of links " + ", ".join(
        f"'{n}'" for n in body.poses if n in r.underwater) + (" (volume-weighted)" if len(vsrcs) > 1 else "") + \
        ", y and z negated (FLU -> FRD)"
    uw = r.underwater[base]
    hm = uw.find("hydrodynamic_model")
    kind = hm.findtext("type", "").strip() if hm is not None else ""
    if kind != "fossen":
        raise error(f"{path}: <link {base}> <hydrodynamic_model> <type> is {kind!r}: only 'fossen' is imported "
                    f"(the plugin's other types compute their own coefficients from a shape)")

    # --- header
    sys_name = name or _sanitise(r.root.get("name", "") or path.stem)
    if not systemfile.NAME_RE.match(sys_name):
        raise error(f"--name {sys_name!r}: must match [a-z][a-z0-9_]* (it names compiled code and files)")
    intro = _comment(f"Imported by `arvcas import-system uuv` from {src} (uuv_simulator / Gazebo), robot "
                     f"'{r.root.get('name', '')}'. docs/importing.md describes the conversion.")
    if includes:
        intro += _comment("xacro included: " + ", ".join(_short(p, packages) for p in includes) + ".")
    intro += _comment("Frames: the description is in ROS's body frame (x forward, y left, z up); this file in "
                      "arvcas's (x forward, y starboard, z down): r' = T r, I' = T I T with T = diag(1, -1, -1). "
                      f"The body origin is the origin of link '{base}'. The plugin's added-mass and "
                      "damping matrices act on the velocity in x forward, y starboard, z down already "
                      "(HydrodynamicModel::ToNED), so they are written unchanged.")
    intro += _comment("The vehicle's body (a thruster's propeller spin is not modelled): " + "; ".join(
        f"'{n}' ({_inertial(r.links[n], r.where, error)[0]:g} kg, {body.via[n]})" for n in body.poses) + ".")
    desc = f"{r.root.get('name') or sys_name} imported from {rel} (uuv_simulator)"
    lines += ["[system]", f"name = {_q(sys_name)}", f"description = {_q(desc)}", ""]
    g = (gravity, "--gravity") if gravity is not None else (SDF_GRAVITY, "Gazebo's world gravity: SDF's default "
                                                            "<gravity> 0 0 -9.8 (uuv_simulator's worlds set none)")
    lines += ["[env]", f"rho = {_e(r.density[0], 'kg/m^3', r.density[1])}", f"g = {_e(g[0], 'm/s^2', g[1])}",
              f"Cd = {_e(0.0, '1', 'unused: no arm link has a drag segment (the plugin models of arm links are not imported, docs/importing.md)')}",
              ""]
    lines += ["[vehicle]", f"m = {_e(m, 'kg', msrc)}", f"volume = {_e(V, 'm^3', bsrc)}"]
    isrc = msrc + "; T I T, Fossen's products of inertia (the tensor has -Ixy off the diagonal)"
    for k, val in (("Ixx", I[0, 0]), ("Iyy", I[1, 1]), ("Izz", I[2, 2]), ("Ixy", -I[0, 1]), ("Iyz", -I[1, 2]),
                   ("Ixz", -I[0, 2])):
        lines.append(f"{k} = {_e(val, 'kg*m^2', isrc)}")
    for k, val in zip(("xG", "yG", "zG"), cg):
        lines.append(f"{k} = {_e(val, 'm', msrc + ': centre of mass, y and z negated (FLU -> FRD)')}")
    for k, val in zip(("xB", "yB", "zB"), cb):
        lines.append(f"{k} = {_e(val, 'm', cobsrc)}")
    lines.append("")
    lines += _hydro(uw, f"{src}: <plugin uuv_plugin> <link {base}> <hydrodynamic_model>", str(path), notes, error)
    B = np.zeros((6, n_thr))
    names = []
    dyn_lines, unit_dyn = _thruster_dynamics(r, limits, notes, error)
    lines += dyn_lines
    for k, (tid, jn, ln, pl) in enumerate(r.thrusters):
        j = r.joints[jn]
        parent = j.find("parent").get("link")
        if parent not in body.poses:
            raise error(f"{path}: thruster joint '{jn}' hangs on link '{parent}', which is not rigid on '{base}'")
        Rp, pp = body.poses[parent]
        R, p = _joint_pose(j, 0.0, r.where, error)
        ax = _floats(j.find("axis").get("xyz") if j.find("axis") is not None else "1 0 0", 3,
                     f"{path}: joint '{jn}' <axis xyz>", error)
        d = Rp @ R @ (ax / np.linalg.norm(ax))
        pos = pp + Rp @ p
        B[:, k] = np.concatenate([d, np.cross(pos, d)])
        tname = f"thruster_{tid}"
        names.append(tname)
        tsrc = f"{src}: joint '{jn}' (thruster plugin '{pl.get('name')}')"
        lines += ["[[thrusters.unit]]", f"name = {_q(tname)}",
                  f"position = {_e(T @ pos, 'm', tsrc + ' <origin xyz>, y and z negated (FLU -> FRD)')}",
                  f"direction = {_e(T @ d, '1', tsrc + ' <axis> turned by its <origin rpy>, y and z negated')}",
                  f"u_min = {_e(-limits[k][0], 'N', limits[k][1])}", f"u_max = {_e(limits[k][0], 'N', limits[k][1])}",
                  ""]
        if limits[k][2] is not None:
            lines[-3] = f"u_min = {_e(limits[k][2][0], 'N', limits[k][1])}"
            lines[-2] = f"u_max = {_e(limits[k][2][1], 'N', limits[k][1])}"
        lines[-1:-1] = unit_dyn[k]
    arm_joints: tuple[str, ...] = ()
    if arm_base is not None:
        arm_lines, arm_joints = _arm(r, body, arm_base, tool_link, tool_offset, locks, stow, src, notes, error)
        lines += arm_lines
    intro += ["#", "# Not imported (the system file has no slot for it; docs/importing.md):"]
    for n in notes:
        intro += [("#  - " if i == 0 else "#    ") + x[2:].lstrip() for i, x in enumerate(_comment(n, 94))]
    text_out = "\n".join(intro + [""] + lines) + "\n"
    return Imported(text_out, sys_name, tuple(notes), tuple(names), B, tuple(body.poses), arm_joints)


def _sanitise(s: str) -> str:
    out = "".join(c if c.isalnum() else "_" for c in s.lower()).strip("_")
    return out if out and out[0].isalpha() else "imported"


def _short(p: str, packages: dict[str, Path]) -> str:
    rp = Path(p).resolve()
    for n, d in packages.items():
        try:
            return f"{n}/{rp.relative_to(d.resolve())}"
        except ValueError:
            continue
    return rp.name


def _description_file(p: Path, error) -> Path:
    """The robot file: ``p`` itself, or in a description package's folder its ``robots/`` (``urdf/``) file
    named ``*default*``, or the only one."""
    from arvcas.util.files import check_input

    if p.is_dir():
        cands = sorted(x for d in ("robots", "urdf", ".") for x in (p / d).glob("*")
                       if x.is_file() and x.name.endswith((".urdf", ".xacro")))
        top = [x for x in cands if x.parent.name == "robots"] or cands
        pick = [x for x in top if "default" in x.name] if len(top) > 1 else top
        if len(pick) != 1:
            found = ", ".join(x.name for x in top[:8]) or "no .urdf or .xacro file in robots/ or urdf/"
            raise error(f"{p}: a folder: name the robot file ({found})")
        return pick[0]
    return check_input(p, "robot description", error)


def _thrust_limits(r: _Robot, max_thrust, manager, error) -> list[tuple[float, str, tuple | None]]:
    """Per thruster (limit, source, (min, max) or None): the plugin's thrustMin/Max, else the option's."""
    out = []
    need = []
    for k, (tid, jn, ln, pl) in enumerate(r.thrusters):
        lo, hi = pl.findtext("thrustMin"), pl.findtext("thrustMax")
        if lo is not None and hi is not None:
            try:
                lo_v, hi_v = float(lo), float(hi)
            except ValueError:
                raise error(f"{r.where}: thruster plugin '{pl.get('name')}': thrustMin/thrustMax must be numbers") \
                    from None
            if lo_v < hi_v:
                out.append((hi_v, f"{r.src}: thruster plugin '{pl.get('name')}' <thrustMin> <thrustMax>",
                            (lo_v, hi_v)))
                continue
        out.append(None)
        need.append(k)
    if need:
        if max_thrust is not None:
            vals, s = [max_thrust] * len(r.thrusters), "--max-thrust"
        elif manager is not None:
            vals = read_max_thrust(Path(manager), len(r.thrusters), error)
            s = f"{rel_path(Path(manager))}: thruster_manager.max_thrust (the thruster manager clips each thrust to +- it)"
        else:
            raise error(f"{r.where}: the thruster plugins give no thrustMin/thrustMax: give the thrust limit with "
                        f"--thruster-manager thruster_manager.yaml (its max_thrust) or --max-thrust N")
        for k in need:
            out[k] = (vals[k], s, None)
    return out


def _hydro(uw: ET.Element, src: str, where: str, notes: list, error) -> list[str]:
    """The [hydro] section from the plugin's Fossen model (its matrices are FRD: see the module docstring)."""
    out = ["[hydro]"]
    out += _comment("uuv_simulator's Fossen model always adds the added-mass Coriolis forces C_A(nu) of its added "
                    "mass (HMFossen::ComputeAddedCoriolisMatrix); arvcas builds them from the symmetric part of M_A.")
    out.append("coriolis_added_mass = true")
    Ma = _hydro_vector(uw, "added_mass", where, error)
    if Ma is None:
        raise error(f"{where}: <link {uw.get('name')}> <hydrodynamic_model>: no <added_mass>")
    zero = 0
    for i in range(6):
        for k in range(6):
            if Ma[i, k] != 0.0:
                out.append(f"{_DOF[i]}_{_VEL[k]}dot = {_e(-Ma[i, k], 'SI', f'{src} <added_mass>[{i},{k}]: M_A[{i},{k}] = {_num(Ma[i, k])} (kg, kg m, kg m^2), the coefficient is -M_A')}")
            else:
                zero += 1
    D = _hydro_vector(uw, "linear_damping", where, error)
    Df = _hydro_vector(uw, "linear_damping_forward_speed", where, error)
    Dq = _hydro_vector(uw, "quadratic_damping", where, error)
    for mat, tag, form in ((D, "linear_damping", "{F}_{v}"), (Df, "linear_damping_forward_speed", "{F}_{v}_u")):
        if mat is None:
            continue
        for i in range(6):
            for k in range(6):
                if mat[i, k] != 0.0:
                    key = form.format(F=_DOF[i], v=_VEL[k])
                    out.append(f"{key} = {_e(mat[i, k], 'SI', f'{src} <{tag}>[{i},{k}]: the force adds this times the velocity' + (' times u' if Df is mat else ''))}")
    if Dq is not None:
        for i in range(6):
            if Dq[i, i] != 0.0:
                out.append(f"{_DOF[i]}_{_VEL[i]}_abs{_VEL[i]} = {_e(Dq[i, i], 'SI', f'{src} <quadratic_damping>[{i},{i}]: the force adds this times the velocity times its absolute value')}")
        off = Dq - np.diag(np.diag(Dq))
        if np.any(off != 0):
            notes.append("the quadratic_damping's off-diagonal entries: uuv_simulator's own Fossen model uses only "
                         "the diagonal (HMFossen::ComputeDampingMatrix)")
    if zero:
        out += _comment(f"{zero} zero entries of <added_mass> are not written.")
    asym = float(np.abs(Ma - Ma.T).max())
    if asym > 0:
        notes.append(f"the added mass's asymmetry in C_A: the plugin's C_A(nu) uses M_A as written, arvcas's its "
                     f"symmetric part (largest |M_A - M_A'| here: {asym:.6g})")
    notes.append("the plugin's acceleration filter (its added-mass force uses a filtered finite difference of the "
                 "velocity; arvcas's M_A acts on the exact acceleration)")
    out.append("")
    return out


DYNAMICS = ("ZeroOrder", "FirstOrder")  # uuv_simulator's thruster dynamics arvcas represents (docs/model.md §9)
CONVERSIONS = ("Basic",)  # and its conversions from the dynamics' state to thrust


def _plugin_float(pl: ET.Element, tag: str, where: str, error, default=None, parent: ET.Element | None = None):
    el = (parent if parent is not None else pl).find(tag)
    if el is None:
        if default is None:
            raise error(f"{where}: thruster plugin '{pl.get('name')}': <{tag}> is missing")
        return default
    try:
        v = float((el.text or "").strip())
    except ValueError:
        raise error(f"{where}: thruster plugin '{pl.get('name')}': <{tag}> must be a number, got "
                    f"{(el.text or '').strip()!r}") from None
    if not math.isfinite(v):
        raise error(f"{where}: thruster plugin '{pl.get('name')}': <{tag}> must be finite, got {v}")
    return v


def _thruster_dynamics(r: _Robot, limits, notes: list, error) -> tuple[list[str], list[list[str]]]:
    """uuv_simulator's thruster models (ThrusterPlugin.cc) as arvcas's thruster dynamics (docs/model.md §9).

    The plugin sends ``x = gain * clamp(input, clampMin, clampMax)`` through its dynamics, multiplies the
    state by ``propeller_efficiency`` and converts it to thrust, times ``thrust_efficiency``. ``FirstOrder``
    (``state += (1 - exp(-dt / timeConstant)) (x - state)``: the exact step of arvcas's lag) with the
    ``Basic`` conversion (``rotorConstant * |s| * s``) is arvcas's quadratic map with the command ``x`` in
    rad/s: ``k = thrust_efficiency * propeller_efficiency^2 * rotorConstant``, the command range
    ``gain * [clampMin, clampMax]`` (without clamps, the rotor speed of the thrust limits, rounded up), no
    dead band, and the lag's time constant. ``ZeroOrder`` thrusters are instantaneous (arvcas allocates
    thrust; the conversion then plays no part). Any other dynamics or conversion is refused, as are
    thrusters of which some have dynamics and others not. Returns the map sections and each thruster's
    ``map`` and ``time_constant`` lines."""
    where = r.where
    kinds = []
    for tid, jn, ln, pl in r.thrusters:
        d = pl.find("dynamics")
        t = (d.findtext("type") or "").strip() if d is not None else "ZeroOrder"
        if t not in DYNAMICS:
            raise error(f"{where}: thruster plugin '{pl.get('name')}': <dynamics> <type> {t!r}: arvcas represents "
                        f"{' or '.join(DYNAMICS)} (a first-order lag with <timeConstant>; docs/importing.md)")
        kinds.append(t)
    empty = ([], [[] for _ in r.thrusters])
    if set(kinds) == {"ZeroOrder"}:
        convs = sorted({(pl.findtext("conversion/type") or "").strip() for *_, pl in r.thrusters} - {""})
        if convs:
            notes.append("the thrusters' conversion to thrust (" + ", ".join(convs) + "): with ZeroOrder dynamics "
                         "the thrust follows the command at once and arvcas allocates thrust")
        return empty
    if len(set(kinds)) > 1:
        first = [pl.get("name") for (*_, pl), k in zip(r.thrusters, kinds) if k == "FirstOrder"][0]
        other = [pl.get("name") for (*_, pl), k in zip(r.thrusters, kinds) if k != "FirstOrder"][0]
        raise error(f"{where}: thruster plugin '{other}' has ZeroOrder dynamics and '{first}' FirstOrder: arvcas "
                    f"gives every thruster dynamics or none (docs/system-file.md)")
    maps: dict[tuple, str] = {}
    sections, per_unit = [], []
    for k, (tid, jn, ln, pl) in enumerate(r.thrusters):
        name = pl.get("name")
        psrc = f"{r.src}: thruster plugin '{name}'"
        dyn = pl.find("dynamics")
        tc = _plugin_float(pl, "timeConstant", where, error, parent=dyn)
        if not tc > 0:
            raise error(f"{where}: thruster plugin '{name}': <dynamics> <timeConstant> must be > 0 s, got {tc:g}")
        conv = pl.find("conversion")
        ct = (conv.findtext("type") or "").strip() if conv is not None else ""
        if ct not in CONVERSIONS:
            raise error(f"{where}: thruster plugin '{name}': <conversion> <type> {ct!r}: arvcas represents "
                        f"{' or '.join(CONVERSIONS)} (thrust = rotorConstant * |x| * x; docs/importing.md)")
        rc = _plugin_float(pl, "rotorConstant", where, error, parent=conv)
        gain = _plugin_float(pl, "gain", where, error, default=1.0)
        eff_t = _plugin_float(pl, "thrust_efficiency", where, error, default=1.0)
        eff_p = _plugin_float(pl, "propeller_efficiency", where, error, default=1.0)
        # the plugin resets an efficiency outside [0, 1] to 1 (ThrusterPlugin::Load)
        eff_t, eff_p = (e if 0.0 <= e <= 1.0 else 1.0 for e in (eff_t, eff_p))
        kk = eff_t * eff_p ** 2 * rc
        if not (kk > 0 and gain > 0):
            raise error(f"{where}: thruster plugin '{name}': rotorConstant, gain and the efficiencies must be > 0")
        ksrc = psrc + " <conversion> Basic <rotorConstant>"
        if (eff_t, eff_p) != (1.0, 1.0):
            ksrc += f" times thrust_efficiency {eff_t:g} and propeller_efficiency^2 ({eff_p:g}^2)"
        cmin, cmax = (_plugin_float(pl, t, where, error, default=math.nan) for t in ("clampMin", "clampMax"))
        if math.isfinite(cmin) and math.isfinite(cmax) and cmin < cmax:
            lo, hi = gain * cmin, gain * cmax
            csrc = psrc + " <clampMin> <clampMax>" + (f" times <gain> {gain:g}" if gain != 1.0 else "")
        else:  # no clamp: the rotor speeds of the thrust limits (the plugin clips the thrust to them)
            u_lo, u_hi = limits[k][2] if limits[k][2] is not None else (-limits[k][0], limits[k][0])
            hi = _speed_of(u_hi, kk) if u_hi > 0 else _speed_of(-u_lo, kk)
            lo = -_speed_of(-u_lo, kk) if u_lo < 0 else -hi
            csrc = (f"the rotor speed of the thrust limits sqrt(|u| / k) ({limits[k][1]}), rounded up: the plugin "
                    f"sets no <clampMin>/<clampMax>")
        key = (kk, lo, hi)
        if key not in maps:
            maps[key] = "basic" if not maps else f"basic_{len(maps) + 1}"
            sections += [f"[thrusters.map.{maps[key]}]", 'command_unit = "rad/s"',
                         f"rotor_constant = {_e(kk, 'N*s^2/rad^2', ksrc)}",
                         f"command_min = {_e(lo, 'rad/s', csrc)}", f"command_max = {_e(hi, 'rad/s', csrc)}",
                         f"dead_band = {_e(0.0, 'rad/s', 'uuv_simulator Basic conversion: no dead band')}", ""]
        per_unit.append([f"map = {_q(maps[key])}",
                         f"time_constant = {_e(tc, 's', psrc + ' <dynamics> FirstOrder <timeConstant>')}"])
    return sections, per_unit


def _speed_of(thrust: float, k: float) -> float:
    """The rotor speed whose thrust ``k c^2`` reaches ``thrust`` (> 0), rounded up to 6 significant digits."""
    c = math.sqrt(thrust / k)
    e = math.floor(math.log10(c)) - 5
    out = float(f"{math.ceil(c / 10.0 ** e) * 10.0 ** e:.6g}")
    while k * out * out < thrust:  # rounding: one more in the last digit
        out = float(f"{out + 10.0 ** e:.6g}")
    return out


def _arm(r: _Robot, body: _Body, arm_base: str, tool: str, tool_offset, locks: dict, stow, src: str,
         notes: list, error) -> tuple[list[str], tuple[str, ...]]:
    """The [arm] (chain form), its mount (FRD), stow pose and hydro, and [payload]; the moving joints."""
    T = T_FLU_FRD
    hydro = {}
    for ln, lk in r.underwater.items():
        if ln in body.poses or ln not in r.links:
            continue
        V, c, vs, cs = _volume(r, lk, r.where, error)
        hydro[ln] = {"volume": (V, vs), "cob": (c, cs)}
    sub = urdf.subtree(r.root, arm_base, r.where, error)
    sub_links = {e.get("name") for e in sub.findall("link")}
    hydro = {k: v for k, v in hydro.items() if k in sub_links}
    models = {f"'{k}' ({r.underwater[k].find('hydrodynamic_model').findtext('type', '').strip()})" for k in hydro
              if r.underwater[k].find("hydrodynamic_model") is not None}
    if models:
        notes.append("the hydrodynamic models of the arm's links " + ", ".join(sorted(models)) + ": added mass and "
                     "drag of a shape; their volumes and centres of buoyancy are imported")
    arm_locks = {k: (v, f"--lock {k}") for k, (v, _) in locks.items() if k in {e.get("name") for e in sub.findall("joint")}}
    off = None if tool_offset is None else (np.asarray(tool_offset, float), "--tool-offset")
    try:
        got = urdf.arm_chain(r.root, arm_base, tool, r.src, r.where, error, locks=arm_locks, hydro=hydro,
                             tool_offset=off)
    except ValueError as e:
        raise error(str(e).replace("[arm.lock]", "--lock JOINT=POSITION")) from None
    R0, p0 = body.poses[arm_base]
    Rm = T @ R0
    roll, pitch, yaw = matrix_rpy(Rm)
    msrc = f"{src}: pose of link '{arm_base}' on '{_base_name(body)}' ({body.via[arm_base]}), turned into FRD (T R)"
    n = len(got.joints)
    lines = ["[arm]"]
    lines += _comment("Gazebo adds no trim ballast: the arm's weight in water acts on the vehicle as it is.")
    lines += ["trim = false", ""]
    lines += ["[arm.mount]"] + [f"{k} = {_e(v, 'm', msrc)}" for k, v in zip("xyz", T @ p0)]
    lines += [f"{k} = {_e(v, 'rad', msrc)}" for k, v in zip(("roll", "pitch", "yaw"), (roll, pitch, yaw))]
    lines.append("")
    for key in ("tool", *(f"joint{i}" for i in range(1, n + 1)), *(f"link{i}" for i in range(1, n + 1))):
        lines.append(f"[arm.{key}]")
        lines += [_entry_line(k, e) for k, e in got.arm[key].items()]
        lines.append("")
    if stow is not None:
        q = [float(x) for x in stow]
        if len(q) != n:
            raise error(f"--stow: {len(q)} angles for an arm of {n} joints ({', '.join(got.joints)})")
        ssrc = "--stow"
    else:
        q = []
        for i in range(1, n + 1):
            lo, hi = got.arm[f"joint{i}"]["qmin"]["value"], got.arm[f"joint{i}"]["qmax"]["value"]
            q.append(min(max(0.0, lo), hi))
        ssrc = "the URDF's zero pose clipped to the joint limits (a URDF names no stow pose: --stow)"
    lines.append("[arm.stow]")
    for i, (jn, v) in enumerate(zip(got.joints, q), start=1):
        lines.append(f"q{i} = {_e(v, 'rad', f'{ssrc}: joint {jn!r}')}")
    lines += ["", "[payload]", f"mass = {_e(0.0, 'kg', 'none: a URDF names no payload')}",
              f"volume = {_e(0.0, 'm^3', 'none: a URDF names no payload')}", ""]
    if got.locked:
        lines = _comment("Locked joints (merged into their parents): " + ", ".join(
            f"{k} at {v:g}" for k, v in got.locked.items()) + ".") + lines
    return lines, got.joints


def _base_name(body: _Body) -> str:
    return next(iter(body.poses))
