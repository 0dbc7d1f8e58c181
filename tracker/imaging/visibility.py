"""Occlusion of contour points by the other parts of the body.

A point P seen from camera centre C is hidden when the segment ``C + s (P - C)``,
``s in [0, 1]``, meets the solid truncated cone of another part (its end caps
included).  In a part's frame the solid is::

    (x/a)² + (y/b)² <= (1 + k z)²,   z1 <= z <= z2

(``1 + k z > 0`` on ``[z1, z2]``, so this is one nappe: a convex solid).  Along
the segment, with ``g = (m1/a, m2/b, 1 + k m3)`` from the camera centre m and
``h = (d1/a, d2/b, k d3)`` from the direction d (both in the part frame), the
cone test is the quadratic ``q(s) = |g + s h|²_(+,+,-) <= 0`` and the caps cut
``s`` to the slab interval.  The segment meets the solid when the minimum of
``q`` over ``[0, 1] ∩ slab`` is negative: the minimum of a quadratic on an
interval is at an end or at its vertex.

Speed: (point, part) pairs are first culled in the image plane: the part's
bounding box, projected by the pinhole model (a central projection maps the
box's convex hull inside the hull of its corners' images, so the cull is
conservative for boxes in front of the camera), must overlap the image box of
the point's chunk of neighbouring points.  The exact test then runs on the
remaining pairs (about a fifth of all), all at once.

A point inside another part's solid counts as hidden (it is not on the body's
outline).  A point exactly on another part's surface is not (tolerance 1e-9
on ``q``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from capture.camera import Camera, stack_cameras
from tracker.body.kinematics import Pose
from tracker.body.model import BodyModel

__all__ = ["hidden_points", "covered_rays"]

_Q_TOL = 1e-9


def hidden_points(
    model: BodyModel,
    pose: Pose,
    cameras: Sequence[Camera],
    cam: np.ndarray,
    part: np.ndarray,
    points: np.ndarray,
    *,
    only: np.ndarray | None = None,
) -> np.ndarray:
    """Which points are hidden from their camera by another part.

    Parameters
    ----------
    model : BodyModel
    pose : Pose
    cameras : sequence of Camera, length n_cams
    cam, part : ndarray of int, shape (n,)
        Camera index and own part index of each point (the own part is not an occluder).
    points : ndarray, shape (n, 3)
        World points.
    only : ndarray of bool, shape (n,), optional
        Test only these points; the others are reported not hidden.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    n = points.shape[0]
    hidden = np.zeros(n, dtype=bool)
    rows = np.arange(n) if only is None else np.flatnonzero(only)
    if rows.size == 0:
        return hidden
    st = stack_cameras(cameras)
    cam_R, cam_t = st.rotation, st.translation  # world2cam (n_cams, 3, 3), (n_cams, 3)
    centres = -np.einsum("cji,cj->ci", cam_R, cam_t)  # (n_cams, 3) world
    c, own, P = cam[rows], part[rows], points[rows]
    i, q = _candidate_pairs(model, pose, cam_R, cam_t, c, own, P)
    if i.size == 0:
        return hidden
    n_parts = model.n_parts
    R, t = pose.rotation, pose.translation
    a, b, k, z1, z2 = model.cones.T  # each (n_parts,)
    # per (camera, part): g = (m1/a, m2/b, 1 + k m3), q(0) = |g|²_(+,+,-), z1 - m3, z2 - m3
    m_all = np.einsum("pji,cpj->cpi", R, centres[:, None, :] - t[None, :, :])  # (n_cams, n_parts, 3)
    per_cp = np.empty((6,) + m_all.shape[:2])  # component-major: gathered rows stay contiguous
    g1, g2 = m_all[..., 0] / a, m_all[..., 1] / b
    g3 = 1.0 + k * m_all[..., 2]
    per_cp[0], per_cp[1], per_cp[2] = g1, g2, g3
    per_cp[3] = g1 * g1 + g2 * g2 - g3 * g3
    per_cp[4], per_cp[5] = z1 - m_all[..., 2], z2 - m_all[..., 2]
    # per (point, part): h = (d1/a, d2/b, k d3) and d3 of d = R_q^T (P - C), all parts from one
    # product (4 n_parts, 3) @ (3, n) with the columns of every R scaled by (1/a, 1/b, k, 1)
    W = np.empty((4, n_parts, 3))
    W[0] = R[:, :, 0] / a[:, None]
    W[1] = R[:, :, 1] / b[:, None]
    W[2] = R[:, :, 2] * k[:, None]
    W[3] = R[:, :, 2]
    n = P.shape[0]
    per_pp = W.reshape(4 * n_parts, 3) @ (P - centres[c]).T  # (4 n_parts, n): [component, part, point]
    h1, h2, h3, d3 = np.take(per_pp.reshape(4, n_parts * n), q * n + i, axis=1)  # each (pairs,)
    g1, g2, g3, qc, e1, e2 = np.take(per_cp.reshape(6, -1), c[i] * n_parts + q, axis=1)
    blocked = _meets_solid(g1, g2, g3, qc, e1, e2, h1, h2, h3, d3, s_max=1.0)
    hidden[rows[i[blocked]]] = True
    return hidden


def _meets_solid(g1, g2, g3, qc, e1, e2, h1, h2, h3, d3, *, s_max: float) -> np.ndarray:
    """Whether ``m + s d``, ``s in [0, s_max]``, meets the solid (module docstring): the minimum
    of ``q(s) = qa s² + 2 qb s + qc`` over ``[0, s_max] ∩ slab`` is below ``-_Q_TOL``.  All
    arguments are arrays of one shape (``qc = |g|²_(+,+,-)``, ``e1 = z1 - m3``, ``e2 = z2 - m3``)."""
    qa = h1 * h1 + h2 * h2 - h3 * h3
    qb = g1 * h1 + g2 * h2 - g3 * h3
    # slab z1 <= m3 + s d3 <= z2, intersected with s in [0, s_max]
    flat = np.abs(d3) < 1e-15
    inside_slab = (e1 <= 0.0) & (e2 >= 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):  # flat rows are replaced below
        sa, sb = e1 / d3, e2 / d3
    lo = np.maximum(np.minimum(sa, sb), 0.0)
    hi = np.minimum(np.maximum(sa, sb), s_max)
    if flat.any():
        lo[flat] = np.where(inside_slab[flat], 0.0, s_max)
        hi[flat] = np.where(inside_slab[flat], s_max, 0.0)
    ok = (lo <= hi) & (~flat | inside_slab)
    # the minimum of q on [lo, hi]: at the (clipped) vertex when q is convex, else at an end
    convex = qa > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        vertex = np.where(convex, np.clip(-qb / qa, lo, hi), lo)

    def q_at(s):
        return (qa * s + 2.0 * qb) * s + qc

    qmin = np.minimum(np.minimum(q_at(lo), q_at(hi)), q_at(vertex))
    return ok & (qmin < -_Q_TOL)


def covered_rays(model: BodyModel, pose: Pose, cameras: Sequence[Camera], cam: np.ndarray, directions: np.ndarray, *,
                 margin_m: np.ndarray | float = 0.0, range_m: float = 50.0) -> np.ndarray:
    """Which rays from the centres of ``cameras`` meet the body: a pixel's ray meets it exactly when
    the pixel lies on the model's silhouette.

    Parameters
    ----------
    cam : ndarray of int, shape (n,)
        Camera of each ray (index into ``cameras``), grouped (non-decreasing) for speed.
    directions : ndarray, shape (n, 3)
        Unit directions, world.
    margin_m : ndarray (n_cams, n_parts) or float
        Every solid grown by this much (its semi-axes before the taper, and both caps), metres:
        e.g. a tolerance of ``t`` pixels is ``t × depth / focal length`` for a part at that depth.
    range_m : rays are followed this far.

    The (ray, part) pairs are culled by the parts' image boxes (as in ``hidden_points``; a ray
    pointing away from a camera meets nothing), then tested exactly on the segment
    ``[0, range_m]`` of each ray.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    D = np.asarray(directions, dtype=float).reshape(-1, 3)
    cam = np.asarray(cam, dtype=np.intp).reshape(-1)
    if cam.shape[0] != D.shape[0]:
        raise ValueError(f"cam, directions: expected one camera index per ray, got {cam.shape[0]} and {D.shape[0]}")
    hit = np.zeros(D.shape[0], dtype=bool)
    if D.shape[0] == 0:
        return hit
    st = stack_cameras(cameras)
    cam_R, cam_t = st.rotation, st.translation
    centres = -np.einsum("cji,cj->ci", cam_R, cam_t)  # (n_cams, 3) world
    n_parts = model.n_parts
    # cull: (ray, part) pairs whose ray's image point lies in the part's image box
    grow = np.broadcast_to(np.asarray(margin_m, dtype=float), (centres.shape[0], n_parts))
    box = _part_boxes(model, pose, cam_R, cam_t, grow)[cam]  # (n, 4, n_parts)
    Dc = np.einsum("nij,nj->ni", cam_R[cam], D)  # directions in the camera frames
    ahead = Dc[:, 2] > 1e-9
    zc = np.where(ahead, Dc[:, 2], 1.0)
    xr, yr = (Dc[:, 0] / zc)[:, None], (Dc[:, 1] / zc)[:, None]
    inside = (xr >= box[:, 0]) & (xr <= box[:, 1]) & (yr >= box[:, 2]) & (yr <= box[:, 3])
    i, q = np.nonzero(inside & ahead[:, None])
    if i.size == 0:
        return hit
    R, t = pose.rotation, pose.translation
    a, b, k, z1, z2 = model.cones.T  # each (n_parts,)
    c = cam[i]
    g_pair = grow[c, q]
    a_g, b_g = a[q] + g_pair, b[q] + g_pair
    Rcat = R.transpose(1, 0, 2).reshape(3, 3 * n_parts)  # x @ Rcat: x in every part frame
    m = ((centres @ Rcat).reshape(-1, n_parts, 3) - np.einsum("pj,pji->pi", t, R)[None])[c, q]  # (pairs, 3)
    d = (D @ (range_m * Rcat)).reshape(-1, n_parts, 3)[i, q]  # (pairs, 3) segment vectors in the part frames
    g1, g2, g3 = m[:, 0] / a_g, m[:, 1] / b_g, 1.0 + k[q] * m[:, 2]
    on = _meets_solid(g1, g2, g3, g1 * g1 + g2 * g2 - g3 * g3, z1[q] - g_pair - m[:, 2], z2[q] + g_pair - m[:, 2],
                      d[:, 0] / a_g, d[:, 1] / b_g, k[q] * d[:, 2], d[:, 2], s_max=1.0)
    hit[i[on]] = True
    return hit


_CHUNK = 4  # consecutive points (same camera) culled together first (half a ruling at n_samples = 8)


def _candidate_pairs(model, pose, cam_R, cam_t, c, own, P):
    """(point, occluder) pairs that may intersect: indices (pairs,), (pairs,).

    The image box of each chunk of ``_CHUNK`` consecutive points of one camera (contour
    samples along a ruling are neighbours) against each part's image box; the points of
    overlapping chunks are paired with that part.  Chunks with a point behind the camera
    are never culled."""
    box = _part_boxes(model, pose, cam_R, cam_t)
    n = c.size
    Pc = _to_cameras(cam_R, cam_t, c, P)
    ahead = Pc[:, 2] > 1e-9
    zp = np.where(ahead, Pc[:, 2], 1.0)
    xp = np.where(ahead, Pc[:, 0] / zp, 0.0)
    yp = np.where(ahead, Pc[:, 1] / zp, 0.0)
    # chunk level: each chunk's box (an unbounded one when a point is behind the camera)
    start = np.ones(n, dtype=bool)
    start[1:] = (c[1:] != c[:-1]) | (np.arange(1, n) % _CHUNK == 0)
    starts = np.flatnonzero(start)
    lens = np.diff(np.append(starts, n))
    behind = np.logical_or.reduceat(~ahead, starts)
    grow = np.where(behind, np.inf, 0.0)[:, None]
    bb = box[c[starts]]  # (n_chunks, 4, n_parts)
    over = np.minimum.reduceat(xp, starts)[:, None] - grow <= bb[:, 1]
    over &= np.maximum.reduceat(xp, starts)[:, None] + grow >= bb[:, 0]
    over &= np.minimum.reduceat(yp, starts)[:, None] - grow <= bb[:, 3]
    over &= np.maximum.reduceat(yp, starts)[:, None] + grow >= bb[:, 2]
    ch, q = np.nonzero(over)
    # every point of an overlapping chunk (a finer, per-point box test costs more than it saves)
    cnt = lens[ch]
    first = np.cumsum(cnt) - cnt
    rep = np.repeat(np.arange(ch.size), cnt)
    i = starts[ch][rep] + (np.arange(rep.size) - first[rep])
    q = q[rep]
    keep = own[i] != q  # a part does not hide its own contour
    return i[keep], q[keep]


def _part_boxes(model, pose, cam_R, cam_t, grow=0.0) -> np.ndarray:
    """Image boxes of the parts' solids in normalised camera coordinates (x/z, y/z), shape
    (n_cams, 4, n_parts): x min, x max, y min, y max (unbounded for a part not wholly in front);
    ``grow`` (n_cams, n_parts) or scalar: the solids grown by that much (metres)."""
    a, b, k, z1, z2 = (model.cones[:, j] for j in range(5))
    s_max = np.maximum(1.0 + k * z1, 1.0 + k * z2)
    g = np.broadcast_to(np.asarray(grow, dtype=float), (cam_R.shape[0], model.n_parts))[..., None]
    corners = np.empty((cam_R.shape[0], model.n_parts, 8, 3))  # part-frame bounding box of each solid
    corners[..., 0] = ((a + g[..., 0]) * s_max)[..., None] * _CORNERS[:, 0]
    corners[..., 1] = ((b + g[..., 0]) * s_max)[..., None] * _CORNERS[:, 1]
    corners[..., 2] = np.where(_CORNERS[:, 2] > 0, z2[:, None] + g, z1[:, None] - g)
    world = np.einsum("pij,cpkj->cpki", pose.rotation, corners) + pose.translation[None, :, None, :]
    Xc = np.einsum("cij,cpkj->cpki", cam_R, world) + cam_t[:, None, None, :]  # (n_cams, n_parts, 8, 3)
    depth = Xc[..., 2]
    front = depth.min(axis=-1) > 1e-9  # (n_cams, n_parts)
    zc = np.where(front[..., None], depth, 1.0)
    xn, yn = Xc[..., 0] / zc, Xc[..., 1] / zc
    inf = np.where(front, 0.0, np.inf)
    return np.stack([xn.min(-1) - inf, xn.max(-1) + inf, yn.min(-1) - inf, yn.max(-1) + inf], axis=1)


def _to_cameras(cam_R, cam_t, c, P):
    """World points P (n, 3) into the frames of their cameras c (n,): (n, 3)."""
    n_cams = cam_R.shape[0]
    if c.size and np.all(c[1:] >= c[:-1]):  # grouped by camera (contour rows are): one product each
        out = np.empty_like(P)
        bounds = np.searchsorted(c, np.arange(n_cams + 1))
        for j in range(n_cams):
            sl = slice(bounds[j], bounds[j + 1])
            out[sl] = P[sl] @ cam_R[j].T + cam_t[j]
        return out
    return np.einsum("nij,nj->ni", cam_R[c], P) + cam_t[c]


_CORNERS = np.array(np.meshgrid([-1, 1], [-1, 1], [0, 1], indexing="ij")).reshape(3, 8).T  # (8, 3)
