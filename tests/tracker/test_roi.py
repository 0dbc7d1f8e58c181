"""Regions of interest from a pose (tracker.roi): they hold the rendered silhouette, tightly, and
fall back to the whole frame when the projection cannot be trusted."""

import cv2
import numpy as np
import pytest

from capture.camera import Camera
from tracker.body.kinematics import forward
from tracker.body.model import load_model
from tracker.imaging.render import render_silhouettes
from tracker.imaging.roi import pose_rois
from tracker.synthetic.scene import ring_cameras


@pytest.fixture(scope="module")
def model():
    return load_model("knossow40")


def _boxes(sils):
    return [cv2.boundingRect(s) for s in sils]


@pytest.mark.parametrize("distortion", [(0.0, 0.0, 0.0, 0.0, 0.0), (-0.25, 0.08, 0.001, -0.001, 0.0)])
def test_roi_holds_the_silhouette_tightly(model, distortion):
    """Every rendered silhouette pixel lies in its camera's rectangle; with zero margins the
    rectangle is at most 1.3x the silhouette's bounding box (measured: 1.03-1.14 without distortion)."""
    rng = np.random.default_rng(3)
    cams = [Camera.look_at(f"c{i}", [3.5 * np.cos(q), 3.5 * np.sin(q), 1.4], [0.0, 0.0, 1.0], size=(800, 600),
                           distortion=distortion) for i, q in enumerate(np.linspace(0, 2 * np.pi, 5)[:-1])]
    for _ in range(6):
        p = model.random_params(rng, fraction=0.3)
        sils = render_silhouettes(model, forward(model, p), cams)
        for margins in ((0.0, 0), (0.1, 8)):
            rois = pose_rois(model, p, cams, margin_m=margins[0], margin_px=margins[1])
            for (x, y, w, h), roi in zip(_boxes(sils), rois):
                assert roi is not None and w > 0
                x0, y0, x1, y1 = roi
                assert 0 <= x0 <= x and 0 <= y0 <= y and x + w <= x1 <= 800 and y + h <= y1 <= 600
                if margins == (0.0, 0) and not any(distortion):
                    assert (x1 - x0) * (y1 - y0) <= 1.3 * w * h


def test_roi_grows_with_the_margins(model):
    cams = ring_cameras(6, size=(800, 600))
    p = model.random_params(np.random.default_rng(1), fraction=0.3)
    small = pose_rois(model, p, cams, margin_m=0.0, margin_px=0)
    big = pose_rois(model, p, cams, margin_m=0.1, margin_px=8)
    for (a0, b0, a1, b1), (c0, d0, c1, d1) in zip(small, big):
        assert c0 <= a0 - 8 or c0 == 0
        assert c1 >= a1 + 8 or c1 == 800
        assert (c1 - c0) * (d1 - d0) > (a1 - a0) * (b1 - b0)


def test_whole_frame_when_the_projection_cannot_be_trusted(model):
    """A camera inside the body's bounding volume, or a non-finite pose: None (segment everything)."""
    p = model.zero()
    p[:3] = [0.0, 0.0, 1.0]
    inside = Camera.look_at("inside", [0.0, 0.0, 1.6], [1.0, 0.0, 1.6], size=(640, 480))
    outside = Camera.look_at("outside", [4.0, 0.0, 1.4], [0.0, 0.0, 1.0], size=(640, 480))
    rois = pose_rois(model, p, [inside, outside])
    assert rois[0] is None and rois[1] is not None
    q = p.copy()
    q[4] = np.nan
    assert pose_rois(model, q, [outside]) == [None]


def _per_camera_rois(model, params, cams, margin_m, margin_px):
    """The rectangles computed camera by camera with ``Camera.depth`` / ``Camera.project`` (the reference)."""
    from tracker.imaging.roi import part_box_corners

    corners = part_box_corners(model, forward(model, params), margin_m=margin_m)
    out = []
    for cam in cams:
        w, h = cam.size
        if not np.all(cam.depth(corners) > 0.05):
            out.append(None)
            continue
        uv = cam.project(corners)
        lo, hi = np.floor(uv.min(axis=0)) - margin_px, np.ceil(uv.max(axis=0)) + margin_px + 1
        x0, y0 = int(np.clip(lo[0], 0, w - 1)), int(np.clip(lo[1], 0, h - 1))
        out.append((x0, y0, int(np.clip(hi[0], x0 + 1, w)), int(np.clip(hi[1], y0 + 1, h))))
    return out


def test_all_cameras_at_once_equal_camera_by_camera_and_two_poses_their_union(model):
    """Distorted cameras of two sizes, one of them inside the body's volume (None), random poses: the
    rectangles equal the per-camera reference; two poses give the union of their rectangles."""
    rng = np.random.default_rng(7)
    cams = [Camera.look_at(f"c{i}", [3.0 * np.cos(q), 3.0 * np.sin(q), 1.3], [0.0, 0.0, 1.0],
                           size=(640, 480) if i % 2 else (320, 240), distortion=(-0.2, 0.05, 0.001, -0.002, 0.0))
            for i, q in enumerate(np.linspace(0, 2 * np.pi, 6)[:-1])]
    cams.append(Camera.look_at("inside", [0.0, 0.0, 1.0], [1.0, 0.0, 1.0], size=(320, 240)))
    for _ in range(10):
        p, q = (model.random_params(rng, fraction=0.4) for _ in range(2))
        p[:3] += rng.normal(0.0, 0.8, 3)  # bodies reaching out of some images
        margin, px = float(rng.uniform(0.0, 0.3)), int(rng.integers(0, 10))
        one = pose_rois(model, p, cams, margin_m=margin, margin_px=px)
        assert one == _per_camera_rois(model, p, cams, margin, px)
        both = pose_rois(model, np.stack([p, q]), cams, margin_m=margin, margin_px=px)
        for a, b, ab in zip(one, pose_rois(model, q, cams, margin_m=margin, margin_px=px), both):
            if a is None or b is None:
                assert ab is None
            else:
                assert ab == (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))
    assert any(r is None for r in one) and any(r is not None for r in one)


def test_rejects_bad_arguments(model):
    cams = ring_cameras(2, size=(320, 240))
    with pytest.raises(ValueError, match="params"):
        pose_rois(model, np.zeros(3), cams)
    with pytest.raises(ValueError, match="params"):
        pose_rois(model, np.zeros((2, 2, model.n_params)), cams)
    with pytest.raises(ValueError, match="margin_m"):
        pose_rois(model, model.zero(), cams, margin_m=-1.0)
    with pytest.raises(ValueError, match="margin_px"):
        pose_rois(model, model.zero(), cams, margin_px=2.5)


FIT_KERNELS = ("hidden_mask", "sample_chamfer", "forward_kinematics", "image_motion", "contour_points",
               "projection_jacobians", "assemble", "reverse_terms")


def test_warm_up_compiles_the_kernels_a_fit_uses():
    # in a fresh process (this one may have compiled them in other tests): before warm_up none of the
    # kernels has a compiled signature, after it every kernel of the fit path has one
    import subprocess
    import sys

    code = ("import json, tracker.kernels as k\n"
            f"names = {FIT_KERNELS!r}\n"
            "before = {n: len(getattr(k, n).signatures) for n in names}\n"
            "from tracker.fitting.warmup import warm_up\n"
            "warm_up()\n"
            "print(json.dumps([before, {n: len(getattr(k, n).signatures) for n in names}]))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=300)
    import json

    before, after = json.loads(out.stdout.strip().splitlines()[-1])
    assert all(v == 0 for v in before.values()), before
    assert all(v >= 1 for v in after.values()), after
