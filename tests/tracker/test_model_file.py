from pathlib import Path

import numpy as np
import pytest

from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import MODELS_DIR, ModelError, available_models, load_model


def test_shipped_models():
    assert {"knossow40", "knossow54"} <= set(available_models())
    m40, m54 = load_model("knossow40"), load_model("knossow54")
    assert (m40.n_parts, m40.n_params) == (18, 40)
    assert (m54.n_parts, m54.n_params) == (19, 54)
    for m in (m40, m54):  # every rotational DOF has finite anatomical limits
        rot = m.param_kind == 2
        assert (m.upper[rot] > m.lower[rot]).all() and (m.upper[rot] < 3.2).all()


def _variant(tmp_path: Path, old: str, new: str) -> Path:
    text = (MODELS_DIR / "knossow40.toml").read_text()
    assert old in text
    p = tmp_path / "bad.toml"
    p.write_text(text.replace(old, new, 1))
    return p


@pytest.mark.parametrize(
    "old,new,match",
    [
        ('parent = "left_forearm"', 'parent = "left_elbowz"', r"part 'left_hand'.*parent 'left_elbowz'"),
        ('parent = "abdomen"', 'parent = "head"', r"part 'torso'.*parent 'head'"),
        ('{ name = "flexion", axis = "y", limits = [0, 150] }', '{ name = "flexion", axis = "w", limits = [0, 150] }', r"part 'left_forearm'.*unknown axis 'w'"),
        ('{ name = "flexion", axis = "y", limits = [0, 150] }', '{ name = "flexion", axis = "y", limits = [150, 0] }', r"part 'left_forearm'.*impossible limits"),
        ('{ name = "flexion", axis = "y", limits = [-20, 120] }', '{ name = "flexion", axis = "y", limits = [-20, 400] }', r"part 'left_thigh'.*impossible limits"),
        ("cone = { a = 0.050, b = 0.050, k = -1.6, z1 = 0.0, z2 = 0.245 }", "cone = { a = 0.050, b = 0.050, k = -1.6, z1 = 0.3, z2 = 0.245 }", r"part 'left_thigh'.*z1 < z2"),
    ],
)
def test_bad_model_named(tmp_path, old, new, match):
    with pytest.raises(ModelError, match=match):
        load_model(_variant(tmp_path, old, new))


def test_unknown_model_and_bad_height():
    with pytest.raises(ModelError, match="available"):
        load_model("knossow99")
    with pytest.raises(ModelError, match="height_m"):
        load_model("knossow40", height_m=17.0)


@pytest.mark.parametrize("text, match", [
    ("part = [1, 2]\n", r"bad.toml: \[\[part\]\] #0 must be a table"),
    ('[[part]]\nname = "root"\njoint = "free"\ncone = { a = 0.1, b = 0.1, k = 0, z1 = 0, z2 = 1 }\n'
     '[[part]]\nname = "arm"\nparent = "root"\ncone = { a = 0.1, b = 0.1, k = 0, z1 = 0, z2 = 1 }\ndofs = [1]\n',
     r"part 'arm'.*'dofs' must be a list"),
    ('[[part]]\nname = "root"\njoint = "free"\ncone = { a = 0.1, b = 0.1, k = 0, z1 = 0, z2 = 1 }\n'
     "[joints]\npelvis = 5\n", r"\[joints\] must map joint names"),
])  # fmt: skip
def test_malformed_model_tables_named(tmp_path, text, match):
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises(ModelError, match=match):
        load_model(tmp_path / "bad.toml")


def test_package_face_resolves_every_name():
    import tracker

    for name in tracker.__all__:
        assert getattr(tracker, name) is not None, name
    with pytest.raises(AttributeError, match="no attribute 'nonsense'"):
        tracker.nonsense  # noqa: B018


def _rest(model):
    pose = forward(model, model.zero())
    return dict(zip(model.joint_names, joint_centre_array(model, pose))), pose.translation


@pytest.mark.parametrize("name", ["knossow40", "knossow54"])
def test_widths_set_the_part_origins_and_nothing_else(name):
    base = load_model(name, height_m=1.7)
    wide = load_model(name, height_m=1.7, widths={"hip_width": 0.21, "shoulder_width": 0.41})
    (jb, tb), (jw, tw) = _rest(base), _rest(wide)
    for side, sign in (("left", 1), ("right", -1)):
        thigh, arm = base.part_index(f"{side}_thigh"), base.part_index(f"{side}_upper_arm")
        assert tw[thigh][1] == pytest.approx(sign * 0.105)
        assert tw[arm][1] == pytest.approx(sign * 0.205)
        assert jw[f"{side}_shoulder"] == pytest.approx(tw[arm])
        # only the lateral place moves: height and forward offset kept, limbs unchanged below
        for i in (thigh, arm):
            assert tw[i][[0, 2]] == pytest.approx(tb[i][[0, 2]])
        assert jw[f"{side}_knee"] - tw[thigh] == pytest.approx(jb[f"{side}_knee"] - tb[thigh])
        # the hip joint centre is a point of the pelvis (Bell et al.), not the thighs' origin: the
        # flesh's spacing does not move it
        assert jw[f"{side}_hip"] == pytest.approx(jb[f"{side}_hip"])
        assert jw[f"{side}_hip"][1] == pytest.approx(sign * 0.045 * 1.7)
        assert abs(tb[thigh][1]) > abs(jb[f"{side}_hip"][1]) + 0.05
    for j in ("pelvis", "spine", "neck", "head"):
        assert jw[j] == pytest.approx(jb[j])
    assert (wide.cones == base.cones).all()


def test_radius_scale_groups():
    base = load_model("knossow40")
    m = load_model("knossow40", radius_scale={"thigh": 1.2, "trunk_width": 0.9, "trunk_depth": 1.1})
    th, pel, sh = (base.part_index(p) for p in ("left_thigh", "pelvis", "left_shank"))
    assert m.cones[th, :2] == pytest.approx(1.2 * base.cones[th, :2])
    assert m.cones[pel, :2] == pytest.approx([1.1 * base.cones[pel, 0], 0.9 * base.cones[pel, 1]])
    assert m.cones[sh] == pytest.approx(base.cones[sh])
    assert m.cones[th, 2:] == pytest.approx(base.cones[th, 2:])  # taper and extent kept


@pytest.mark.parametrize("kwargs, match", [
    ({"widths": {"ear_width": 0.1}}, "unknown width"),
    ({"widths": {"hip_width": 2.0}}, "implausible"),
    ({"radius_scale": {"tail": 1.1}}, "unknown radius group"),
    ({"radius_scale": {"thigh": 9.0}}, "implausible"),
])  # fmt: skip
def test_bad_widths_and_radii_named(kwargs, match):
    with pytest.raises(ModelError, match=match):
        load_model("knossow40", **kwargs)
