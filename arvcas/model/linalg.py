"""Small dense linear algebra written out for SX graphs (cheaper than casadi.solve's symbolic QR).

Used on the hot path of the compiled closed loop; exactness is tested against numpy.linalg.
Gaussian elimination without pivoting, split into the factorisation (:func:`lu_nopivot`, which the
closed loop tabulates per time because the coupled inertia depends on time only) and the
substitutions (:func:`lu_solve`, per state). ``solve_nopivot`` is the two in one, with the same
operations in the same order.
"""

from __future__ import annotations

import casadi as ca

__all__ = ["solve_nopivot", "lu_nopivot", "lu_solve", "lu_pack", "lu_unpack"]


def lu_nopivot(A):
    """A = L U without pivoting: (multipliers ``F[i][k]`` of L below the diagonal, ``U`` upper incl. diagonal).

    Only for matrices whose leading principal minors are well away from zero, e.g. the diagonally
    dominant coupled inertia M + M_arm of the vehicle (added mass and rigid body on the diagonal
    dominate every row). Returned as nested lists of scalar expressions.
    """
    n = A.shape[0]
    a = [[A[i, j] for j in range(n)] for i in range(n)]
    F = [[0] * n for _ in range(n)]
    for k in range(n):
        inv = 1 / a[k][k]
        for i in range(k + 1, n):
            f = a[i][k] * inv
            F[i][k] = f
            for j in range(k + 1, n):
                a[i][j] = a[i][j] - f * a[k][j]
    return F, a


def lu_solve(F, U, b):
    """Solve L U x = b from :func:`lu_nopivot`'s factors; ``b`` may have several columns."""
    n = len(U)
    m = b.shape[1]
    r = [[b[i, k] for k in range(m)] for i in range(n)]
    for k in range(n):
        for i in range(k + 1, n):
            for c in range(m):
                r[i][c] = r[i][c] - F[i][k] * r[k][c]
    x = [[0] * m for _ in range(n)]
    for i in range(n - 1, -1, -1):
        for c in range(m):
            acc = r[i][c]
            for j in range(i + 1, n):
                acc = acc - U[i][j] * x[j][c]
            x[i][c] = acc / U[i][i]
    return ca.vertcat(*[ca.horzcat(*row) for row in x])


def solve_nopivot(A, b):
    """Solve A x = b by Gaussian elimination without pivoting (see :func:`lu_nopivot`)."""
    return lu_solve(*lu_nopivot(A), b)




def lu_pack(F, U):
    """The factors as one column: the multipliers row by row below the diagonal, then U's upper triangle."""
    n = len(U)
    return ca.vertcat(*[F[i][k] for i in range(n) for k in range(i)], *[U[i][j] for i in range(n) for j in range(i, n)])


def lu_unpack(v, n: int):
    """Inverse of :func:`lu_pack`: (F, U) as nested lists of the column's entries."""
    F = [[0] * n for _ in range(n)]
    U = [[0] * n for _ in range(n)]
    k = 0
    for i in range(n):
        for j in range(i):
            F[i][j] = v[k]
            k += 1
    for i in range(n):
        for j in range(i, n):
            U[i][j] = v[k]
            k += 1
    return F, U
