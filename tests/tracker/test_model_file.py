from pathlib import Path

import pytest

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
