"""Front/back: colour and feet evidence (tracker.search.appearance), the guard (tracker.fitting.hypotheses)
and the mirror test of issue 12 (a T-pose subject unlike the model is never tracked turned round after 1 s)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tracker.body.kinematics import forward
from tracker.body.model import load_model
from tracker.search.appearance import (AppearanceModel, colour_features, feet_forward, head_cue, mirror_samples,
                                       surface_colours)
from tracker.search.scoring import chamfer_from_silhouette
from tracker.search.mirror import mirror_params
from tracker.synthetic.scene import make_room_texture, render_background, ring_cameras
from tracker.synthetic.synth import make_palette, render_frame
from tracker.synthetic.tpose import mirrored_frames, sided_palette, subject_model


def _tpose(model, rng):
    p = model.zero()
    p[:2] = rng.uniform(-0.5, 0.5, 2)
    p[5] = rng.uniform(-np.pi, np.pi)
    return p


def _frame(seed: int, *, sided: bool = True, cameras: int = 4):
    """One rendered T-pose of a subject whose segments differ up to 15 % from the tracking model:
    (tracking model, its pose at the truth's angles, cameras, images, chamfer images)."""
    rng = np.random.default_rng(seed)
    subject = subject_model(rng)
    truth = _tpose(subject, rng)
    truth[2] = -min(0.0, float(forward(subject, truth).translation[:, 2].min()))  # on the floor (approx.)
    cams = ring_cameras(cameras, size=(320, 240))
    texture = make_room_texture(seed, extent_m=8.0, wall_radius_m=7.0)
    bgs = [render_background(c, texture, with_floor_mask=True) for c in cams]
    palette = (sided_palette if sided else make_palette)(subject, np.random.default_rng(seed + 1))
    images, labels = render_frame(subject, forward(subject, truth), cams, [b for b, _ in bgs],
                                  [f.astype(np.float32) for _, f in bgs], palette)
    chamfer = [chamfer_from_silhouette(np.where(lab >= 0, 255, 0).astype(np.uint8)) for lab in labels]
    return load_model("knossow40"), truth, cams, images, chamfer


def test_feet_cue_follows_the_legs_not_the_reported_hip_centres(tmp_path):
    """The feet are looked for under the thighs' origins (``PIVOT_PART``): a model reporting its
    hip joint centres at those origins instead of inside them gets the same cue."""
    from tracker.body.model import MODELS_DIR

    model, truth, cams, _, chamfer = _frame(2)
    text = (MODELS_DIR / "knossow40.toml").read_text()
    for side in ("left", "right"):
        line = next(ln for ln in text.splitlines() if ln.startswith(f"{side}_hip = "))
        text = text.replace(line, f'{side}_hip = {{ part = "{side}_thigh" }}')
    (tmp_path / "thigh_hips.toml").write_text(text)
    variant = load_model(tmp_path / "thigh_hips.toml")
    assert not np.allclose(variant.joint_point, model.joint_point)
    for p in (truth, mirror_params(model, truth)):
        assert feet_forward(variant, p, cams, chamfer) == feet_forward(model, p, cams, chamfer)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_colour_and_feet_prefer_the_true_hypothesis(seed):
    model, truth, cams, images, chamfer = _frame(seed)
    turned = mirror_params(model, truth)
    # the feet point forward: ahead of the truth's hips every silhouette holds a foot, behind them not
    ahead, behind = feet_forward(model, truth, cams, chamfer)
    assert ahead > 0.9 and ahead - behind > 0.2
    ahead_m, behind_m = feet_forward(model, turned, cams, chamfer)
    assert behind_m - ahead_m > 0.2
    s, sm = (surface_colours(model, p, cams, images, chamfer) for p in (truth, turned))
    assert s.count.sum() > 200 and sm.count.sum() > 200
    # a face is skin, the back of a head is hair
    assert head_cue(model, s) > 1.0 > -1.0 > head_cue(model, sm)
    # the colours learned under the truth prefer the truth's labelling to the mirrored one
    learned = AppearanceModel(model)
    learned.update(s)
    assert learned.evidence(s) > 0.5 and learned.evidence(sm) < -0.5
    # the mirror's samples are the truth's relabelled (same surface, other part and half)
    relabelled = mirror_samples(model, s)
    both = (relabelled.count > 5) & (sm.count > 5)
    assert both.sum() >= 6
    assert np.median(np.abs(relabelled.mean[both] - sm.mean[both])[..., :2]) < 0.02


def test_same_colours_front_and_back_give_no_colour_evidence():
    model, truth, cams, images, chamfer = _frame(4, sided=False)
    s = surface_colours(model, truth, cams, images, chamfer)
    learned = AppearanceModel(model)
    learned.update(s)
    assert abs(learned.evidence(s)) < 0.5  # nothing to tell front from back
    assert abs(head_cue(model, s)) < 1.0  # the head is skin all round


def test_colour_features_and_bad_images():
    f = colour_features(np.array([[0, 0, 0], [255, 255, 255], [0, 0, 200]], float))
    assert f.shape == (3, 3) and np.all(f[0] == 0) and f[1, 2] == pytest.approx(1.0)
    assert f[2, 0] > 0.8 and f[2, 1] == 0.0
    model, truth, cams, images, chamfer = _frame(1, cameras=2)
    with pytest.raises(ValueError, match="cam1"):
        surface_colours(model, truth, cams, [images[0], images[1][:10]], chamfer)


def test_mirrored_frames_counts_a_turned_pose():
    from tracker.body.kinematics import joint_centre_array

    model = load_model("knossow40")
    p = _tpose(model, np.random.default_rng(0))
    names = model.joint_names
    truth = dict(zip(names, joint_centre_array(model, forward(model, p)).tolist()))
    turned = dict(zip(names, joint_centre_array(model, forward(model, mirror_params(model, p))).tolist()))
    records = [{"frame": 0, "joints": truth}, {"frame": 1, "joints": turned}, {"frame": 2, "ok": False}]
    assert mirrored_frames(records, [{"joints": truth}] * 3) == [1]


# ----------------------------------------------------------------------------- the tracker
def _track(tmp_path, seed: int, **session):
    from capture.session import load_session
    from service.offline import track_session
    from service.synthetic_session import make_synthetic_session
    from tracker.synthetic.tpose import tpose_subject

    motion, palette = tpose_subject(seed, hold_s=1.2, lower_s=0.4, blend_s=0.3, move_s=0.3, **session)
    root = make_synthetic_session(f"tpose_{seed}", tmp_path / f"s{seed}", cameras=4, size=(320, 240), seed=seed,
                                  n_background=10, retargeted=motion, palette=palette)
    truth = [json.loads(line) for line in (root / "ground_truth.jsonl").read_text().splitlines() if line]
    return list(track_session(load_session(root))), truth


@pytest.mark.slow
@pytest.mark.parametrize("seed, shoes", [(11, "dark"), (12, "shadow"), (13, "shadow")])
def test_a_tpose_subject_is_never_tracked_turned_after_one_second(tmp_path, seed, shoes):
    """Issue 12's mirror test: a subject whose segments differ up to 15 % from the model, T-pose at a
    random place and heading (held, arms lowered with straight legs: the silhouettes cannot tell front
    from back), then moving; 4 cameras at 320x240; with ``shoes="shadow"`` the segmentation loses
    the feet.  No frame after the first second is mirrored, no mirrored frame is reported ok, and
    the frames after the first second are ok (or refused by the limb colour check with a hand truly lost)."""
    records, truth = _track(tmp_path, seed, shoes=shoes)
    mirrored = mirrored_frames(records, truth)
    assert [f for f in mirrored if f >= 30] == [], mirrored
    assert [r["frame"] for r in records if r["frame"] in mirrored and r["ok"]] == []
    late = [r for r in records if r["frame"] >= 30]

    def hand_lost(r) -> bool:  # refused by the limb colour check with a wrist truly off (> 80 mm)
        t = truth[r["frame"]]["joints"]
        return "limb_colour" in r.get("failed", ()) and max(
            np.linalg.norm(np.subtract(r["joints"][w], t[w])) for w in ("left_wrist", "right_wrist")) > 0.08

    assert sum(r["ok"] or hand_lost(r) for r in late) >= 0.9 * len(late), [r.get("reason") for r in late if not r["ok"]]
