"""Compiled (numba) kernels of the tracker's per-evaluation hot loops.

The cost of one frame is a few dozen evaluations of the chamfer cost, each made of many small
array operations over ~2000 contour points and ~900 silhouette boundary samples: the occlusion
tests of ``tracker.imaging.visibility`` (segment or ray against every other part's solid), the reverse
term's nearest contour point of every boundary sample (``tracker.fitting.cost``), the bilinear sampling
of the distance images and the forward kinematics.  Written as numpy, each is tens of calls whose
fixed overhead dominates; here each is one loop.  The maths is the one documented in the module
that calls the kernel (its docstring is the reference); these functions take plain arrays only.

Compiled on first use and cached on disk (``cache=True``): a process pays the compilation once per
installed version (a few seconds; ``warm_up`` triggers it, e.g. in a live worker before its first
frame), later processes load the cached machine code.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["part_boxes", "hidden_mask", "covered_mask", "nearest_rows", "sample_chamfer", "forward_kinematics",
           "screw_rows", "image_motion",
           "contour_points", "ruling_angles", "projection_jacobians", "assemble", "reverse_terms"]

_Q_TOL = 1e-9  # tracker.visibility: a point exactly on another part's surface is not hidden
_AHEAD = 1e-9  # smallest camera depth of a point (or a ray's direction) counted as in front


@njit(cache=True, inline="always")
def _q_min_negative(g1, g2, g3, qc, e1, e2, h1, h2, h3, d3, s_max):
    """Whether ``q(s) = qa s² + 2 qb s + qc`` has a value below ``-_Q_TOL`` on ``[0, s_max] ∩ slab``
    (``tracker.imaging.visibility._meets_solid`` for one pair)."""
    if abs(d3) < 1e-15:
        if not (e1 <= 0.0 and e2 >= 0.0):
            return False
        lo, hi = 0.0, s_max
    else:
        sa, sb = e1 / d3, e2 / d3
        lo = max(min(sa, sb), 0.0)
        hi = min(max(sa, sb), s_max)
        if not lo <= hi:
            return False
    qa = h1 * h1 + h2 * h2 - h3 * h3
    qb = g1 * h1 + g2 * h2 - g3 * h3
    q = min((qa * lo + 2.0 * qb) * lo + qc, (qa * hi + 2.0 * qb) * hi + qc)
    if qa > 0.0:
        s = min(max(-qb / qa, lo), hi)
        q = min(q, (qa * s + 2.0 * qb) * s + qc)
    return q < -_Q_TOL


@njit(cache=True)
def part_boxes(cones, R, t, cam_R, cam_t, grow):
    """Image boxes of the parts' solids in normalised camera coordinates, ``(n_cams, 4, n_parts)``:
    x min, x max, y min, y max (±inf for a part not wholly in front of the camera).

    cones (n_parts, 5), R (n_parts, 3, 3), t (n_parts, 3) part2world; cam_R (n_cams, 3, 3),
    cam_t (n_cams, 3) world2cam; grow (n_cams, n_parts) metres added to the semi-axes and caps."""
    n_cams, n_parts = cam_R.shape[0], cones.shape[0]
    out = np.empty((n_cams, 4, n_parts))
    for c in range(n_cams):
        for p in range(n_parts):
            a, b, k, z1, z2 = cones[p, 0], cones[p, 1], cones[p, 2], cones[p, 3], cones[p, 4]
            g = grow[c, p]
            s = max(1.0 + k * z1, 1.0 + k * z2)
            xmin = ymin = np.inf
            xmax = ymax = -np.inf
            front = True
            for corner in range(8):
                lx = (a + g) * s * (1.0 if corner & 4 else -1.0)
                ly = (b + g) * s * (1.0 if corner & 2 else -1.0)
                lz = z2 + g if corner & 1 else z1 - g
                wx = R[p, 0, 0] * lx + R[p, 0, 1] * ly + R[p, 0, 2] * lz + t[p, 0]
                wy = R[p, 1, 0] * lx + R[p, 1, 1] * ly + R[p, 1, 2] * lz + t[p, 1]
                wz = R[p, 2, 0] * lx + R[p, 2, 1] * ly + R[p, 2, 2] * lz + t[p, 2]
                xc = cam_R[c, 0, 0] * wx + cam_R[c, 0, 1] * wy + cam_R[c, 0, 2] * wz + cam_t[c, 0]
                yc = cam_R[c, 1, 0] * wx + cam_R[c, 1, 1] * wy + cam_R[c, 1, 2] * wz + cam_t[c, 1]
                zc = cam_R[c, 2, 0] * wx + cam_R[c, 2, 1] * wy + cam_R[c, 2, 2] * wz + cam_t[c, 2]
                if not zc > _AHEAD:
                    front = False
                    break
                xmin, xmax = min(xmin, xc / zc), max(xmax, xc / zc)
                ymin, ymax = min(ymin, yc / zc), max(ymax, yc / zc)
            if front:
                out[c, 0, p], out[c, 1, p], out[c, 2, p], out[c, 3, p] = xmin, xmax, ymin, ymax
            else:
                out[c, 0, p], out[c, 1, p], out[c, 2, p], out[c, 3, p] = -np.inf, np.inf, -np.inf, np.inf
    return out


@njit(cache=True)
def _centres(cam_R, cam_t):
    """Camera centres in the world ``-R^T t``, (n_cams, 3)."""
    n_cams = cam_R.shape[0]
    centres = np.empty((n_cams, 3))
    for c in range(n_cams):
        for j in range(3):
            centres[c, j] = -(cam_R[c, 0, j] * cam_t[c, 0] + cam_R[c, 1, j] * cam_t[c, 1]
                              + cam_R[c, 2, j] * cam_t[c, 2])
    return centres


@njit(cache=True)
def _camera_terms(cones, R, t, centres, grow):
    """Per (camera, part): the camera centre m in the part frame as ``g = (m1/a', m2/b', 1 + k m3)``,
    ``q(0) = |g|²_(+,+,-)``, ``z1' - m3``, ``z2' - m3`` (a', b', z1', z2' grown by ``grow``), shape
    (n_cams, n_parts, 6)."""
    n_cams, n_parts = centres.shape[0], cones.shape[0]
    out = np.empty((n_cams, n_parts, 6))
    for c in range(n_cams):
        for p in range(n_parts):
            dx, dy, dz = centres[c, 0] - t[p, 0], centres[c, 1] - t[p, 1], centres[c, 2] - t[p, 2]
            m1 = R[p, 0, 0] * dx + R[p, 1, 0] * dy + R[p, 2, 0] * dz
            m2 = R[p, 0, 1] * dx + R[p, 1, 1] * dy + R[p, 2, 1] * dz
            m3 = R[p, 0, 2] * dx + R[p, 1, 2] * dy + R[p, 2, 2] * dz
            g = grow[c, p]
            g1 = m1 / (cones[p, 0] + g)
            g2 = m2 / (cones[p, 1] + g)
            g3 = 1.0 + cones[p, 2] * m3
            out[c, p, 0], out[c, p, 1], out[c, p, 2] = g1, g2, g3
            out[c, p, 3] = g1 * g1 + g2 * g2 - g3 * g3
            out[c, p, 4] = cones[p, 3] - g - m3
            out[c, p, 5] = cones[p, 4] + g - m3
    return out


@njit(cache=True, inline="always")
def _meets(cones, R, per_cp, c, q, g, dx, dy, dz, s_max):
    """Whether the segment ``C_c + s (dx, dy, dz)``, ``s in [0, s_max]``, meets part q's solid
    grown by g (``per_cp`` from ``_camera_terms``)."""
    d1 = R[q, 0, 0] * dx + R[q, 1, 0] * dy + R[q, 2, 0] * dz
    d2 = R[q, 0, 1] * dx + R[q, 1, 1] * dy + R[q, 2, 1] * dz
    d3 = R[q, 0, 2] * dx + R[q, 1, 2] * dy + R[q, 2, 2] * dz
    return _q_min_negative(per_cp[c, q, 0], per_cp[c, q, 1], per_cp[c, q, 2], per_cp[c, q, 3],
                           per_cp[c, q, 4], per_cp[c, q, 5], d1 / (cones[q, 0] + g), d2 / (cones[q, 1] + g),
                           cones[q, 2] * d3, d3, s_max)


@njit(cache=True)
def hidden_mask(cones, R, t, cam_R, cam_t, cam, part, points, test):
    """``tracker.imaging.visibility.hidden_points`` on plain arrays: bool (n,), True where the segment from
    camera ``cam[i]``'s centre to ``points[i]`` meets the solid of a part other than ``part[i]``
    (tested where ``test[i]``).  Pairs are culled by the point's image position against the part's
    image box (exact: the line of sight projects to that one point)."""
    n, n_cams, n_parts = points.shape[0], cam_R.shape[0], cones.shape[0]
    grow = np.zeros((n_cams, n_parts))
    box = part_boxes(cones, R, t, cam_R, cam_t, grow)
    centres = _centres(cam_R, cam_t)
    per_cp = _camera_terms(cones, R, t, centres, grow)
    hidden = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        if not test[i]:
            continue
        c = cam[i]
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        xc = cam_R[c, 0, 0] * px + cam_R[c, 0, 1] * py + cam_R[c, 0, 2] * pz + cam_t[c, 0]
        yc = cam_R[c, 1, 0] * px + cam_R[c, 1, 1] * py + cam_R[c, 1, 2] * pz + cam_t[c, 1]
        zc = cam_R[c, 2, 0] * px + cam_R[c, 2, 1] * py + cam_R[c, 2, 2] * pz + cam_t[c, 2]
        ahead = zc > _AHEAD
        x = xc / zc if ahead else 0.0
        y = yc / zc if ahead else 0.0
        dx, dy, dz = px - centres[c, 0], py - centres[c, 1], pz - centres[c, 2]
        for q in range(n_parts):
            if q == part[i]:
                continue
            if ahead and not (box[c, 0, q] <= x <= box[c, 1, q] and box[c, 2, q] <= y <= box[c, 3, q]):
                continue
            if _meets(cones, R, per_cp, c, q, 0.0, dx, dy, dz, 1.0):
                hidden[i] = True
                break
    return hidden


@njit(cache=True)
def covered_mask(cones, R, t, cam_R, cam_t, cam, directions, grow, range_m):
    """``tracker.imaging.visibility.covered_rays`` on plain arrays: bool (n,), True where the ray from camera
    ``cam[i]``'s centre along the unit ``directions[i]`` meets a solid (grown by ``grow`` (n_cams,
    n_parts) metres) within ``range_m``; culled by the parts' image boxes as ``hidden_mask``."""
    n, n_cams, n_parts = directions.shape[0], cam_R.shape[0], cones.shape[0]
    box = part_boxes(cones, R, t, cam_R, cam_t, grow)
    centres = _centres(cam_R, cam_t)
    per_cp = _camera_terms(cones, R, t, centres, grow)
    hit = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        c = cam[i]
        ux, uy, uz = directions[i, 0], directions[i, 1], directions[i, 2]
        zc = cam_R[c, 2, 0] * ux + cam_R[c, 2, 1] * uy + cam_R[c, 2, 2] * uz
        if not zc > _AHEAD:
            continue  # a ray pointing away from the camera meets nothing in front of it
        x = (cam_R[c, 0, 0] * ux + cam_R[c, 0, 1] * uy + cam_R[c, 0, 2] * uz) / zc
        y = (cam_R[c, 1, 0] * ux + cam_R[c, 1, 1] * uy + cam_R[c, 1, 2] * uz) / zc
        for q in range(n_parts):
            if not (box[c, 0, q] <= x <= box[c, 1, q] and box[c, 2, q] <= y <= box[c, 3, q]):
                continue
            if _meets(cones, R, per_cp, c, q, grow[c, q], range_m * ux, range_m * uy, range_m * uz, 1.0):
                hit[i] = True
                break
    return hit


@njit(cache=True)
def nearest_rows(samples, sample_cam, uv, used, per_cam):
    """Nearest used contour row of every boundary sample, within the sample's camera.

    samples (k, 2) pixels and their camera ``sample_cam`` (k,); contour pixels ``uv`` (N, 2) with
    camera c's rows in ``[c per_cam, (c + 1) per_cam)`` and ``used`` (N,) bool.  Returns (k,) int,
    -1 where the camera has no used row.  Per camera the used rows are binned by whole pixels along
    the image axis in which they spread most (v for an upright body, one counting sort); a
    sample's search visits the bins outwards from its own and stops once a bin's edge is farther
    than the best distance found (exact)."""
    k = samples.shape[0]
    out = np.full(k, -1, dtype=np.intp)
    if k == 0 or per_cam <= 0:
        return out
    n_cams = uv.shape[0] // per_cam
    for c in range(n_cams):
        rows = np.flatnonzero(used[c * per_cam:(c + 1) * per_cam]) + c * per_cam
        m = rows.size
        if m == 0:
            continue
        ax = 0 if np.ptp(uv[rows, 0]) >= np.ptp(uv[rows, 1]) else 1
        lo = uv[rows, ax].min()
        n_bins = int(uv[rows, ax].max() - lo) + 1
        start = np.zeros(n_bins + 1, dtype=np.intp)
        for r in rows:
            start[int(uv[r, ax] - lo) + 1] += 1
        for b in range(n_bins):
            start[b + 1] += start[b]
        fill = start[:-1].copy()
        us = np.empty(m)  # coordinate along the binning axis, binned order
        vs = np.empty(m)  # the other coordinate
        order = np.empty(m, dtype=np.intp)
        for r in rows:
            b = int(uv[r, ax] - lo)
            us[fill[b]], vs[fill[b]], order[fill[b]] = uv[r, ax], uv[r, 1 - ax], r
            fill[b] += 1
        for j in range(k):
            if sample_cam[j] != c:
                continue
            y0, y1 = samples[j, ax], samples[j, 1 - ax]
            b0 = min(max(int(math.floor(y0 - lo)), 0), n_bins - 1)
            best, arg = np.inf, -1
            b = b0
            while b < n_bins:
                edge = lo + b - y0  # distance along the axis to the bin's near edge (b > b0)
                if b > b0 and edge > 0.0 and edge * edge >= best:
                    break
                for i in range(start[b], start[b + 1]):
                    du, dv = us[i] - y0, vs[i] - y1
                    d2 = du * du + dv * dv
                    if d2 < best:
                        best, arg = d2, i
                b += 1
            b = b0 - 1
            while b >= 0:
                edge = y0 - (lo + b + 1)
                if edge > 0.0 and edge * edge >= best:
                    break
                for i in range(start[b], start[b + 1]):
                    du, dv = us[i] - y0, vs[i] - y1
                    d2 = du * du + dv * dv
                    if d2 < best:
                        best, arg = d2, i
                b -= 1
            out[j] = order[arg]
    return out


@njit(cache=True)
def sample_chamfer(sil, edge, offset_x, offset_y, fill, resolution, uv, rows, truncate, edge_weight, d, grad, dest):
    """Bilinear distances and gradients of one camera's quantised chamfer images
    (``segmentation.distance.ChamferImages.sample``: pixel centres at integer (u, v), the arrays
    extended with the truncation code ``fill``) at rows ``rows`` (n,) of ``uv`` (N, 2), written to
    rows ``dest`` (n,) of ``d`` (., 2) (silhouette, edge) and ``grad`` (., 2, 2), pixels.

    sil, edge (h, w) codes stored at ``offset_x, offset_y`` of the image; ``resolution`` pixels
    per code.  Distances above ``truncate`` are clipped to it with zero gradient; the edge
    distance is scaled by ``edge_weight``."""
    h, w = sil.shape
    for j in range(rows.size):
        i = rows[j]
        x = uv[i, 0] - offset_x
        y = uv[i, 1] - offset_y
        xf, yf = math.floor(x), math.floor(y)
        fx, fy = x - xf, y - yf
        ix, iy = int(min(max(xf, -2.0), w + 1.0)), int(min(max(yf, -2.0), h + 1.0))
        in_x0, in_x1 = 0 <= ix < w, -1 <= ix < w - 1
        in_y0, in_y1 = 0 <= iy < h, -1 <= iy < h - 1
        for img in range(2):
            a = sil if img == 0 else edge
            v00 = float(a[iy, ix]) if in_x0 and in_y0 else fill
            v10 = float(a[iy, ix + 1]) if in_x1 and in_y0 else fill
            v01 = float(a[iy + 1, ix]) if in_x0 and in_y1 else fill
            v11 = float(a[iy + 1, ix + 1]) if in_x1 and in_y1 else fill
            dx0 = v10 - v00
            dx1 = v11 - v01
            top = v00 + fx * dx0
            bottom = v01 + fx * dx1
            value = (top + fy * (bottom - top)) * resolution
            gx = (dx0 + fy * (dx1 - dx0)) * resolution
            gy = (bottom - top) * resolution
            if value > truncate:
                value, gx, gy = truncate, 0.0, 0.0
            wgt = 1.0 if img == 0 else edge_weight
            o = dest[j]
            d[o, img] = value * wgt
            grad[o, img, 0] = gx * wgt
            grad[o, img, 1] = gy * wgt


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


@njit(cache=True)
def screw_rows(motion, part, screws, affects):
    """Rows of per-screw motion times the parameters' screws of their parts (``tracker.imaging.jacobian.
    apply_screws``): ``J[i, k] = motion[i] · screws[:, k]`` where ``affects[part[i], k]``, else 0.

    motion (n, 6), part (n,), screws (6, n_params), affects (n_parts, n_params) bool."""
    n, n_params = motion.shape[0], screws.shape[1]
    J = np.zeros((n, n_params))
    for i in range(n):
        p = part[i]
        m0, m1, m2, m3, m4, m5 = motion[i, 0], motion[i, 1], motion[i, 2], motion[i, 3], motion[i, 4], motion[i, 5]
        for k in range(n_params):
            if affects[p, k]:
                J[i, k] = (m0 * screws[0, k] + m1 * screws[1, k] + m2 * screws[2, k]
                           + m3 * screws[3, k] + m4 * screws[4, k] + m5 * screws[5, k])
    return J


@njit(cache=True)
def image_motion(Y, JI, cam, part, z, theta, cones, R, t, cam_R, cam_t, sliding):
    """``J_I (A + B)`` of contour points (``tracker.imaging.jacobian``): (n, d, 6).

    Y (n, 3) world points, JI (n, d, 3) their projection Jacobians (d = 2; the identity, d = 3,
    gives A + B itself); per point its camera, part, height z and ruling angle θ; cones
    (n_parts, 5); R, t part2world; cam_R, cam_t world2cam.  Rows without a real ruling (f_θ²
    below its threshold) get no sliding term."""
    n, dim = Y.shape[0], JI.shape[1]
    M = np.empty((n, dim, 6))
    centres = _centres(cam_R, cam_t)
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


@njit(cache=True, inline="always")
def _screw_row(motion, p, screws, affects, J, out):
    """``J[out, k] = motion · screws[:, k]`` for the parameters k that move part p."""
    for k in range(screws.shape[1]):
        if affects[p, k]:
            J[out, k] = (motion[0] * screws[0, k] + motion[1] * screws[1, k] + motion[2] * screws[2, k]
                         + motion[3] * screws[3, k] + motion[4] * screws[4, k] + motion[5] * screws[5, k])


@njit(cache=True)
def assemble(d, grad, urows, rev_r, compact, jacobian, Mx, part, match, unit, weight, screws, affects):
    """Residual vector and Jacobian of ``tracker.fitting.cost.ChamferCost.evaluate`` (its module docstring
    gives the layout).

    d (N, 2), grad (N, 2, 2) sampled distances and gradients of the contour rows; urows (n,)
    the used rows (sorted); rev_r (K,) reverse residuals; ``compact``: keep only used rows' and
    reverse samples' residuals that are non-zero or have a non-zero gradient (else the fixed
    layout, 2 N + K).  With ``jacobian``: Mx (n, 2, 6) image motion of the used rows, part (N,),
    match (K,) matched contour row (-1: none), unit (K, 2) directions, ``weight`` the reverse
    weight, screws (6, n_params), affects (n_parts, n_params) bool; each row is its per-screw
    motion (gradient · Mx, or -weight · unit · Mx) times its part's parameter screws."""
    N, n, K = d.shape[0], urows.size, rev_r.size
    n_params = screws.shape[1]
    keep = np.ones((n, 2), dtype=np.bool_)
    n_fwd = 0
    for j in range(n):
        i = urows[j]
        for s in range(2):
            if compact:
                keep[j, s] = d[i, s] != 0.0 or grad[i, s, 0] != 0.0 or grad[i, s, 1] != 0.0
            n_fwd += keep[j, s]
    n_rev = 0
    for k in range(K):
        if not compact or rev_r[k] != 0.0:  # a matched sample has r > 0
            n_rev += 1
    m_rows = (n_fwd if compact else 2 * N) + n_rev
    r = np.zeros(m_rows)
    J = np.zeros((m_rows if jacobian else 0, n_params))
    motion = np.empty(6)
    row = 0
    for j in range(n):
        i = urows[j]
        for s in range(2):
            if not keep[j, s]:
                continue
            out = row if compact else 2 * i + s
            r[out] = d[i, s]
            if jacobian:
                for q in range(6):
                    motion[q] = grad[i, s, 0] * Mx[j, 0, q] + grad[i, s, 1] * Mx[j, 1, q]
                _screw_row(motion, part[i], screws, affects, J, out)
            row += 1
    if not compact:
        for i in range(N):  # unused rows: their residuals (0), no gradient
            r[2 * i], r[2 * i + 1] = d[i, 0], d[i, 1]
    base = n_fwd if compact else 2 * N
    row = 0
    pos = np.full(N, -1, dtype=np.intp)
    if jacobian:
        for j in range(n):
            pos[urows[j]] = j
    for k in range(K):
        if compact and rev_r[k] == 0.0:
            continue
        out = base + row
        r[out] = rev_r[k]
        if jacobian and match[k] >= 0:
            jm = pos[match[k]]  # matched rows are used rows
            for q in range(6):
                motion[q] = -weight * (unit[k, 0] * Mx[jm, 0, q] + unit[k, 1] * Mx[jm, 1, q])
            _screw_row(motion, part[match[k]], screws, affects, J, out)
        row += 1
    return r, J


@njit(cache=True)
def reverse_terms(samples, sample_cam, uv, used, per_cam, min_px, truncate, weight, cover_px, directions, focal,
                  cones, R, t, cam_R, cam_t, range_m):
    """The reverse (silhouette → model) term of ``tracker.fitting.cost.ChamferCost`` (its module docstring).

    samples (K, 2) boundary pixels of cameras ``sample_cam`` (K,); contour pixels ``uv`` (N, 2), used
    rows ``used`` (N,) with ``per_cam`` rows per camera.  Each sample is matched to its nearest used
    contour row (``nearest_rows``); one farther than ``min_px`` has the residual ``weight (dist -
    min_px)`` (clipped at ``truncate``, unmatched beyond), unless ``cover_px`` >= 0 and its pixel's
    ray (unit ``directions`` (K, 3)) meets the body grown by ``cover_px`` pixels at each part's depth
    (``covered_mask``; focal (n_cams,) pixels): then it lies on the predicted silhouette.

    Returns residuals (K,), matched rows (K,) (-1: none), unit directions from the match to the
    sample (K, 2) and distances (K,) (inf: no match; 0: on the predicted silhouette)."""
    K = samples.shape[0]
    nearest = nearest_rows(samples, sample_cam, uv, used, per_cam)
    r = np.zeros(K)
    match = np.full(K, -1, dtype=np.intp)
    unit = np.zeros((K, 2))
    dist = np.full(K, np.inf)
    far = np.zeros(K, dtype=np.bool_)
    n_far = 0
    for k in range(K):
        j = nearest[k]
        if j < 0:
            continue
        dx, dy = samples[k, 0] - uv[j, 0], samples[k, 1] - uv[j, 1]
        dist[k] = math.sqrt(dx * dx + dy * dy)
        if dist[k] > min_px:
            far[k] = True
            n_far += 1
    if cover_px >= 0.0 and n_far > 0:
        n_cams, n_parts = cam_R.shape[0], cones.shape[0]
        grow = np.empty((n_cams, n_parts))  # cover_px pixels in metres at each part's origin depth
        for c in range(n_cams):
            for p in range(n_parts):
                depth = cam_R[c, 2, 0] * t[p, 0] + cam_R[c, 2, 1] * t[p, 1] + cam_R[c, 2, 2] * t[p, 2] + cam_t[c, 2]
                grow[c, p] = cover_px * max(depth, 0.0) / focal[c]
        idx = np.flatnonzero(far)
        on = covered_mask(cones, R, t, cam_R, cam_t, sample_cam[idx], directions[idx], grow, range_m)
        for i in range(idx.size):
            if on[i]:
                far[idx[i]] = False
                dist[idx[i]] = 0.0
    for k in range(K):
        if not far[k]:
            continue
        j = nearest[k]
        d = dist[k]
        rk = d - min_px
        if rk > truncate:
            r[k] = weight * truncate
        else:
            r[k] = weight * rk
            match[k] = j
        inv = 1.0 / max(d, 1e-12)
        unit[k, 0] = (samples[k, 0] - uv[j, 0]) * inv
        unit[k, 1] = (samples[k, 1] - uv[j, 1]) * inv
    return r, match, unit, dist

