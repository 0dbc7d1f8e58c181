import numpy as np
import pytest

from capture.camera import (
    Camera,
    matrix_to_rodrigues,
    project_many,
    project_many_with_jacobian,
    rodrigues_to_matrix,
)


def random_camera(rng, *, distorted=True):
    eye = rng.uniform(-4, 4, 3) + np.array([0, 0, 1.5])
    eye[:2] += np.sign(eye[:2]) * 1.0
    target = rng.uniform(-0.3, 0.3, 3) + np.array([0, 0, 1.0])
    dist = rng.normal(0, [0.1, 0.05, 0.002, 0.002, 0.02]) if distorted else np.zeros(5)
    return Camera.look_at("c", eye, target, size=(800, 600), fov_deg=rng.uniform(40, 80), distortion=dist)


def test_project_matches_opencv(rng):
    cv2 = pytest.importorskip("cv2")
    for _ in range(5):
        cam = random_camera(rng)
        X = rng.uniform(-0.5, 0.5, (50, 3)) + np.array([0, 0, 1.0])
        ours = cam.project(X)
        theirs, _ = cv2.projectPoints(X, cam.rvec, cam.translation, cam.matrix, cam.distortion)
        np.testing.assert_allclose(ours, theirs[:, 0], atol=1e-8)


def test_projection_jacobian_matches_central_differences(rng):
    h = 1e-6
    for _ in range(10):
        cam = random_camera(rng)
        X = rng.uniform(-0.5, 0.5, (30, 3)) + np.array([0, 0, 1.0])
        uv, J = cam.project_with_jacobian(X)
        np.testing.assert_allclose(uv, cam.project(X), atol=1e-12)
        fd = np.stack([(cam.project(X + h * e) - cam.project(X - h * e)) / (2 * h) for e in np.eye(3)], axis=-1)
        rel = np.abs(J - fd).max() / np.abs(fd).max()
        assert rel < 1e-6


def test_rodrigues_round_trip(rng):
    for _ in range(50):
        r = rng.normal(size=3)
        r *= rng.uniform(0, np.pi - 1e-3) / np.linalg.norm(r)
        np.testing.assert_allclose(matrix_to_rodrigues(rodrigues_to_matrix(r)), r, atol=1e-9)
    # angle = pi exactly
    r = np.array([0.0, np.pi, 0.0])
    np.testing.assert_allclose(rodrigues_to_matrix(matrix_to_rodrigues(rodrigues_to_matrix(r))), rodrigues_to_matrix(r), atol=1e-9)


def test_look_at_puts_target_at_image_centre_and_up_is_up():
    cam = Camera.look_at("c", [3, 0, 1.5], [0, 0, 1.5], size=(640, 480))
    np.testing.assert_allclose(cam.project(np.array([0, 0, 1.5])), [319.5, 239.5], atol=1e-9)
    assert cam.project(np.array([0, 0, 2.0]))[1] < cam.project(np.array([0, 0, 1.0]))[1]
    np.testing.assert_allclose(cam.center, [3, 0, 1.5], atol=1e-12)


def test_bad_camera_rejected_with_its_name():
    with pytest.raises(ValueError, match="cam7"):
        Camera("cam7", np.eye(3) * [1, 1, 2], np.zeros(5), np.eye(3), np.zeros(3), (10, 10))
    with pytest.raises(ValueError, match="cam7.*rotation"):
        Camera("cam7", np.eye(3), np.zeros(5), np.eye(3) * 2, np.zeros(3), (10, 10))


def _camera_set(rng, *, distorted):
    cams = [random_camera(rng, distorted=distorted) for _ in range(4)]
    # one camera with a skew term, K kept upper-triangular
    c = cams[1]
    K = c.matrix.copy()
    K[0, 1] = 3.0
    cams[1] = Camera("skew", K, c.distortion, c.rotation, c.translation, c.size)
    return cams


@pytest.mark.parametrize("distorted", [True, False])
def test_project_many_equals_per_camera_methods(rng, distorted):
    cams = _camera_set(rng, distorted=distorted)
    X = rng.uniform(-0.5, 0.5, (len(cams), 40, 3)) + np.array([0, 0, 1.0])
    uv = project_many(cams, X)
    uv2, J = project_many_with_jacobian(cams, X)
    assert uv.shape == (4, 40, 2) and J.shape == (4, 40, 2, 3)
    for c, cam in enumerate(cams):
        ref_uv, ref_J = cam.project_with_jacobian(X[c])
        np.testing.assert_allclose(uv[c], cam.project(X[c]), rtol=0, atol=1e-12)
        np.testing.assert_allclose(uv2[c], ref_uv, rtol=0, atol=1e-12)
        np.testing.assert_allclose(J[c], ref_J, rtol=0, atol=1e-12)
    # the same with a camera index per point, in shuffled order
    idx = rng.integers(0, len(cams), 90)
    P = rng.uniform(-0.5, 0.5, (90, 3)) + np.array([0, 0, 1.0])
    uv_i, J_i = project_many_with_jacobian(cams, P, cam_index=idx)
    np.testing.assert_array_equal(project_many(cams, P, cam_index=idx), uv_i)
    for c, cam in enumerate(cams):
        ref_uv, ref_J = cam.project_with_jacobian(P[idx == c])
        np.testing.assert_allclose(uv_i[idx == c], ref_uv, rtol=0, atol=1e-12)
        np.testing.assert_allclose(J_i[idx == c], ref_J, rtol=0, atol=1e-12)


def test_project_many_jacobian_matches_central_differences(rng):
    h = 1e-6
    cams = _camera_set(rng, distorted=True)
    idx = rng.integers(0, len(cams), 60)
    X = rng.uniform(-0.5, 0.5, (60, 3)) + np.array([0, 0, 1.0])
    _, J = project_many_with_jacobian(cams, X, cam_index=idx)
    fd = np.stack([(project_many(cams, X + h * e, cam_index=idx) - project_many(cams, X - h * e, cam_index=idx))
                   / (2 * h) for e in np.eye(3)], axis=-1)
    assert np.abs(J - fd).max() / np.abs(fd).max() < 1e-6


def test_project_many_bad_shapes_named(rng):
    cams = _camera_set(rng, distorted=False)
    with pytest.raises(ValueError, match="points_world"):
        project_many(cams, np.zeros((3, 5, 3)))
    with pytest.raises(ValueError, match="cam_index"):
        project_many(cams, np.zeros((5, 3)), cam_index=np.array([0, 1, 2, 3, 4]))
    with pytest.raises(ValueError, match="cameras"):
        project_many([], np.zeros((0, 5, 3)))


@pytest.mark.parametrize("distorted", [True, False])
def test_rays_project_back_to_their_pixels(rng, distorted):
    cam = random_camera(rng, distorted=distorted)
    w, h = cam.size
    uv = rng.uniform([0.2 * w, 0.2 * h], [0.8 * w, 0.8 * h], size=(50, 2))
    d = cam.rays(uv)
    assert d.shape == (50, 3) and np.allclose(np.linalg.norm(d, axis=1), 1.0)
    depth = rng.uniform(0.5, 5.0, size=(50, 1))
    np.testing.assert_allclose(cam.project(cam.center + depth * d), uv, atol=1e-6)
    assert np.all(cam.depth(cam.center + depth * d) > 0)  # in front of the camera
    assert cam.rays(np.zeros((0, 2))).shape == (0, 3)
