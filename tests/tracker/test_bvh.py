"""BVH parsing and forward kinematics: CMU files, a hand-computed joint, channel orders, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tracker.synthetic.bvh import BvhError, bvh_forward, euler_channels_to_matrix, load_bvh, parse_bvh

TINY = """HIERARCHY
ROOT root
{
  OFFSET 1 0 0
  CHANNELS 6 Zposition Xposition Yposition Xrotation Zrotation Yrotation
  JOINT arm
  {
    OFFSET 0 2 0
    CHANNELS 3 Yrotation Xrotation Zrotation
    End Site
    {
      OFFSET 0 0 3
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.04
0 0 0 0 0 0 0 0 0
1 2 3 90 0 0 0 0 90
"""


@pytest.fixture(scope="module")
def cmu(shared_data):
    return load_bvh(shared_data / "cmu_mocap" / "scaled_131_03.bvh")


def test_tiny_file_by_hand():
    bvh = parse_bvh(TINY, source="tiny.bvh")
    assert bvh.names == ("root", "arm", "arm_End")
    assert list(bvh.parent) == [-1, 0, 1]
    assert bvh.n_frames == 2 and bvh.fps == pytest.approx(25.0)
    P, R = bvh_forward(bvh)
    # frame 0: offsets only
    assert np.allclose(P[0], [[1, 0, 0], [1, 2, 0], [1, 2, 3]])
    # frame 1: root at offset + (x=2, y=3, z=1), rotated 90° about X; arm rotated 90° about its local Z
    assert np.allclose(P[1, 0], [3, 3, 1])
    Rx = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    assert np.allclose(P[1, 1], P[1, 0] + Rx @ [0, 2, 0])  # = (3, 3, 3)
    Rz = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert np.allclose(P[1, 2], P[1, 1] + Rx @ Rz @ [0, 0, 3])
    assert np.allclose(R[1, 2], Rx @ Rz)


def test_channel_order_is_respected(rng):
    ang = rng.uniform(-180, 180, (5, 3))
    for order in ("ZYX", "ZXY", "XYZ", "YXZ"):
        names = [f"{a}rotation" for a in order]
        R = euler_channels_to_matrix(names, ang)
        # scipy: upper-case = intrinsic rotations in the given order
        ref = Rotation.from_euler(order, ang, degrees=True).as_matrix()
        assert np.allclose(R, ref, atol=1e-12)


def test_cmu_structure(cmu):
    assert cmu.n_frames == 1248
    assert cmu.fps == pytest.approx(120.0, rel=1e-3)
    for name in ("Hips", "LeftHip", "LeftKnee", "LeftAnkle", "Chest", "Neck", "Head", "LeftShoulder",
                 "LeftElbow", "LeftWrist", "RightShoulder", "RightElbow", "RightWrist"):  # fmt: skip
        cmu.index(name)
    assert cmu.channels[cmu.index("LeftShoulder")] == ("Zrotation", "Xrotation", "Yrotation")
    with pytest.raises(KeyError, match="scaled_131_03.bvh.*Nope"):
        cmu.index("Nope")


def test_cmu_bone_lengths_constant(cmu):
    P, _ = bvh_forward(cmu, frames=np.arange(0, cmu.n_frames, 7))
    child = np.flatnonzero(cmu.parent >= 0)
    lengths = np.linalg.norm(P[:, child] - P[:, cmu.parent[child]], axis=-1)  # (n_frames, n_bones)
    expected = np.linalg.norm(cmu.offset[child], axis=1)
    assert np.abs(lengths - expected[None]).max() < 1e-9
    # a plausible human: Y up, head well above the feet, metres
    top, toe = P[0, cmu.index("Head_End")], P[0, cmu.index("LeftToe_End")]  # frame 0: standing
    assert 1.2 < top[1] - toe[1] < 2.0


def test_cmu_left_knee_frame0_by_hand(cmu):
    """Hips -> LHipJoint -> LeftHip -> LeftKnee, composed by hand with scipy rotations."""
    row = cmu.motion[0]

    def rot(name):
        j = cmu.index(name)
        chans = cmu.channels[j]
        vals = row[cmu.channel_start[j] : cmu.channel_start[j] + len(chans)]
        order = "".join(c[0] for c in chans if c.endswith("rotation"))
        angles = [v for c, v in zip(chans, vals) if c.endswith("rotation")]
        return Rotation.from_euler(order, angles, degrees=True).as_matrix()

    hips_pos = row[:3] + cmu.offset[cmu.index("Hips")]
    R_hips = rot("Hips")
    R_lhj = R_hips @ rot("LHipJoint")
    p_lhj = hips_pos + R_hips @ cmu.offset[cmu.index("LHipJoint")]
    R_lhip = R_lhj @ rot("LeftHip")
    p_lhip = p_lhj + R_lhj @ cmu.offset[cmu.index("LeftHip")]
    p_knee = p_lhip + R_lhip @ cmu.offset[cmu.index("LeftKnee")]
    P, _ = bvh_forward(cmu, frames=[0])
    assert np.allclose(P[0, cmu.index("LeftKnee")], p_knee, atol=1e-12)
    # the first three values of the file: Hips at (0.291945, 0.955998, -1.644011)
    assert np.allclose(P[0, cmu.index("Hips")], [0.291945, 0.955998, -1.644011])


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda s: s.replace("HIERARCHY", "HIERARCHX"), "HIERARCHY"),
        (lambda s: s.replace("CHANNELS 3 Yrotation", "CHANNELS 2 Yrotation"), "CHANNELS says 2"),
        (lambda s: s.replace("Zrotation Yrotation\n", "Zrotation Wrotation\n"), "unknown channel"),
        (lambda s: s.replace("Frames: 2", "Frames: 3"), "only 2 motion lines"),
        (lambda s: s.replace("1 2 3 90 0 0 0 0 90", "1 2 3 90 0 0 0 0"), "motion frame 1 has 8"),
        (lambda s: s.replace("1 2 3 90", "1 2 x 90"), "non-numeric"),
        (lambda s: s.replace("Frame Time: 0.04", "Frame Time: 0"), "frame time"),
        (lambda s: s.replace("MOTION", ""), "Frames:|MOTION"),
        (lambda s: s.replace("    OFFSET 0 2 0\n", ""), "no OFFSET"),
        (lambda s: s.replace("OFFSET 0 2 0", "OFFSET 0 nan 0"), "OFFSET needs three"),
        (lambda s: s.rsplit("}", 1)[0], "unclosed|MOTION"),
        (lambda s: s.replace("  JOINT arm\n", "  JOINT arm\n  JOINT hand\n"), "'arm' has no '{'"),
    ],
)
def test_malformed_files_name_file_and_line(mutate, match):
    with pytest.raises(BvhError, match=f"bad.bvh:\\d+: .*({match})"):
        parse_bvh(mutate(TINY), source="bad.bvh")


def test_missing_file(tmp_path):
    with pytest.raises(BvhError, match="nothere.bvh"):
        load_bvh(tmp_path / "nothere.bvh")
