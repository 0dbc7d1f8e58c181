"""The walking-direction cue of the blob tracker (tracker.blobs.walk_heading), at seeded random poses."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tracker.blobs.tracking import BlobOptions
from tracker.blobs.walk_heading import WalkHeading, walk_turn
from tracker.body.kinematics import forward, joint_centre_array, so3_exp
from tracker.body.model import ROOT_ROTATION, ROOT_TRANSLATION, load_model
from tracker.search.candidates import turn_about_vertical
from tracker.search.mirror import pelvis_heading


@pytest.fixture(scope="module")
def model():
    return load_model("knossow40", height_m=1.75)


def _angle(v):
    return np.arctan2(v[1], v[0])


def test_walk_turn_weights_by_speed_and_wraps():
    rng = np.random.default_rng(3)
    for _ in range(50):
        f, d = rng.uniform(-np.pi, np.pi, 2)
        facing = np.array([np.cos(f), np.sin(f)]) * rng.uniform(0.1, 2.0)
        unit = np.array([np.cos(d), np.sin(d)])
        wrapped = np.angle(np.exp(1j * (d - f)))
        full = walk_turn(facing, 1.0 * unit, gain=0.5, speed_min=0.3, speed_full=0.6)
        assert full == pytest.approx(0.5 * wrapped, abs=1e-9)
        half = walk_turn(facing, 0.45 * unit, gain=0.5, speed_min=0.3, speed_full=0.6)
        assert half == pytest.approx(0.25 * wrapped, abs=1e-9)
        assert walk_turn(facing, 0.2 * unit, gain=0.5, speed_min=0.3, speed_full=0.6) == 0.0
    assert walk_turn(np.zeros(2), np.array([1.0, 0.0]), gain=0.5, speed_min=0.3, speed_full=0.6) == 0.0


def test_walk_turn_leaves_large_angles_alone():
    rng = np.random.default_rng(5)
    for _ in range(50):
        f, d = rng.uniform(-np.pi, np.pi, 2)
        wrapped = np.angle(np.exp(1j * (d - f)))
        got = walk_turn([np.cos(f), np.sin(f)], [np.cos(d), np.sin(d)], gain=1.0, speed_min=0.3, speed_full=0.6,
                        max_rad=np.radians(45.0))
        assert got == (pytest.approx(wrapped, abs=1e-9) if abs(wrapped) <= np.radians(45.0) else 0.0)


def test_walk_turn_dead_band_turns_only_the_excess():
    rng = np.random.default_rng(23)
    dead, top = np.radians(30.0), np.radians(90.0)
    for _ in range(50):
        f, d = rng.uniform(-np.pi, np.pi, 2)
        wrapped = np.angle(np.exp(1j * (d - f)))
        got = walk_turn([np.cos(f), np.sin(f)], [np.cos(d), np.sin(d)], gain=0.5, speed_min=0.3, speed_full=0.6,
                        max_rad=top, dead_rad=dead)
        want = 0.5 * np.sign(wrapped) * (abs(wrapped) - dead) if dead < abs(wrapped) <= top else 0.0
        assert got == pytest.approx(want, abs=1e-9)


def _pelvis_joint(model, params):
    return joint_centre_array(model, forward(model, params))[list(model.joint_names).index("pelvis")]


def test_walk_heading_turns_a_pose_toward_its_walk(model):
    rng = np.random.default_rng(7)
    t_idx = np.flatnonzero(model.param_kind == ROOT_TRANSLATION)
    for _ in range(10):
        p = turn_about_vertical(model, model.zero(), rng.uniform(-np.pi, np.pi), np.zeros(3))
        walk = rng.uniform(-np.pi, np.pi)
        wh = WalkHeading(model, gain=1.0, speed_min=0.3, speed_full=0.6, window_s=0.3, upright=0.9)
        for k in range(12):  # 1 m/s along `walk`, 30 frames per second
            q = p.copy()
            q[t_idx[:2]] += (k / 30.0) * np.array([np.cos(walk), np.sin(walk)])
            wh.add_pose(k / 30.0, joint_centre_array(model, forward(model, q)))
        assert np.allclose(wh.velocity(), [np.cos(walk), np.sin(walk)], atol=1e-9)
        turned = turn_about_vertical(model, q, wh.turn(q), q[t_idx])
        assert np.degrees(abs(np.angle(np.exp(1j * (_angle(pelvis_heading(model, turned)) - walk))))) < 0.01
        assert np.allclose(turned[t_idx], q[t_idx])
        wh.reset()
        assert wh.turn(q) == 0.0


def test_leaning_over_still_feet_is_no_walk(model):
    """The root rotates about the model's origin on the floor: a lean moves the root translation, not the
    pelvis joint.  A pose leaning forward at up to 35 degrees with the pelvis joint kept still gives no
    velocity (the root translation's own 'velocity' is well above walking speed)."""
    rng = np.random.default_rng(13)
    t_idx = np.flatnonzero(model.param_kind == ROOT_TRANSLATION)
    for _ in range(5):
        base = turn_about_vertical(model, model.zero(), rng.uniform(-np.pi, np.pi), np.zeros(3))
        wh = WalkHeading(model, gain=1.0, speed_min=0.3, speed_full=0.6, window_s=0.3)
        still = _pelvis_joint(model, base)
        roots = []
        for k in range(10):
            axis = np.append(pelvis_heading(model, base)[::-1] * [-1, 1], 0.0)  # horizontal, across the body
            q = _lean(model, base, axis, np.radians(3.5 * k))
            q[t_idx] += still - _pelvis_joint(model, q)
            roots.append(q[t_idx[:2]].copy())
            wh.add_pose(k / 30.0, joint_centre_array(model, forward(model, q)))
        assert np.hypot(*wh.velocity()) < 1e-6
        assert wh.turn(q) == 0.0
        assert np.hypot(*(roots[-1] - roots[0])) / (9 / 30.0) > 1.0


def test_low_pelvis_gives_no_turn(model):
    rng = np.random.default_rng(17)
    wh = WalkHeading(model, gain=1.0, speed_min=0.3, speed_full=0.6, window_s=0.3, upright=0.9)
    p = turn_about_vertical(model, model.zero(), rng.uniform(-np.pi, np.pi), np.zeros(3))
    walk = _angle(pelvis_heading(model, p)) + np.radians(40.0)
    for z_frac, turns in ((0.8, False), (0.95, True)):
        wh.reset()
        for k in range(12):  # 1 m/s at 40 degrees from the facing direction
            wh.add(k / 30.0, (k / 30.0) * np.array([np.cos(walk), np.sin(walk)]), z_frac * wh.standing_z)
        assert (wh.turn(p) != 0.0) == turns
        if turns:
            assert wh.turn(p) == pytest.approx(np.radians(40.0), abs=1e-6)


def _lean(model, params, axis, angle):
    """``params`` with the root rotated by ``angle`` about the horizontal ``axis`` (through the origin)."""
    q = params.copy()
    r = np.flatnonzero(model.param_kind == ROOT_ROTATION)
    q[r] = Rotation.from_matrix(so3_exp(axis / np.linalg.norm(axis) * angle) @ so3_exp(q[r])).as_rotvec()
    return q


def test_walk_options_validated(model):
    with pytest.raises(ValueError, match="gain"):
        WalkHeading(model, gain=1.5, speed_min=0.3, speed_full=0.6, window_s=0.3)
    with pytest.raises(ValueError, match="speed_min"):
        WalkHeading(model, gain=0.5, speed_min=0.6, speed_full=0.3, window_s=0.3)
    with pytest.raises(ValueError, match="window_s"):
        WalkHeading(model, gain=0.5, speed_min=0.3, speed_full=0.6, window_s=0.0)
    with pytest.raises(ValueError, match="dead_rad"):
        WalkHeading(model, gain=0.5, speed_min=0.3, speed_full=0.6, window_s=0.3, max_rad=1.0, dead_rad=1.0)
    with pytest.raises(ValueError, match="upright"):
        WalkHeading(model, gain=0.5, speed_min=0.3, speed_full=0.6, window_s=0.3, upright=1.2)
    with pytest.raises(ValueError, match="walk_source"):
        BlobOptions(walk_source="feet")


def test_walk_heading_from_points(model):
    rng = np.random.default_rng(11)
    v = rng.normal(size=2)
    wh = WalkHeading(model, gain=0.5, speed_min=0.3, speed_full=0.6, window_s=0.3)
    for k in range(20):
        wh.add(k / 25.0, v * k / 25.0 + rng.normal(0, 1e-4, 2))
    assert np.allclose(wh.velocity(), v, atol=0.01)


def test_velocity_is_the_least_squares_slope(model):
    """Noise on the last point moves a least-squares slope over the window less than an end-to-end one."""
    rng = np.random.default_rng(19)
    for _ in range(20):
        v = rng.normal(size=2)
        wh = WalkHeading(model, gain=0.5, speed_min=0.3, speed_full=0.6, window_s=0.3)
        t = np.arange(10) / 30.0
        xy = t[:, None] * v + rng.normal(0, 0.01, (10, 2))
        for k in range(10):
            wh.add(t[k], xy[k])
        slope = np.polyfit(t, xy, 1)[0]
        assert np.allclose(wh.velocity(), slope, atol=1e-9)


@pytest.fixture(scope="module")
def skeleton():
    from tracker.synthetic.bvh import load_bvh
    from tracker.synthetic.synth import bundled_motion

    return load_bvh(bundled_motion("scaled_131_01"))


def _retargeted(skeleton, name, seed, frames=40):
    from tracker.synthetic.motions import make_motion
    from tracker.synthetic.retarget import retarget_bvh

    motion = make_motion(name, skeleton, frames=frames, fps=30.0, rng=np.random.default_rng(seed))
    return retarget_bvh(motion, fps=30.0, height_m=1.75)


def test_synthetic_crouch_gives_no_turn_and_a_walk_does(skeleton):
    """``tracker.synthetic.motions``' crouch (35 deg lean, thighs near horizontal) and walk_turn, put on the model by
    ``retarget_bvh``: the default options' cue never turns the crouch (its pelvis joint moves < 0.3 m/s; its root
    translation does not matter), and turns a walking pose held 60 deg off its walk back toward it."""
    o = BlobOptions()
    for seed in (1, 2):
        crouch = _retargeted(skeleton, "crouch", seed)
        model = crouch.model
        wh = WalkHeading(model, gain=o.walk_gain, speed_min=o.walk_speed_min, speed_full=o.walk_speed_full,
                         window_s=o.walk_window_s)
        old = WalkHeading(model, gain=o.walk_gain, speed_min=o.walk_speed_min, speed_full=o.walk_speed_full,
                          window_s=o.walk_window_s)  # fed the root translation, as round 8's cue was
        t_idx = np.flatnonzero(model.param_kind == ROOT_TRANSLATION)[:2]
        old_turned = False
        for k, p in enumerate(crouch.params):
            wh.add_pose(k / 30.0, joint_centre_array(model, forward(model, p)))
            assert wh.turn(p) == 0.0, k
            old.add(k / 30.0, p[t_idx])
            old_turned |= old.turn(p) != 0.0
        assert old_turned
        if seed != 1:
            continue
        walk = _retargeted(skeleton, "walk_turn", seed)
        wh.reset()
        for k, p in enumerate(walk.params[:11]):  # the walk before its turn (which starts at 30 % of the clip)
            wh.add_pose(k / 30.0, joint_centre_array(walk.model, forward(walk.model, p)))
        heading = _angle(wh.velocity())
        off = turn_about_vertical(walk.model, p, heading + np.radians(60.0) - _angle(pelvis_heading(walk.model, p)),
                                  p[np.flatnonzero(walk.model.param_kind == ROOT_TRANSLATION)])
        turn = wh.turn(off)
        assert np.hypot(*wh.velocity()) > o.walk_speed_min
        assert -np.radians(60.0) * o.walk_gain - 1e-9 <= turn < -0.5 * np.radians(60.0) * o.walk_gain
