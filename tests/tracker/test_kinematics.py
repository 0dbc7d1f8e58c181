import numpy as np
import pytest

from tracker.body.kinematics import body_jacobian, forward, joint_centre_array, joint_centres, point_jacobian, so3_exp
from tracker.body.model import JOINT_NAMES, BodyModel

MODELS = ["knossow40", "knossow54"]


@pytest.fixture(scope="module", params=MODELS)
def model(request) -> BodyModel:
    from tracker.body.model import load_model

    return load_model(request.param, height_m=1.8)


def attached_points(model, pose, rng, n_per_part=3):
    """Random points on every part's cone (world), with their part index."""
    part = np.repeat(np.arange(model.n_parts), n_per_part)
    a, b, k, z1, z2 = model.cones[part].T
    theta = rng.uniform(0, 2 * np.pi, part.size)
    z = rng.uniform(z1, z2)
    local = np.stack([a * np.cos(theta) * (1 + k * z), b * np.sin(theta) * (1 + k * z), z], -1)
    return part, local, pose.to_world(part, local)


def test_point_jacobian_matches_central_differences(model, rng):
    h = 1e-6
    for _ in range(5):
        params = model.random_params(rng)
        pose = forward(model, params)
        part, local, X = attached_points(model, pose, rng)
        J = point_jacobian(model, pose, part, X)
        fd = np.empty_like(J)
        for k in range(model.n_params):
            dp = np.zeros(model.n_params)
            dp[k] = h
            Xp = forward(model, params + dp).to_world(part, local)
            Xm = forward(model, params - dp).to_world(part, local)
            fd[:, :, k] = (Xp - Xm) / (2 * h)
        rel = np.abs(J - fd).max() / np.abs(fd).max()
        assert rel < 1e-5, rel


def test_body_jacobian_is_the_point_jacobian_factor(model, rng):
    pose = forward(model, model.random_params(rng))
    part, _, X = attached_points(model, pose, rng)
    JH = body_jacobian(model, pose)  # (n_parts, 6, n_params)
    # dX/dΦ = [-[X]x | I] J_H  (A = [-[X]x | I] is the rigid term of IJCV eq. 24)
    Xx = np.zeros((X.shape[0], 3, 3))
    Xx[:, 0, 1], Xx[:, 0, 2], Xx[:, 1, 2] = -X[:, 2], X[:, 1], -X[:, 0]
    Xx = Xx - Xx.transpose(0, 2, 1)
    A = np.concatenate([-Xx, np.broadcast_to(np.eye(3), Xx.shape)], axis=2)
    np.testing.assert_allclose(A @ JH[part], point_jacobian(model, pose, part, X), atol=1e-12)


def test_zero_reference_pose(model):
    pose = forward(model, model.zero())
    # Φ = 0: rotations are the fixed rest rotations composed along the chain, feet on the floor, T-pose
    j = joint_centres(model, pose)
    H = model.height_m
    assert set(JOINT_NAMES) <= set(j)
    assert abs(j["left_ankle"][2] - 0.039 * H) < 0.01 * H
    assert abs(j["left_hip"][2] - 0.530 * H) < 0.01 * H
    assert abs(j["left_shoulder"][2] - 0.818 * H) < 0.02 * H
    # T-pose: wrists at shoulder height, left arm along +y
    assert abs(j["left_wrist"][2] - j["left_shoulder"][2]) < 1e-9
    assert j["left_wrist"][1] > 0.3 * H and j["right_wrist"][1] < -0.3 * H
    # head top near the full height
    head = model.part_index("head")
    top = pose.translation[head] + pose.rotation[head] @ np.array([0, 0, model.cones[head, 4]])
    assert abs(top[2] - H) < 0.03 * H
    for p in range(model.n_parts):
        R = pose.rotation[p]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)


def test_sizing_scales_lengths(model):
    from tracker.body.model import load_model

    small = load_model(model.name, height_m=1.5)
    a = joint_centre_array(model, forward(model, model.zero()))
    b = joint_centre_array(small, forward(small, small.zero()))
    np.testing.assert_allclose(b, a * 1.5 / 1.8, atol=1e-12)


def test_explicit_segment_lengths(model):
    from tracker.body.model import load_model

    m = load_model(model.name, height_m=1.8, segment_lengths={"upper_arm": 0.40, "shank": 0.50})
    j = joint_centres(m, forward(m, m.zero()))
    assert np.linalg.norm(j["left_elbow"] - j["left_shoulder"]) == pytest.approx(0.40)
    assert np.linalg.norm(j["right_knee"] - j["right_ankle"]) == pytest.approx(0.50, abs=0.03)
    with pytest.raises(ValueError, match="unknown segment"):
        load_model(model.name, segment_lengths={"tail": 0.3})


def test_clamp_respects_limits(model, rng):
    p = rng.normal(0, 5, model.n_params)
    c = model.clamp(p)
    assert model.within_limits(c)
    inside = model.random_params(rng)
    assert model.within_limits(inside)
    np.testing.assert_array_equal(model.clamp(inside), inside)


def test_so3_exp_is_rotation(rng):
    R = so3_exp(rng.normal(size=(20, 3)))
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(so3_exp(np.zeros(3)), np.eye(3))
