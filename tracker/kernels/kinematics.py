"""Forward kinematics and the parameters' screws (``tracker.body.kinematics``)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["forward_kinematics"]


@njit(cache=True, inline="always")
def _rodrigues(wx, wy, wz, out):
    """``out (3, 3) = exp([w]×)`` (``tracker.body.kinematics.so3_exp`` for one vector)."""
    theta = math.sqrt(wx * wx + wy * wy + wz * wz)
    if theta < 1e-8:
        A, B = 1.0 - theta * theta / 6.0, 0.5 - theta * theta / 24.0
    else:
        A, B = math.sin(theta) / theta, (1.0 - math.cos(theta)) / (theta * theta)
    xx, yy, zz, xy, xz, yz = wx * wx, wy * wy, wz * wz, wx * wy, wx * wz, wy * wz
    out[0, 0], out[0, 1], out[0, 2] = 1.0 - B * (yy + zz), -A * wz + B * xy, A * wy + B * xz
    out[1, 0], out[1, 1], out[1, 2] = A * wz + B * xy, 1.0 - B * (xx + zz), -A * wx + B * yz
    out[2, 0], out[2, 1], out[2, 2] = -A * wy + B * xz, A * wx + B * yz, 1.0 - B * (xx + yy)


@njit(cache=True)
def forward_kinematics(params, axis, parent, dof_ptr, dof_idx, rest, offset, ti, ri):
    """``tracker.body.kinematics.forward`` on plain arrays: part2world R (n_parts, 3, 3), t (n_parts, 3)
    and the parameters' screws w, v (n_params, 3).

    params (n_params,), axis (n_params, 3) joint axes (part frame); per part p in order (parents
    first): ``parent[p]`` (-1 for the root), its joint parameters ``dof_idx[dof_ptr[p]:dof_ptr[p+1]]``,
    ``rest[p]`` (3, 3), ``offset[p]`` (3,); ti, ri the root translation and rotation parameters."""
    n_parts, n_params = parent.shape[0], params.shape[0]
    R = np.empty((n_parts, 3, 3))
    t = np.empty((n_parts, 3))
    w = np.zeros((n_params, 3))
    v = np.zeros((n_params, 3))
    root_t = np.array([params[ti[0]], params[ti[1]], params[ti[2]]])
    r0, r1, r2 = params[ri[0]], params[ri[1]], params[ri[2]]
    R_root = np.empty((3, 3))
    _rodrigues(r0, r1, r2, R_root)
    Q = np.empty((3, 3))
    Rb = np.empty((3, 3))
    tmp = np.empty((3, 3))
    for p in range(n_parts):
        par = parent[p]
        Rp = R_root if par < 0 else R[par]
        tp = root_t if par < 0 else t[par]
        for i in range(3):
            for j in range(3):
                Rb[i, j] = Rp[i, 0] * rest[p, 0, j] + Rp[i, 1] * rest[p, 1, j] + Rp[i, 2] * rest[p, 2, j]
        tb0 = Rp[0, 0] * offset[p, 0] + Rp[0, 1] * offset[p, 1] + Rp[0, 2] * offset[p, 2] + tp[0]
        tb1 = Rp[1, 0] * offset[p, 0] + Rp[1, 1] * offset[p, 1] + Rp[1, 2] * offset[p, 2] + tp[1]
        tb2 = Rp[2, 0] * offset[p, 0] + Rp[2, 1] * offset[p, 1] + Rp[2, 2] * offset[p, 2] + tp[2]
        for s in range(dof_ptr[p], dof_ptr[p + 1]):
            kk = dof_idx[s]
            ax0, ax1, ax2 = axis[kk, 0], axis[kk, 1], axis[kk, 2]
            # screw: w = R_before a, v = t_before × w
            w0 = Rb[0, 0] * ax0 + Rb[0, 1] * ax1 + Rb[0, 2] * ax2
            w1 = Rb[1, 0] * ax0 + Rb[1, 1] * ax1 + Rb[1, 2] * ax2
            w2 = Rb[2, 0] * ax0 + Rb[2, 1] * ax1 + Rb[2, 2] * ax2
            w[kk, 0], w[kk, 1], w[kk, 2] = w0, w1, w2
            v[kk, 0], v[kk, 1], v[kk, 2] = tb1 * w2 - tb2 * w1, tb2 * w0 - tb0 * w2, tb0 * w1 - tb1 * w0
            lam = params[kk]
            _rodrigues(ax0 * lam, ax1 * lam, ax2 * lam, Q)
            for i in range(3):
                for j in range(3):
                    tmp[i, j] = Rb[i, 0] * Q[0, j] + Rb[i, 1] * Q[1, j] + Rb[i, 2] * Q[2, j]
            Rb[:, :] = tmp
        R[p] = Rb
        t[p, 0], t[p, 1], t[p, 2] = tb0, tb1, tb2
    # root screws: translation v = e_j; rotation w = column j of the left Jacobian, v = t × w
    for j in range(3):
        v[ti[j], j] = 1.0
    theta = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    if theta < 1e-6:
        A, B = 0.5, 1.0 / 6.0
    else:
        A, B = (1.0 - math.cos(theta)) / theta ** 2, (theta - math.sin(theta)) / theta ** 3
    K = np.array([[0.0, -r2, r1], [r2, 0.0, -r0], [-r1, r0, 0.0]])
    for j in range(3):
        for i in range(3):
            kk2 = K[i, 0] * K[0, j] + K[i, 1] * K[1, j] + K[i, 2] * K[2, j]
            w[ri[j], i] = (1.0 if i == j else 0.0) + A * K[i, j] + B * kk2
        a0, a1, a2 = w[ri[j], 0], w[ri[j], 1], w[ri[j], 2]
        v[ri[j], 0] = root_t[1] * a2 - root_t[2] * a1
        v[ri[j], 1] = root_t[2] * a0 - root_t[0] * a2
        v[ri[j], 2] = root_t[0] * a1 - root_t[1] * a0
    return R, t, w, v
