"""Compiled (numba) loops of the blob tracker's per-frame work.

Each function is the loop form of a computation documented in the module that calls it (that
docstring is the reference; the tests compare the loops with numpy forms of it): the coloured hull's
per-view cube pixels, classes and colours and its neighbour vote (``tracker.blobs.colour_hull``), the
EM's expectation and moments (``tracker.blobs.em``), the body's point containment and the hull's
lattice membership (``tracker.blobs.tracking.body_contains``, ``hull_support``).
They take plain arrays only.  Compiled on first use and cached on disk (``cache=True``);
:func:`warm_up` compiles them before a live worker's first frame.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["pattern_pixels", "view_classes", "sample_colours", "cones_contain", "assign", "neighbour_vote", "weighted_moments", "lattice_member", "warm_up"]


@njit(cache=True, nogil=True, boundscheck=False)
def pattern_pixels(uv, side, pattern, w, h):
    """Pixels of a sample pattern over each cube's footprint: ``clip(rint(uv_i + side_i · pattern_j))``
    within the ``w × h`` image; uv (m, 2), side (m,), pattern (n, 2); returns cols, rows (m n,) intp."""
    m, n = uv.shape[0], pattern.shape[0]
    cols = np.empty(m * n, np.intp)
    rows = np.empty(m * n, np.intp)
    for i in range(m):
        for j in range(n):
            c = min(max(np.rint(uv[i, 0] + side[i] * pattern[j, 0]), 0.0), w - 1.0)
            r = min(max(np.rint(uv[i, 1] + side[i] * pattern[j, 1]), 0.0), h - 1.0)
            cols[i * n + j] = int(c)
            rows[i * n + j] = int(r)
    return cols, rows


@njit(cache=True, nogil=True, boundscheck=False)
def view_classes(d, inside, low, high, camouflage, background, edge, foreground, unknown):
    """Class (m,) int8 of each cube in one view from its samples' distances d (m, n)
    (``tracker.blobs.colour_hull._classify_view``); ``inside`` (m,) False: background."""
    m, n = d.shape
    cls = np.empty(m, np.int8)
    for i in range(m):
        n_bg = n_fg = 0
        total = 0.0
        for j in range(n):
            v = d[i, j]
            n_bg += v < low
            n_fg += v > high
            total += v
        if not inside[i] or (n_bg == n and (camouflage <= 0.0 or total / n < camouflage)):
            cls[i] = background
        elif n_fg == n:
            cls[i] = foreground
        elif n_bg > 0 and n_fg > 0:
            cls[i] = edge
        else:
            cls[i] = unknown
    return cls


@njit(cache=True, nogil=True, boundscheck=False)
def sample_colours(d, bgr, rows, low):
    """Mean colour (r, 3) float32 of the samples above ``low`` (all of them where none is) of cubes
    ``rows`` (r,) of distances d (m, n) and colours bgr (m, n, 3) (``tracker.blobs.colour_hull``'s docstring)."""
    n = d.shape[1]
    out = np.zeros((rows.shape[0], 3), np.float32)
    for k in range(rows.shape[0]):
        i = rows[k]
        cnt = 0
        s0 = s1 = s2 = 0.0
        for j in range(n):
            if d[i, j] > low:
                cnt += 1
                s0 += bgr[i, j, 0]
                s1 += bgr[i, j, 1]
                s2 += bgr[i, j, 2]
        if cnt == 0:
            for j in range(n):
                s0 += bgr[i, j, 0]
                s1 += bgr[i, j, 1]
                s2 += bgr[i, j, 2]
            cnt = n
        out[k, 0], out[k, 1], out[k, 2] = s0 / cnt, s1 / cnt, s2 / cnt
    return out


@njit(cache=True, nogil=True, boundscheck=False)
def cones_contain(cones, R, t, points, margins):
    """Whether each point lies in some part's cone grown by each margin
    (``tracker.blobs.tracking.body_contains``); cones (p, 5) a b k z1 z2, R (p, 3, 3), t (p, 3)
    part2world, points (m, 3), margins (k,) metres; returns (k, m) bool."""
    n_m, n_p, m = margins.shape[0], cones.shape[0], points.shape[0]
    out = np.zeros((n_m, m), np.bool_)
    for i in range(m):
        left = n_m
        for p in range(n_p):
            dx, dy, dz = points[i, 0] - t[p, 0], points[i, 1] - t[p, 1], points[i, 2] - t[p, 2]
            x = R[p, 0, 0] * dx + R[p, 1, 0] * dy + R[p, 2, 0] * dz  # R^T (x - t)
            y = R[p, 0, 1] * dx + R[p, 1, 1] * dy + R[p, 2, 1] * dz
            z = R[p, 0, 2] * dx + R[p, 1, 2] * dy + R[p, 2, 2] * dz
            r = max(1.0 + cones[p, 2] * z, 0.0)
            for k in range(n_m):
                if out[k, i]:
                    continue
                g = margins[k]
                if z < cones[p, 3] - g or z > cones[p, 4] + g:
                    continue
                ra = max(cones[p, 0] * r + g, 1e-9)
                rb = max(cones[p, 1] * r + g, 1e-9)
                if (x / ra) ** 2 + (y / rb) ** 2 <= 1.0:
                    out[k, i] = True
                    left -= 1
            if left == 0:
                break
    return out


@njit(cache=True, nogil=True, boundscheck=False)
def assign(centres, colours, mean, precision, colour_mean, colour_precision, extra, use, colour_weight, gate, soft,
           fallback):
    """Eqs. 2–3 for every voxel (``tracker.blobs.em.expectation``, its docstring).

    centres (n, 3), colours (n, v, 3); mean (b, 3), precision (b, 3, 3) the position Gaussians' inverse
    covariances; colour_mean (b, 3), colour_precision (b, 3, 3); extra (b,) added to each blob's
    distance (log-determinants or 0); use (b,) bool; soft ``k > 1`` shares among the k nearest;
    fallback (n, 3) each voxel's colour when ``colour_weight <= 0``.  Returns labels (n,) int64, colour
    (n, 3) float32, distance (n,), and the shares' voxel, blob (s,) int64, colour (s, 3) float32, weight (s,)."""
    n, v, b = centres.shape[0], colours.shape[1], mean.shape[0]
    k = min(soft, b) if soft > 1 else 0
    labels = np.empty(n, np.int64)
    dist = np.empty(n)
    colour = np.empty((n, 3), np.float32)
    s_vox = np.empty(n * k, np.int64)
    s_blob = np.empty(n * k, np.int64)
    s_col = np.empty((n * k, 3), np.float32)
    s_w = np.empty(n * k)
    n_s = 0
    dpos = np.empty(b)
    total = np.empty(b)
    view = np.zeros(b, np.int64)
    near = np.empty(max(k, 1), np.int64)
    wk = np.empty(max(k, 1))
    for i in range(n):
        for j in range(b):
            if not use[j]:
                dpos[j] = np.inf
                total[j] = np.inf
                continue
            x, y, z = centres[i, 0] - mean[j, 0], centres[i, 1] - mean[j, 1], centres[i, 2] - mean[j, 2]
            P = precision[j]
            q = (P[0, 0] * x * x + P[1, 1] * y * y + P[2, 2] * z * z
                 + (P[0, 1] + P[1, 0]) * x * y + (P[0, 2] + P[2, 0]) * x * z + (P[1, 2] + P[2, 1]) * y * z)
            dpos[j] = max(q, 0.0)
            t = dpos[j] + extra[j]
            if colour_weight > 0:
                C = colour_precision[j]
                best, arg = np.inf, 0
                for w in range(v):
                    x = colours[i, w, 0] - colour_mean[j, 0]
                    y = colours[i, w, 1] - colour_mean[j, 1]
                    z = colours[i, w, 2] - colour_mean[j, 2]
                    c = (C[0, 0] * x * x + C[1, 1] * y * y + C[2, 2] * z * z
                         + (C[0, 1] + C[1, 0]) * x * y + (C[0, 2] + C[2, 0]) * x * z + (C[1, 2] + C[2, 1]) * y * z)
                    if c < best:
                        best, arg = c, w
                view[j] = arg
                t += colour_weight * max(best, 0.0)
            total[j] = t
        lab = 0
        for j in range(1, b):
            if total[j] < total[lab]:
                lab = j
        if dpos[lab] > gate:
            labels[i], dist[i] = -1, np.inf
            lab_col = b - 1  # (the numpy form indexed the last blob's view for an unassigned voxel)
        else:
            labels[i], dist[i] = lab, total[lab]
            lab_col = lab
        for c in range(3):
            colour[i, c] = colours[i, view[lab_col], c] if colour_weight > 0 else fallback[i, c]
        if k == 0:
            continue
        for r in range(k):  # the k nearest by total distance, in order
            best = -1
            for j in range(b):
                taken = False
                for q in range(r):
                    if near[q] == j:
                        taken = True
                        break
                if not taken and (best < 0 or total[j] < total[best]):
                    best = j
            near[r] = best
        t0 = total[near[0]]
        s = 0.0
        for r in range(k):
            j = near[r]
            wk[r] = 0.0 if dpos[j] > gate else np.exp(-0.5 * (total[j] - t0))
            s += wk[r]
        s = max(s, 1e-300)
        for r in range(k):
            wr = wk[r] / s
            if wr > 1e-3:
                j = near[r]
                s_vox[n_s], s_blob[n_s], s_w[n_s] = i, j, wr
                for c in range(3):
                    s_col[n_s, c] = colours[i, view[j], c] if colour_weight > 0 else fallback[i, c]
                n_s += 1
    return labels, colour, dist, s_vox[:n_s], s_blob[:n_s], s_col[:n_s], s_w[:n_s]


@njit(cache=True, nogil=True, boundscheck=False)
def neighbour_vote(cells, cls, todo, background, edge, foreground, unknown):
    """The majority class of the 26 neighbours of each cell ``cells[todo]`` among ``cells`` (m, 3)
    int64 with classes ``cls`` (m,) int8 (``tracker.blobs.colour_hull._neighbour_vote``, its docstring);
    a dense grid of the cells' bounding box holds the classes.  Returns (t,) int8."""
    lo0, lo1, lo2 = cells[:, 0].min() - 1, cells[:, 1].min() - 1, cells[:, 2].min() - 1
    d0 = cells[:, 0].max() - lo0 + 2
    d1 = cells[:, 1].max() - lo1 + 2
    d2 = cells[:, 2].max() - lo2 + 2
    grid = np.full((d0, d1, d2), -1, np.int8)
    for i in range(cells.shape[0]):
        grid[cells[i, 0] - lo0, cells[i, 1] - lo1, cells[i, 2] - lo2] = cls[i]
    out = np.empty(todo.shape[0], np.int8)
    for k in range(todo.shape[0]):
        c = todo[k]
        x, y, z = cells[c, 0] - lo0, cells[c, 1] - lo1, cells[c, 2] - lo2
        n_bg = n_edge = n_fg = 0
        for a in range(-1, 2):
            for b in range(-1, 2):
                for e in range(-1, 2):
                    if a == 0 and b == 0 and e == 0:
                        continue
                    v = grid[x + a, y + b, z + e]
                    if v == background:
                        n_bg += 1
                    elif v == edge:
                        n_edge += 1
                    elif v == foreground:
                        n_fg += 1
        best = max(n_bg, n_edge, n_fg)
        if best == 0:
            out[k] = unknown
        elif n_edge == best:
            out[k] = edge
        elif n_fg == best:
            out[k] = foreground
        else:
            out[k] = background
    return out


@njit(cache=True, nogil=True, boundscheck=False)
def weighted_moments(label, X, w, extra, n_blobs):
    """Per blob the weighted mean (b, 3) and covariance (b, 3, 3) of points X (m, 3) with labels
    (m,) and weights w (m,), plus ``extra`` (m,) weighted into the diagonal (``tracker.blobs.em.maximisation``:
    a cube's own spread); NaN for a blob without weight.  Two passes: the covariance about the mean."""
    W = np.zeros(n_blobs)
    mu = np.zeros((n_blobs, 3))
    cov = np.zeros((n_blobs, 3, 3))
    ext = np.zeros(n_blobs)
    for i in range(label.shape[0]):
        j = label[i]
        W[j] += w[i]
        for a in range(3):
            mu[j, a] += w[i] * X[i, a]
    for j in range(n_blobs):
        for a in range(3):
            mu[j, a] = mu[j, a] / W[j] if W[j] > 0 else np.nan
    for i in range(label.shape[0]):
        j = label[i]
        d0, d1, d2 = X[i, 0] - mu[j, 0], X[i, 1] - mu[j, 1], X[i, 2] - mu[j, 2]
        wi = w[i]
        cov[j, 0, 0] += wi * d0 * d0
        cov[j, 1, 1] += wi * d1 * d1
        cov[j, 2, 2] += wi * d2 * d2
        cov[j, 0, 1] += wi * d0 * d1
        cov[j, 0, 2] += wi * d0 * d2
        cov[j, 1, 2] += wi * d1 * d2
        ext[j] += wi * extra[i]
    for j in range(n_blobs):
        inv = 1.0 / W[j] if W[j] > 0 else np.nan
        for a in range(3):
            for b in range(a, 3):
                cov[j, a, b] *= inv
                cov[j, b, a] = cov[j, a, b]
            cov[j, a, a] += ext[j] * inv
    return mu, cov


@njit(cache=True, nogil=True, boundscheck=False)
def lattice_member(cells, query):
    """Whether each lattice cell ``query`` (m, 3) int64 is one of ``cells`` (k, 3) int64, through a
    dense grid of the cells' bounding box (``tracker.blobs.tracking.hull_support``); (m,) bool."""
    out = np.zeros(query.shape[0], np.bool_)
    if cells.shape[0] == 0:
        return out
    lo0, lo1, lo2 = cells[:, 0].min(), cells[:, 1].min(), cells[:, 2].min()
    d0 = cells[:, 0].max() - lo0 + 1
    d1 = cells[:, 1].max() - lo1 + 1
    d2 = cells[:, 2].max() - lo2 + 1
    grid = np.zeros((d0, d1, d2), np.bool_)
    for i in range(cells.shape[0]):
        grid[cells[i, 0] - lo0, cells[i, 1] - lo1, cells[i, 2] - lo2] = True
    for i in range(query.shape[0]):
        x, y, z = query[i, 0] - lo0, query[i, 1] - lo1, query[i, 2] - lo2
        if 0 <= x < d0 and 0 <= y < d1 and 0 <= z < d2:
            out[i] = grid[x, y, z]
    return out


def _read_only(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def warm_up() -> None:
    """Compile every kernel of this module (or load it from numba's on-disk cache), for the array
    kinds the fit passes (a model's cones are read-only: another numba signature)."""
    m = 2
    cones = _read_only(np.ones((1, 5)))
    cols, rows = pattern_pixels(np.zeros((m, 2)), np.ones(m), np.zeros((4, 2)), 4, 3)
    d = np.zeros((m, 4), np.float32)
    view_classes(d, np.ones(m, bool), 16.0, 64.0, 6.0, 0, 1, 2, 3)
    sample_colours(d, np.zeros((m, 4, 3), np.float32), np.arange(m), 16.0)
    cones_contain(cones, np.eye(3)[None], np.zeros((1, 3)), np.zeros((m, 3)), np.zeros(2))
    neighbour_vote(np.zeros((m, 3), np.int64), np.zeros(m, np.int8), np.arange(1), 0, 1, 2, 3)
    lattice_member(np.zeros((m, 3), np.int64), np.zeros((m, 3), np.int64))
    weighted_moments(np.zeros(m, np.int64), np.zeros((m, 3)), np.ones(m), np.zeros(m), 2)
    eye = np.eye(3)[None]
    assign(np.zeros((m, 3)), np.zeros((m, 2, 3), np.float32), np.zeros((1, 3)), eye, np.zeros((1, 3)), eye,
           np.zeros(1), np.ones(1, bool), 1.0, 25.0, 3, np.zeros((m, 3), np.float32))
