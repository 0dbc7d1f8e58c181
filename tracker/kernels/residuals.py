"""The chamfer cost's per-evaluation loops (``tracker.fitting.cost``): sampling, the reverse term,
residual and Jacobian assembly."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tracker.kernels.occlusion import covered_mask

__all__ = ["nearest_rows", "sample_chamfer", "screw_rows", "assemble", "reverse_terms"]


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


@njit(cache=True)
def screw_rows(motion, part, screws, affects):
    """Rows of per-screw motion times the parameters' screws of their parts (``tracker.imaging.jacobian.
    apply_screws``): ``J[i, k] = motion[i] · screws[:, k]`` where ``affects[part[i], k]``, else 0 (a row
    whose ``part[i]`` is negative is zero).

    motion (n, 6), part (n,), screws (6, n_params), affects (n_parts, n_params) bool."""
    n, n_params = motion.shape[0], screws.shape[1]
    J = np.zeros((n, n_params))
    for i in range(n):
        p = part[i]
        if p < 0:
            continue
        m0, m1, m2, m3, m4, m5 = motion[i, 0], motion[i, 1], motion[i, 2], motion[i, 3], motion[i, 4], motion[i, 5]
        for k in range(n_params):
            if affects[p, k]:
                J[i, k] = (m0 * screws[0, k] + m1 * screws[1, k] + m2 * screws[2, k]
                           + m3 * screws[3, k] + m4 * screws[4, k] + m5 * screws[5, k])
    return J


@njit(cache=True)
def assemble(d, grad, urows, rev_r, compact, jacobian, Mx, part, match, unit, weight):
    """Residual vector and Jacobian rows of ``tracker.fitting.cost.ChamferCost.evaluate`` (its module
    docstring gives the layout).

    d (N, 2), grad (N, 2, 2) sampled distances and gradients of the contour rows; urows (n,)
    the used rows (sorted); rev_r (K,) reverse residuals; ``compact``: keep only used rows' and
    reverse samples' residuals that are non-zero or have a non-zero gradient (else the fixed
    layout, 2 N + K).  With ``jacobian``: Mx (n, 2, 6) image motion of the used rows, part (N,),
    match (K,) matched contour row (-1: none), unit (K, 2) directions, ``weight`` the reverse
    weight.  Returns r (m,), and with ``jacobian`` each row's motion per unit screw of its part
    (gradient · Mx, or -weight · unit · Mx) (m, 6) and that part (m,) (-1: a zero row): the
    Jacobian row is that motion times the part's parameter screws (``screw_rows``)."""
    N, n, K = d.shape[0], urows.size, rev_r.size
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
    M = np.zeros((m_rows if jacobian else 0, 6))
    P = np.full(m_rows if jacobian else 0, -1, dtype=np.intp)
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
                    M[out, q] = grad[i, s, 0] * Mx[j, 0, q] + grad[i, s, 1] * Mx[j, 1, q]
                P[out] = part[i]
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
                M[out, q] = -weight * (unit[k, 0] * Mx[jm, 0, q] + unit[k, 1] * Mx[jm, 1, q])
            P[out] = part[match[k]]
        row += 1
    return r, M, P


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
