"""Occlusion and ray tests against the body's solids (``tracker.imaging.visibility``)."""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["part_boxes", "hidden_mask", "covered_mask"]

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
def camera_centres_kernel(cam_R, cam_t):
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
    centres = camera_centres_kernel(cam_R, cam_t)
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
    centres = camera_centres_kernel(cam_R, cam_t)
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
