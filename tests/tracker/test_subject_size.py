"""Subject calibration: segment lengths from silhouettes and fitted poses; subject files."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.body.kinematics import forward
from tracker.body.model import ModelError, load_model
from tracker.body.subject import Subject, read_subject, write_subject
from tracker.fitting.subject_size import (SCORE_INSET_PX, WIDTH_ORDER, estimate_segment_lengths, nominal_segment_lengths,
                                          nominal_widths)
from tracker.search.scoring import ScoreViews
from tracker.imaging.render import render_silhouettes
from tracker.synthetic.scene import ring_cameras


def _rendered_subject(seed: int, n_frames: int = 6):
    """A subject with every segment length drawn within ±15 % of the anthropometric one, rendered
    in random poses by 4 ring cameras; the poses as a tracker on the default model would start
    them (the true angles, perturbed)."""
    rng = np.random.default_rng(seed)
    nominal_model = load_model("knossow40")
    nominal = nominal_segment_lengths(nominal_model)
    true = {k: v * rng.uniform(0.85, 1.15) for k, v in nominal.items()}
    body = load_model("knossow40", segment_lengths=true)
    cams = ring_cameras(4, size=(640, 480))
    starts, sils = [], []
    for _ in range(n_frames):
        p = body.random_params(rng, fraction=0.4)
        p[:2] *= 0.3
        p[2] = 0.0
        sils.append({c.name: s for c, s in zip(cams, render_silhouettes(body, forward(body, p), cams))})
        starts.append(p + np.r_[rng.normal(0, 0.01, 3), rng.normal(0, 0.02, p.size - 3)])
    return nominal_model, nominal, true, cams, starts, sils


@pytest.mark.slow
def test_segment_lengths_recovered():
    # measured (seed 3): 0.1-0.6 cm on trunk, legs and forearm, 2.4 cm on the upper arm (its length
    # trades against the torso's: both place the elbow); the bar is 2 cm on every segment
    model, nominal, true, cams, starts, sils = _rendered_subject(3)
    fit = estimate_segment_lengths(model, cams, starts, sils)
    err = np.array([abs(fit.segment_lengths[k] - true[k]) for k in true])
    before = np.array([abs(nominal[k] - true[k]) for k in true])
    assert np.median(err) <= 0.01, (err, before)
    assert err.max() <= 0.03, (err, before)
    assert err.mean() <= 0.5 * before.mean(), (err, before)
    assert fit.iou_after > fit.iou_before


def test_subject_file_round_trip(tmp_path):
    sub = Subject("knossow40", 1.82, {"thigh": 0.46, "forearm": 0.27}, "test", {"hip_width": 0.17},
                  {"thigh": 1.1, "trunk_width": 0.95})
    write_subject(tmp_path / "s.toml", sub)
    back = read_subject(tmp_path / "s.toml")
    assert back == sub
    body = back.body()
    ref = load_model("knossow40", height_m=1.82, segment_lengths={"thigh": 0.46, "forearm": 0.27},
                     widths={"hip_width": 0.17}, radius_scale={"thigh": 1.1, "trunk_width": 0.95})
    np.testing.assert_allclose(body.offset, ref.offset)
    np.testing.assert_allclose(body.cones, ref.cones)


@pytest.mark.parametrize("text, match", [
    ("[subject]\nheight_m = 9.0\n", "height_m"),
    ("[subject]\n[subject.segment_lengths]\nthigh = -1.0\n", "segment_lengths"),
    ("[subject]\n[subject.segment_lengths]\ntail = 0.3\n", "unknown segment"),
    ("height_m = 1.7\n", r"\[subject\]"),
    ("[subject]\n[subject.widths]\nhip_width = true\n", "widths"),
    ("[subject]\n[subject.radius_scale]\nfins = 1.1\n", "unknown radius group"),
])
def test_bad_subject_file_one_clear_error(tmp_path, text, match):
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ModelError, match=match):
        read_subject(path)


@pytest.mark.slow
def test_widths_and_radii_recovered():
    # a body with hip and shoulder widths +20 % / -15 % and limb/trunk radii ±15-20 % off the model's,
    # rendered by 4 cameras in 3 poses, scored at full resolution; started at the true poses, the fit
    # halves every radius factor's error and the widths' mean error (measured: radius factors 0.004-0.065
    # off, hip width 3.2 -> 2.3 cm, shoulder width 5.5 -> 1.8 cm: the hip width is weakly observable)
    rng = np.random.default_rng(5)
    nominal_model = load_model("knossow40")
    nominal = nominal_widths(nominal_model)
    widths = {"hip_width": nominal["hip_width"] * 1.2, "shoulder_width": nominal["shoulder_width"] * 0.85}
    radii = {"thigh": 1.2, "upper_arm": 0.85, "trunk_width": 1.15, "shank": 0.85}
    body = load_model("knossow40", widths=widths, radius_scale=radii)
    cams = ring_cameras(4, size=(480, 360))
    poses, sils = [], []
    for _ in range(3):
        p = body.random_params(rng, fraction=0.3)
        p[:2] *= 0.3
        p[2] = 0.0
        sils.append({c.name: s for c, s in zip(cams, render_silhouettes(body, forward(body, p), cams))})
        poses.append(p)
    fit = estimate_segment_lengths(nominal_model, cams, poses, sils, segments=(), widths=WIDTH_ORDER,
                                   radii=tuple(radii), rounds=3, step=0.05, scale=1.0)
    err = [abs(fit.widths[k] - v) for k, v in widths.items()]
    assert np.mean(err) <= 0.6 * np.mean([abs(nominal[k] - v) for k, v in widths.items()]), (fit.widths, widths)
    for k, v in radii.items():
        assert abs(fit.radius_scale[k] - v) <= 0.5 * abs(1.0 - v), (k, fit.radius_scale, radii)
    assert fit.iou_after > fit.iou_before


def _own_renders(seed: int, size=(320, 240)):
    rng = np.random.default_rng(seed)
    model = load_model("knossow40")
    cams = ring_cameras(4, size=size)
    p = model.random_params(rng, fraction=0.4)
    p[:2] *= 0.3
    p[2] = 0.0
    return model, cams, p, render_silhouettes(model, forward(model, p), cams)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_inset_views_draw_the_rendered_area(seed):
    # at full scale the observed masks are the renderer's (pixel centre inside the outline): the inset
    # draw covers the same pixels' count, the plain draw (the outline's pixels set too) more
    model, cams, p, sils = _own_renders(seed)
    area = np.array([np.count_nonzero(s) for s in sils])
    for inset, lo, hi in ((0.5, 0.97, 1.03), (0.0, 1.05, 1.3)):
        drawn = np.array([np.count_nonzero(r) for r in ScoreViews(model, cams, sils, scale=1.0, inset_px=inset).render(p)])
        assert np.all((drawn > lo * area) & (drawn < hi * area)), (inset, drawn / area)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_calibration_views_score_the_own_body_best(seed):
    # on the model's own renders at its true pose no uniformly longer, shorter, thicker or thinner body
    # scores better in the calibration's views; the plain views prefer a thinner one
    model, cams, p, sils = _own_renders(seed)
    nominal = nominal_segment_lengths(model)
    others = [load_model("knossow40", segment_lengths={k: f * v for k, v in nominal.items()}) for f in (0.97, 1.03)]
    others += [load_model("knossow40", radius_scale={g: f for g in model.radius_groups}) for f in (0.95, 1.05)]
    views = ScoreViews(model, cams, sils, scale=0.5, inset_px=SCORE_INSET_PX)
    own = views.score(p)
    assert all(views.with_model(m).score(p) < own for m in others), [views.with_model(m).score(p) - own for m in others]
    plain = ScoreViews(model, cams, sils, scale=0.5)
    assert plain.with_model(others[2]).score(p) > plain.score(p)
