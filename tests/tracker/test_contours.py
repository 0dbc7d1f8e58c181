"""Extremal contours: tangency, the closed-form roots against a brute-force scan, symmetry, degenerate cases."""

import warnings

import numpy as np
import pytest

from capture.camera import Camera
from tracker.imaging.contours import contour_generator_angles, extremal_contours, sample_heights
from tracker.body.kinematics import forward
from tracker.body.model import load_model

MODELS = ["knossow40", "knossow54"]


def ring(n=6, *, radius=4.0, height=1.5, distortion=(0.0, 0.0, 0.0, 0.0, 0.0)):
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False) + 0.3
    return [
        Camera.look_at(f"cam{i}", [radius * np.cos(q), radius * np.sin(q), height], [0, 0, 1.0], distortion=distortion)
        for i, q in enumerate(angles)
    ]


@pytest.fixture(scope="module", params=MODELS)
def model(request):
    return load_model(request.param, height_m=1.75)


def cone_normals(model, pose, contours):
    """Outward surface normals (N, 3), world, unit."""
    a, b, k = (model.cones[contours.part, j] for j in range(3))
    th = contours.theta
    n = np.stack([b * np.cos(th), a * np.sin(th), -a * b * k], axis=-1)
    n = np.einsum("nij,nj->ni", pose.rotation[contours.part], n)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def test_line_of_sight_is_tangent_at_every_contour_point(model, rng):
    cams = ring(distortion=(-0.2, 0.05, 0.001, -0.001, 0.0))
    centres = np.array([c.center for c in cams])
    for _ in range(5):
        pose = forward(model, model.random_params(rng))
        ct = extremal_contours(model, pose, cams, n_samples=7, visibility=False)
        assert ct.valid.mean() > 0.8
        ray = ct.points - centres[ct.cam]
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        cos = np.abs(np.sum(cone_normals(model, pose, ct) * ray, axis=1))
        assert cos[ct.valid].max() < 1e-9
        # the points are on their cones, at the fixed heights
        local = np.einsum("nji,nj->ni", pose.rotation[ct.part], ct.points - pose.translation[ct.part])
        a, b, k = (model.cones[ct.part, j] for j in range(3))
        np.testing.assert_allclose(local[:, 2], ct.z, atol=1e-12)
        np.testing.assert_allclose(np.hypot(local[:, 0] / a, local[:, 1] / b), 1 + k * ct.z, rtol=1e-12)
        # uv is the camera's projection of the points
        for c, cam in enumerate(cams):
            sel = ct.valid & (ct.cam == c)
            np.testing.assert_allclose(ct.uv[sel], cam.project(ct.points[sel]), atol=1e-9)


def test_closed_form_roots_match_a_brute_force_scan(rng):
    """The two tan(θ/2) roots are exactly the sign changes of f(θ) found by scanning θ."""
    n = 200
    ab = rng.uniform(0.02, 0.2, (n, 2))
    cones = np.c_[ab, rng.uniform(-2, 2, n), np.full(n, -0.1), np.full(n, 0.2)]
    m = rng.normal(0, 0.12, (n, 3))
    theta, real = contour_generator_angles(cones, m)
    a, b, k = cones[:, 0:1], cones[:, 1:2], cones[:, 2:3]
    scan = np.linspace(-np.pi, np.pi, 20001)[None, :]
    f = a * b * (1 + k * m[:, 2:3]) - b * m[:, 0:1] * np.cos(scan) - a * m[:, 1:2] * np.sin(scan)
    crossings = np.diff(np.sign(f), axis=1) != 0
    assert 20 < real.sum() < n - 20  # both cases are exercised
    for i in range(n):
        found = scan[0, :-1][crossings[i]]
        if not real[i]:
            assert found.size == 0
            continue
        assert found.size == 2
        got = np.sort(np.mod(theta[i] + np.pi, 2 * np.pi) - np.pi)
        np.testing.assert_allclose(got, np.sort(found), atol=4e-4)


def test_root_at_theta_pi_when_h_equals_f():
    """H - F = 0 makes the tan(θ/2) quadratic linear: one root is θ = π, finite and exact."""
    a, b, k = 0.05, 0.08, 0.7
    cones = np.array([[a, b, k, 0.0, 0.3]] * 3)
    m3 = np.array([0.1, -0.2, 0.4])
    m = np.stack([-a * (1 + k * m3), [0.3, -0.5, 0.05], m3], axis=1)  # F = -b m1 = H
    theta, real = contour_generator_angles(cones, m)
    assert real.all() and np.isfinite(theta).all()
    f = a * b * (1 + k * m[:, 2:3]) - b * m[:, 0:1] * np.cos(theta) - a * m[:, 1:2] * np.sin(theta)
    assert np.abs(f).max() < 1e-15
    dist_to_pi = np.abs(np.mod(theta, 2 * np.pi) - np.pi).min(axis=1)
    assert dist_to_pi.max() < 1e-12
    # nearby configurations give nearby angles (the labelled sides are continuous through θ = π)
    theta2, _ = contour_generator_angles(cones, m + [1e-9, 0, 0])
    assert np.abs(np.angle(np.exp(1j * (theta2 - theta)))).max() < 1e-6


def test_sides_are_continuous_along_a_camera_path():
    """Moving the camera smoothly moves each labelled side smoothly (no swaps), all around the cone."""
    cone = np.array([[0.06, 0.1, 1.1, 0.0, 0.2]])
    s = np.linspace(0, 2 * np.pi, 4001)
    m = np.stack([0.7 * np.cos(s), 0.5 * np.sin(s), 0.1 + 0.05 * np.sin(3 * s)], axis=1)
    theta, real = contour_generator_angles(np.repeat(cone, s.size, 0), m)
    assert real.all()
    step = np.abs(np.angle(np.exp(1j * np.diff(theta, axis=0))))
    assert step.max() < 0.01


def test_symmetric_reference_pose_gives_mirrored_contours(model):
    """Φ = 0 seen by a camera on the body's symmetry plane (y = 0): left parts mirror right parts."""
    cam = Camera.look_at("front", [4.0, 0.0, 1.3], [0.0, 0.0, 1.0])
    pose = forward(model, model.zero())
    ct = extremal_contours(model, pose, [cam], n_samples=9)
    pts, uv, vis = ct.shaped(ct.points), ct.shaped(ct.uv), ct.shaped(ct.visible)
    pairs = 0
    for p, name in enumerate(model.part_names):
        if not name.startswith("left_"):
            continue
        q = model.part_index("right_" + name[len("left_") :])
        mirrored = pts[0, p] * [1, -1, 1]  # (2, n_samples, 3)
        # the sides swap under the mirror; match each left side to the nearest right side
        d_same = np.abs(mirrored - pts[0, q]).max()
        d_swap = np.abs(mirrored - pts[0, q, ::-1]).max()
        assert min(d_same, d_swap) < 1e-9, name
        other = uv[0, q] if d_same < d_swap else uv[0, q, ::-1]
        np.testing.assert_allclose(uv[0, p, ..., 0], (cam.width - 1) - other[..., 0], atol=1e-7)
        np.testing.assert_allclose(uv[0, p, ..., 1], other[..., 1], atol=1e-7)
        other_vis = vis[0, q] if d_same < d_swap else vis[0, q, ::-1]
        np.testing.assert_array_equal(vis[0, p], other_vis)
        pairs += 1
    assert pairs >= 6
    # centred parts are symmetric by themselves: their two sides mirror each other
    torso = model.part_index("torso")
    np.testing.assert_allclose(pts[0, torso, 0] * [1, -1, 1], pts[0, torso, 1], atol=1e-9)


def test_camera_inside_a_cone_is_invalid_without_warnings(model):
    pose = forward(model, model.zero())
    torso = model.part_index("torso")
    inside = pose.to_world(np.array([torso]), np.array([[0.0, 0.0, 0.05]]))[0]
    cams = [Camera.look_at("inside", inside, inside + [1.0, 0.0, 0.0]), *ring(2)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ct = extremal_contours(model, pose, cams, n_samples=5)
    for arr in (ct.points, ct.uv, ct.theta, ct.z):
        assert np.isfinite(arr).all()
    sel = (ct.cam == 0) & (ct.part == torso)
    assert not ct.valid[sel].any() and not ct.visible[sel].any()
    assert ct.valid[ct.cam > 0].mean() > 0.8


def test_points_behind_or_outside_the_camera_are_invalid(model):
    pose = forward(model, model.zero())
    away = Camera.look_at("away", [4.0, 0.0, 1.0], [8.0, 0.0, 1.0])  # the body is behind it
    narrow = Camera.look_at("narrow", [4.0, 0.0, 1.0], [0.0, 0.0, 1.8], fov_deg=5.0)  # sees the head only
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ct = extremal_contours(model, pose, [away, narrow], n_samples=5)
    assert not ct.valid[ct.cam == 0].any()
    seen = set(ct.part[ct.valid])
    assert seen and seen <= {model.part_index("head"), model.part_index("torso")}
    assert np.isfinite(ct.uv).all()


def test_layout_and_fixed_heights(model, rng):
    cams = ring(3)
    pose = forward(model, model.random_params(rng))
    ct = extremal_contours(model, pose, cams, n_samples=4, visibility=False)
    N = 3 * model.n_parts * 2 * 4
    assert ct.n_points == N and ct.points.shape == (N, 3) and ct.uv.shape == (N, 2)
    np.testing.assert_array_equal(ct.cam, np.repeat(np.arange(3), N // 3))
    np.testing.assert_array_equal(ct.shaped(ct.part)[1, :, 1, 2], np.arange(model.n_parts))
    np.testing.assert_array_equal(ct.shaped(ct.side)[2, 5, :, 0], [0, 1])
    np.testing.assert_array_equal(ct.shaped(ct.z)[0], ct.shaped(ct.z)[2])  # heights do not depend on camera or pose
    np.testing.assert_allclose(ct.shaped(ct.z)[0, :, 0], sample_heights(model, 4))
    np.testing.assert_array_equal(ct.visible, ct.valid)


def test_bad_arguments_are_named(model):
    pose = forward(model, model.zero())
    with pytest.raises(ValueError, match="n_samples"):
        extremal_contours(model, pose, ring(1), n_samples=0)
    with pytest.raises(ValueError, match="cameras"):
        extremal_contours(model, pose, [])
    other = load_model("knossow54" if model.name == "knossow40" else "knossow40")
    with pytest.raises(ValueError, match="pose"):
        extremal_contours(model, forward(other, other.zero()), ring(1))


try:
    from hypothesis import given
    from hypothesis import strategies as st
except ImportError:  # pragma: no cover
    given = None

if given is not None:
    finite = dict(allow_nan=False, allow_infinity=False)

    @given(
        a=st.floats(0.01, 0.3, **finite),
        b=st.floats(0.01, 0.3, **finite),
        k=st.floats(-3.0, 3.0, **finite),
        m=st.tuples(*[st.floats(-5.0, 5.0, **finite)] * 3),
    )
    def test_roots_satisfy_the_tangency_equation(a, b, k, m):
        """Any cone, any camera centre: finite angles; where real, both roots solve f(θ) = 0."""
        cone = np.array([[a, b, k, 0.0, 0.1]])
        mv = np.array([m], dtype=float)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            theta, real = contour_generator_angles(cone, mv)
        assert np.isfinite(theta).all()
        F, G, H = -b * mv[0, 0], -a * mv[0, 1], a * b * (1 + k * mv[0, 2])
        scale = np.sqrt(F * F + G * G + H * H)
        f = F * np.cos(theta[0]) + G * np.sin(theta[0]) + H
        if real[0]:
            assert np.abs(f).max() <= 1e-9 * scale
        else:
            assert F * F + G * G - H * H <= 1e-12 * scale * scale
