"""``tracker.body.window``: centred-window smoothing of pose trajectories, by its properties at seeded random
poses (linear kept away from segment ends, constant kept everywhere, limits held, breaks not crossed, a lone
frame unchanged, the root rotation averaged across ±π) and the joint fit's bone lengths."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.body.kinematics import forward, joint_centre_array, so3_exp
from tracker.body.model import JOINT_ROTATION, ROOT_ROTATION, load_model
from tracker.body.window import (fit_joints, nearest_rotvec, quat_to_rotvec, rotvec_to_quat, segment_halves,
                                 smooth_params, smooth_poses, window_mean)

MODEL = load_model("knossow40")
ROT = MODEL.param_kind == ROOT_ROTATION
ANG = MODEL.param_kind == JOINT_ROTATION


def _joints(P):
    return np.array([joint_centre_array(MODEL, forward(MODEL, p)) for p in P])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_segment_halves_shrink_symmetrically_at_breaks(seed):
    rng = np.random.default_rng(seed)
    n = 60
    breaks = rng.random(n) < 0.15
    h = segment_halves(breaks, 3)
    starts = np.flatnonzero(np.append(True, breaks[1:]))
    stops = np.append(starts[1:], n)
    for a, b in zip(starts, stops):
        k = np.arange(a, b)
        assert np.array_equal(h[a:b], np.minimum(np.minimum(k - a, b - 1 - k), 3))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_trajectory_linear_in_time_is_kept_and_a_constant_one_everywhere(seed):
    rng = np.random.default_rng(seed)
    n = 30
    p0 = MODEL.random_params(rng, fraction=0.5)
    rate = np.zeros(MODEL.n_params)
    rate[:3] = rng.normal(0, 0.02, 3)                     # metres per frame
    rate[ANG] = rng.normal(0, 0.004, ANG.sum())            # radians per frame, inside the limits
    P = p0 + np.arange(n)[:, None] * rate
    P[:, ANG] = np.clip(P[:, ANG], MODEL.lower[ANG], MODEL.upper[ANG])
    lin = P.copy()
    lin[:, ROT] = p0[ROT]                                  # the rotation constant: linear in every coordinate
    out = smooth_params(MODEL, lin, half=3)
    clipped = (P[:, ANG] <= MODEL.lower[ANG]) | (P[:, ANG] >= MODEL.upper[ANG])
    keep = ~clipped.any(axis=0)                            # angles that stayed linear
    cols = np.flatnonzero(ANG)[keep]
    assert np.allclose(out[:, cols], lin[:, cols], atol=1e-12)
    assert np.allclose(out[:, :6], lin[:, :6], atol=1e-9)
    const = np.repeat(p0[None], n, axis=0)
    assert np.allclose(smooth_params(MODEL, const, half=4, weights=rng.random(n)), const, atol=1e-12)
    Q, J = smooth_poses(MODEL, const, _joints(const), half=4)
    assert np.allclose(J, _joints(const), atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_limits_and_bone_lengths_hold_near_the_limits(seed):
    rng = np.random.default_rng(seed)
    n = 25
    P = np.repeat(MODEL.random_params(rng)[None], n, axis=0)
    span = MODEL.upper[ANG] - MODEL.lower[ANG]
    near = np.where(rng.random((n, ANG.sum())) < 0.5, MODEL.lower[ANG], MODEL.upper[ANG])
    P[:, ANG] = near - np.sign(near - MODEL.lower[ANG] - 1e-12) * rng.random((n, ANG.sum())) * 0.05 * span
    P[:, :3] += rng.normal(0, 0.05, (n, 3))
    J = _joints(P) + rng.normal(0, 0.03, (n, len(MODEL.joint_names), 3))  # the targets need not be a body
    Q, JQ = smooth_poses(MODEL, P, J, half=2, weights=rng.random(n))
    assert MODEL.within_limits(Q).all()
    assert MODEL.within_limits(smooth_params(MODEL, P, half=3)).all()
    assert np.allclose(JQ[1:-1], _joints(Q[1:-1]), atol=1e-12)  # the ends' windows are themselves: unchanged
    assert np.array_equal(JQ[[0, -1]], J[[0, -1]]) and np.array_equal(Q[[0, -1]], P[[0, -1]])


@pytest.mark.parametrize("seed", [0, 1])
def test_a_break_is_not_crossed_and_a_lone_frame_is_unchanged(seed):
    rng = np.random.default_rng(seed)
    a, b = MODEL.random_params(rng, fraction=0.5), MODEL.random_params(rng, fraction=0.5)
    P = np.array([a] * 6 + [b] + [a] * 6)  # a lone frame (breaks on both sides) inside a steady pose
    breaks = np.zeros(len(P), bool)
    breaks[[6, 7]] = True
    J = _joints(P)
    Q, JQ = smooth_poses(MODEL, P, J, half=3, breaks=breaks)
    assert np.allclose(Q, P, atol=1e-12) and np.allclose(JQ, J, atol=1e-9)
    Q2, J2 = smooth_poses(MODEL, P, J, half=3)  # without the breaks the odd frame pulls its neighbours
    assert np.abs(J2[5] - J[5]).max() > 1e-3
    assert np.array_equal(smooth_params(MODEL, P[6:7], half=3), P[6:7])


def test_the_root_rotation_is_averaged_across_pi():
    """A heading turning through ±π (rotation vectors that wrap) is averaged as the rotation in between."""
    n = 9
    yaw = np.pi - 0.3 + 0.075 * np.arange(n)              # through π at the middle
    R = np.zeros((n, MODEL.n_params))
    R[:, 5] = (yaw + np.pi) % (2 * np.pi) - np.pi         # principal vectors: jump from +π to −π
    out = smooth_params(MODEL, R, half=2)
    got = np.arctan2(so3_exp(out[:, 3:6])[:, 1, 0], so3_exp(out[:, 3:6])[:, 0, 0])
    assert np.allclose(np.angle(np.exp(1j * (got - yaw))), 0.0, atol=1e-9)
    assert np.all(np.abs(out[:, 5] - R[:, 5]) < 0.5)      # each frame keeps its own branch of the vector
    assert np.allclose(_joints(out)[:, 0], _joints(R)[:, 0], atol=1e-9)  # a rotation about the pelvis: still


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_pitch_about_the_pelvis_keeps_the_pelvis_still(seed):
    """The root is averaged about the pelvis, not the model's origin: a jittery pitch and roll with the pelvis
    held still in the world (the root's translation following the rotation's lever) leaves it still."""
    rng = np.random.default_rng(seed)
    n = 11
    P = np.repeat(MODEL.random_params(rng, fraction=0.3)[None], n, axis=0)
    P[:, 3:5] = rng.normal(0, 0.15, (n, 2))               # pitch and roll jitter about a fixed heading
    pelvis = _joints(P[:1])[0, 0]
    P[:, :3] += pelvis - _joints(P)[:, 0]                 # the pelvis at the same world point in every frame
    out = smooth_params(MODEL, P, half=3)
    assert np.abs(out[1:-1, 3:5] - P[1:-1, 3:5]).max() > 0.05  # the jitter is smoothed (the ends are kept)
    assert np.allclose(_joints(out)[:, 0], pelvis, atol=1e-9)


def test_a_rotation_vector_keeps_its_branch():
    """A heading past π written as vectors longer than π (2π − 0.2 + 0.01 k about z): each frame's smoothed
    vector stays on its own branch, the rotation averaged."""
    n = 9
    R = np.zeros((n, MODEL.n_params))
    R[:, 5] = 2 * np.pi - 0.2 + 0.01 * np.arange(n)
    out = smooth_params(MODEL, R, half=2)
    assert np.abs(out[:, 3:6] - R[:, 3:6]).max() < 1e-12


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rotation_vector_quaternion_round_trip(seed):
    rng = np.random.default_rng(seed)
    r = rng.normal(0, 1, (50, 3))
    r *= (rng.random((50, 1)) * np.pi) / np.linalg.norm(r, axis=1, keepdims=True)
    r[0] = 0.0
    assert np.allclose(quat_to_rotvec(rotvec_to_quat(r)), r, atol=1e-9)
    ref = r + rng.normal(0, 0.1, r.shape)
    alt = r - 2 * np.pi * r / np.maximum(np.linalg.norm(r, axis=1, keepdims=True), 1e-12)  # the same rotations
    assert np.allclose(so3_exp(nearest_rotvec(alt, ref)), so3_exp(r), atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1])
def test_window_mean_weights_and_fit_joints_reaches_reachable_targets(seed):
    rng = np.random.default_rng(seed)
    X = rng.normal(0, 1, (7, 2))
    h = np.array([0, 1, 2, 3, 2, 1, 0])
    w = rng.random(7)
    m = window_mean(X, h, w)
    k = 3  # the pair k ± d weighs min(w[k - d], w[k + d]) each, the row itself 1
    pair = np.minimum(w[k - np.arange(1, 4)], w[k + np.arange(1, 4)])
    ww = np.concatenate([pair[::-1], [1.0], pair])
    assert np.allclose(m[k], (ww[:, None] * X).sum(0) / ww.sum())
    assert np.allclose(window_mean(np.arange(7.0)[:, None], h, w)[:, 0], np.arange(7.0))  # linear: no lag
    assert np.allclose(m[[0, 6]], X[[0, 6]])
    p0 = MODEL.random_params(rng, fraction=0.3)
    p1 = np.clip(p0 + rng.normal(0, 0.05, MODEL.n_params), MODEL.lower, MODEL.upper)
    fit = fit_joints(MODEL, p0[None], _joints(p1[None]), damping=1e-3, iterations=20)
    assert np.abs(_joints(fit) - _joints(p1[None])).max() < 0.01
