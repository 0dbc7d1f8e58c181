"""The Gauss–Newton products of a Jacobian held as per-row screw motion (``tracker.fitting.screw_jacobian``).

Row i of the chamfer cost's Jacobian is ``J[i, k] = M[i] · S[:, k]`` where ``affects[P[i], k]`` (else 0):
``M[i]`` (6,) the row's motion per unit screw of its part ``P[i]``, ``S`` (6, n_params) the parameters'
screws (``tracker.body.kinematics.parameter_screws``).  Grouped by part, ``JᵀWJ = Σ_p S_pᵀ G_p S_p``
with the 6×6 ``G_p = Σ_{i∈p} w_i M_i M_iᵀ``, and ``JᵀWr = Σ_p S_pᵀ Σ_{i∈p} w_i r_i M_i`` (``S_p``: the
columns of S that move part p): the rows are visited once, with 21 products each, instead of a dense
m × n_params product.  A row with ``P[i] < 0`` is zero.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["screw_normal_equations", "screw_matvec"]


@njit(cache=True)
def screw_normal_equations(M, P, w, r, screws, affects):
    """``(JᵀWJ (n, n), JᵀWr (n,))`` of the Jacobian (M (m, 6), P (m,)) with the row weights w (m,) and
    residuals r (m,); screws (6, n), affects (n_parts, n) bool (module docstring)."""
    n_parts, n = affects.shape
    G = np.zeros((n_parts, 6, 6))
    h = np.zeros((n_parts, 6))
    seen = np.zeros(n_parts, dtype=np.bool_)
    for i in range(M.shape[0]):
        p = P[i]
        wi = w[i]
        if p < 0 or wi == 0.0:
            continue
        seen[p] = True
        for a in range(6):
            wa = wi * M[i, a]
            h[p, a] += wa * r[i]
            for b in range(a, 6):
                G[p, a, b] += wa * M[i, b]
    A = np.zeros((n, n))
    g = np.zeros(n)
    T = np.zeros((n, 6))
    cols = np.empty(n, dtype=np.intp)
    for p in range(n_parts):
        if not seen[p]:
            continue
        for a in range(6):
            for b in range(a):
                G[p, a, b] = G[p, b, a]
        nc = 0
        for k in range(n):
            if affects[p, k]:
                cols[nc] = k
                nc += 1
        for c in range(nc):
            k = cols[c]
            for a in range(6):
                s = 0.0
                for b in range(6):
                    s += G[p, a, b] * screws[b, k]
                T[k, a] = s
            g[k] += (h[p, 0] * screws[0, k] + h[p, 1] * screws[1, k] + h[p, 2] * screws[2, k]
                     + h[p, 3] * screws[3, k] + h[p, 4] * screws[4, k] + h[p, 5] * screws[5, k])
        for c in range(nc):
            k = cols[c]
            for e in range(c + 1):
                q = cols[e]
                A[k, q] += (T[k, 0] * screws[0, q] + T[k, 1] * screws[1, q] + T[k, 2] * screws[2, q]
                            + T[k, 3] * screws[3, q] + T[k, 4] * screws[4, q] + T[k, 5] * screws[5, q])
    for k in range(n):  # the lower triangle was filled (cols ascend)
        for q in range(k):
            A[q, k] = A[k, q]
    return A, g


@njit(cache=True)
def screw_matvec(M, P, screws, affects, x):
    """``J x`` (m,) of the Jacobian (M (m, 6), P (m,)) for x (n,) (module docstring)."""
    n_parts, n = affects.shape
    U = np.zeros((n_parts, 6))
    for p in range(n_parts):
        for k in range(n):
            if affects[p, k] and x[k] != 0.0:
                for a in range(6):
                    U[p, a] += screws[a, k] * x[k]
    out = np.zeros(M.shape[0])
    for i in range(M.shape[0]):
        p = P[i]
        if p >= 0:
            out[i] = (M[i, 0] * U[p, 0] + M[i, 1] * U[p, 1] + M[i, 2] * U[p, 2] + M[i, 3] * U[p, 3]
                      + M[i, 4] * U[p, 4] + M[i, 5] * U[p, 5])
    return out
