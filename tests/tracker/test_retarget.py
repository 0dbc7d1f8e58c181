"""Retargeting CMU motion onto knossow40: residuals, limits, floor, sizing, and IK on known poses."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.synthetic.bvh import load_bvh
from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import load_model
from tracker.imaging.render import body_points
from tracker.synthetic.retarget import BVH_TO_WORLD, _solve_frame, estimate_size, palindrome, retarget_bvh

LIMB = ("left_shoulder", "left_elbow", "left_wrist", "right_shoulder", "right_elbow", "right_wrist",
        "left_knee", "left_ankle", "right_knee", "right_ankle")  # fmt: skip


@pytest.fixture(scope="module")
def cmu(shared_data):
    return load_bvh(shared_data / "cmu_mocap" / "scaled_131_03.bvh")


def limb_mean_mm(r):
    idx = [r.joint_names.index(n) for n in LIMB]
    return r.residual_m[:, idx].mean(axis=0) * 1000


def test_axes_rotation_is_proper():
    assert np.allclose(BVH_TO_WORLD @ BVH_TO_WORLD.T, np.eye(3))
    assert np.linalg.det(BVH_TO_WORLD) == pytest.approx(1.0)
    assert np.allclose(BVH_TO_WORLD @ [0, 1, 0], [0, 0, 1])  # Y up -> Z up
    assert np.allclose(BVH_TO_WORLD @ [0, 0, 1], [1, 0, 0])  # BVH forward (+Z) -> model forward (+X)


def test_size_estimate_cmu(cmu):
    h, lengths = estimate_size(cmu)
    # subject 131's skeleton: thigh 0.41 m, shank 0.39 m, head top ~1.45 m above the toes standing
    assert 1.4 < h < 1.65
    assert lengths == {}
    _, fitted = estimate_size(cmu, fit_segments=True)
    assert fitted["thigh"] == pytest.approx(0.409, abs=0.003)
    assert fitted["forearm"] == pytest.approx(0.190, abs=0.003)


def test_retarget_cmu_height_only(cmu):
    """Residuals with the model's own (Winter) proportions at the fitted height.

    Subject 131's limbs are not in Winter's ratios (forearm 0.19 m vs 0.22 m for the model at
    1.5 m, hips 14 cm apart vs 29 cm), so limb joints are off by the proportion mismatch:
    ~15–30 mm measured; 35 mm bounds that with a margin.  The hip joint centres (points of the
    pelvis, not the thighs' origins the IK matches) are off by the pelvis' own mismatch: 17–26 mm
    measured (~78 mm when the thighs' origins were reported), bound 35 mm.
    """
    r = retarget_bvh(cmu, fps=30, frames=8, start_s=1.0)
    assert r.params.shape == (8, r.model.n_params) and r.targets.shape == (8, 16, 3)
    assert np.allclose(r.times_s, 1.0 + np.arange(8) / 30)
    assert r.model.height_m == pytest.approx(r.height_m)
    assert np.all(r.model.within_limits(r.params))
    mm = limb_mean_mm(r)
    assert mm.max() < 35, dict(zip(LIMB, mm.round(1)))
    hips = [r.joint_names.index(n) for n in ("left_hip", "right_hip")]
    assert r.residual_m[:, hips].mean(axis=0).max() < 0.035
    assert np.isfinite(r.residual_m).all()
    # the floor touches the lowest foot point of the clip; the clip is centred
    lows = [body_points(r.model, forward(r.model, q))[:, :, 2].min() for q in r.params]
    assert min(lows) == pytest.approx(0.0, abs=1e-9)
    # the pelvis target moves like the BVH's hips, relative to its own start
    assert r.joint_names == r.model.joint_names  # knossow40: every joint has a BVH counterpart
    pel = r.targets[:, r.joint_names.index("pelvis")]
    assert np.all(np.abs(pel[:, :2]) < 2.0)
    assert 0.6 < pel[0, 2] < 1.0


def test_retarget_cmu_fitted_segments(cmu):
    """With the BVH's limb lengths the limbs follow closely: elbows/wrists/knees/ankles measured
    ≤ 12 mm, shoulders ≤ 15 mm (the clavicle geometry differs); bound 20 mm."""
    r = retarget_bvh(cmu, fps=30, frames=8, start_s=1.0, fit_segments=True)
    assert set(r.segment_lengths) == {"thigh", "shank", "upper_arm", "forearm"}
    mm = limb_mean_mm(r)
    assert mm.max() < 20, dict(zip(LIMB, mm.round(1)))
    base = retarget_bvh(cmu, fps=30, frames=8, start_s=1.0)
    assert mm.mean() < limb_mean_mm(base).mean()


def test_ik_recovers_model_joints(rng):
    """Targets made by the model itself are reached (to 2 mm) from a perturbed start."""
    model = load_model("knossow40", height_m=1.7)
    truth = model.random_params(rng, fraction=0.4)
    target = joint_centre_array(model, forward(model, truth))
    start = model.clamp(truth + rng.normal(0, 0.1, model.n_params))
    p = _solve_frame(model, target, start, start, 0.001, 0.0, model.joint_part, model.joint_point)
    err = np.linalg.norm(joint_centre_array(model, forward(model, p)) - target, axis=1)
    assert err.max() < 0.002


def test_bad_arguments(cmu):
    with pytest.raises(ValueError, match="fps"):
        retarget_bvh(cmu, fps=0)
    with pytest.raises(ValueError, match="frames=100000"):
        retarget_bvh(cmu, frames=100000)
    with pytest.raises(ValueError, match="start_s"):
        retarget_bvh(cmu, start_s=-1)


def test_palindrome_loops_without_a_jump():
    from tracker.synthetic.synth import bundled_motion

    bvh = load_bvh(bundled_motion("scaled_131_03"))  # bundled with the package: no shared data needed
    r = retarget_bvh(bvh, fps=30, frames=8, start_s=1.0)
    p = palindrome(r)
    n = r.n_frames
    assert p.n_frames == 2 * n - 2 and p.model is r.model
    for k in range(1, n - 1):  # the way back is the way there, reversed
        np.testing.assert_array_equal(p.params[2 * n - 2 - k], r.params[k])
        np.testing.assert_array_equal(p.targets[2 * n - 2 - k], r.targets[k])
    np.testing.assert_array_equal(p.params[:n], r.params)
    # looped, the step from the last frame to the first is one of the clip's own steps (a plain loop jumps)
    steps = np.linalg.norm(np.diff(p.targets, axis=0), axis=2).max(axis=1)
    wrap = np.linalg.norm(p.targets[0] - p.targets[-1], axis=1).max()
    assert wrap == pytest.approx(np.linalg.norm(r.targets[1] - r.targets[0], axis=1).max())
    assert wrap <= steps.max()
    assert palindrome(retarget_bvh(bvh, fps=30, frames=2, start_s=1.0)).n_frames == 2


def test_the_motion_does_not_depend_on_where_the_hips_are_reported(tmp_path):
    """The IK matches the BVH's hips to the thighs' origins (the pivots, ``BodyModel.pivots``), so a model
    reporting its hip joint centres elsewhere is posed the same; its reported hips are where the
    ``[joints]`` table puts them."""
    from tracker.body.model import MODELS_DIR
    from tracker.synthetic.synth import bundled_motion

    cmu = load_bvh(bundled_motion("scaled_131_03"))
    text = (MODELS_DIR / "knossow40.toml").read_text()
    at_thighs = text
    for side, sign in (("left", ""), ("right", "-")):
        line = next(ln for ln in text.splitlines() if ln.startswith(f"{side}_hip = "))
        at_thighs = at_thighs.replace(line, f'{side}_hip = {{ part = "{side}_thigh" }}')
    assert at_thighs != text
    variant = tmp_path / "knossow40_thigh_hips.toml"
    variant.write_text(at_thighs)
    shipped = retarget_bvh(cmu, fps=30, frames=4, start_s=1.0)
    moved = retarget_bvh(cmu, model=str(variant), fps=30, frames=4, start_s=1.0)
    assert moved.height_m == pytest.approx(shipped.height_m)
    assert np.allclose(moved.params, shipped.params, atol=1e-9)
    m = shipped.model
    part, point = m.pivots(["left_hip", "pelvis"])
    assert part[0] == m.part_index("left_thigh") and np.all(point[0] == 0.0)
    assert part[1] == m.joint_part[m.joint_names.index("pelvis")]
    hips = [shipped.joint_names.index(n) for n in ("left_hip", "right_hip")]
    assert np.all(shipped.residual_m[:, hips] < moved.residual_m[:, hips])
