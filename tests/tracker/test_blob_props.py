"""The operator's props in the blob tracker: carved from the hull, a limit in the inverse kinematics."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.blobs import ColourHull, damped_least_squares
from tracker.blobs.props import carve, in_props
from tracker.body.kinematics import forward
from tracker.body.model import load_model
from tracker.fitting.props import PropBox, PropPenalty


@pytest.fixture(scope="module")
def model():
    return load_model("knossow40", height_m=1.75)


def _hull(rng, n=400) -> ColourHull:
    centres = rng.uniform([-0.5, -0.5, 0.0], [0.5, 0.5, 1.0], (n, 3))
    return ColourHull(centres, np.full(n, 0.03), np.ones(n, bool), np.array([[-0.5, -0.5, 0.0], [0.5, 0.5, 1.0]]),
                      0.03, colours=rng.uniform(0, 255, (n, 2, 3)).astype(np.float32), camera_names=("a", "b"))


def test_carve_drops_exactly_the_voxels_whose_centre_is_in_a_box(rng):
    hull = _hull(rng)
    boxes = [PropBox.from_values([-0.2, -0.2, 0.0, 0.1, 0.3, 0.45]), PropBox.from_values([0.3, -0.5, 0.5, 0.5, 0.5, 1.0])]
    inside = ((np.all((hull.centres >= boxes[0].lo) & (hull.centres <= boxes[0].hi), axis=1))
              | (np.all((hull.centres >= boxes[1].lo) & (hull.centres <= boxes[1].hi), axis=1)))
    assert 0 < inside.sum() < hull.n_voxels
    np.testing.assert_array_equal(in_props(hull.centres, boxes), inside)
    out = carve(hull, boxes)
    assert out.n_voxels == hull.n_voxels - inside.sum()
    np.testing.assert_array_equal(out.centres, hull.centres[~inside])
    np.testing.assert_array_equal(out.colours, hull.colours[~inside])
    np.testing.assert_array_equal(out.sizes, hull.sizes[~inside])
    assert out.camera_names == hull.camera_names
    assert carve(hull, []) is hull


def test_dls_with_the_prop_limit_keeps_the_arm_out_of_a_box_on_its_goal(model):
    rng = np.random.default_rng(7)
    parts = [model.part_index(n) for n in ("right_upper_arm", "right_forearm", "right_hand")]
    free = np.isin(model.param_part, parts)
    hand = np.full(3, model.part_index("right_hand"))
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 0.05, 0.1], [0.0, 0.0, 0.15]])
    for _ in range(4):
        target = model.zero()
        target[free] = rng.uniform(model.lower[free], model.upper[free]) * 0.6
        start = model.clamp(target + np.where(free, rng.normal(0.0, 0.3, model.n_params), 0.0))
        goals = forward(model, target).to_world(hand, pts)
        box = PropBox.from_values(list(goals[0] - 0.06) + list(goals[0] + 0.06))
        penalty = PropPenalty([box], weight=10.0)
        plain = damped_least_squares(model, start, hand, pts, goals, free=free, iterations=20)
        assert in_props(forward(model, plain).to_world(hand[:1], pts[:1]), [box]).all(), "no limit: the goal reached"
        limited = damped_least_squares(model, start, hand, pts, goals, free=free, iterations=20,
                                       penalty=penalty)
        assert model.within_limits(limited)
        assert not in_props(forward(model, limited).to_world(hand[:1], pts[:1]), [box]).any()
        # what is left of the intrusion is small: the goals' pull against the limit's weight
        depth = penalty.residuals(model, limited)[0] / penalty.weight
        assert depth.max() < 0.02, depth.max()
