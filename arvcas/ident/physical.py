"""Identification that cannot leave physics: the optimiser's variables and the physical parameters they map to.

The free parameters keep the names the user gave (``--free``); inside the optimiser each free parameter is a
variable ``v`` (zero at the starting value) mapped to its physical value (docs/identification.md,
"Physical parameterisations"):

* a free parameter outside a group: ``theta = theta_0 + scale v`` within bounds that keep its sign
  (:func:`bounds`: masses, inertias, diameters > 0, volumes >= 0; Fossen's signs for diagonal added mass and
  damping, so that the added mass is positive and the damping dissipates);
* the vehicle's rigid body, when its three principal moments ``vehicle.Ixx, Iyy, Izz`` are free (with any of
  ``vehicle.m``, the products ``Ixy, Iyz, Ixz`` and the centre of gravity ``xG, yG, zG``): through the
  Cholesky factor of the second moment of mass about the centre of gravity,
  ``Sigma_c = L L'`` with ``L_ii = L0_ii exp(v)``, the mass ``m = m0 exp(v)``. This is the pseudo-inertia
  matrix ``[[Sigma, h], [h', m]]`` (Wensing, Kim and Slotine 2017, "Linear matrix inequalities for physically
  consistent inertial parameter identification") factored as in Rucker and Wensing 2022 (log-Cholesky):
  every ``v`` gives a positive definite pseudo-inertia, i.e. a positive mass and an inertia about the
  centre of gravity whose principal moments keep the strict triangle inequalities, and every such body has
  exactly one ``v``. An off-diagonal entry of ``L`` is free where its product of inertia is free, and
  otherwise solved so that the product keeps its file value; the inertia about the body origin is then
  ``Sigma_b = Sigma_c + m r_G r_G'``, ``I = tr(Sigma_b) 1 - Sigma_b``. A chain-form arm link whose
  ``inertia.ixx, iyy, izz`` are free likewise (its tensor is about its centre of mass: the mass and the
  centre of mass do not enter, and keep their bounds);
* the added mass and the linear damping, when an off-diagonal term of one is free: the symmetric part of
  the matrix (Fossen's signs) through its Cholesky factor (:meth:`Mapping._hydro_matrix`): positive
  semi-definite for every value, the held terms at their file values.

Anything else with a physical set (a principal moment freed alone, a centre of gravity with the inertia
held, command-map points) is bounded per parameter, and the estimate
is held inside the set the loader checks (:func:`loads`) by :func:`pull_back`: if the optimiser's last
point breaks a rule of ``arvcas.system.params.check_physical`` or ``check_plausible``, or makes the added
mass or the linear damping matrix indefinite, the estimate is moved back along the way from the start to
the last point onto the last point that keeps them, and the report says so.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass

import casadi as ca
import numpy as np

from arvcas.system.systemfile import parse_term

__all__ = ["Mapping", "bounds", "loads", "pull_back", "RIGID_BODY", "EDGE_RATIO"]

RIGID_BODY = ("vehicle.m", "vehicle.Ixx", "vehicle.Iyy", "vehicle.Izz", "vehicle.Ixy", "vehicle.Iyz", "vehicle.Ixz",
              "vehicle.xG", "vehicle.yG", "vehicle.zG")
_AXES = ((1, 0), (2, 1), (2, 0))  # the products' places in the lower triangle: xy, yz, xz


@dataclass(frozen=True)
class _Body:
    """A rigid body's parameters: ``principal`` (xx, yy, zz) and ``products`` by place; ``sign``: the product
    parameter is ``sign`` times the second moment's off-diagonal entry (Fossen's vehicle tensor writes
    ``-Ixy``: +1; a URDF tensor ``ixy``: -1); ``com``: the centre of mass when the inertia is about another
    point (the vehicle's body origin: then the mass enters), () when it is about the centre of mass."""

    label: str
    mass: str
    principal: tuple[str, str, str]
    products: dict
    sign: float
    com: tuple[str, ...] = ()

    def sigma_c(self, p: dict) -> np.ndarray:
        """The second moment of mass about the centre of mass, Sigma = tr(I)/2 1 - I less m r r'."""
        T = np.diag([p[n] for n in self.principal])
        for (i, j), n in self.products.items():
            T[i, j] = T[j, i] = -self.sign * p[n]
        S = 0.5 * np.trace(T) * np.eye(3) - T
        if self.com:
            r = np.array([p[k] for k in self.com])
            S -= p[self.mass] * np.outer(r, r)
        return S


def _bodies(layout) -> list[_Body]:
    """The vehicle and every chain-form link with an inertia tensor in ``layout``."""
    out = []
    if all(k in layout.index for k in RIGID_BODY):
        out.append(_Body("vehicle rigid body", "vehicle.m", RIGID_BODY[1:4], dict(zip(_AXES, RIGID_BODY[4:7])), 1.0,
                         RIGID_BODY[7:]))
    for i in range(1, layout.structure.n_joints + 1):
        k = f"arm.link{i}.inertia"
        if f"{k}.ixx" in layout.index:
            out.append(_Body(f"arm link {i}", f"arm.link{i}.mass", (f"{k}.ixx", f"{k}.iyy", f"{k}.izz"),
                             dict(zip(_AXES, (f"{k}.ixy", f"{k}.iyz", f"{k}.ixz"))), -1.0))
    return out


_LOG_BOUND = 40.0  # |v| of a factor's logarithm: exp(40) = 2e17 times the start, far outside any vehicle
EDGE_RATIO = 0.01  # smallest / largest eigenvalue of Sigma_c below which an estimate is "at the edge"


def bounds(layout, name: str) -> tuple[float, float]:
    """(lower, upper) SI bounds that keep ``name`` physical: the layout's sign rule (``pos``: > 0, ``nonneg``:
    >= 0), and for hydrodynamic derivatives Fossen's signs: a diagonal added-mass term (``X_udot``) and a
    diagonal damping term (``X_u``, ``X_u_absu``: force along the velocity it multiplies) are <= 0, so that
    the added mass is positive and the damping dissipates."""
    i = layout.index[name]
    rule = layout.rules[i]
    lo, hi = -math.inf, math.inf
    if rule == "pos":
        lo = 1e-12
    elif rule == "nonneg":
        lo = 0.0
    if name.startswith("hydro."):
        t = parse_term(name[len("hydro."):])
        if (t.dot is not None and t.dot == t.row) or (t.col is not None and t.col == t.row and
                                                       all(f in (f"abs{'uvwpqr'[t.row]}",) for f in t.factors)):
            hi = 0.0
    return lo, hi


class Mapping:
    """``v`` (one per free parameter, zero at the start) -> the free parameters' physical values, with its
    Jacobian; ``lo, hi``: bounds on ``v``; ``groups``: one line per group mapped through a factor (none
    without ``factors``: each parameter by its bounds alone). ``held``: free parameters held at their values
    (no information in the trials): a group is formed as if they were not free."""

    def __init__(self, layout, free: tuple[str, ...], p0: np.ndarray, factors: bool = True, held=()):
        self.free = tuple(free)
        n = len(self.free)
        self._active = {name: k for k, name in enumerate(self.free) if name not in held}  # grouped if they form one
        self.theta0 = np.array([p0[layout.index[k]] for k in self.free])
        self.scale = np.where(np.abs(self.theta0) > 0, np.abs(self.theta0), 0.1)
        self.lo, self.hi = np.full(n, -np.inf), np.full(n, np.inf)
        v = ca.SX.sym("v", n)
        out = [self.theta0[k] + self.scale[k] * v[k] for k in range(n)]
        self.groups: list[str] = []
        self._edges: list[tuple[tuple[str, ...], object]] = []  # (names, values -> the group's matrix)
        self.mapped: set[str] = set()
        self.notes: list[str] = []
        values = {k: float(p0[layout.index[k]]) for k in layout.names}
        for body in _bodies(layout) if factors else ():
            if set(body.principal) <= set(self._active):
                self._rigid_body(v, out, values, body)
        if factors and "env.rho" not in self.free:
            for kind in ("added mass", "linear damping"):
                self._hydro_matrix(kind, layout, v, out, values)
        for k, name in enumerate(self.free):
            if name in self.mapped:
                continue
            a, b = bounds(layout, name)
            self.lo[k] = (a - self.theta0[k]) / self.scale[k]
            self.hi[k] = (b - self.theta0[k]) / self.scale[k]
        th = ca.vertcat(*out)
        self._f = ca.Function("ident_map", [v], [th, ca.jacobian(th, v)])

    def _rigid_body(self, v, out: list, p: dict, body: "_Body") -> None:
        """A rigid body whose three principal moments are free (module docstring): its second moment about
        the centre of mass through its Cholesky factor; for the vehicle (inertia about the body origin) the
        mass by its logarithm and the centre of gravity free."""
        ix = dict(self._active)
        m0 = p[body.mass] if body.com else 0.0
        r0 = np.array([p[k] for k in body.com]) if body.com else np.zeros(3)
        Sc0 = body.sigma_c(p)
        try:
            L0 = np.linalg.cholesky(Sc0)
        except np.linalg.LinAlgError:
            self.notes.append(f"{body.label}: the starting inertia about its centre of mass breaks the triangle "
                              f"inequality: its parameters are bounded one by one")
            return
        m = m0 * ca.exp(v[ix[body.mass]]) if body.com and body.mass in ix else m0
        r = [r0[i] + self.scale[ix[k]] * v[ix[k]] if k in ix else r0[i] for i, k in enumerate(body.com or ("",) * 3)]
        L = [[ca.SX(0)] * 3 for _ in range(3)]
        for i in range(3):
            for j in range(i):
                name = body.products[(i, j)]
                if name in ix:
                    L[i][j] = L0[i, j] + max(abs(L0[i, j]), 0.1 * L0[j, j]) * v[ix[name]]
                else:  # the product keeps its file value: Sigma_c[i, j] = sign * product - m r_i r_j
                    s = body.sign * p[name] - m * r[i] * r[j] - sum(L[i][k] * L[j][k] for k in range(j))
                    L[i][j] = s / L[j][j]
            L[i][i] = L0[i, i] * ca.exp(v[ix[body.principal[i]]])
        Lm = ca.vertcat(*[ca.horzcat(*row) for row in L])
        rv = ca.vertcat(*r)
        Sb = ca.mtimes(Lm, Lm.T) + m * ca.mtimes(rv, rv.T)  # about the frame the file's inertia is written in
        T = ca.trace(Sb) * ca.DM.eye(3) - Sb
        phys = {body.principal[i]: T[i, i] for i in range(3)}
        phys.update({name: body.sign * Sb[i, j] for (i, j), name in body.products.items()})
        if body.com:
            phys[body.mass] = m
        names = tuple(n for n in self.free if n in ix and (n in phys or n in body.com))
        for name in names:
            k = ix[name]
            self.mapped.add(name)
            if name in phys:
                out[k] = phys[name]
                self.lo[k], self.hi[k] = -_LOG_BOUND, _LOG_BOUND
            # a centre of gravity: any value (the factor holds the body physical)
        self._edges.append((names, body.sigma_c))
        self.groups.append(f"{body.label} ({', '.join(names)}): Cholesky factor of the second moment about its "
                           f"centre of mass{', mass by its logarithm' if body.com else ''}: a physical body "
                           f"(positive definite pseudo-inertia) for every value")

    def _hydro_matrix(self, kind: str, layout, v, out: list, p: dict) -> None:
        """The added mass or the linear damping, when an off-diagonal term of it is free: the symmetric part
        ``S = (A + A') / 2`` of the matrix (``A[row, col] = -coefficient``, Fossen's signs) through its
        Cholesky factor over the rows in use, those with a free diagonal last: ``L_ii = L0_ii exp(v)`` for a
        free diagonal term, an off-diagonal ``L_ij`` free where a term of ``S_ij`` is free (the other term of
        the pair, if free too, moves the antisymmetric part), every other entry solved so that the held terms
        keep their values. Any ``v`` gives a positive semi-definite ``S``."""
        st = layout.structure
        scale = p["env.rho"] if st.hydro_per_rho else 1.0
        terms = {}  # (row, col) -> parameter name
        for t in st.hydro:
            if kind == "added mass" and t.dot is not None:
                terms[(t.row, t.dot)] = f"hydro.{t.name}"
            elif kind == "linear damping" and t.col is not None and not t.factors:
                terms[(t.row, t.col)] = f"hydro.{t.name}"
        ix = dict(self._active)
        free = {rc: n for rc, n in terms.items() if n in ix}
        if not any(i != j for i, j in free) or scale <= 0:
            return
        A0 = np.zeros((6, 6))
        for (i, j), n in terms.items():
            A0[i, j] = -p[n] * scale
        S0 = 0.5 * (A0 + A0.T)
        used = [i for i in range(6) if np.any(S0[i]) or any(i in rc for rc in free)]
        diag_free = [i for i in used if (i, i) in free]
        order = [i for i in used if i not in diag_free] + diag_free
        pos = {i: k for k, i in enumerate(order)}
        held = [i for i in used if i not in diag_free]
        bad = [rc for rc in free if rc[0] != rc[1] and rc[0] in held and rc[1] in held]
        try:
            L0 = np.linalg.cholesky(S0[np.ix_(order, order)])
        except np.linalg.LinAlgError:
            L0 = None
        if bad or L0 is None:
            why = ("a free term between rows whose diagonal is held" if bad else
                   "its starting symmetric part is singular or indefinite")
            self.notes.append(f"{kind}: {why}: its terms are bounded one by one and the estimate held inside the "
                              f"loader's rules")
            return
        n = len(order)
        L = [[ca.SX(0)] * n for _ in range(n)]
        S = {}  # (a, b) in ``order`` positions, a >= b -> the expression of S
        for a in range(n):
            for b in range(a + 1):
                i, j = order[a], order[b]
                pair = (i, j) in free or (j, i) in free
                if a == b and pair:
                    L[a][a] = L0[a, a] * ca.exp(v[ix[free[(i, i)]]])
                elif a == b:
                    L[a][a] = ca.sqrt(S0[i, i] - sum(L[a][k] ** 2 for k in range(a)))
                elif pair:
                    L[a][b] = L0[a, b] + max(abs(L0[a, b]), 0.1 * L0[b, b]) * v[ix[free[_first(i, j, free)]]]
                else:
                    L[a][b] = (S0[i, j] - sum(L[a][k] * L[b][k] for k in range(b))) / L[b][b]
                S[(a, b)] = sum(L[a][k] * L[b][k] for k in range(b + 1))
        for (i, j), name in free.items():
            a, b = max(pos[i], pos[j]), min(pos[i], pos[j])
            sym = S[(a, b)]
            k = ix[name]
            first = _first(order[a], order[b], free)
            if i == j:
                A = sym
            elif (j, i) not in free:  # the held partner keeps its value
                A = 2 * sym - A0[j, i]
            else:  # both free: the second's variable moves the antisymmetric part K = (A_second - A_first) / 2
                second = (j, i) if (i, j) == first else (i, j)
                ks = ix[free[second]]
                K = 0.5 * (A0[second] - A0[first]) + self.scale[ks] * scale * v[ks]
                A = sym + K if (i, j) == second else sym - K
            out[k] = -A / scale
            self.mapped.add(name)
            self.lo[k], self.hi[k] = (-_LOG_BOUND, _LOG_BOUND) if i == j else (-np.inf, np.inf)
        which = 0 if kind == "added mass" else 1

        def sym(vals):
            A = _matrices(vals, layout)[which]
            return 0.5 * (A + A.T)[np.ix_(used, used)]

        self._edges.append((tuple(n for n in self.free if n in free.values()), sym))
        self.groups.append(f"{kind} ({', '.join(n for n in self.free if n in free.values())}): Cholesky factor of "
                           f"its symmetric part: positive semi-definite for every value")

    def theta(self, v) -> np.ndarray:
        return np.array(self._f(np.asarray(v, dtype=float))[0]).reshape(-1)

    def jacobian(self, v) -> np.ndarray:
        """d theta / d v (n x n)."""
        return np.array(self._f(np.asarray(v, dtype=float))[1])

    def edge(self, values: dict) -> list[str]:
        """The free parameters of every mapped group whose estimate lies near the edge of its physical set: the
        group's matrix (Sigma_c, or the symmetric part of the added mass or damping over its rows in use) has
        an eigenvalue below :data:`EDGE_RATIO` of its largest."""
        out = []
        for names, matrix in self._edges:
            lam = np.linalg.eigvalsh(matrix(values))
            if lam[0] < EDGE_RATIO * lam[-1]:
                out += [n for n in names if n not in out]
        return out


def _first(i: int, j: int, free: dict) -> tuple[int, int]:
    """Of the terms (i, j) and (j, i) of a symmetric entry, the one whose variable moves the factor: (i, j)
    if it is free, else (j, i)."""
    return (i, j) if (i, j) in free else (j, i)


def _psd(A: np.ndarray) -> bool:
    S = 0.5 * (A + A.T)
    return float(np.linalg.eigvalsh(S)[0]) >= -1e-9 * max(1.0, float(np.abs(S).max()))


def _matrices(values: dict, layout) -> tuple[np.ndarray, np.ndarray]:
    """The added mass M_A and the linear damping D (6 x 6, Fossen's signs: both positive for a physical
    vehicle) of the hydrodynamic terms."""
    st = layout.structure
    scale = values["env.rho"] if st.hydro_per_rho else 1.0
    MA, D = np.zeros((6, 6)), np.zeros((6, 6))
    for t in st.hydro:
        c = values[f"hydro.{t.name}"] * scale
        if t.dot is not None:
            MA[t.row, t.dot] -= c
        elif t.col is not None and not t.factors:
            D[t.row, t.col] -= c
    return MA, D


def loads(values: dict, layout, where: str, accept: bool, matrices: tuple[bool, bool]) -> str | None:
    """None if the SI ``values`` pass the loader's rules (``check_physical``, ``check_plausible``'s refusals
    unless ``accept``) and, where ``matrices`` says the start had them, keep the added mass and the linear
    damping positive semi-definite; else the first rule broken, one line."""
    from arvcas.system.params import ParamsError, check_physical, check_plausible

    try:
        check_physical(values, where, layout)
        check_plausible(values, where, layout, accept)
    except ParamsError as e:
        return str(e)
    MA, D = _matrices(values, layout)
    if matrices[0] and not _psd(MA):
        return f"{where}: the added mass's symmetric part is not positive semi-definite"
    if matrices[1] and not _psd(D):
        return f"{where}: the linear damping's symmetric part is not positive semi-definite"
    return None


def accepts_implausible(path) -> bool:
    """The system file's ``[system] accept_implausible`` (False when the file cannot be read)."""
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh).get("system", {}).get("accept_implausible", False) is True
    except (OSError, tomllib.TOMLDecodeError, AttributeError):
        return False


def pull_back(system, mapping: Mapping, v: np.ndarray, steps: int = 20) -> tuple[np.ndarray, float, str | None]:
    """(v', t, why): ``v`` itself (t = 1, why None) when its parameters pass :func:`loads`, else the point
    ``t v`` (largest t in [0, 1) found by ``steps`` bisections: to 1e-6 of the step) that passes, with the rule
    ``v`` broke. The start (t = 0) is the loaded system, which passes. Each check runs the loader's rules
    (0.01 to 2 s, by system)."""
    lay = system.layout
    p = system.params.vector()
    idx = [lay.index[n] for n in mapping.free]
    where = str(system.params.path)
    accept = accepts_implausible(system.params.path)
    start = dict(zip(lay.names, map(float, p)))
    MA, D = _matrices(start, lay)
    mats = (_psd(MA), _psd(D))

    def why(t: float) -> str | None:
        pv = p.copy()
        pv[idx] = mapping.theta(t * v)
        if not np.all(np.isfinite(pv)):
            return f"{where}: a parameter is not finite"
        return loads(dict(zip(lay.names, map(float, pv))), lay, where, accept, mats)

    broke = why(1.0)
    if broke is None or why(0.0) is not None:
        return v, 1.0, broke
    a, b = 0.0, 1.0
    for _ in range(steps):
        c = 0.5 * (a + b)
        if why(c) is None:
            a = c
        else:
            b = c
    return a * v, a, broke
