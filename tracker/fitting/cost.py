"""Chamfer residuals of predicted extremal contours and their analytic Jacobian.

For every visible contour point ``x_i = uv(Φ)`` (``tracker.imaging.contours``) seen by camera c, two
residuals (Knossow et al., ACCV 2006 §3): the bilinearly interpolated distance to camera c's
silhouette (0 inside it) and the distance to the edges inside the silhouette.  Their sum has
one clear minimum where the predicted contour lies on the observed one.  The residual Jacobian
is the image gradient of the distance times the contour-point Jacobian (IJCV 2008 §5)::

    dr_i/dΦ = ∇D_c(x_i) · dx_i/dΦ,     dx_i/dΦ = J_I (A + B) J_H   (tracker.imaging.jacobian)

Distances are truncated at ``truncate_px`` (zero gradient beyond), so clutter and a missing limb
add a bounded constant; the solver's robust loss (IRLS) does the rest.

``chamfer`` objects are ``tracker.fitting.sampler.ChamferSampler``: anything with
``sample(uv (n, 2)) -> (d_sil (n,), grad_sil (n, 2), d_edge (n,), grad_edge (n, 2))`` in pixels,
e.g. ``segmentation.distance.ChamferImages``.

**Reverse term** (optional, ``reverse_weight > 0``): the chamfer cost above is model → image
only, so a limb whose contour lies inside the silhouette (e.g. over the torso) is not pulled
back to the part of the silhouette it left uncovered.  For ``reverse_samples`` points ``y_j``
per camera on the observed silhouette boundary, the residual is
``w (max(0, ‖y_j − x_m(j)‖ − reverse_min_px))`` with ``x_m(j)`` the nearest used predicted
contour point of that camera (matches recomputed at every evaluation, as in ICP); its Jacobian
is ``−w u_jᵀ dx_m(j)/dΦ`` with ``u_j`` the unit vector from ``x_m(j)`` to ``y_j``.  A sample that
lies on the predicted silhouette (its pixel's ray meets a cone grown by ``reverse_cover_px``,
``tracker.imaging.visibility.covered_rays``) is explained by the model and has no residual: the contour
samples are sparse and leave out the end caps (the top of the head, the soles, the tips of the
hands), so without that test the residual was not zero at the true pose (6 renders of a knossow54
pose, reverse_min_px 2: 352 of 900 samples, sum of squares 3040 px² against 617 px² for the
forward term) and pulled the pose off it; with it, it is zero there.

Residual layout: ``r`` has shape ``(2 N + K,)``: ``r[2i] = d_sil_i``, ``r[2i+1] = d_edge_i`` for
the N contour rows, 0 for rows not used (not visible, or camera absent), then the K reverse
residuals (K = 0 without the reverse term).  ``compact=True`` (what the LM solver takes; the scipy
baseline needs the fixed length) keeps only the residuals of used contour rows and reverse samples
that are non-zero or have a non-zero gradient: the others add exactly 0 to the cost and to the
normal equations (most silhouette residuals are 0 inside the silhouette, most reverse ones 0
within ``reverse_min_px``), so the solver's products are about 3x smaller.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from capture.camera import Camera, stack_cameras
from tracker.imaging.contours import Contours, extremal_contours
from tracker.imaging.jacobian import contour_image_motion
from tracker.fitting.boundary import boundary_rays
from tracker.fitting.screw_jacobian import ScrewJacobian
from tracker.kernels import assemble, reverse_terms, sample_chamfer, screw_rows
from tracker.body.kinematics import Pose, forward
from tracker.body.model import BodyModel
from tracker.imaging.visibility import hidden_points

__all__ = ["ChamferCost", "CostTerms"]

# placeholders of tracker.kernels.assemble's arguments when there is no Jacobian or no reverse term
_NO_MOTION = np.zeros((0, 2, 6))
_NO_REV, _NO_MATCH, _NO_UNIT = np.zeros(0), np.zeros(0, dtype=np.intp), np.zeros((0, 2))
_RAY_RANGE_M = 50.0  # boundary-sample rays are followed this far (tracker.visibility.covered_rays)


class _StackedChamfer:
    """The quantised ``ChamferImages`` of all cameras behind one ``sample`` call: each camera's
    points are sampled by one compiled call on its own arrays (no copy), reading exactly what its
    ``ChamferImages.sample`` reads (the truncation value, zero gradient, off the stored array).
    ``build`` returns None unless every object is a ``ChamferImages`` with the same resolution,
    truncation and dtype."""

    def __init__(self, chamfer) -> None:
        self.chamfer = list(chamfer)
        # per camera: the arguments of tracker.kernels.sample_chamfer before the points
        self._args = [((ch.silhouette_q, ch.edges_q) if ch.silhouette_q.size else
                       (np.zeros((0, 0), ch.silhouette_q.dtype), np.zeros((0, 0), ch.silhouette_q.dtype)))
                      + (float(ch.offset_xy[0]), float(ch.offset_xy[1]), float(ch.max_code), float(ch.resolution_px))
                      for ch in self.chamfer]

    @classmethod
    def build(cls, chamfer: Sequence):
        from segmentation.distance import ChamferImages

        if not chamfer or not all(type(ch) is ChamferImages for ch in chamfer):
            return None
        first = chamfer[0]
        if any(ch.resolution_px != first.resolution_px or ch.max_distance_px != first.max_distance_px
               or ch.silhouette_q.dtype != first.silhouette_q.dtype for ch in chamfer):
            return None
        return cls(chamfer)

    def sample(self, uv: np.ndarray, cam: np.ndarray):
        """``ChamferImages.sample`` of camera ``cam`` (n,) at its pixels ``uv`` (n, 2)."""
        d, grad = self.sample_rows(uv, cam, np.arange(len(uv)))
        return d[:, 0], grad[:, 0], d[:, 1], grad[:, 1]

    def sample_rows(self, uv: np.ndarray, cam: np.ndarray, rows: np.ndarray, *, truncate_px: float | None = None,
                    edge_weight: float = 1.0, out=None):
        """Distances (n, 2) (silhouette, edge) and gradients (n, 2, 2) at rows ``rows`` (n,) of
        ``uv`` (N, 2), ``cam`` (N,); distances above ``truncate_px`` clipped with zero gradient,
        the edge distance scaled by ``edge_weight`` (``tracker.kernels.sample_chamfer``).  With
        ``out = (d (N, 2), grad (N, 2, 2))`` they are written to rows ``rows`` of those instead."""
        rows = np.asarray(rows, dtype=np.intp)
        cr = np.asarray(cam)[rows]
        if out is None:
            d, grad = np.empty((rows.size, 2)), np.empty((rows.size, 2, 2))
            dest = np.arange(rows.size)
        else:
            d, grad = out
            dest = rows
        if cr.size > 1 and np.any(cr[1:] < cr[:-1]):  # group by camera (contour rows already are)
            order = np.argsort(cr, kind="stable")
            rows, cr, dest = rows[order], cr[order], dest[order]
        bounds = np.searchsorted(cr, np.arange(len(self.chamfer) + 1)).tolist()
        uv = np.ascontiguousarray(uv, dtype=float)
        trunc = np.inf if truncate_px is None else float(truncate_px)
        weight = float(edge_weight)
        for c, args in enumerate(self._args):
            b0, b1 = bounds[c], bounds[c + 1]
            if b1 > b0:
                sample_chamfer(*args, uv, rows[b0:b1], trunc, weight, d, grad, dest[b0:b1])
        return d, grad


@dataclass(frozen=True, eq=False)
class CostTerms:
    """The cost evaluated at one pose.

    Attributes
    ----------
    pose : Pose
    contours : Contours
        N rows over the cost's cameras.
    used : ndarray of bool, shape (N,)
        Rows that contribute.
    d_sil, d_edge : ndarray, shape (N,)
        Truncated distances, pixels (0 where not used).
    residuals : ndarray, shape (2 N + K,)
        Or fewer when compact (module docstring; K reverse residuals).
    jacobian : ndarray, shape (len(residuals), n_params), ScrewJacobian (``structured``), or None
    boundary_dist : ndarray, shape (K,), or None
        Distance in pixels from each observed boundary sample to the nearest used contour point of
        its camera (0 on the predicted silhouette, inf where that camera has no contour point);
        None without the reverse term.
    boundary_cam : ndarray of int, shape (K,), or None
        The camera (index into the cost's cameras) of each observed boundary sample; None without the
        reverse term.
    """

    pose: Pose
    contours: Contours
    used: np.ndarray
    d_sil: np.ndarray
    d_edge: np.ndarray
    residuals: np.ndarray
    jacobian: np.ndarray | ScrewJacobian | None
    boundary_dist: np.ndarray | None = None
    boundary_cam: np.ndarray | None = None

    @property
    def n_used(self) -> int:
        return int(self.used.sum())

    def inside_fraction(self, *, tol_px: float = 1.0) -> float:
        """Fraction of used contour points within ``tol_px`` of their camera's silhouette (NaN if none)."""
        n = self.n_used
        return float(np.count_nonzero(self.d_sil[self.used] <= tol_px) / n) if n else float("nan")

    def coverage(self, *, tol_px: float = 8.0) -> float:
        """Fraction of the observed silhouette-boundary samples within ``tol_px`` of a predicted
        contour point or on the predicted silhouette; NaN without the reverse term.  Low when the
        model misses part of the silhouette (e.g. a limb tracked to the wrong place)."""
        if self.boundary_dist is None or not self.boundary_dist.size:
            return float("nan")
        return float(np.count_nonzero(self.boundary_dist <= tol_px) / self.boundary_dist.size)

    def coverage_per_camera(self, n_cams: int, *, tol_px=8.0) -> np.ndarray:
        """``coverage`` of each camera's own boundary samples, shape (n_cams,) (NaN for a camera
        without samples, and everywhere without the reverse term); ``tol_px``: a float, or one per
        camera, shape (n_cams,)."""
        if self.boundary_dist is None or self.boundary_cam is None:
            return np.full(n_cams, np.nan)
        tol = np.broadcast_to(np.asarray(tol_px, dtype=float), (n_cams,))
        n = np.bincount(self.boundary_cam, minlength=n_cams)[:n_cams]
        hit = np.bincount(self.boundary_cam, weights=self.boundary_dist <= tol[self.boundary_cam],
                          minlength=n_cams)[:n_cams]
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(n > 0, hit / np.maximum(n, 1), np.nan)

    def rms_px(self, *, max_px: float | None = None) -> float:
        """RMS of the used residuals (both terms), pixels (NaN if none); with ``max_px``, of those
        at most ``max_px`` only (the inliers: see ``outlier_fraction``).

        The tracker's quality figure is the plain RMS: a few large residuals dominate it (contour
        crossing the torso where the image shows no edge, feet the segmentation lost; measured
        shares: docs/tuning.md, "Cost"); the inlier RMS measures the fit on the rest."""
        n = self.n_used
        if not n:
            return float("nan")
        r = np.concatenate([self.d_sil[self.used], self.d_edge[self.used]])
        if max_px is not None:
            r = r[r <= max_px]
            if not r.size:
                return float("nan")
        return float(np.sqrt(r @ r / r.size))

    def outlier_fraction(self, *, max_px: float) -> float:
        """Fraction of the used residuals (both terms) above ``max_px`` (NaN if none)."""
        n = self.n_used
        if not n:
            return float("nan")
        return float((np.count_nonzero(self.d_sil[self.used] > max_px)
                      + np.count_nonzero(self.d_edge[self.used] > max_px)) / (2 * n))


class ChamferCost:
    """The tracker's data term for one frame set (the tracker's tuned option values are in
    ``tracker.fitting.tracking.TrackerOptions``; the defaults here are the plain chamfer cost).

    Parameters
    ----------
    model : BodyModel
    cameras : sequence of Camera, length n_cams (only the cameras with an image this frame)
    chamfer : sequence, length n_cams, of ChamferSampler (``tracker.fitting.sampler``), aligned with
        ``cameras`` (``in_camera_order`` of the mapping the rest of the tracker takes)
    sliding : use the sliding term B of the contour Jacobian (IJCV 2008 §5, ``tracker.imaging.jacobian``)
    n_samples : contour points per side of each part
    truncate_px : distances above it are clipped (zero gradient); None keeps the images' own
    edge_weight : scale of the edge residual relative to the silhouette residual
    reverse_weight, reverse_samples, reverse_min_px, reverse_cover_px : the reverse term (module
        docstring); off at weight 0.  Boundary samples come from the chamfer objects'
        ``silhouette_q``; ``reverse_cover_px`` None (the default) turns the on-silhouette test
        off (the tracker turns it on, ``TrackerOptions``; ``tracker.search.refine.refine`` leaves it
        off: its searches from far-off poses rely on the pull of all far samples).
    visibility : ``"step"`` (default): occlusion is recomputed where the Jacobian is evaluated
        (each linearisation point) and that set of rows is kept for the trial steps from it;
        ``"frame"``: computed once, at the first pose evaluated, and kept; ``"always"``: at every
        evaluation; ``"none"``: occlusion ignored.  (Occlusion tests are the costly part.)
    """

    def __init__(self, model: BodyModel, cameras: Sequence[Camera], chamfer: Sequence, *, sliding: bool = True,
                 n_samples: int = 12, visibility: str = "step", truncate_px: float | None = 30.0,
                 edge_weight: float = 1.0, reverse_weight: float = 0.0, reverse_samples: int = 120,
                 reverse_min_px: float = 2.0, reverse_cover_px: float | None = None) -> None:
        cameras = list(cameras)
        chamfer = list(chamfer)
        if len(cameras) != len(chamfer):
            raise ValueError(f"chamfer: expected one per camera ({len(cameras)}), got {len(chamfer)}")
        for cam, ch in zip(cameras, chamfer):
            if not callable(getattr(ch, "sample", None)):
                raise TypeError(f"chamfer for camera {cam.name!r}: expected an object with sample(uv)")
        if n_samples < 1:
            raise ValueError(f"n_samples: expected >= 1, got {n_samples}")
        self.model = model
        self.cameras = cameras
        self.chamfer = chamfer
        self.sliding = bool(sliding)
        self.n_samples = int(n_samples)
        if visibility not in ("step", "frame", "always", "none"):
            raise ValueError(f"visibility: expected 'step', 'frame', 'always' or 'none', got {visibility!r}")
        self.visibility = visibility
        self._frozen_visible: np.ndarray | None = None
        self.truncate_px = None if truncate_px is None else float(truncate_px)
        self.edge_weight = float(edge_weight)
        self.reverse_weight = float(reverse_weight)
        self.reverse_min_px = float(reverse_min_px)
        self.reverse_cover_px = None if reverse_cover_px is None else float(reverse_cover_px)
        want_rays = self.reverse_weight > 0 and self.reverse_cover_px is not None
        if self.reverse_weight > 0:
            got = [boundary_rays(ch, cam, max_points=reverse_samples, rays=want_rays)
                   for ch, cam in zip(chamfer, cameras)]
        else:
            got = [(np.zeros((0, 2)), np.zeros((0, 3))) for _ in chamfer]
        self.boundary = [b for b, _ in got]
        self.n_reverse = sum(len(b) for b in self.boundary)
        self._boundary_all = np.concatenate(self.boundary) if self.n_reverse else np.zeros((0, 2))
        self._boundary_cam = np.repeat(np.arange(len(self.boundary)), [len(b) for b in self.boundary])
        self._ray_dirs = (np.concatenate([r for _, r in got]) if want_rays and self.n_reverse
                          else np.zeros((self.n_reverse, 3)))
        self._focal = np.array([c.matrix[0, 0] for c in cameras], dtype=float)
        self._stacked = _StackedChamfer.build(chamfer)
        self._cache: tuple | None = None
        self.n_evaluations = 0

    @property
    def n_rows(self) -> int:
        """N, the number of contour rows (residuals = 2 N)."""
        return len(self.cameras) * self.model.n_parts * 2 * self.n_samples

    def _sample(self, contours: Contours, used: np.ndarray):
        """Distances (N, 2) and gradients (N, 2, 2) of both images at the used rows (0 elsewhere)."""
        N = contours.n_points
        d = np.zeros((N, 2))
        grad = np.zeros((N, 2, 2))
        rows = np.flatnonzero(used)
        if self._stacked is not None:
            self._stacked.sample_rows(contours.uv, contours.cam, rows, truncate_px=self.truncate_px,
                                      edge_weight=self.edge_weight, out=(d, grad))
        else:
            d[rows], grad[rows] = self._sample_rows(contours, rows)
        return d, grad

    def _sample_rows(self, contours: Contours, rows: np.ndarray):
        """Distances (n, 2) and gradients (n, 2, 2) (silhouette, edge) at contour rows ``rows`` (n,),
        truncated and weighted."""
        if self._stacked is not None:
            return self._stacked.sample_rows(contours.uv, contours.cam, rows, truncate_px=self.truncate_px,
                                             edge_weight=self.edge_weight)
        d = np.zeros((rows.size, 2))
        grad = np.zeros((rows.size, 2, 2))
        cam = contours.cam[rows]
        for c, ch in enumerate(self.chamfer):  # other chamfer objects: one call per camera
            sel = np.flatnonzero(cam == c)
            if sel.size:
                ds, gs, de, ge = ch.sample(contours.uv[rows[sel]])
                d[sel, 0], d[sel, 1] = ds, de
                grad[sel, 0], grad[sel, 1] = gs, ge
        if self.truncate_px is not None:
            over = d > self.truncate_px
            d[over] = self.truncate_px
            grad[over] = 0.0
        d[:, 1] *= self.edge_weight
        grad[:, 1] *= self.edge_weight
        return d, grad

    def _reverse(self, pose: Pose, contours: Contours, used: np.ndarray):
        """Reverse residuals (K,), matched contour rows (K,), unit directions (K, 2), distances (K,)
        (0 for a sample on the predicted silhouette) (``tracker.kernels.reverse_terms``).

        A sample on the predicted silhouette (e.g. on an end cap, or between two contour samples)
        is explained by the model: no residual, whatever its nearest contour point.  (Tested at
        every evaluation: reusing a linearisation point's answer at the trial points let steps
        that uncover samples look free: see docs/tuning.md, Cost.)"""
        per_cam = contours.n_points // max(len(self.cameras), 1)
        st = stack_cameras(self.cameras)
        return reverse_terms(self._boundary_all, self._boundary_cam, contours.uv, used, per_cam, self.reverse_min_px,
                             np.inf if self.truncate_px is None else self.truncate_px, self.reverse_weight,
                             -1.0 if self.reverse_cover_px is None else self.reverse_cover_px, self._ray_dirs,
                             self._focal, self.model.cones, pose.rotation, pose.translation, st.rotation,
                             st.translation, _RAY_RANGE_M)

    def evaluate(self, params: np.ndarray, *, jacobian: bool = False, compact: bool = False,
                 structured: bool = False) -> CostTerms:
        """Residuals (and Jacobian) at a pose; see the module docstring for the layout.

        Parameters
        ----------
        params : ndarray, shape (n_params,)
        jacobian : bool
            Also the Jacobian (a new linearisation point: occlusion recomputed with ``"step"``).
        compact : bool
            Keep only the residuals that can be non-zero (what the LM solver takes).
        structured : bool
            The Jacobian as a ``ScrewJacobian`` (per-row screw motion; what the LM solver takes)
            instead of the dense array.

        Returns
        -------
        CostTerms
        """
        params = np.asarray(params, dtype=float)
        fresh = self.visibility == "always" or (self.visibility in ("frame", "step") and self._frozen_visible is None)
        if self.visibility == "step" and jacobian and not (self._cache is not None and self._cache[-1]
                                                           and np.array_equal(self._cache[0], params)):
            fresh = True  # a new linearisation point: recompute occlusion there
        same = self._cache is not None and np.array_equal(self._cache[0], params)
        if not fresh and same:
            pose, contours, used, d, grad, rev = self._cache[1:-1]
        elif fresh and same and self.visibility in ("frame", "step") and not self._cache[-1]:
            # a trial point becomes the linearisation point: keep its contours, add the occlusion test
            pose, contours, used_trial, d, grad, rev = self._cache[1:-1]
            hidden = hidden_points(self.model, pose, self.cameras, contours.cam, contours.part, contours.points,
                                   only=contours.valid)
            contours = replace(contours, visible=contours.valid & ~hidden)
            self._frozen_visible = contours.visible.copy()
            used = contours.valid & self._frozen_visible
            if not np.array_equal(used, used_trial):  # sample the rows that came into use only
                d, grad = d.copy(), grad.copy()
                d[used_trial & ~used] = 0.0
                grad[used_trial & ~used] = 0.0
                added = np.flatnonzero(used & ~used_trial)
                d[added], grad[added] = self._sample_rows(contours, added)
                rev = self._reverse(pose, contours, used) if self.n_reverse else None
            self._cache = (params.copy(), pose, contours, used, d, grad, rev, True)
        else:
            pose = forward(self.model, params)
            contours = extremal_contours(self.model, pose, self.cameras, n_samples=self.n_samples,
                                         visibility=fresh)
            if fresh and self.visibility in ("frame", "step"):
                self._frozen_visible = contours.visible.copy()
            if self.visibility in ("frame", "step"):
                used = contours.valid & self._frozen_visible
            else:
                used = contours.visible.copy()
            d, grad = self._sample(contours, used)
            rev = self._reverse(pose, contours, used) if self.n_reverse else None
            self._cache = (params.copy(), pose, contours, used, d, grad, rev, fresh)
            self.n_evaluations += 1
        urows = np.flatnonzero(used)
        # compact: a residual that is 0 with a 0 gradient (a contour point inside its silhouette, a
        # boundary sample within reverse_min_px) adds nothing to the cost or the normal equations.
        # Residual rows are linear in the image motion J_I (A + B) (n, 2, 6): gradients and reverse
        # directions are applied there, then the parts' screws (tracker.kernels.assemble)
        if jacobian:
            Mx = contour_image_motion(self.model, pose, self.cameras, contours, sliding=self.sliding, rows=urows)
        else:
            Mx = _NO_MOTION
        rev_r, match, unit = (rev[0], rev[1], rev[2]) if rev is not None else (_NO_REV, _NO_MATCH, _NO_UNIT)
        r, motion, part = assemble(d, grad, urows, rev_r, bool(compact), bool(jacobian), Mx, contours.part, match,
                                   unit, self.reverse_weight)
        J = None
        if jacobian:
            screws = np.ascontiguousarray(np.concatenate([pose.screw_w, pose.screw_v], axis=1).T)
            J = (ScrewJacobian(motion, part, screws, self.model.affects) if structured
                 else screw_rows(motion, part, screws, self.model.affects))
        return CostTerms(pose, contours, used, d[:, 0], d[:, 1], r, J, None if rev is None else rev[3],
                         None if rev is None else self._boundary_cam)

    def residual_fn(self, *, compact: bool = True, structured: bool = False):
        """``fun(x, jacobian) -> (r, J or None)`` for ``tracker.fitting.solver``; ``compact`` and
        ``structured`` as ``evaluate``."""

        def fun(x, jacobian):
            t = self.evaluate(x, jacobian=jacobian, compact=compact, structured=structured)
            return t.residuals, t.jacobian

        return fun
