"""The independent person renderer (tracker/synthetic/people.py), its procedural motions and the
robustness metrics (tracker/synthetic/evaluation.py)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from tracker.synthetic.bvh import load_bvh
from tracker.synthetic.scene import ring_cameras
from tracker.synthetic.synth import bundled_motion
from tracker.synthetic.evaluation import (FALSE_ALARM_M, FALSE_OK_M, mirrored_frames, frame_errors, reflect_front_back,
                                          score_clip, summarise_clips, swap_left_right)
from tracker.synthetic.motions import MOTIONS, make_motion
from tracker.synthetic.people import (HAND_LENGTH_H, JOINT_NAMES, SEGMENTS, Studio, body_primitives, make_subject,
                                      subject_height, subject_motion)


@pytest.fixture(scope="module")
def skeleton():
    return load_bvh(bundled_motion("scaled_131_01"))


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock")
        yield


def _scene(skeleton, seed, motion="tpose_start", frames=4, n_cams=4, size=(160, 120)):
    subject = make_subject(seed)
    mot = make_motion(motion, skeleton, frames=frames, rng=np.random.default_rng(seed))
    sm = subject_motion(mot, subject)
    cams = ring_cameras(n_cams, size=size, radius_m=4.0, target=(*sm.joints[0, 0, :2], 0.9))
    return subject, sm, body_primitives(sm, subject), Studio(cams, seed=seed, dark_floor=seed % 2 == 0)


def test_render_is_deterministic_for_a_seed(skeleton):
    outs = []
    for _ in range(2):
        subject, sm, prim, studio = _scene(skeleton, 3)
        images, masks = studio.render(prim, 2)
        jpegs = [studio.camera_output(im, np.random.default_rng(5))[1] for im in images]
        outs.append(jpegs + [m.tobytes() for m in masks])
    assert outs[0] == outs[1]
    _, _, prim4, studio4 = _scene(skeleton, 4)
    assert studio4.render(prim4, 2)[1][0].tobytes() != outs[0][4]


@pytest.mark.parametrize("motion", sorted(MOTIONS))
def test_silhouettes_contain_the_projected_joints(skeleton, motion):
    for seed in range(2):
        _, sm, prim, studio = _scene(skeleton, seed, motion=motion, frames=30)
        for f in (0, 21):
            _, masks = studio.render(prim, f)
            for cam, mask in zip(studio.cameras, masks):
                uv = np.rint(cam.project(sm.joints[f])).astype(int)
                inside = (uv[:, 0] >= 0) & (uv[:, 0] < cam.size[0]) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.size[1])
                assert inside.all(), (motion, seed, f, cam.name)
                hits = mask[uv[:, 1], uv[:, 0]]
                assert hits.all(), (motion, seed, f, cam.name, [JOINT_NAMES[i] for i in np.flatnonzero(~hits)])
            # the soles touch the floor and no capsule goes below it
            low = np.minimum(prim.cap_a[f, :, 2], prim.cap_b[f, :, 2]) - prim.cap_r
            assert low.min() == pytest.approx(0.0, abs=1e-9)


def test_proportions_vary_between_seeds(skeleton):
    subjects = [make_subject(s) for s in range(6)]
    for seg in SEGMENTS:
        vals = np.array([s.scale[seg] for s in subjects])
        assert np.all((vals >= 0.85) & (vals <= 1.15)) and np.ptp(vals) > 0.05, seg
    # measured on the rendered skeleton: thigh/shank ratio and standing height differ between subjects
    ratios, heights = [], []
    for subject in subjects:
        sm = subject_motion(make_motion("crouch", skeleton, frames=2), subject)
        j = {n: sm.joints[0, i] for i, n in enumerate(JOINT_NAMES)}
        ratios.append(np.linalg.norm(j["left_hip"] - j["left_knee"]) / np.linalg.norm(j["left_knee"] - j["left_ankle"]))
        heights.append(subject_height(skeleton, subject))
    assert np.ptp(ratios) > 0.1
    assert 1.4 < min(heights) and max(heights) < 2.0 and np.ptp(heights) > 0.05
    radii = np.array([[s.radius["thigh"], s.radius["upper_arm"]] for s in subjects])
    assert np.all(np.ptp(radii / radii.mean(axis=0), axis=0) > 0.15)


def test_hands_are_a_persons_size_along_the_bvh_fingers(skeleton):
    # wrist to fingertips: 0.09-0.125 of the standing height (HAND_LENGTH_H x the hand scale's U(0.85, 1.15)),
    # not the CMU skeleton's finger end site (about half a hand); the hand points along wrist -> finger end
    assert 0.10 <= HAND_LENGTH_H <= 0.12
    lengths = []
    for seed in range(6):
        subject, sm, prim, studio = _scene(skeleton, seed, motion="arms", frames=20)
        height = subject_height(skeleton, subject)
        assert sm.height_m == pytest.approx(height)
        for k, (wrist, fingers) in enumerate((("left_wrist", "LFingers_End"), ("right_wrist", "RFingers_End"))):
            e = prim.head + 1 + k
            w = sm.joints[:, JOINT_NAMES.index(wrist)]
            tip = prim.ell_c[:, e] + prim.ell_r[e, 2] * prim.ell_axes[:, e, 2]
            length = np.linalg.norm(tip - w, axis=1)
            assert np.all((length > 0.09 * height) & (length < 0.125 * height)), (seed, wrist, length / height)
            cmu = np.linalg.norm(sm.joint(fingers) - w, axis=1)
            assert np.all(length > 1.5 * cmu), (seed, wrist)
            direction = (sm.joint(fingers) - w) / cmu[:, None]
            np.testing.assert_allclose((tip - w) / length[:, None], direction, atol=1e-9)
            lengths.append(length[0] / height / subject.scale["hand"])
            # the rendered silhouette holds the hand beyond the CMU finger end site (~0.45 of it) in every camera
            for f in (0, 13):
                near_tip = w[f] + 0.75 * (tip[f] - w[f])
                for cam, mask in zip(studio.cameras, studio.render(prim, f)[1]):
                    u, v = np.rint(cam.project(near_tip[None])[0]).astype(int)
                    assert mask[v, u], (seed, wrist, f, cam.name)
    np.testing.assert_allclose(lengths, HAND_LENGTH_H, rtol=1e-9)


def test_t_pose_start_is_a_t_pose_at_the_drawn_heading(skeleton):
    _, sm, _, _ = _scene(skeleton, 2, frames=10)
    j = {n: sm.joints[0, i] for i, n in enumerate(JOINT_NAMES)}
    for side in ("left", "right"):
        arm = j[f"{side}_wrist"] - j[f"{side}_shoulder"]
        assert abs(arm[2]) < 0.03 * np.linalg.norm(arm)  # arms horizontal
    lateral = j["left_shoulder"] - j["right_shoulder"]
    assert abs(np.dot(j["left_wrist"] - j["right_wrist"], lateral)) / np.linalg.norm(lateral) > 1.0


# --------------------------------------------------------------------------- metrics


def _truth(n=10, rng=None):
    """A walking-like symmetric body: joints (n, 16, 3) around the origin facing +X."""
    rng = np.random.default_rng(0) if rng is None else rng
    base = {"pelvis": (0, 0, 0.9), "spine": (0, 0, 1.1), "neck": (0, 0, 1.4), "head": (0, 0, 1.6),
            "left_shoulder": (0, 0.2, 1.4), "left_elbow": (0.1, 0.25, 1.15), "left_wrist": (0.25, 0.25, 1.0),
            "left_hip": (0, 0.1, 0.9), "left_knee": (0.15, 0.1, 0.5), "left_ankle": (0.1, 0.1, 0.1)}
    for k in list(base):
        if k.startswith("left_"):
            x, y, z = base[k]
            base[k.replace("left_", "right_")] = (-x, -y, z)
    J = np.array([base[n] for n in JOINT_NAMES], float)
    return J[None] + rng.normal(0, 0.002, (n, len(JOINT_NAMES), 3))


def test_swaps_are_involutions_and_change_limbs_only():
    t = _truth()
    assert np.allclose(swap_left_right(swap_left_right(t)), t)
    assert np.allclose(reflect_front_back(reflect_front_back(t)), t)
    trunk = [JOINT_NAMES.index(n) for n in ("pelvis", "spine", "neck", "head")]
    assert np.allclose(swap_left_right(t)[:, trunk], t[:, trunk])


def test_mirror_detection_on_swapped_predictions():
    t = _truth(20)
    rng = np.random.default_rng(1)
    good = t + rng.normal(0, 0.01, t.shape)
    turned = swap_left_right(t) + rng.normal(0, 0.01, t.shape)  # a track turned round onto the body
    flipped = reflect_front_back(t) + rng.normal(0, 0.01, t.shape)  # knees and arms front to back
    assert not mirrored_frames(frame_errors(good, t)).any()
    assert mirrored_frames(frame_errors(turned, t)).all()
    assert mirrored_frames(frame_errors(flipped, t)).all()
    # a poor fit that is not closer to a swapped truth is not called mirrored
    poor = t + np.array([0.0, 0.0, 0.1])
    assert not mirrored_frames(frame_errors(poor, t)).any()


def test_score_counts_false_ok_false_alarm_and_mirrored_after_the_first_second():
    n, fps = 12, 4.0
    t = _truth(n)
    pred = t.copy()
    pred[0:3] = swap_left_right(t[0:3])          # mirrored in the first second (frames 0-3)
    pred[5] = swap_left_right(t[5:6])[0]         # mirrored after it
    pred[6] += np.array([FALSE_OK_M + 0.02, 0, 0])   # > 80 mm
    pred[7] += np.array([FALSE_ALARM_M - 0.01, 0, 0])  # < 40 mm
    pred[8] += np.array([0.06, 0, 0])            # 60 mm: neither
    pred[9] = np.nan                             # no pose
    ok = np.ones(n, bool)
    ok[[7, 8, 9, 10]] = False
    s = score_clip(pred, ok, t, fps=fps)
    assert s["frames"] == n and s["posed"] == n - 1 and s["ok"] == 8
    assert s["mirrored"] == 4 and s["mirrored_after"] == 1 and s["frames_after"] == n - 4
    # false ok: ok frames above 80 mm = the 4 mirrored ones and frame 6
    assert s["false_ok"] == 5
    # false alarm: not ok with a pose under 40 mm = frames 7 and 10 (not 8: 60 mm; not 9: no pose)
    assert s["false_alarm"] == 2
    tot = summarise_clips([s, s])
    assert tot["frames"] == 2 * n
    assert tot["false_ok_percent"] == pytest.approx(100 * 5 / n)
    assert tot["false_alarm_percent"] == pytest.approx(100 * 2 / n)
    # mirrored: of the frames with a pose (frame 9 has none)
    assert s["posed_after"] == n - 4 - 1
    assert tot["mirrored_frames_percent"] == pytest.approx(100 * 1 / (n - 5))
    assert tot["mirrored_frames_percent_including_first_second"] == pytest.approx(100 * 4 / (n - 1))
    assert tot["no_pose_percent"] == pytest.approx(100 / n)


def test_metrics_reject_bad_shapes():
    with pytest.raises(ValueError, match="shape"):
        frame_errors(np.zeros((3, 15, 3)), np.zeros((3, 15, 3)))
    with pytest.raises(ValueError, match="ok has"):
        score_clip(np.zeros((3, 16, 3)), [True] * 2, np.zeros((3, 16, 3)), fps=30.0)
