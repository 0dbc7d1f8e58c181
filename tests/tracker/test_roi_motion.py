"""Per-part ROI margins from the predicted motion (tracker.imaging.roi.motion_margins)."""

import cv2
import numpy as np
import pytest

from tracker.body.kinematics import forward
from tracker.body.model import load_model
from tracker.imaging.render import render_silhouettes
from tracker.imaging.roi import motion_margins, pose_rois
from tracker.synthetic.scene import ring_cameras


@pytest.fixture(scope="module")
def model():
    return load_model("knossow40")


def test_still_body_gets_the_base_and_a_translation_its_length(model):
    p = model.random_params(np.random.default_rng(0), fraction=0.3)
    np.testing.assert_allclose(motion_margins(model, p, p, base_m=0.03), 0.03)
    q = p.copy()
    q[:3] += [0.03, -0.04, 0.0]  # the root translation: every part moves 5 cm
    np.testing.assert_allclose(motion_margins(model, q, p, base_m=0.01, gain=2.0), 0.01 + 2.0 * 0.05, atol=1e-9)
    np.testing.assert_allclose(motion_margins(model, q, p, base_m=0.01, gain=2.0, max_m=0.08), 0.08)


def test_only_the_moving_parts_get_a_larger_margin(model):
    rng = np.random.default_rng(1)
    p = model.random_params(rng, fraction=0.3)
    for k in rng.choice(np.arange(6, model.n_params), 5, replace=False):
        q = p.copy()
        q[k] += 0.2
        moved = np.array([not (np.allclose(a, b) and np.allclose(c, d)) for a, b, c, d in zip(
            forward(model, q).rotation, forward(model, p).rotation,
            forward(model, q).translation, forward(model, p).translation)])
        assert moved.any() and not moved.all()
        m = motion_margins(model, q, p, base_m=0.02)
        np.testing.assert_allclose(m[~moved], 0.02, atol=1e-9)
        assert (m[moved] > 0.02).all()


def test_rois_hold_the_silhouette_when_the_motion_changes_by_up_to_its_size(model):
    """Constant-velocity prediction; the true pose stops, or moves twice as far: the ROI from the
    motion margins (gain 1) still holds every pixel of the true silhouette."""
    rng = np.random.default_rng(2)
    cams = ring_cameras(4, size=(800, 600))
    for _ in range(5):
        p0 = model.random_params(rng, fraction=0.3)
        p1 = model.clamp(p0 + rng.normal(0.0, 0.03, model.n_params))
        pred = model.clamp(2 * p1 - p0)
        margins = motion_margins(model, pred, p1, base_m=0.0, gain=1.0)
        rois = pose_rois(model, pred, cams, margin_m=margins, margin_px=2)
        for u in (0.0, 0.5, 1.5, 2.0):
            truth = model.clamp(p1 + u * (pred - p1))
            for sil, roi in zip(render_silhouettes(model, forward(model, truth), cams), rois):
                x, y, w, h = cv2.boundingRect(sil)
                x0, y0, x1, y1 = roi
                assert x0 <= x and y0 <= y and x + w <= x1 and y + h <= y1


def test_per_part_margins_of_one_value_equal_the_scalar(model):
    cams = ring_cameras(3, size=(640, 480))
    p = model.random_params(np.random.default_rng(3), fraction=0.3)
    assert pose_rois(model, p, cams, margin_m=np.full(model.n_parts, 0.04)) == pose_rois(model, p, cams, margin_m=0.04)


def test_bad_arguments(model):
    p = model.zero()
    with pytest.raises(ValueError, match="margin_m"):
        pose_rois(model, p, ring_cameras(2), margin_m=np.zeros(model.n_parts + 1))
    with pytest.raises(ValueError, match="margin_m"):
        pose_rois(model, p, ring_cameras(2), margin_m=-0.01)
    with pytest.raises(ValueError, match="previous"):
        motion_margins(model, p, p[:-1])
    with pytest.raises(ValueError, match="gain"):
        motion_margins(model, p, p, gain=float("nan"))
    with pytest.raises(ValueError, match="base_m"):
        motion_margins(model, p, p, base_m=0.6, max_m=0.5)
    bad = p.copy()
    bad[7] = np.nan
    np.testing.assert_array_equal(motion_margins(model, bad, p, max_m=0.3), 0.3)


def test_gain_one_covers_the_previous_pose(model):
    """Every corner of a part's box at ``previous`` is within the part's motion of a corner at the
    prediction, so with gain 1 the rectangle also holds the previous pose's rectangle (no union needed)."""
    rng = np.random.default_rng(4)
    cams = ring_cameras(4, size=(800, 600))
    for _ in range(8):
        prev = model.random_params(rng, fraction=0.3)
        pred = model.clamp(prev + rng.normal(0.0, 0.08, model.n_params))
        grown = pose_rois(model, pred, cams, margin_m=motion_margins(model, pred, prev, base_m=0.0), margin_px=0)
        for (a0, b0, a1, b1), (c0, d0, c1, d1) in zip(pose_rois(model, prev, cams, margin_m=0.0, margin_px=0), grown):
            assert c0 <= a0 and d0 <= b0 and a1 <= c1 and b1 <= d1
