"""When the blob tracker calls a fit ok (``BlobTracker.explains`` / ``judge``): the fitted body and the hull
must explain each other.  Hulls here are the body model's own volume on the hull's lattice, so the
truth is known exactly."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.blobs import BlobTracker, ColourHull
from tracker.blobs.tracking import body_contains, hull_support
from tracker.body.kinematics import forward
from tracker.body.model import JOINT_ROTATION, load_model

VOXEL_M = 0.03
GOOD = {"active_fraction": 1.0, "goal_rms_m": 0.02}


@pytest.fixture(scope="module")
def model():
    return load_model("knossow40", height_m=1.75)


def _i(model, name):
    return model.param_names.index(name)


def _standing(model):
    """The zero pose lifted so that its lowest point is 1 cm above the floor."""
    from tracker.imaging.render import body_points

    p = model.zero()
    p[_i(model, "pelvis.tz")] += 0.01 - body_points(model, forward(model, p))[..., 2].min()
    return model.clamp(p)


def _hull_of(model, params, *, extra=None) -> ColourHull:
    """Finest voxels (3 cm lattice) whose centre lies in the body at ``params`` grown by half a voxel
    (the conservative fattening a visual hull has), plus ``extra`` voxel centres."""
    from tracker.imaging.render import body_points

    pose = forward(model, params)
    pts = body_points(model, pose, n_theta=8, n_z=2).reshape(-1, 3)
    lo = np.floor((pts.min(0) - 0.05) / VOXEL_M)
    hi = np.ceil((pts.max(0) + 0.05) / VOXEL_M)
    cells = (np.stack(np.meshgrid(*(np.arange(a, b) for a, b in zip(lo, hi)), indexing="ij"), -1).reshape(-1, 3)
             + 0.5) * VOXEL_M
    keep = cells[body_contains(model, pose, cells, margin_m=VOXEL_M / 2)]
    if extra is not None:
        keep = np.unique(np.vstack([keep, extra]), axis=0)
    n = len(keep)
    return ColourHull(keep, np.full(n, VOXEL_M), np.ones(n, bool), np.array([[-1.2, -1.2, 0.0], [1.2, 1.2, 2.1]]),
                      VOXEL_M, colours=np.zeros((n, 1, 3), np.float32), camera_names=("cam0",))


def _tracker(model):
    from tests.tracker.test_blobs import _cube_scene, _ring  # a studio the tracker can be built on

    cams = _ring(2)
    models, _ = _cube_scene(np.random.default_rng(0), cams, (0, 0, 0))
    return BlobTracker(model, cams, {c.name: m for c, m in zip(cams, models)})


def test_hull_support_matches_contains(model):
    hull = _hull_of(model, _standing(model))
    pts = np.random.default_rng(3).uniform([-0.6, -0.6, 0.0], [0.6, 0.6, 1.9], (3000, 3))
    assert np.array_equal(hull_support(hull, pts), hull.contains(pts))
    near = hull_support(hull, pts, tolerance_m=VOXEL_M)
    assert np.all(near >= hull.contains(pts)) and near.sum() > hull.contains(pts).sum()


def test_the_true_pose_explains_its_hull(model):
    tracker, p = _tracker(model), _standing(model)
    q = tracker.explains(_hull_of(model, p), p)
    assert q["support_min"] >= 0.9 and q["unexplained"] <= 0.05, q
    assert tracker.judge({**GOOD, **q}) == []


def test_a_shank_swung_back_out_of_the_hull_is_not_ok(model):
    """The fit put the left shank behind the thigh (knee flexed 100°, as under a chair seat) where the
    hull is empty: that part (and its foot) is unsupported, the others are not affected."""
    tracker, p = _tracker(model), _standing(model)
    hull = _hull_of(model, p)
    bent = p.copy()
    bent[_i(model, "left_shank.flexion")] = np.radians(100)
    bent = model.clamp(bent)
    assert abs(bent[_i(model, "left_shank.flexion")]) > np.radians(60)  # within the knee's limit
    q = tracker.explains(hull, bent)
    support = dict(zip(tracker.support_parts, tracker.part_support(hull, bent)))
    assert support["left_shank"] < 0.4 and min(v for k, v in support.items() if "left_" not in k) >= 0.9, support
    why = tracker.judge({**GOOD, **q})
    assert any(w.startswith(("left_shank outside the hull", "left_foot outside the hull")) for w in why), why


def test_a_hull_the_body_explains_only_half_of_is_not_ok(model):
    """A second body's volume beside the person (another person, furniture, a shadow the background
    model took for foreground): every part of the true pose is supported, yet half the hull is
    unexplained, so the pose is not trusted."""
    tracker, p = _tracker(model), _standing(model)
    other = p.copy()
    other[_i(model, "pelvis.tx")] += 0.7
    other_cells = _hull_of(model, other).centres
    hull = _hull_of(model, p, extra=other_cells)
    q = tracker.explains(hull, p)
    assert q["support_min"] >= 0.9 and 0.4 < q["unexplained"] < 0.6, q
    assert any("of the hull outside the body" in w for w in tracker.judge({**GOOD, **q}))


def test_body_contains_is_the_grown_cone_test_at_a_random_pose(model):
    # the compiled containment (tracker/blobs/kernels.py) against the cone inequality written out per part, at a
    # seeded random pose, for one margin and for several at once
    rng = np.random.default_rng(11)
    p = model.clamp(_standing(model) + rng.normal(0.0, 0.3, model.n_params) * (model.param_kind == JOINT_ROTATION))
    pose = forward(model, p)
    pts = rng.uniform([-1.0, -1.0, 0.0], [1.0, 1.0, 1.9], (3000, 3))
    margins = [0.0, 0.03, 0.1]
    want = np.zeros((len(margins), len(pts)), bool)
    for part, (a, b, k, z1, z2) in enumerate(model.cones):
        x, y, z = ((pts - pose.translation[part]) @ pose.rotation[part]).T
        r = np.maximum(1.0 + k * z, 0.0)
        for i, g in enumerate(margins):
            want[i] |= ((x / np.maximum(a * r + g, 1e-9)) ** 2 + (y / np.maximum(b * r + g, 1e-9)) ** 2 <= 1.0) & (z >= z1 - g) & (z <= z2 + g)
    assert 0 < want[0].sum() < want[1].sum() < want[2].sum() < len(pts)
    np.testing.assert_array_equal(body_contains(model, pose, pts, margin_m=margins), want)
    np.testing.assert_array_equal(body_contains(model, pose, pts, margin_m=0.03), want[1])
