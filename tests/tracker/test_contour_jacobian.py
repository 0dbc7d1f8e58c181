"""dx/dΦ = J_I (A + B) J_H against central finite differences of the contours themselves."""

import numpy as np
import pytest

from capture.camera import Camera
from tracker.imaging.contours import extremal_contours
from tracker.imaging.jacobian import contour_jacobian, contour_motion, contour_point_jacobian
from tracker.body.kinematics import body_jacobian, forward, point_jacobian
from tracker.body.model import load_model

MODELS = ["knossow40", "knossow54"]
DISTORTION = (-0.2, 0.05, 0.001, -0.001, 0.01)
N_SAMPLES = 3
H = 1e-6


def ring(n=6):
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False) + 0.3
    return [
        Camera.look_at(f"cam{i}", [4.0 * np.cos(q), 4.0 * np.sin(q), 1.5], [0, 0, 1.0], distortion=DISTORTION)
        for i, q in enumerate(angles)
    ]


CAMERAS = ring()


@pytest.fixture(scope="module", params=MODELS)
def case(request):
    """A model, seeded poses, and central differences of the contour points (world) and pixels."""
    model = load_model(request.param, height_m=1.75)
    rng = np.random.default_rng(2024)
    out = []
    for _ in range(2):
        params = model.random_params(rng)
        pose = forward(model, params)
        ct = extremal_contours(model, pose, CAMERAS, n_samples=N_SAMPLES, visibility=False)
        fd_xyz = np.empty((ct.n_points, 3, model.n_params))
        fd_uv = np.empty((ct.n_points, 2, model.n_params))
        for k in range(model.n_params):
            dp = np.zeros(model.n_params)
            dp[k] = H
            plus, minus = (
                extremal_contours(model, forward(model, p), CAMERAS, n_samples=N_SAMPLES, visibility=False)
                for p in (params + dp, params - dp)
            )
            fd_xyz[:, :, k] = (plus.points - minus.points) / (2 * H)
            fd_uv[:, :, k] = (plus.uv - minus.uv) / (2 * H)
        out.append((pose, ct, fd_xyz, fd_uv))
    return model, out


def rel_error(J, fd, rows):
    """Per-point relative error ||J - FD|| / ||FD|| over the point's whole Jacobian, shape (n,)."""
    n = rows.sum()
    diff = (J - fd)[rows].reshape(n, -1)
    return np.linalg.norm(diff, axis=1) / np.linalg.norm(fd[rows].reshape(n, -1), axis=1)


def test_rigid_plus_sliding_motion_matches_contour_point_differences(case):
    """(A + B) J_H is the velocity of the point that stays on the contour generator at fixed z."""
    model, poses = case
    for pose, ct, fd_xyz, _ in poses:
        J = contour_point_jacobian(model, pose, CAMERAS, ct)
        assert ct.valid.sum() > 0.8 * ct.n_points
        assert rel_error(J, fd_xyz, ct.valid).max() < 1e-5
        # the rigid term alone is the wrong velocity: the point slides
        rigid = contour_point_jacobian(model, pose, CAMERAS, ct, sliding=False)
        assert np.median(rel_error(rigid, fd_xyz, ct.valid)) > 1e-2


def test_full_chain_matches_pixel_differences_and_sliding_matters(case):
    model, poses = case
    for pose, ct, _, fd_uv in poses:
        J = contour_jacobian(model, pose, CAMERAS, ct)
        err = rel_error(J, fd_uv, ct.valid)
        assert err.max() < 1e-5
        err_rigid = rel_error(contour_jacobian(model, pose, CAMERAS, ct, sliding=False), fd_uv, ct.valid)
        assert np.median(err_rigid) > 1e-2 and np.median(err_rigid) > 1e4 * err.max()


def test_image_jacobian_factor_with_distortion(case, rng):
    """J_I: the camera's analytic d(uv)/dX at contour points against central differences."""
    model, poses = case
    _, ct, _, _ = poses[0]
    for c, cam in enumerate(CAMERAS):
        X = ct.points[ct.valid & (ct.cam == c)]
        _, JI = cam.project_with_jacobian(X)
        fd = np.empty_like(JI)
        for j in range(3):
            d = np.zeros(3)
            d[j] = H
            fd[:, :, j] = (cam.project(X + d) - cam.project(X - d)) / (2 * H)
        assert np.abs(JI - fd).max() / np.abs(fd).max() < 1e-6


def test_factors_compose(case):
    """contour_jacobian = J_I (A + B) J_H with J_H = tracker.body.kinematics.body_jacobian."""
    model, poses = case
    pose, ct, _, _ = poses[1]
    JH = body_jacobian(model, pose)[ct.part]  # (N, 6, n_params)
    AB = contour_motion(model, pose, CAMERAS, ct)
    np.testing.assert_allclose(AB @ JH, contour_point_jacobian(model, pose, CAMERAS, ct), atol=1e-12)
    # the rigid term alone is tracker.body.kinematics.point_jacobian (A J_H)
    np.testing.assert_allclose(
        contour_point_jacobian(model, pose, CAMERAS, ct, sliding=False),
        point_jacobian(model, pose, ct.part, ct.points),
        atol=1e-12,
    )
    rows = np.flatnonzero(ct.valid)
    JI = np.concatenate([CAMERAS[c].project_with_jacobian(ct.points[rows][ct.cam[rows] == c])[1] for c in range(6)])
    np.testing.assert_allclose(
        JI @ AB[rows] @ JH[rows], contour_jacobian(model, pose, CAMERAS, ct, rows=rows), rtol=1e-10, atol=1e-9
    )


def test_sliding_moves_points_along_the_image_contour(case):
    """J_I B lies along the image of the ruling: the rigid model already has the right normal motion."""
    model, poses = case
    pose, ct, _, _ = poses[0]
    rows = ct.valid
    B = contour_jacobian(model, pose, CAMERAS, ct, rows=rows) - contour_jacobian(
        model, pose, CAMERAS, ct, rows=rows, sliding=False
    )
    # image direction of the ruling through each point: J_I R X_z
    part = ct.part[rows]
    a, b, k = (model.cones[part, j] for j in range(3))
    th = ct.theta[rows]
    Xz_local = np.stack([a * k * np.cos(th), b * k * np.sin(th), np.ones_like(th)], axis=1)
    Xz = np.einsum("nij,nj->ni", pose.rotation[part], Xz_local)
    pts, cam = ct.points[rows], ct.cam[rows]
    tangent = np.empty((rows.sum(), 2))
    for c in range(6):
        sel = cam == c
        tangent[sel] = np.einsum("nij,nj->ni", CAMERAS[c].project_with_jacobian(pts[sel])[1], Xz[sel])
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal_part = tangent[:, 0, None] * B[:, 1] - tangent[:, 1, None] * B[:, 0]  # 2-D cross: (n, n_params)
    assert np.abs(B).max() > 1.0  # the sliding term is not negligible in pixels
    assert np.abs(normal_part).max() < 1e-8 * np.abs(B).max()


def test_rows_select_points(case):
    model, poses = case
    pose, ct, _, _ = poses[0]
    full = contour_jacobian(model, pose, CAMERAS, ct)
    idx = np.array([5, 0, ct.n_points - 1, 17])
    np.testing.assert_allclose(contour_jacobian(model, pose, CAMERAS, ct, rows=idx), full[idx], rtol=1e-12, atol=1e-12)
    by_mask = contour_jacobian(model, pose, CAMERAS, ct, rows=ct.valid)
    np.testing.assert_allclose(by_mask, full[ct.valid], rtol=1e-12, atol=1e-12)
    assert contour_jacobian(model, pose, CAMERAS, ct, rows=np.array([], dtype=int)).shape == (0, 2, model.n_params)
    with pytest.raises(ValueError, match="rows"):
        contour_jacobian(model, pose, CAMERAS, ct, rows=np.array([ct.n_points]))
    with pytest.raises(ValueError, match="rows"):
        contour_jacobian(model, pose, CAMERAS, ct, rows=ct.valid[:-1])
    with pytest.raises(ValueError, match="cameras"):
        contour_jacobian(model, pose, CAMERAS[:3], ct)
    other = load_model("knossow54" if model.name == "knossow40" else "knossow40")
    with pytest.raises(ValueError, match="pose"):
        contour_jacobian(model, forward(other, other.zero()), CAMERAS, ct)


def test_camera_inside_a_cone_gives_finite_jacobians_without_warnings():
    """Rows without a real contour generator (camera inside the cone) get finite values, no warnings."""
    import warnings

    model = load_model("knossow40", height_m=1.75)
    pose = forward(model, model.random_params(np.random.default_rng(5), fraction=0.3))
    torso = model.part_index("torso")
    inside = pose.to_world(np.array([torso]), np.array([[0.0, 0.0, 0.05]]))[0]
    cams = [Camera.look_at("inside", inside, inside + [1.0, 0.0, -1.0], distortion=DISTORTION), *CAMERAS[:2]]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ct = extremal_contours(model, pose, cams, n_samples=4)
        assert not ct.valid[(ct.cam == 0) & (ct.part == torso)].any()
        for sliding in (True, False):
            J = contour_jacobian(model, pose, cams, ct, sliding=sliding)
            assert np.isfinite(J).all()
            assert np.isfinite(contour_point_jacobian(model, pose, cams, ct, sliding=sliding)).all()
        # no ruling, no sliding: those rows get the rigid term only
        rows = (ct.cam == 0) & (ct.part == torso)
        np.testing.assert_array_equal(
            contour_point_jacobian(model, pose, cams, ct, rows=rows),
            contour_point_jacobian(model, pose, cams, ct, rows=rows, sliding=False),
        )
