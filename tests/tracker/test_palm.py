"""The frame fit's palm-length hands (``TrackerOptions.palm_length``, ``palm_model``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from segmentation.distance import chamfer_images
from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import load_model
from tracker.fitting.tracking import Tracker, TrackerOptions, palm_model
from tracker.imaging.render import internal_edges, render_label_images
from tracker.synthetic.bvh import load_bvh
from tracker.synthetic.retarget import retarget_bvh
from tracker.synthetic.scene import ring_cameras

HOP = Path(__file__).resolve().parents[2] / "tracker" / "synthetic" / "data" / "scaled_131_03.bvh"
ARM_JOINTS = ("left_shoulder", "left_elbow", "left_wrist", "right_shoulder", "right_elbow", "right_wrist")


@pytest.mark.parametrize("name", ["knossow40", "knossow54"])
def test_palm_model_cuts_only_the_hands(name, rng):
    """Only the hands' cone lengths change (to the fraction of height asked, never longer), and the
    joint centres are the model's at seeded random poses; None gives the model itself."""
    model = load_model(name, height_m=1.7)
    assert palm_model(model, None) is model
    palm = palm_model(model, 0.06)
    hands = [i for i, n in enumerate(model.part_names) if n.endswith("_hand")]
    assert len(hands) == 2
    others = np.setdiff1d(np.arange(model.n_parts), hands)
    np.testing.assert_array_equal(palm.cones[others], model.cones[others])
    np.testing.assert_allclose(palm.cones[hands, 4], 0.06 * 1.7)
    np.testing.assert_array_equal(palm.cones[hands, :4], model.cones[hands, :4])
    np.testing.assert_array_equal(palm_model(model, 0.5).cones, model.cones)  # longer than the hand: as it is
    for _ in range(3):
        p = model.random_params(rng, fraction=0.5)
        np.testing.assert_array_equal(joint_centre_array(palm, forward(palm, p)),
                                      joint_centre_array(model, forward(model, p)))
    with pytest.raises(ValueError, match="palm_length"):
        palm_model(model, 0.0)


def _render(model, params, cameras):
    labels = render_label_images(model, forward(model, params), cameras)
    sils = {c.name: np.where(lab >= 0, 255, 0).astype(np.uint8) for c, lab in zip(cameras, labels)}
    return {c.name: chamfer_images(sils[c.name], internal_edges(lab)) for c, lab in zip(cameras, labels)}, sils


def test_a_short_hand_does_not_pull_the_arm_up_its_axis():
    """A body whose hands are shorter than the model's (0.045 of height, less than a fist), hop
    frames refitted from the true pose (3 tracker steps on one frame set, 4 cameras): with the
    whole-hand fit (``palm_length=None``) the arms slide towards the shoulders to keep the model's
    hands inside the silhouettes; the palm fit stays nearer the truth on every frame."""
    rt = retarget_bvh(load_bvh(HOP), model="knossow40", frames=21, start_s=0.0, fps=10)
    model, cams = rt.model, ring_cameras(4, size=(320, 240))
    subject = palm_model(model, 0.045)  # the rendered body: short hands
    arms = [model.joint_names.index(j) for j in ARM_JOINTS]
    err = {None: [], 0.06: []}
    for frame in (0, 10, 20):
        chamfer, sils = _render(subject, rt.params[frame], cams)
        truth = joint_centre_array(model, forward(model, rt.params[frame]))[arms]
        for palm in err:
            tracker = Tracker(model, cams, initial_params=rt.params[frame], options=TrackerOptions(palm_length=palm),
                              front_back=None)
            for k in range(3):
                rec = tracker.step(k, int(k * 1e9 / 30), chamfer, sils)
            err[palm].append(1e3 * np.linalg.norm(np.array([rec["joints"][j] for j in ARM_JOINTS]) - truth,
                                                  axis=1).mean())
    whole, palm = np.array(err[None]), np.array(err[0.06])
    assert np.all(palm < whole) and palm.mean() < whole.mean() - 10.0, err
