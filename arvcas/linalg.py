"""Small dense linear algebra written out for SX graphs (cheaper than casadi.solve's symbolic QR).

Used on the hot path of the compiled closed loop; exactness is tested against numpy.linalg.
"""

from __future__ import annotations

import casadi as ca

__all__ = ["solve_nopivot"]


def solve_nopivot(A, b):
    """Solve A x = b by Gaussian elimination without pivoting.

    Only for matrices whose leading principal minors are well away from zero, e.g. the
    diagonally dominant coupled inertia M + M_arm of the vehicle (added mass and rigid body on
    the diagonal dominate every row). ``b`` may have several columns.
    """
    n = A.shape[0]
    a = [[A[i, j] for j in range(n)] for i in range(n)]
    m = b.shape[1]
    r = [[b[i, k] for k in range(m)] for i in range(n)]
    for k in range(n):
        inv = 1 / a[k][k]
        for i in range(k + 1, n):
            f = a[i][k] * inv
            for j in range(k + 1, n):
                a[i][j] = a[i][j] - f * a[k][j]
            for c in range(m):
                r[i][c] = r[i][c] - f * r[k][c]
    x = [[0] * m for _ in range(n)]
    for i in range(n - 1, -1, -1):
        for c in range(m):
            acc = r[i][c]
            for j in range(i + 1, n):
                acc = acc - a[i][j] * x[j][c]
            x[i][c] = acc / a[i][i]
    return ca.vertcat(*[ca.horzcat(*row) for row in x])
