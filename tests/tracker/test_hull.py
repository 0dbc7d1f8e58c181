"""Visual hull: the real 8-view dancer, synthetic renders with known joints, monotonicity, bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tracker.search.hull import VoxelHull, common_view_bounds, render_hull, silhouette_iou, visual_hull
from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import load_model
from tracker.imaging.render import render_silhouettes
from tracker.synthetic.scene import ring_cameras


def _dancer(shared_data):
    from capture.calib_formats import read_projection_matrix

    folder = shared_data / "dancer_8view"
    masks = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted(folder.glob("silh_cam*.pbm"))]
    cams = [read_projection_matrix(folder / "calibration" / f"cam{i:02d}.xml", size=(780, 582)) for i in range(8)]
    assert len(masks) == 8 and all(m is not None and m.shape == (582, 780) for m in masks)
    return cams, masks


def test_dancer_hull_height_and_reprojection(shared_data):
    cams, masks = _dancer(shared_data)
    hull = visual_hull(cams, masks, min_voxel_m=0.02)
    assert hull.min_voxel_m == 0.02 and hull.sizes.min() == pytest.approx(0.02)
    # the README's figure: about 1.64 m tall, standing on the floor
    assert 1.60 <= hull.height() <= 1.70
    lo, hi = hull.extent()
    assert abs(lo[2]) <= 0.03
    ious = [silhouette_iou(render_hull(hull, c), m) for c, m in zip(cams, masks)]
    assert min(ious) >= 0.85, ious
    # coarse-to-fine really merged: interior voxels coarser than the finest level exist
    assert hull.sizes.max() >= 4 * hull.min_voxel_m
    assert hull.full.any() and (~hull.full).any()


def _synthetic(seed, n_cams=6, fraction=0.4):
    rng = np.random.default_rng(seed)
    model = load_model("knossow40")
    params = model.random_params(rng, fraction=fraction)
    pose = forward(model, params)
    cams = ring_cameras(n_cams)
    return model, pose, cams, render_silhouettes(model, pose, cams)


@pytest.mark.parametrize("seed", [0, 1])
def test_synthetic_hull_contains_joints_and_reprojects(seed):
    model, pose, cams, sils = _synthetic(seed)
    hull = visual_hull(cams, sils, min_voxel_m=0.02)
    joints = joint_centre_array(model, pose)
    assert hull.contains(joints).all(), np.array(model.joint_names)[~hull.contains(joints)]
    # the body's interior (cone points pulled 30 % toward the axis, away from the end caps) is in the hull
    from tracker.imaging.render import cone_points

    local = cone_points(model, n_theta=12, n_z=5)[:, 12:-12].copy()
    local[..., :2] *= 0.7
    inner = np.einsum("pij,pmj->pmi", pose.rotation, local).reshape(-1, 3) + pose.translation.repeat(local.shape[1], 0)
    # finest voxels are kept by their centre, so a point of a limb thinner than a voxel may sit
    # just outside a kept cube: allow half a voxel
    near = np.zeros(len(inner), bool)
    for d in np.vstack([np.zeros(3), np.eye(3), -np.eye(3)]):
        near |= hull.contains(inner + 0.5 * hull.min_voxel_m * d)
    assert near.all()
    assert hull.contains(inner).mean() > 0.97
    views = range(len(cams)) if seed == 0 else [seed % len(cams)]  # reprojection is the slow part
    ious = [silhouette_iou(render_hull(hull, cams[i]), sils[i]) for i in views]
    assert min(ious) >= 0.85, ious
    # moments: the centroid lies near the pelvis, the height is near the model's
    assert np.linalg.norm(hull.centroid()[:2] - pose.translation[0, :2]) < 0.25
    assert abs(hull.height() - (joints[:, 2].max() + 0.12)) < 0.25


def test_fewer_cameras_give_a_superset(rng):
    model, pose, cams, sils = _synthetic(3)
    box = common_view_bounds(cams)
    h6 = visual_hull(cams, sils, min_voxel_m=0.03, bounds=box)
    h3 = visual_hull(cams[::2], sils[::2], min_voxel_m=0.03, bounds=box)
    assert h3.volume > h6.volume
    assert h3.contains(h6.centres).all()
    pts = rng.uniform(box[0], box[1], size=(20000, 3))
    assert not np.any(h6.contains(pts) & ~h3.contains(pts))


def test_tolerance_keeps_a_limb_one_view_missed():
    model, pose, cams, sils = _synthetic(5)
    joints = joint_centre_array(model, pose)
    wrist = joints[model.joint_names.index("right_wrist")]
    u, v = np.rint(cams[0].project(wrist)).astype(int)
    damaged = [s.copy() for s in sils]
    cv2.circle(damaged[0], (int(u), int(v)), 25, 0, -1)  # segmentation lost the hand in cam0
    box = common_view_bounds(cams)
    strict = visual_hull(cams, damaged, min_voxel_m=0.02, bounds=box)
    tolerant = visual_hull(cams, damaged, min_voxel_m=0.02, bounds=box, tolerance=1)
    assert not strict.contains(wrist[None])[0]
    assert tolerant.contains(wrist[None])[0] and tolerant.contains(joints).all()
    assert tolerant.contains(strict.centres).all() and tolerant.volume > strict.volume
    with pytest.raises(ValueError, match="tolerance"):
        visual_hull(cams, sils, tolerance=len(cams))


def test_largest_component_drops_a_phantom_blob():
    model, pose, cams, sils = _synthetic(6)
    pelvis = pose.translation[0]
    away = -pelvis[:2] / max(np.linalg.norm(pelvis[:2]), 1e-9)  # towards the middle of the room
    blob = np.array([*(pelvis[:2] + 0.9 * away), 0.3])  # a ball seen by every camera, off the subject
    assert all(c.in_image(c.project(blob), margin=-20) for c in cams)
    marked = []
    for cam, s in zip(cams, sils):
        s = s.copy()
        u, v = np.rint(cam.project(blob)).astype(int)
        r = int(np.ceil(cam.matrix[0, 0] * 0.08 / cam.depth(blob)))
        cv2.circle(s, (int(u), int(v)), r, 255, -1)
        marked.append(s)
    hull = visual_hull(cams, marked, min_voxel_m=0.03)
    assert hull.contains(blob[None])[0]
    body = hull.largest_component()
    assert not body.contains(blob[None])[0]
    assert body.contains(joint_centre_array(model, pose)).mean() > 0.9
    assert body.volume < hull.volume and np.linalg.norm(body.centroid()[:2] - pose.translation[0, :2]) < 0.15


def test_contains_matches_cubes(rng):
    model, pose, cams, sils = _synthetic(4)
    hull = visual_hull(cams, sils, min_voxel_m=0.03)
    pts = np.concatenate([hull.points(), rng.uniform(*hull.extent(), size=(5000, 3))])
    lo = hull.centres - 0.5 * hull.sizes[:, None]
    hi = hull.centres + 0.5 * hull.sizes[:, None]
    # brute force for a subset of points (strict interior, away from faces)
    sub = pts[rng.choice(len(pts), 400, replace=False)]
    inside = ((sub[:, None] > lo[None] + 1e-9) & (sub[:, None] < hi[None] - 1e-9)).all(2).any(1)
    on_face = ((np.abs(sub[:, None] - lo[None]) < 1e-9) | (np.abs(sub[:, None] - hi[None]) < 1e-9)).any(2).any(1)
    assert np.array_equal(hull.contains(sub)[~on_face], inside[~on_face])
    assert hull.contains(hull.points()).all()


def test_empty_silhouettes_give_empty_hull():
    cams = ring_cameras(4)
    sils = [np.zeros((c.height, c.width), np.uint8) for c in cams]
    hull = visual_hull(cams, sils, min_voxel_m=0.05)
    assert hull.empty and hull.volume == 0.0
    assert not render_hull(hull, cams[0]).any()
    with pytest.raises(ValueError, match="empty"):
        hull.centroid()


def test_bad_input_names_the_argument():
    cams = ring_cameras(3)
    good = [np.zeros((c.height, c.width), np.uint8) for c in cams]
    with pytest.raises(ValueError, match="3 cameras"):
        visual_hull(cams, good[:2])
    with pytest.raises(ValueError, match="cam1"):
        visual_hull(cams, [good[0], np.zeros((10, 10), np.uint8), good[2]])
    with pytest.raises(ValueError, match="min_voxel_m"):
        visual_hull(cams, good, min_voxel_m=0.0)
    with pytest.raises(ValueError, match="bounds"):
        visual_hull(cams, good, bounds=[[0, 0, 0], [1, -1, 1]])
    assert isinstance(visual_hull(cams, good, min_voxel_m=0.1), VoxelHull)


def _box_silhouettes(cams, lo, hi):
    """Exact masks of an axis-aligned box: a convex solid projects onto the hull of its corners."""
    corners = lo + (hi - lo) * np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)], float)
    out = []
    for c in cams:
        m = np.zeros((c.height, c.width), np.uint8)
        uv = np.round(c.project(corners) * 16).astype(np.int32)
        cv2.fillConvexPoly(m, cv2.convexHull(uv), 255, shift=4)
        out.append(m)
    return out


try:
    from hypothesis import given, settings
    from hypothesis import strategies as st
except ImportError:  # pragma: no cover
    given = None

if given is not None:

    @settings(max_examples=15, deadline=None)
    @given(centre=st.tuples(st.floats(-0.8, 0.8), st.floats(-0.8, 0.8), st.floats(0.3, 1.5)),
           half=st.tuples(st.floats(0.05, 0.4), st.floats(0.05, 0.4), st.floats(0.05, 0.3)))
    def test_box_hull_encloses_the_box_and_not_much_more(centre, half):
        cams = ring_cameras(6)
        lo, hi = np.array(centre) - half, np.array(centre) + half
        hull = visual_hull(cams, _box_silhouettes(cams, lo, hi), min_voxel_m=0.03)
        g = np.stack(np.meshgrid(*(np.linspace(0.1, 0.9, 5),) * 3, indexing="ij"), -1).reshape(-1, 3)
        inner = lo + 0.5 * 0.03 + (hi - lo - 0.03) * g  # grid inside the box, half a voxel from its faces
        assert hull.contains(inner).all()
        # a box seen from 6 directions around it: the hull adds at most the corner wedges + a voxel layer
        grown = np.prod(hi - lo + 2 * 0.03)
        assert np.prod(hi - lo) * 0.7 < hull.volume < 1.6 * grown
        assert np.all(hull.extent()[0] > lo - 0.35) and np.all(hull.extent()[1] < hi + 0.35)


def test_distorted_cameras():
    """Lens distortion takes the general projection path (corners projected one by one, rays undistorted)."""
    model = load_model("knossow40")
    pose = forward(model, model.random_params(np.random.default_rng(8), fraction=0.3))
    cams = ring_cameras(6, distortion=(-0.25, 0.08, 0.001, -0.001, 0.0))
    sils = render_silhouettes(model, pose, cams)
    hull = visual_hull(cams, sils, min_voxel_m=0.02)
    joints = joint_centre_array(model, pose)
    near = np.zeros(len(joints), bool)
    for d in np.vstack([np.zeros(3), np.eye(3), -np.eye(3)]):
        near |= hull.contains(joints + 0.01 * d)
    assert near.all()
    assert silhouette_iou(render_hull(hull, cams[1]), sils[1]) >= 0.85


def test_common_view_bounds_cache_is_keyed_by_calibration():
    """The box is cached per camera set: the same calibration gives the same box (a copy the
    caller may change), another calibration its own box."""
    from tracker.search.hull import _common_view_bounds

    cams = ring_cameras(4, size=(320, 240))
    first = common_view_bounds(cams)
    assert np.array_equal(first, _common_view_bounds(cams, (0.0, 2.5), 0.2, 0.2))
    first[:] = 0.0
    assert np.array_equal(common_view_bounds(cams), _common_view_bounds(cams, (0.0, 2.5), 0.2, 0.2))
    wide = ring_cameras(4, size=(320, 240), radius_m=6.0)
    assert np.array_equal(common_view_bounds(wide), _common_view_bounds(wide, (0.0, 2.5), 0.2, 0.2))
    assert not np.allclose(common_view_bounds(wide), common_view_bounds(cams))
    assert common_view_bounds(cams, z_range=(0.0, 2.0))[1, 2] < common_view_bounds(cams)[1, 2]
