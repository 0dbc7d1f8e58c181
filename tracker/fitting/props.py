"""Props: operator-given world boxes (a chair, a stool) that are never body.

A prop is an axis-aligned box in world coordinates (metres, the calibration's frame; z up from
the floor), ``--prop x0,y0,z0,x1,y1,z1`` or ``[[prop]] box = [x0, y0, z0, x1, y1, z1]`` in
``session.toml``.  It acts twice:

* **clutter**: its projection in each camera (``prop_masks``) is cut from the silhouette where
  the body's projection does not cover it (``tracker.fitting.scene``), so it neither pulls
  through the reverse term nor counts in the IoU gate;
* **a limit in the fit** (``PropPenalty``): points along every part's axis may not come nearer
  to the box than ``clearance`` × the part's smaller radius there (the root part, the pelvis,
  whose cone reaches below the hip joints onto a seat, ``root_clearance`` ×).  Each point contributes one
  residual ``weight × max(0, clearance × r − s(X))`` (pixels), ``s`` the signed distance of the
  point to the box (negative inside); its Jacobian is the box's outward direction times the
  point's Jacobian (``tracker.body.kinematics.point_jacobian``).  A limb can then not be fitted
  into the chair, whatever the chair's pixels say.

``prop_rays`` gives, per pixel of a prop's projection, where its ray enters the nearest solid box,
and ``rays_meet_capsules`` whether a ray segment passes within a radius of segments: a pixel whose
ray meets a solid box before it meets the body shows the prop, not the body
(``SceneOptions.prop_depth_tol_m``).  A box marked hollow (``solid`` False, ``[[prop]] hollow =
true``: a chair's bounding box around its solid seat and legs) is cut and limits the fit as any, but
the rays pass through it: what is seen through it is body only where the ray meets the body.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

import cv2
import numpy as np

from capture.session import check_box
from tracker.body.kinematics import forward, point_jacobian
from tracker.body.model import BodyModel
from tracker.errors import TrackerError

__all__ = ["PropBox", "PropPenalty", "parse_prop", "PropRays", "prop_rays", "rays_meet_capsules", "prop_masks", "seat_box"]

_NUMBER = r"\s*(-?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*"
_PROP = re.compile(r"^" + ",".join([_NUMBER] * 6) + r"$")


class PropError(TrackerError, ValueError):
    """A bad prop box; the message names it."""


@dataclass(frozen=True, eq=False)
class PropBox:
    """An axis-aligned world box.

    Attributes
    ----------
    lo, hi : ndarray, shape (3,)
        Opposite corners, metres, ``lo < hi`` on every axis.
    solid : bool
        The box is filled (a seat slab, a leg): the body cannot be in it and it hides what is
        behind it.  False: a hollow region (a chair's bounding box) whose pixels are never body
        unless a ray through it meets the body; the fit may put the body in it.
    """

    lo: np.ndarray
    hi: np.ndarray
    solid: bool = True

    @classmethod
    def from_values(cls, values: Sequence, where: str = "prop", *, solid: bool = True) -> "PropBox":
        """A box from ``[x0, y0, z0, x1, y1, z1]`` (metres, the corners in any order per axis);
        PropError naming ``where`` unless ``capture.session.check_box`` accepts them."""
        box = np.asarray(check_box(values, where, PropError))
        lo, hi = box[:3].copy(), box[3:].copy()
        lo.setflags(write=False)
        hi.setflags(write=False)
        return cls(lo, hi, bool(solid))

    def corners(self) -> np.ndarray:
        """The eight corners, (8, 3) metres."""
        return np.array([[x, y, z] for x in (self.lo[0], self.hi[0]) for y in (self.lo[1], self.hi[1])
                         for z in (self.lo[2], self.hi[2])])

    def signed_distance(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance of ``points`` (n, 3) to the box (metres, negative inside) and its
        gradient (n, 3), the unit outward direction (inside: the nearest face's normal)."""
        X = np.asarray(points, dtype=float).reshape(-1, 3)
        below, above = self.lo - X, X - self.hi
        out = np.maximum(np.maximum(below, above), 0.0)
        d_out = np.linalg.norm(out, axis=1)
        grad = np.where(above > 0, 1.0, 0.0) * out - np.where(below > 0, 1.0, 0.0) * out
        outside = d_out > 0
        grad[outside] /= d_out[outside, None]
        # inside: distance to the nearest face
        gaps = np.concatenate([-below, -above], axis=1)  # (n, 6) >= 0 inside: X - lo, hi - X
        face = np.argmin(gaps, axis=1)
        inside = ~outside
        if np.any(inside):
            normals = np.concatenate([-np.eye(3), np.eye(3)])
            grad[inside] = normals[face[inside]]
        dist = np.where(outside, d_out, -gaps[np.arange(len(X)), face])
        return dist, grad


def parse_prop(text: str) -> PropBox:
    """``"x0,y0,z0,x1,y1,z1"`` (metres) -> PropBox; PropError otherwise."""
    m = _PROP.match(str(text))
    if m is None:
        raise PropError(f"--prop: expected x0,y0,z0,x1,y1,z1 in metres, got {text!r}")
    return PropBox.from_values([float(g) for g in m.groups()], where=f"--prop {text!r}")


def prop_masks(cameras: Iterable, props: Sequence[PropBox]) -> dict[str, np.ndarray]:
    """Per camera name, the (h, w) bool mask of the props' projections (each box the convex hull
    of its projected corners; a box with a corner behind the camera is left out of that camera's
    mask: its projection is unbounded, and the fit's limit still keeps the body out of it)."""
    out = {}
    for cam in cameras:
        mask = np.zeros((cam.height, cam.width), np.uint8)
        for box in props:
            corners = box.corners()
            if np.any(cam.depth(corners) <= 1e-3):
                continue
            uv = np.clip(cam.project(corners), -1e4, 1e4)
            hull = cv2.convexHull(np.round(uv * 16).astype(np.int32))
            cv2.fillConvexPoly(mask, hull, 1, shift=4)
        out[cam.name] = mask.astype(bool)
    return out


@dataclass(frozen=True, eq=False)
class PropRays:
    """The rays of one camera's prop pixels.

    Attributes
    ----------
    pixels : ndarray of int, shape (n, 2)
        (row, column) of every pixel of the props' projection.
    origin : ndarray, shape (3,)
        The camera's centre, world metres.
    directions : ndarray, shape (n, 3)
        Unit world direction of each pixel's ray.
    entry : ndarray, shape (n,)
        Distance (metres along the ray) at which it first enters a solid box (0: the centre is
        inside one), inf where it meets none.
    through : ndarray of bool, shape (n,)
        The ray meets a box, solid or hollow (False: a pixel of the projection's outline whose
        ray passes beside every box).
    """

    pixels: np.ndarray
    origin: np.ndarray
    directions: np.ndarray
    entry: np.ndarray
    through: np.ndarray


def prop_rays(cameras: Iterable, props: Sequence[PropBox], masks: Mapping[str, np.ndarray]) -> dict[str, PropRays]:
    """Per camera name, the ``PropRays`` of the pixels of ``masks[name]`` (the props'
    projections, ``prop_masks``) against ``props``."""
    out = {}
    for cam in cameras:
        mask = masks.get(cam.name)
        v, u = np.nonzero(mask) if mask is not None else (np.zeros(0, int), np.zeros(0, int))
        d = cam.rays(np.stack([u, v], axis=1).astype(float)) if len(v) else np.zeros((0, 3))
        c = np.asarray(cam.center, dtype=float)
        best = np.full(len(d), np.inf)
        through = np.zeros(len(d), bool)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            for box in props:
                t1, t2 = (box.lo - c) * inv, (box.hi - c) * inv
                t_near = np.nanmax(np.minimum(t1, t2), axis=1)
                t_far = np.nanmin(np.maximum(t1, t2), axis=1)
                hit = (t_near <= t_far) & (t_far > 0)
                through |= hit
                if box.solid:
                    best = np.where(hit, np.minimum(best, np.maximum(t_near, 0.0)), best)
        out[cam.name] = PropRays(np.stack([v, u], axis=1), c, d, best, through)
    return out


def rays_meet_capsules(origin: np.ndarray, directions: np.ndarray, length: np.ndarray, ends_a: np.ndarray,
                       ends_b: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Whether each ray segment ``origin + t d``, 0 <= t <= ``length`` (metres; (n,), non-positive:
    empty) comes within ``radius`` (m,) of a capsule axis ``ends_a``–``ends_b`` ((m, 3) each):
    (n,) bool.  The segments' closest points, clamped to both segments (Ericson's method); capsule
    after capsule, only the rays not yet met."""
    d1 = np.asarray(directions, dtype=float).reshape(-1, 3)
    L = np.maximum(np.asarray(length, dtype=float).reshape(-1), 0.0)
    o = np.asarray(origin, dtype=float)
    met = np.zeros(len(d1), bool)
    todo = np.flatnonzero(L > 0)
    for p2, q2, rad in zip(np.asarray(ends_a, float), np.asarray(ends_b, float), np.asarray(radius, float)):
        if not todo.size:
            break
        d2, r = q2 - p2, p2 - o
        e = max(float(d2 @ d2), 1e-12)
        f = float(d2 @ r)
        dd, ll = d1[todo], L[todo]
        b = dd @ d2
        c = dd @ r
        # s on the ray, t on the axis: minimise |o + s d1 - p2 - t d2| (|d1| = 1)
        s = np.clip((c * e - b * f) / np.maximum(e - b * b, 1e-12), 0.0, ll)
        t = np.clip((b * s - f) / e, 0.0, 1.0)
        s = np.clip(c + b * t, 0.0, ll)
        gap = s[:, None] * dd - r - t[:, None] * d2
        hit = np.einsum("ij,ij->i", gap, gap) <= rad * rad
        met[todo[hit]] = True
        todo = todo[~hit]
    return met


class PropPenalty:
    """The fit's limit keeping the body out of the props (module docstring).

    Parameters
    ----------
    props : sequence of PropBox
    weight : residual per metre of intrusion, pixels per metre
    samples : points per part along its cone's axis (ends included)
    clearance : the axis keeps this many times the part's smaller radius from a box
    root_clearance : the same for the root part (the pelvis: it rests on a seat)
    thigh_taper : a thigh's factor goes from ``root_clearance`` at its hip end to ``clearance`` at
        its knee end (the buttock rests on the seat with the pelvis)
    """

    def __init__(self, props: Sequence[PropBox], *, weight: float = 2000.0, samples: int = 5,
                 clearance: float = 1.0, root_clearance: float = 0.0, thigh_taper: bool = False) -> None:
        if samples < 2:
            raise PropError(f"samples: expected >= 2, got {samples!r}")
        self.props = list(props)
        self.weight = float(weight)
        self.samples = int(samples)
        self.clearance = float(clearance)
        self.root_clearance = float(root_clearance)
        self.thigh_taper = bool(thigh_taper)
        self._points: dict[int, tuple] = {}

    def _model_points(self, model: BodyModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Part index (m,), part-frame axis points (m, 3), required clearance (m,) metres."""
        key = id(model)
        if key not in self._points or self._points[key][0] is not model:
            a, b, k, z1, z2 = (model.cones[:, i] for i in range(5))
            t = np.linspace(0.0, 1.0, self.samples)
            z = z1[:, None] + (z2 - z1)[:, None] * t[None, :]  # (n_parts, samples)
            radius = np.minimum(a, b)[:, None] * np.maximum(1.0 + k[:, None] * z, 0.0)
            part = np.repeat(np.arange(model.n_parts), self.samples)
            pts = np.zeros((part.size, 3))
            pts[:, 2] = z.ravel()
            factor = np.repeat(np.where(model.parent < 0, self.root_clearance, self.clearance)[:, None],
                               self.samples, axis=1)
            if self.thigh_taper:
                thighs = [i for i, n in enumerate(model.part_names) if n.endswith("thigh")]
                factor[thighs] = self.root_clearance + (self.clearance - self.root_clearance) * t[None, :]
            self._points = {key: (model, part, pts, (factor * radius).ravel())}
        return self._points[key][1:]

    def residuals(self, model: BodyModel, params: np.ndarray, *, jacobian: bool = False, pose=None):
        """Residuals (m × n_props,) in pixels and, with ``jacobian``, their Jacobian
        (m × n_props, n_params); ``pose``: ``forward(model, params)`` when already made."""
        part, pts, clear = self._model_points(model)
        pose = forward(model, np.asarray(params, dtype=float)) if pose is None else pose
        X = pose.to_world(part, pts)
        rs, gs = [], []
        for box in self.props:
            dist, grad = box.signed_distance(X)
            depth = clear - dist
            active = depth > 0
            rs.append(self.weight * np.where(active, depth, 0.0))
            gs.append(np.where(active[:, None], -self.weight * grad, 0.0))
        r = np.concatenate(rs) if rs else np.zeros(0)
        if not jacobian:
            return r, None
        J = np.zeros((r.size, model.n_params))
        G = np.concatenate(gs) if gs else np.zeros((0, 3))
        rows = np.flatnonzero(np.any(G != 0, axis=1))
        if rows.size:
            idx = rows % len(part)
            PJ = point_jacobian(model, pose, part[idx], X[idx])  # (n, 3, n_params)
            J[rows] = np.einsum("ni,nip->np", G[rows], PJ)
        return r, J



def seat_box(cameras: Sequence, silhouettes: Mapping[str, np.ndarray], explained: Mapping[str, np.ndarray],
             joints: Mapping[str, np.ndarray], *, thigh_radius: float = 0.0, voxel_m: float = 0.02,
             behind_knee_m: float = 0.10,
             behind_hip_m: float = 0.35, side_m: float = 0.35, quantile: float = 2.0) -> PropBox | None:
    """The seat under a seated subject, learned from one frame set: a seated prior, no operator.

    The foreground's visual hull (``tracker.search.hull``, ``voxel_m`` cubes) minus the voxels
    every camera's ``explained`` mask (the fitted body's grown projection, camera name -> (h, w)
    bool) covers, kept below the hip joints, along the thighs' forward direction from
    ``behind_hip_m`` behind the hips to ``behind_knee_m`` short of the knees (the shanks hang in
    front of a seat), within ``side_m`` of the hips sideways; the box is those voxels'
    ``quantile``–(100 − ``quantile``) % extent, down to the floor and up to at least the thighs'
    underside (the lower hip joint minus ``thigh_radius``, metres: a seat supports the thighs; the
    hull under them is hidden by the body).  ``joints``: the fit's joint centres (name -> (3,) m).  None when the fit is not seated (a thigh more than 35° off
    the horizontal) or fewer than 50 voxels are left."""
    from tracker.search.hull import centres_inside, visual_hull

    hips = 0.5 * (np.asarray(joints["left_hip"], float) + np.asarray(joints["right_hip"], float))
    knees = 0.5 * (np.asarray(joints["left_knee"], float) + np.asarray(joints["right_knee"], float))
    for side in ("left", "right"):
        thigh = np.asarray(joints[f"{side}_knee"], float) - np.asarray(joints[f"{side}_hip"], float)
        if abs(thigh[2]) > np.sin(np.radians(35.0)) * np.linalg.norm(thigh):
            return None
    fwd = np.array([knees[0] - hips[0], knees[1] - hips[1], 0.0])
    reach = float(np.linalg.norm(fwd))
    if reach < 0.1:
        return None
    fwd /= reach
    left = np.array([-fwd[1], fwd[0], 0.0])
    cams = list(cameras)
    hull = visual_hull(cams, [silhouettes[c.name] for c in cams], min_voxel_m=voxel_m)
    X = hull.centres
    if len(X) == 0:
        return None
    covered = centres_inside(X, cams, [explained[c.name] for c in cams])
    rel = X - hips
    along, across = rel @ fwd, rel @ left
    keep = (~covered & (X[:, 2] < hips[2]) & (along > -behind_hip_m) & (along < reach - behind_knee_m)
            & (np.abs(across) < side_m))
    if np.count_nonzero(keep) < 50:
        return None
    Y = X[keep]
    lo = np.percentile(Y, quantile, axis=0)
    hi = np.percentile(Y, 100.0 - quantile, axis=0)
    lo[2] = 0.0
    hip_z = min(float(joints["left_hip"][2]), float(joints["right_hip"][2]))
    hi[2] = max(hi[2], hip_z - float(thigh_radius))
    return PropBox.from_values(list(lo) + list(hi), where="seat_box")
