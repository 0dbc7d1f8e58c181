"""The colour check of the distal limbs (``AppearanceModel.part_distances``, ``Tracker`` option
``limb_colour_margin``): a forearm fitted onto the torso samples the shirt, not its own skin."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.body.kinematics import forward
from tracker.body.model import load_model
from tracker.fitting.hypotheses import FrontBackOptions
from tracker.fitting.tracking import Tracker, TrackerOptions
from tracker.search.appearance import AppearanceModel, ColourSamples, surface_colours, view_colours
from tracker.search.scoring import chamfer_from_silhouette
from tracker.synthetic.scene import make_room_texture, render_background, ring_cameras
from tracker.synthetic.synth import make_palette, render_frame


def _scene(seed: int):
    """The model in a T-pose at a seeded place and heading, rendered in 6 cameras with skin forearms
    and hands and a shirt (``make_palette``): (model, truth, the same pose with the left forearm folded
    across the chest, cameras, images, chamfer images)."""
    rng = np.random.default_rng(seed)
    model = load_model("knossow40")
    truth = model.zero()
    truth[:2] = rng.uniform(-0.3, 0.3, 2)
    truth[5] = rng.uniform(-np.pi, np.pi)
    truth[2] = -min(0.0, float(forward(model, truth).translation[:, 2].min()))
    cams = ring_cameras(6, size=(320, 240))
    texture = make_room_texture(seed, extent_m=8.0, wall_radius_m=7.0)
    bgs = [render_background(c, texture, with_floor_mask=True) for c in cams]
    images, labels = render_frame(model, forward(model, truth), cams, [b for b, _ in bgs],
                                  [f.astype(np.float32) for _, f in bgs], make_palette(model, rng))
    chamfer = [chamfer_from_silhouette(np.where(lab >= 0, 255, 0).astype(np.uint8)) for lab in labels]
    lost = truth.copy()
    names = model.param_names
    lost[names.index("left_upper_arm.abduction")] -= 1.0
    lost[names.index("left_upper_arm.flexion")] += 0.8
    lost[names.index("left_forearm.flexion")] += 2.2
    return model, truth, model.clamp(lost), cams, images, chamfer


def _tracker(model, truth, cams, images, chamfer, **options):
    tracker = Tracker(model, cams, initial_params=truth, front_back=FrontBackOptions(),
                      options=TrackerOptions(**options))
    tracker.guard.appearance.update(surface_colours(model, truth, cams, images, chamfer))
    return tracker


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_forearm_folded_onto_the_torso_is_flagged_and_the_right_pose_is_not(seed):
    model, truth, lost, cams, images, chamfer = _scene(seed)
    tracker = _tracker(model, truth, cams, images, chamfer)
    assert tracker.guard.appearance.learned
    chs = {c.name: ch for c, ch in zip(cams, chamfer)}
    imgs = {c.name: img for c, img in zip(cams, images)}
    assert tracker._limb_colour(cams, chs, imgs, truth) == ""
    note = tracker._limb_colour(cams, chs, imgs, lost)
    assert "left forearm" in note and "right" not in note
    # off, or without images or learned colours, the check says nothing
    assert _tracker(model, truth, cams, images, chamfer, limb_colour_margin=None)._limb_colour(
        cams, chs, imgs, lost) == ""
    assert tracker._limb_colour(cams, chs, None, lost) == ""
    bare = Tracker(model, cams, initial_params=truth, front_back=FrontBackOptions())
    assert bare._limb_colour(cams, chs, imgs, lost) == ""


def _margins(learned, samples, parts):
    """own − other of ``part_distances``: positive where a part's samples are nearer another part's colour."""
    own, other = learned.part_distances(samples, parts)
    return own - other


def test_part_margins_per_view_are_the_pooled_formula_per_camera():
    model, truth, lost, cams, images, chamfer = _scene(2)
    learned = AppearanceModel(model)
    learned.update(surface_colours(model, truth, cams, images, chamfer))
    per_view = view_colours(model, lost, cams, images, chamfer)
    pooled = surface_colours(model, lost, cams, images, chamfer)
    # the cameras' samples pool to surface_colours's
    assert np.allclose(per_view.count.sum(axis=0), pooled.count)
    both = pooled.count > 0
    mean = (per_view.mean * per_view.count[..., None]).sum(axis=0)[both] / pooled.count[both][:, None]
    assert np.allclose(mean, pooled.mean[both])
    parts = [model.part_names.index(n) for n in ("left_forearm", "right_forearm", "left_shank")]
    m = _margins(learned, per_view, parts)
    assert m.shape == (len(cams), 3)
    for v in range(len(cams)):
        one = ColourSamples(per_view.mean[v], per_view.count[v], per_view.bgr[v])
        assert np.allclose(_margins(learned, one, parts), m[v], equal_nan=True)
    # the learned pose's own samples are nearest their own colours; the folded forearm is not
    own = _margins(learned, surface_colours(model, truth, cams, images, chamfer), parts)
    assert np.nanmax(own) <= 1e-9
    assert _margins(learned, pooled, parts)[0] > 1.0
    # brute force at random colours: own = the nearer of its own and its other side's learned half,
    # other = the nearest learned half of any third part
    rng = np.random.default_rng(5)
    learned.mean = rng.random((model.n_parts, 2, 3))
    learned.weight = np.where(rng.random((model.n_parts, 2)) < 0.8, 50.0, 0.0)
    s = ColourSamples(rng.random((model.n_parts, 2, 3)), rng.integers(0, 8, (model.n_parts, 2)).astype(float),
                      np.zeros((model.n_parts, 2, 3)))
    names = model.part_names
    every = list(range(model.n_parts))
    got_own, got_other = learned.part_distances(s, every)
    for i, p in enumerate(every):
        twin = names.index(names[p].replace("left_", "@").replace("right_", "left_").replace("@", "right_"))
        num_own = num_other = den = 0.0
        for h in (0, 1):
            if s.count[p, h] < 3 or learned.weight[p, h] < 10:
                continue
            dist = np.minimum((((s.mean[p, h] - learned.mean) / learned.sigma) ** 2).sum(-1), 9.0)
            dist[learned.weight < 10] = np.inf
            third = np.ones(model.n_parts, bool)
            third[[p, twin]] = False
            num_own += s.count[p, h] * min(dist[p, h], dist[twin, h])
            num_other += s.count[p, h] * dist[third].min()
            den += s.count[p, h]
        if den == 0:
            assert np.isnan(got_own[i]) and np.isnan(got_other[i])
        else:
            assert got_own[i] == pytest.approx(num_own / den) and got_other[i] == pytest.approx(num_other / den)
    assert np.isfinite(got_own).sum() >= 5
