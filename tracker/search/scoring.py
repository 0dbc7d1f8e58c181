"""The views a pose search works on, and how well a pose explains them (silhouette IoU).

``prepare_inputs`` validates a frame set once (``SearchInputs``); ``ScoreViews`` down-scales its
silhouettes and cameras and scores a pose by the mean IoU of the model's silhouette with the
observed ones: a symmetric score (a limb missing from the model costs as much as a limb the images
lack), which the model -> image chamfer cost is not.  ``chamfer_from_silhouette`` and
``rendered_views`` build chamfer samplers when no segmentation gives them (a bare silhouette; a
perfect segmentation of a rendered pose, for tests and benchmarks).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Mapping, Sequence

import cv2
import numpy as np

from capture.camera import Camera, project_many, stack_cameras
from segmentation.distance import ChamferImages, chamfer_images
from segmentation.edges import silhouette_boundary
from tracker.body.kinematics import forward
from tracker.body.model import BodyModel
from tracker.fitting.sampler import ChamferSampler, ChamferViews, in_camera_order
from tracker.imaging.render import cone_points, internal_edges, render_label_images

__all__ = ["ScoreViews", "SearchInputs", "prepare_inputs", "chamfer_from_silhouette", "rendered_views"]


def _inset_hulls(hulls: Sequence[np.ndarray], d: float) -> list[np.ndarray]:
    """Convex polygons (``cv2.convexHull`` output, each (n, 1, 2) int32) moved inward by ``d`` (their
    units), all at once: each edge along its normal, the corners on the miter (capped as
    ``tracker.imaging.render``'s ``_shrink``); a polygon thinner than ``2 d`` shrinks about its centroid."""
    sizes = np.array([len(h) for h in hulls])
    start = np.repeat(np.cumsum(sizes) - sizes, sizes)
    n = np.repeat(sizes, sizes)
    pos = np.arange(sizes.sum()) - start
    v = np.concatenate(hulls)[:, 0, :].astype(np.float64)
    e = v[start + (pos + 1) % n] - v  # edge i: v_i -> v_{i+1}
    length = np.maximum(np.hypot(e[:, 0], e[:, 1]), 1e-9)
    which = np.repeat(np.arange(len(hulls)), sizes)
    area2 = np.bincount(which, v[:, 0] * e[:, 1] - v[:, 1] * e[:, 0])  # twice the signed area
    normal = np.stack([e[:, 1], -e[:, 0]], axis=1) / length[:, None]
    normal *= np.where(area2 < 0, -1.0, 1.0)[which, None]  # outward
    prev = normal[start + (pos - 1) % n]
    denom = np.maximum(1.0 + np.sum(prev * normal, axis=1), 0.2)
    out = v - d * (prev + normal) / denom[:, None]
    thin = (np.abs(area2) < 2 * d * np.bincount(which, length))[which] | (n < 3)
    if thin.any():
        centre = np.stack([np.bincount(which, v[:, k]) / sizes for k in (0, 1)], axis=1)[which]
        out[thin] = centre[thin] + (v[thin] - centre[thin]) * 0.999
    pts = np.round(out).astype(np.int32)[:, None, :]
    return np.split(pts, np.cumsum(sizes)[:-1])


class ScoreViews:
    """Silhouettes and cameras down-scaled by ``scale`` for fast overlap scoring of poses.

    Parameters
    ----------
    model : BodyModel
    cameras : sequence of Camera, length n_cams
    silhouettes : sequence of ndarray, each shape (h, w)
        One mask per camera, in camera order; non-zero = body.
    scale : float
        Image scale of the scoring views (0.5: half width and height).
    inset_px : float
        Each part's outline moved inward by this many scoring-view pixels before it is filled
        (0: none).  ``cv2.fillConvexPoly`` also sets the pixels the outline passes through, which
        grows a shape by about half a pixel; 0.5 fills the pixels whose centre is inside, as
        ``tracker.imaging.render`` does.

    Attributes
    ----------
    cameras : list of Camera
        The down-scaled cameras.
    masks : list of ndarray of bool, each shape (h', w')
        The down-scaled silhouettes.
    n_scored : int
        Poses scored so far (``ious`` calls).
    """

    def __init__(self, model: BodyModel, cameras: Sequence[Camera], silhouettes: Sequence[np.ndarray], *,
                 scale: float = 0.5, inset_px: float = 0.0) -> None:
        self.model = model
        self.inset_px = float(inset_px)
        self.cameras, self.masks = [], []
        for cam, sil in zip(cameras, silhouettes):
            w, h = max(1, int(round(cam.width * scale))), max(1, int(round(cam.height * scale)))
            sx, sy = w / cam.width, h / cam.height
            # pixel centres at integers: u' = sx (u + 0.5) - 0.5
            S = np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])
            self.cameras.append(Camera(cam.name, S @ cam.matrix, cam.distortion, cam.rotation, cam.translation, (w, h)))
            small = cv2.resize((np.asarray(sil) > 0).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
            self.masks.append(small >= 0.5)
        self._masks_u8 = [m.view(np.uint8) for m in self.masks]
        self._areas = [np.count_nonzero(m) for m in self.masks]
        self._stack = stack_cameras(self.cameras)
        self._local = cone_points(model, n_theta=12, n_z=2)  # (n_parts, 24, 3) part frames
        self.n_scored = 0

    def with_model(self, model: BodyModel) -> "ScoreViews":
        """The same views and silhouettes scoring another model (e.g. resized): a shallow copy."""
        out = copy.copy(self)
        out.model, out._local = model, cone_points(model, n_theta=12, n_z=2)
        return out

    def _draw(self, poses: Sequence[np.ndarray], parts: np.ndarray | None,
              base: Sequence[np.ndarray] | None) -> list[np.ndarray]:
        """``render``'s masks of several poses as uint8 images (1 = model), pose-major: image
        ``j * n_cams + k`` is pose j in camera k; every pose and view projected at once."""
        sel = np.arange(self.model.n_parts) if parts is None else np.asarray(parts, dtype=int)
        local = self._local[sel]
        pts = []
        for params in poses:
            pose = forward(self.model, params)
            pts.append(np.einsum("pij,pmj->pmi", pose.rotation[sel], local) + pose.translation[sel, None, :])
        n_cams, n_poses, shape = len(self.cameras), len(pts), local.shape[:2]
        flat = np.concatenate(pts).reshape(-1, 3) if pts else np.zeros((0, 3))
        # depths and fixed-point pixels (4 fractional bits), (n_cams, n_poses, n_parts, m) -> pose-major
        ok = (flat @ self._stack.rotation[:, 2].T + self._stack.translation[:, 2]).T > 0.05
        uv = project_many(self.cameras, np.broadcast_to(flat, (n_cams,) + flat.shape))
        np.clip(uv, -1e5, 1e5, out=uv)
        uv[np.isnan(uv)] = 0.0
        uv = (uv * 16.0).astype(np.int32)
        ok = ok.reshape(n_cams, n_poses, *shape).swapaxes(0, 1)
        uv = uv.reshape(n_cams, n_poses, *shape, 2).swapaxes(0, 1)
        counts = np.count_nonzero(ok, axis=3).ravel()  # points in front per (pose, camera, part)
        front = uv[ok]  # their pixels, part after part
        ends = [0] + np.cumsum(counts).tolist()
        out = [np.zeros((cam.height, cam.width), np.uint8) if base is None else base[k].astype(np.uint8)
               for _ in range(n_poses) for k, cam in enumerate(self.cameras)]
        drawn = np.flatnonzero(counts >= 3).tolist()  # the parts with a polygon in front
        hulls = [cv2.convexHull(front[ends[i]:ends[i + 1]]) for i in drawn]
        if self.inset_px and hulls:
            hulls = _inset_hulls(hulls, 16.0 * self.inset_px)
        for i, hull in zip(drawn, hulls):
            cv2.fillConvexPoly(out[i // shape[0]], hull, 1, shift=4)
        return out

    def render(self, params: np.ndarray, parts: np.ndarray | None = None,
               base: Sequence[np.ndarray] | None = None) -> list[np.ndarray]:
        """The model's silhouette in each scoring view: the union of the parts' projected convex hulls.

        A coarse, fast stand-in for ``tracker.imaging.render``.

        Parameters
        ----------
        params : ndarray, shape (n_params,)
        parts : ndarray of int, optional
            Indices of the parts to draw (default all).
        base : sequence of ndarray, each shape (h', w'), optional
            Per-view masks to draw them onto (e.g. the other parts, rendered once while a search
            varies one chain).

        Returns
        -------
        list of ndarray of bool, each shape (h', w')
        """
        return [img.astype(bool) for img in self._draw([params], parts, base)]

    def ious(self, params: np.ndarray, parts: np.ndarray | None = None,
             base: Sequence[np.ndarray] | None = None) -> np.ndarray:
        """Per-camera IoU of the model's silhouette with the observed one.

        Parameters
        ----------
        params, parts, base
            As ``render``; the IoU is of ``base`` and ``parts`` together.

        Returns
        -------
        ndarray, shape (n_cams,)
            IoU in [0, 1] (1 where both are empty).
        """
        return self.ious_many([params], parts, base)[0]

    def ious_many(self, poses: Sequence[np.ndarray], parts: np.ndarray | None = None,
                  base: Sequence[np.ndarray] | None = None, *, batch: int = 32) -> np.ndarray:
        """``ious`` of several poses, rendered ``batch`` at a time (the same values).

        Parameters
        ----------
        poses : sequence of ndarray, each shape (n_params,)
        parts, base
            As ``render``, for every pose.
        batch : int
            Poses projected and drawn together (bounds the images held at once).

        Returns
        -------
        ndarray, shape (n_poses, n_cams)
        """
        poses = list(poses)
        n_cams = len(self.masks)
        out = np.ones((len(poses), n_cams))
        for start in range(0, len(poses), max(1, int(batch))):
            chunk = poses[start:start + max(1, int(batch))]
            for i, r in enumerate(self._draw(chunk, parts, base)):
                j, k = divmod(i, n_cams)
                inter, union = self._overlap(r, k)
                if union:
                    out[start + j, k] = inter / union
        self.n_scored += len(poses)
        return out

    def _overlap(self, drawn: np.ndarray, k: int) -> tuple[int, int]:
        """(intersection, union) pixel counts of a drawn model silhouette with camera ``k``'s observed one."""
        inter = np.count_nonzero(drawn & self._masks_u8[k])
        return inter, np.count_nonzero(drawn) + self._areas[k] - inter

    def ious_unexplained(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-camera IoU (as ``ious``) and share of the observed silhouette the model leaves uncovered.

        Parameters
        ----------
        params : ndarray, shape (n_params,)

        Returns
        -------
        ious : ndarray, shape (n_cams,)
            IoU in [0, 1] (1 where both are empty).
        unexplained : ndarray, shape (n_cams,)
            Silhouette pixels outside the model's silhouette over silhouette pixels, in [0, 1] (0 where
            the silhouette is empty).
        """
        ious, unexplained = np.ones(len(self.masks)), np.zeros(len(self.masks))
        for k, r in enumerate(self._draw([params], None, None)):
            inter, union = self._overlap(r, k)
            if union:
                ious[k] = inter / union
            if self._areas[k]:
                unexplained[k] = (self._areas[k] - inter) / self._areas[k]
        self.n_scored += 1
        return ious, unexplained

    def expected_iou(self, *, loss_per_boundary: float = 0.28) -> float:
        """The mean IoU a correct pose reaches on these views.

        The scoring loses a share of the silhouettes' boundary pixels (polygonal parts, down-scaled
        masks), so 1 - IoU is about ``loss_per_boundary`` times the fraction of mask pixels on the
        boundary (measured values: docs/tuning.md, "Search").

        Parameters
        ----------
        loss_per_boundary : float
            Share of the boundary pixels the scoring loses.

        Returns
        -------
        float
            Expected mean IoU in [0, 1].
        """
        kernel = np.ones((3, 3), np.uint8)
        fractions = [1.0 - np.count_nonzero(cv2.erode(m.astype(np.uint8), kernel)) / max(np.count_nonzero(m), 1)
                     for m in self.masks]
        return float(1.0 - loss_per_boundary * np.mean(fractions))

    def score(self, params: np.ndarray, parts: np.ndarray | None = None,
              base: Sequence[np.ndarray] | None = None) -> float:
        """Mean IoU over the cameras (higher is better).

        Parameters
        ----------
        params, parts, base
            As ``render``.

        Returns
        -------
        float
        """
        return float(self.ious(params, parts, base).mean())

    def scores(self, poses: Sequence[np.ndarray], parts: np.ndarray | None = None,
               base: Sequence[np.ndarray] | None = None) -> np.ndarray:
        """``score`` of several poses at once (``ious_many``): shape (n_poses,)."""
        return self.ious_many(poses, parts, base).mean(axis=1)


@dataclass(frozen=True, eq=False)
class SearchInputs:
    """One frame set, validated for a search (``prepare_inputs``).

    Attributes
    ----------
    cameras : list of Camera, length n_cams
    silhouettes : list of ndarray, each shape (h, w)
        One mask per camera, in camera order (as ``visual_hull`` and ``ScoreViews`` take them).
    chamfer : dict str -> ChamferSampler
        Camera name -> sampler, one per camera (empty when built without chamfer images).
    """

    cameras: list
    silhouettes: list
    chamfer: dict


def chamfer_from_silhouette(silhouette: np.ndarray, *, max_distance_px: float = 48.0) -> ChamferImages:
    """Chamfer images of a bare silhouette, its outline doubling as the edge map.

    Parameters
    ----------
    silhouette : ndarray, shape (h, w)
        Non-zero = body.
    max_distance_px : float
        Truncation distance of the distance images, pixels.

    Returns
    -------
    segmentation.distance.ChamferImages
    """
    sil = (np.asarray(silhouette) > 0).astype(np.uint8) * 255
    return chamfer_images(sil, silhouette_boundary(sil), max_distance_px=max_distance_px, resolution_px=0.25)


def rendered_views(model: BodyModel, params: np.ndarray,
                   cameras: Sequence[Camera]) -> tuple[dict[str, np.ndarray], dict[str, ChamferImages]]:
    """What a perfect segmentation of the model at ``params`` gives (tests, benchmarks).

    Parameters
    ----------
    model : BodyModel
    params : ndarray, shape (n_params,)
    cameras : sequence of Camera

    Returns
    -------
    silhouettes : dict str -> ndarray, shape (h, w), uint8
        Camera name -> rendered silhouette (255 = body).
    chamfer : dict str -> ChamferImages
        Camera name -> chamfer images of the silhouette and the parts' internal edges
        (``tracker.imaging.render.internal_edges``).
    """
    labels = render_label_images(model, forward(model, params), cameras)
    sils = {c.name: np.where(lab >= 0, 255, 0).astype(np.uint8) for c, lab in zip(cameras, labels)}
    chamfer = {c.name: chamfer_images(sils[c.name], internal_edges(lab), max_distance_px=48.0, resolution_px=0.25)
               for c, lab in zip(cameras, labels)}
    return sils, chamfer


def prepare_inputs(model: BodyModel, cameras: Sequence[Camera], silhouettes: Mapping[str, np.ndarray],
                   chamfer: ChamferViews | None, *, with_chamfer: bool = True) -> SearchInputs:
    """Validate the views of one frame set once, for every step of a search.

    Parameters
    ----------
    model : BodyModel
    cameras : sequence of Camera
        At least one.
    silhouettes : mapping str -> ndarray, shape (h, w)
        Camera name -> mask of that camera's image size, non-zero = body.
    chamfer : mapping str -> ChamferSampler, or None
        Camera name -> sampler; None builds them from the silhouettes (``chamfer_from_silhouette``).
    with_chamfer : bool
        False: leave ``SearchInputs.chamfer`` empty (a search that only scores silhouettes).

    Returns
    -------
    SearchInputs

    Raises
    ------
    ValueError
        No camera, or a camera without a mask of its size or without a sampler (named).
    TypeError
        ``silhouettes`` or ``chamfer`` is not a mapping.
    """
    cameras = list(cameras)
    if not cameras:
        raise ValueError("cameras: need at least one camera")
    if not isinstance(silhouettes, Mapping):
        raise TypeError("silhouettes: expected a dict camera name -> (h, w) mask")
    sils = []
    for cam in cameras:
        if cam.name not in silhouettes:
            raise ValueError(f"silhouettes: no mask for camera {cam.name!r}")
        s = np.asarray(silhouettes[cam.name])
        if s.shape != (cam.height, cam.width):
            raise ValueError(f"silhouettes[{cam.name!r}]: shape {s.shape} != (h, w) = {(cam.height, cam.width)}")
        sils.append(s)
    chs: dict[str, ChamferSampler] = {}
    if with_chamfer and chamfer is None:
        chs = {c.name: chamfer_from_silhouette(s) for c, s in zip(cameras, sils)}
    elif with_chamfer:
        chs = dict(zip((c.name for c in cameras), in_camera_order(chamfer, cameras)))
    return SearchInputs(cameras, sils, chs)
