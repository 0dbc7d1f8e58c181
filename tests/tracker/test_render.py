"""Renderer: convex-hull silhouettes vs an exact per-pixel ray–cone test, ring cameras, occlusion, edges."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from capture.camera import Camera
from tracker.body.kinematics import forward
from tracker.body.model import load_model
from tracker.imaging.render import (
    body_points,
    fill_convex_hulls,
    internal_edges,
    render_label_images,
    render_labels,
    render_silhouettes,
)
from tracker.synthetic.scene import pixel_rays, ring_cameras


@pytest.fixture(scope="module")
def model():
    return load_model("knossow40")


def ray_hits_cone(cone, origin, dirs):
    """Exact test: does the ray ``origin + t dirs`` (t > 0, part frame) meet the solid cone?

    cone = (a, b, k, z1, z2); origin (3,), dirs (n, 3).  Inside the solid means
    z1 <= z <= z2 and (x/a)² + (y/b)² <= (1 + k z)², a quadratic q(t) <= 0 on
    the t-interval where z is in range: its minimum there is at an end or the vertex.
    """
    a, b, k, z1, z2 = cone
    px, py, pz = origin
    dx, dy, dz = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (z1 - pz) / dz, (z2 - pz) / dz
    flat = np.abs(dz) < 1e-12
    lo = np.where(flat, 0.0, np.minimum(ta, tb))
    hi = np.where(flat, 1e6, np.maximum(ta, tb))
    in_z = ~flat | ((pz >= z1) & (pz <= z2))
    lo = np.maximum(lo, 0.0)
    # q(t) = A t^2 + B t + C
    A = (dx / a) ** 2 + (dy / b) ** 2 - (k * dz) ** 2
    B = 2 * (px * dx / a**2 + py * dy / b**2 - k * dz * (1 + k * pz))
    C = (px / a) ** 2 + (py / b) ** 2 - (1 + k * pz) ** 2

    def q(t):
        return A * t * t + B * t + C

    with np.errstate(divide="ignore", invalid="ignore"):
        tv = np.where(A > 0, -B / (2 * A), lo)
    tv = np.clip(tv, lo, hi)
    qmin = np.minimum(np.minimum(q(lo), q(hi)), q(tv))
    return in_z & (hi >= lo) & (qmin <= 0)


def brute_force_part_mask(model, pose, camera, part):
    """Per-pixel ray–cone intersection through every pixel centre, shape (h, w) bool."""
    rays = pixel_rays(camera).reshape(-1, 3)  # world directions
    R, t = pose.rotation[part], pose.translation[part]
    origin = R.T @ (camera.center - t)
    dirs = rays @ R  # world -> part frame: R^T d
    hit = ray_hits_cone(model.cones[part], origin, dirs)
    return hit.reshape(camera.height, camera.width)


def single_part_mask(model, pose, camera, part, **kw):
    pts = body_points(model, pose, **kw)
    uv = camera.project(pts)
    valid = camera.depth(pts) > 0.01
    img = np.zeros((camera.height, camera.width), np.uint8)
    fill_convex_hulls(img, uv, valid, [part], [1] * model.n_parts)
    return img.astype(bool)


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


@pytest.mark.parametrize("distortion", [(0, 0, 0, 0, 0), (-0.25, 0.08, 0.001, -0.001, 0.0)])
@pytest.mark.parametrize("part_name", ["torso", "left_thigh", "right_forearm", "head"])
def test_lone_part_matches_exact_ray_cone_test(model, rng, distortion, part_name):
    p = model.random_params(rng, fraction=0.5)
    p[:3] = 0.0
    pose = forward(model, p)
    part = model.part_index(part_name)
    centre = pose.translation[part] + pose.rotation[part] @ [0, 0, 0.5 * (model.cones[part, 3] + model.cones[part, 4])]
    # close enough that the part spans many pixels (boundary pixels then matter little)
    cam = Camera.look_at("c", centre + [1.2, 0.5, 0.3], centre, size=(320, 240), fov_deg=45, distortion=distortion)
    hull = single_part_mask(model, pose, cam, part)
    exact = brute_force_part_mask(model, pose, cam, part)
    assert exact.sum() > 500, "the part must cover a real area for the comparison to mean anything"
    assert iou(hull, exact) > 0.98, f"{part_name}: IoU {iou(hull, exact):.4f}"


def test_more_sections_follow_distortion_better(model):
    """With strong barrel distortion, the end-ellipse-only hull misses the bulge that more sections catch."""
    pose = forward(model, model.zero())
    part = model.part_index("left_thigh")
    centre = pose.translation[part] + pose.rotation[part] @ [0, 0, 0.12 * model.height_m]
    cam = Camera.look_at("c", centre + [0.6, 0.0, 0.0], centre, size=(320, 240), fov_deg=70, distortion=(-0.4, 0.12, 0, 0, 0))
    exact = brute_force_part_mask(model, pose, cam, part)
    coarse = iou(single_part_mask(model, pose, cam, part, n_z=2), exact)
    fine = iou(single_part_mask(model, pose, cam, part, n_z=8), exact)
    assert fine > coarse
    assert fine > 0.98


def test_whole_body_inside_every_ring_camera(model):
    pose = forward(model, model.zero())
    cams = ring_cameras(6)
    assert len({c.name for c in cams}) == 6
    pts = body_points(model, pose).reshape(-1, 3)
    for cam, sil in zip(cams, render_silhouettes(model, pose, cams)):
        assert np.all(cam.depth(pts) > 2.0)
        uv = cam.project(pts)
        assert np.all(cam.in_image(uv, margin=-40)), f"{cam.name}: body closer than 40 px to the border"
        assert sil.dtype == np.uint8 and sil.shape == (600, 800)
        ys, xs = np.nonzero(sil)
        assert xs.min() >= 40 and ys.min() >= 40 and xs.max() < 760 and ys.max() < 560
        # a 1.75 m person at 4 m with 60° hfov is ~300 px tall
        assert 250 < ys.max() - ys.min() < 400
        assert set(np.unique(sil)) == {0, 255}


def test_ring_cameras_look_at_target():
    cams = ring_cameras(4, radius_m=3.0, height_m=2.0, target=(0.5, -0.2, 1.0), size=(640, 480))
    for i, cam in enumerate(cams):
        c = cam.center
        assert np.hypot(c[0] - 0.5, c[1] + 0.2) == pytest.approx(3.0)
        assert c[2] == pytest.approx(2.0)
        assert np.allclose(cam.project(np.array([0.5, -0.2, 1.0])), [319.5, 239.5], atol=1e-6)
    with pytest.raises(ValueError, match="n must be"):
        ring_cameras(0)


def test_nearer_part_occludes_farther(model):
    """Left arm reaching forward with the forearm across the chest: seen from the front, the
    forearm covers the torso; from behind, the torso covers the forearm."""
    p = model.zero()
    p[model.param_index("left_upper_arm.flexion")] = np.radians(90)
    p[model.param_index("left_forearm.flexion")] = np.radians(90)
    pose = forward(model, p)
    front, back = ring_cameras(2)  # cam0 on +X (the subject faces +X), cam1 on -X
    fa, torso = model.part_index("left_forearm"), model.part_index("torso")
    labs = {}
    for cam in (front, back):
        labs[cam.name] = lab = render_labels(model, pose, cam)
        both = single_part_mask(model, pose, cam, fa) & single_part_mask(model, pose, cam, torso)
        assert both.sum() > 100, f"{cam.name}: the test pose must make the two parts overlap"
        labs[cam.name + "_both"] = lab[both]
    # front: the forearm (and its hand) cover the chest where they overlap
    assert np.mean(np.isin(labs["cam0_both"], [fa, model.part_index("left_hand")])) > 0.97
    # back: the forearm is hidden there; the torso (and the clavicles, nearer still) show instead
    assert np.mean(labs["cam1_both"] == fa) < 0.01
    assert np.sum(labs["cam1_both"] == torso) > 50
    # the silhouette is the union of the parts whatever the order
    sil = render_silhouettes(model, pose, [front])[0] > 0
    union = np.zeros_like(sil)
    for part in range(model.n_parts):
        union |= single_part_mask(model, pose, front, part)
    assert np.array_equal(sil, union)


def test_label_images_agree_with_single_camera_call(model, rng):
    pose = forward(model, model.random_params(rng, fraction=0.3))
    cams = ring_cameras(3, size=(200, 150))
    many = render_label_images(model, pose, cams)
    for cam, lab in zip(cams, many):
        assert lab.dtype == np.int16 and lab.shape == (150, 200)
        assert np.array_equal(lab, render_labels(model, pose, cam))
        assert lab.min() >= -1 and lab.max() < model.n_parts


def test_internal_edges_constructed():
    lab = np.full((8, 10), -1, np.int16)
    lab[2:6, 1:5] = 0
    lab[2:6, 5:8] = 3
    e = internal_edges(lab) > 0
    body = lab >= 0
    expected = np.zeros_like(e)
    # silhouette boundary (body side)
    expected[2, 1:8] = expected[5, 1:8] = True
    expected[2:6, 1] = expected[2:6, 7] = True
    # part boundary: one pixel, on the larger label's side
    expected[2:6, 5] = True
    assert np.array_equal(e, expected)
    assert not np.any(e & ~body)
    with pytest.raises(ValueError, match="2-D"):
        internal_edges(np.zeros((2, 2, 2)))


def test_edges_of_rendered_body(model):
    pose = forward(model, model.zero())
    cam = ring_cameras(6)[1]
    lab = render_labels(model, pose, cam)
    e = internal_edges(lab) > 0
    sil = lab >= 0
    inner = sil.copy()
    inner[1:-1, 1:-1] = sil[1:-1, 1:-1] & sil[:-2, 1:-1] & sil[2:, 1:-1] & sil[1:-1, :-2] & sil[1:-1, 2:]
    boundary = sil & ~inner
    assert np.array_equal(e & boundary, boundary)  # every silhouette boundary pixel is an edge
    assert (e & inner).sum() > 50  # and there are internal part boundaries too


def test_points_behind_the_camera_are_not_drawn(model):
    """A camera in front of the body looking away sees nothing (without clipping, the body would
    project mirrored through the centre into the image)."""
    pose = forward(model, model.zero())
    away = Camera.look_at("away", [0.6, 0.0, 1.0], [3.0, 0.0, 1.0], size=(160, 120))
    assert np.all(render_labels(model, pose, away) == -1)
    facing = Camera.look_at("facing", [0.6, 0.0, 1.0], [-3.0, 0.0, 1.0], size=(160, 120), fov_deg=120)
    assert np.sum(render_labels(model, pose, facing) >= 0) > 1000


def test_shrink_moves_every_edge_inward_by_the_inset(rng):
    from tracker.imaging.render import _shrink

    for _ in range(50):
        pts = rng.uniform(0, 100, (12, 2)).astype(np.float32)
        hull = cv2.convexHull(pts)[:, 0, :].astype(float)
        out = _shrink(hull, 0.5)
        a, b = hull, np.roll(hull, -1, axis=0)
        e = b - a
        n = np.stack([e[:, 1], -e[:, 0]], 1) / np.linalg.norm(e, axis=1)[:, None]
        centroid = hull.mean(axis=0)
        n *= np.sign(np.sum((a - centroid) * n, axis=1))[:, None]  # outward
        # signed distance of each new vertex to each original edge line (negative = inside)
        dist = np.einsum("ek,vk->ve", n, out) - np.sum(n * a, axis=1)[None]
        assert dist.max() <= -0.5 + 1e-9
        # each new vertex sits exactly 0.5 inside the two edges that met at the old vertex
        own = np.stack([dist[np.arange(len(out)), np.arange(len(out))],
                        dist[np.arange(len(out)), np.arange(len(out)) - 1]], 1)  # fmt: skip
        sharp = np.sum(n * np.roll(n, 1, axis=0), axis=1) < -0.8  # miter capped there
        assert np.allclose(own[~sharp], -0.5)
