"""Extremal contours, the camera projection and the contour image motion (``tracker.imaging.contours``,
``tracker.imaging.jacobian``)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tracker.kernels.occlusion import camera_centres_kernel

__all__ = ["ruling_angles", "contour_points", "projection_jacobians", "image_motion"]


@njit(cache=True, inline="always")
def _ruling_angles(a, b, k, m0, m1, m2):
    """θ of side 0 (+√D) and side 1 (-√D) of a cone (a, b, k) seen from m (part frame), and whether
    the rulings are real (``tracker.imaging.contours.contour_generator_angles`` for one cone)."""
    F = -b * m0
    G = -a * m1
    H = a * b * (1.0 + k * m2)
    D = F * F + G * G - H * H
    real = D > 1e-12 * (F * F + G * G + H * H)
    sq = math.sqrt(max(D, 0.0))
    hmf, hpf = H - F, H + F
    # t± = (-G ± √D) / (H - F) = (H + F) / (-G ∓ √D); the form whose numerator does not cancel
    if G <= 0:
        th_p = 2.0 * math.atan2(-G + sq, hmf)
    else:
        th_p = 2.0 * math.atan2(hpf, -G - sq)
    if G >= 0:
        th_m = 2.0 * math.atan2(-G - sq, hmf)
    else:
        th_m = 2.0 * math.atan2(hpf, -G + sq)
    return th_p, th_m, real


@njit(cache=True)
def ruling_angles(cones, m):
    """``_ruling_angles`` over arrays: cones (n, 5), m (n, 3) -> θ (n, 2), real (n,)."""
    n = m.shape[0]
    theta = np.empty((n, 2))
    real = np.empty(n, dtype=np.bool_)
    for i in range(n):
        theta[i, 0], theta[i, 1], real[i] = _ruling_angles(cones[i, 0], cones[i, 1], cones[i, 2],
                                                           m[i, 0], m[i, 1], m[i, 2])
    return theta, real


@njit(cache=True, inline="always")
def _project(intr, dist, c, xc, yc, zc, jac):
    """Pixel (u, v) of the camera-frame point (xc, yc, zc) of camera c (``capture.camera``: pinhole,
    OpenCV k1 k2 p1 p2 k3 distortion, skew) and, when ``jac``, d(u, v)/d(xc, yc, zc) as
    (du/dx, du/dy, du/dz, dv/dx, dv/dy, dv/dz)."""
    fx, sk, cx, fy, cy = intr[c, 0], intr[c, 1], intr[c, 2], intr[c, 3], intr[c, 4]
    k1, k2, p1, p2, k3 = dist[c, 0], dist[c, 1], dist[c, 2], dist[c, 3], dist[c, 4]
    inv_z = 1.0 / zc
    x, y = xc * inv_z, yc * inv_z
    xy, xx, yy = x * y, x * x, y * y
    r2 = xx + yy
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * xx)
    yd = y * radial + p1 * (r2 + 2.0 * yy) + 2.0 * p2 * xy
    u = fx * xd + sk * yd + cx
    v = fy * yd + cy
    if not jac:
        return u, v, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    dxd_dx = radial + 2.0 * xx * drad + 2.0 * p1 * y + 6.0 * p2 * x
    dxd_dy = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y
    dyd_dy = radial + 2.0 * yy * drad + 6.0 * p1 * y + 2.0 * p2 * x
    du_dx = fx * dxd_dx + sk * dxd_dy
    du_dy = fx * dxd_dy + sk * dyd_dy
    dv_dx = fy * dxd_dy
    dv_dy = fy * dyd_dy
    return (u, v, du_dx * inv_z, du_dy * inv_z, -(du_dx * x + du_dy * y) * inv_z,
            dv_dx * inv_z, dv_dy * inv_z, -(dv_dx * x + dv_dy * y) * inv_z)


@njit(cache=True)
def contour_points(cones, R, t, zs, cam_R, cam_t, intr, dist, size):
    """The sampled extremal contours of every part in every camera (``tracker.imaging.contours.
    extremal_contours`` before the occlusion test).

    cones (n_parts, 5); R, t part2world; zs (n_parts, n_samples) sample heights; cam_R, cam_t
    world2cam; intr (n_cams, 5) fx, skew, cx, fy, cy; dist (n_cams, 5); size (n_cams, 2) pixels.
    Rows ordered (camera, part, side, sample).  Returns θ (N,), world points (N, 3), pixels (N, 2)
    (0 where not valid) and valid (N,): a real ruling, in front of the camera, inside the image."""
    n_cams, n_parts, ns = cam_R.shape[0], cones.shape[0], zs.shape[1]
    N = n_cams * n_parts * 2 * ns
    theta = np.empty(N)
    points = np.empty((N, 3))
    uv = np.zeros((N, 2))
    valid = np.zeros(N, dtype=np.bool_)
    row = 0
    for c in range(n_cams):
        C0 = -(cam_R[c, 0, 0] * cam_t[c, 0] + cam_R[c, 1, 0] * cam_t[c, 1] + cam_R[c, 2, 0] * cam_t[c, 2])
        C1 = -(cam_R[c, 0, 1] * cam_t[c, 0] + cam_R[c, 1, 1] * cam_t[c, 1] + cam_R[c, 2, 1] * cam_t[c, 2])
        C2 = -(cam_R[c, 0, 2] * cam_t[c, 0] + cam_R[c, 1, 2] * cam_t[c, 1] + cam_R[c, 2, 2] * cam_t[c, 2])
        w_max, h_max = size[c, 0] - 1.0, size[c, 1] - 1.0
        for p in range(n_parts):
            a, b, k = cones[p, 0], cones[p, 1], cones[p, 2]
            dx, dy, dz = C0 - t[p, 0], C1 - t[p, 1], C2 - t[p, 2]
            m0 = R[p, 0, 0] * dx + R[p, 1, 0] * dy + R[p, 2, 0] * dz
            m1 = R[p, 0, 1] * dx + R[p, 1, 1] * dy + R[p, 2, 1] * dz
            m2 = R[p, 0, 2] * dx + R[p, 1, 2] * dy + R[p, 2, 2] * dz
            th_p, th_m, real = _ruling_angles(a, b, k, m0, m1, m2)
            for side in range(2):
                th = th_p if side == 0 else th_m
                ca, sb = a * math.cos(th), b * math.sin(th)
                # world point = (1 + k z) (a cos θ R e1 + b sin θ R e2) + z R e3 + t
                r0 = ca * R[p, 0, 0] + sb * R[p, 0, 1]
                r1 = ca * R[p, 1, 0] + sb * R[p, 1, 1]
                r2 = ca * R[p, 2, 0] + sb * R[p, 2, 1]
                for j in range(ns):
                    z = zs[p, j]
                    s = 1.0 + k * z
                    X0 = r0 * s + (z * R[p, 0, 2] + t[p, 0])
                    X1 = r1 * s + (z * R[p, 1, 2] + t[p, 1])
                    X2 = r2 * s + (z * R[p, 2, 2] + t[p, 2])
                    theta[row] = th
                    points[row, 0], points[row, 1], points[row, 2] = X0, X1, X2
                    xc = cam_R[c, 0, 0] * X0 + cam_R[c, 0, 1] * X1 + cam_R[c, 0, 2] * X2 + cam_t[c, 0]
                    yc = cam_R[c, 1, 0] * X0 + cam_R[c, 1, 1] * X1 + cam_R[c, 1, 2] * X2 + cam_t[c, 1]
                    zc = cam_R[c, 2, 0] * X0 + cam_R[c, 2, 1] * X1 + cam_R[c, 2, 2] * X2 + cam_t[c, 2]
                    if real and zc > 1e-6:
                        u, v, _, _, _, _, _, _ = _project(intr, dist, c, xc, yc, zc, False)
                        if u >= 0.0 and v >= 0.0 and u <= w_max and v <= h_max:
                            uv[row, 0], uv[row, 1] = u, v
                            valid[row] = True
                    row += 1
    return theta, points, uv, valid


@njit(cache=True)
def projection_jacobians(cam_R, cam_t, intr, dist, points, cam):
    """d(u, v)/d(world point) of ``points`` (n, 3) seen by cameras ``cam`` (n,): (n, 2, 3) (junk for
    points at or behind their camera)."""
    n = points.shape[0]
    JI = np.empty((n, 2, 3))
    for i in range(n):
        c = cam[i]
        X0, X1, X2 = points[i, 0], points[i, 1], points[i, 2]
        xc = cam_R[c, 0, 0] * X0 + cam_R[c, 0, 1] * X1 + cam_R[c, 0, 2] * X2 + cam_t[c, 0]
        yc = cam_R[c, 1, 0] * X0 + cam_R[c, 1, 1] * X1 + cam_R[c, 1, 2] * X2 + cam_t[c, 1]
        zc = cam_R[c, 2, 0] * X0 + cam_R[c, 2, 1] * X1 + cam_R[c, 2, 2] * X2 + cam_t[c, 2]
        _, _, a0, a1, a2, b0, b1, b2 = _project(intr, dist, c, xc, yc, zc, True)
        for j in range(3):
            JI[i, 0, j] = a0 * cam_R[c, 0, j] + a1 * cam_R[c, 1, j] + a2 * cam_R[c, 2, j]
            JI[i, 1, j] = b0 * cam_R[c, 0, j] + b1 * cam_R[c, 1, j] + b2 * cam_R[c, 2, j]
    return JI


@njit(cache=True)
def image_motion(Y, JI, cam, part, z, theta, cones, R, t, cam_R, cam_t, sliding):
    """``J_I (A + B)`` of contour points (``tracker.imaging.jacobian``): (n, d, 6).

    Y (n, 3) world points, JI (n, d, 3) their projection Jacobians (d = 2; the identity, d = 3,
    gives A + B itself); per point its camera, part, height z and ruling angle θ; cones
    (n_parts, 5); R, t part2world; cam_R, cam_t world2cam.  Rows without a real ruling (f_θ²
    below its threshold) get no sliding term."""
    n, dim = Y.shape[0], JI.shape[1]
    M = np.empty((n, dim, 6))
    centres = camera_centres_kernel(cam_R, cam_t)
    for i in range(n):
        y0, y1, y2 = Y[i, 0], Y[i, 1], Y[i, 2]
        for r in range(dim):
            j0, j1, j2 = JI[i, r, 0], JI[i, r, 1], JI[i, r, 2]
            M[i, r, 0] = y1 * j2 - y2 * j1
            M[i, r, 1] = y2 * j0 - y0 * j2
            M[i, r, 2] = y0 * j1 - y1 * j0
            M[i, r, 3], M[i, r, 4], M[i, r, 5] = j0, j1, j2
        if not sliding:
            continue
        p, c = part[i], cam[i]
        a, b, k = cones[p, 0], cones[p, 1], cones[p, 2]
        cos, sin = math.cos(theta[i]), math.sin(theta[i])
        C0, C1, C2 = centres[c, 0], centres[c, 1], centres[c, 2]
        dx, dy, dz = C0 - t[p, 0], C1 - t[p, 1], C2 - t[p, 2]
        m0 = R[p, 0, 0] * dx + R[p, 1, 0] * dy + R[p, 2, 0] * dz
        m1 = R[p, 0, 1] * dx + R[p, 1, 1] * dy + R[p, 2, 1] * dz
        m2 = R[p, 0, 2] * dx + R[p, 1, 2] * dy + R[p, 2, 2] * dz
        f_theta = b * m0 * sin - a * m1 * cos
        F, G, H = -b * m0, -a * m1, a * b * (1.0 + k * m2)
        if f_theta * f_theta <= 1e-12 * (F * F + G * G + H * H):
            continue
        scale = (1.0 + k * z[i]) / f_theta
        # e = R X_θ / (-f_θ) (X_θ = (1 + k z) (-a sin, b cos, 0)); nw = R n; w = (C × nw, nw)
        ca, cb = a * sin * scale, b * cos * scale
        e0 = R[p, 0, 0] * ca - R[p, 0, 1] * cb
        e1 = R[p, 1, 0] * ca - R[p, 1, 1] * cb
        e2 = R[p, 2, 0] * ca - R[p, 2, 1] * cb
        n0, n1, n2 = b * cos, a * sin, -a * b * k
        nw0 = R[p, 0, 0] * n0 + R[p, 0, 1] * n1 + R[p, 0, 2] * n2
        nw1 = R[p, 1, 0] * n0 + R[p, 1, 1] * n1 + R[p, 1, 2] * n2
        nw2 = R[p, 2, 0] * n0 + R[p, 2, 1] * n1 + R[p, 2, 2] * n2
        w0, w1, w2 = C1 * nw2 - C2 * nw1, C2 * nw0 - C0 * nw2, C0 * nw1 - C1 * nw0
        for r in range(dim):
            je = JI[i, r, 0] * e0 + JI[i, r, 1] * e1 + JI[i, r, 2] * e2
            M[i, r, 0] += je * w0
            M[i, r, 1] += je * w1
            M[i, r, 2] += je * w2
            M[i, r, 3] += je * nw0
            M[i, r, 4] += je * nw1
            M[i, r, 5] += je * nw2
    return M
