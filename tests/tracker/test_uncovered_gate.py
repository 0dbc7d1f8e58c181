"""The unexplained-boundary check of the gate (``TrackerOptions.uncovered_margin``,
``tracker.fitting.uncovered``): a frame whose silhouette has an outline the model leaves unexplained in
one camera, beyond that camera's usual share, is reported not ok; a body the model over- or
undershoots everywhere by a little passes; the check never changes the track."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from segmentation.distance import chamfer_images
from tests.tracker.test_tracking import hop_scene, perturb
from tracker.fitting.tracking import Tracker, TrackerOptions, _chamfer_cost
from tracker.fitting.uncovered import UncoveredWatch


def test_watch_flags_one_camera_above_its_own_median():
    w = UncoveredWatch(margin=0.03, window=30, min_samples=3)
    names = ["a", "b"]
    assert w.check(names, np.array([0.5, 0.5])) == ""  # no reference yet
    for _ in range(3):
        w.update(names, np.array([0.01, 0.10]))  # the cameras differ: each has its own reference
    assert w.check(names, np.array([0.03, 0.12])) == ""
    why = w.check(names, np.array([0.05, 0.12]))
    assert why.startswith("boundary unexplained: a 5%") and "b " not in why
    assert w.check(["b", "a"], np.array([0.12, 0.03])) == ""  # by name, not by position
    np.testing.assert_allclose(w.excess(["a", "c"], np.array([0.05, 0.2])), [0.04, np.nan])
    w.update(names, np.array([np.nan, 0.1]))  # a camera without a share keeps its reference
    np.testing.assert_allclose(w.excess(names, np.array([0.01, 0.1])), [0.0, 0.0])
    w.reset()
    assert np.isnan(w.excess(names, np.array([0.0, 0.0]))).all()
    with pytest.raises(ValueError):
        UncoveredWatch(margin=0.0)


def test_observe_needs_frames_in_a_row_and_only_vouched_frames_join():
    w = UncoveredWatch(margin=0.03, min_samples=2, frames=2)
    for _ in range(2):
        assert w.observe(["a"], np.array([0.0]), vouched=True) == ""
    assert w.observe(["a"], np.array([0.1]), vouched=True) == ""  # one frame above: not yet
    assert w.observe(["a"], np.array([0.1]), vouched=True).startswith("boundary unexplained")
    assert w.observe(["a"], np.array([0.1]), vouched=False) == ""  # a frame already not ok is not flagged again
    assert w.observe(["a"], np.array([0.0]), vouched=True) == ""  # the run is broken
    assert w.observe(["a"], np.array([0.1]), vouched=True) == ""
    np.testing.assert_allclose(w.excess(["a"], np.array([0.0])), [0.0])  # frames above the margin never joined
    w.observe(["a"], np.array([0.01]), vouched=False)  # a frame the gate refused does not join either
    np.testing.assert_allclose(w.excess(["a"], np.array([0.0])), [0.0])


def test_watch_window_keeps_the_recent_frames():
    w = UncoveredWatch(margin=0.03, window=3, min_samples=1)
    for v in (0.5, 0.5, 0.0, 0.0, 0.0):
        w.update(["a"], np.array([v]))
    np.testing.assert_allclose(w.excess(["a"], np.array([0.0])), [0.0])



@pytest.mark.parametrize("seed", [0, 1, 2])
def test_reference_is_the_median_of_the_last_window_frames(seed):
    rng = np.random.default_rng(seed)
    window, names = int(rng.integers(3, 31)), ["a", "b", "c"]
    w = UncoveredWatch(margin=0.03, window=window, min_samples=2)
    seen = {n: [] for n in names}
    for _ in range(int(rng.integers(2, 60))):
        shares = rng.random(3) * 0.2
        shares[rng.random(3) < 0.2] = np.nan  # a camera without a share this frame
        w.update(names, shares)
        for n, v in zip(names, shares):
            if np.isfinite(v):
                seen[n].append(v)
        now = rng.random(3) * 0.2
        want = [now[k] - np.median(seen[n][-window:]) if len(seen[n][-window:]) >= 2 else np.nan
                for k, n in enumerate(names)]
        np.testing.assert_allclose(w.excess(names, now), want, rtol=0, atol=1e-15)


ON = {"uncovered_margin": 0.03, "uncovered_frames": 1}  # the check on, from the first frame, whatever the default


@pytest.fixture(scope="module")
def scene():
    return hop_scene()


def with_limb(sil: dict, cameras, k: int = 0) -> tuple[dict, dict]:
    """Silhouettes and chamfer images with a limb-sized blob, apart from the body, in camera ``k`` only:
    an outline the model cannot explain there (a limb it lost), the other cameras unchanged."""
    name = cameras[k].name
    s = sil[name].copy()
    ys, xs = np.nonzero(s)
    h = ys.max() - ys.min()
    s[int(ys.min() + 0.3 * h):int(ys.min() + 0.6 * h), xs.max() + 25:xs.max() + 37] = 255
    out = dict(sil)
    out[name] = s
    edges = cv2.Canny(s, 50, 150)
    return out, {**{c.name: None for c in cameras}, name: chamfer_images(s, edges)}


def test_coverage_per_camera_counts_each_cameras_samples(scene):
    cameras, model, p0, ch, sil = scene
    sil2, ch2 = with_limb(sil, cameras)
    chamfer = [ch2[c.name] if ch2[c.name] is not None else ch[c.name] for c in cameras]
    t = _chamfer_cost(model, cameras, {c.name: x for c, x in zip(cameras, chamfer)}, TrackerOptions()).evaluate(p0)
    per = t.coverage_per_camera(len(cameras))
    for k in range(len(cameras)):
        mine = t.boundary_dist[t.boundary_cam == k]
        assert per[k] == pytest.approx(np.mean(mine <= 8.0))
    assert per[0] < 0.95 and np.all(per[1:] > 0.97)
    weights = np.bincount(t.boundary_cam, minlength=len(cameras))
    assert np.average(per, weights=weights) == pytest.approx(t.coverage())
    tol = np.array([100.0, 8.0, 8.0, 8.0])  # a tolerance per camera
    np.testing.assert_allclose(t.coverage_per_camera(len(cameras), tol_px=tol), [1.0, *per[1:]])


def track(scene, later, n_later: int = 3, **options) -> tuple[list[dict], Tracker]:
    """Six frames on the model's own silhouettes, then ``n_later`` on ``later`` = (silhouettes, chamfer)."""
    cameras, model, p0, ch, sil = scene
    tracker = Tracker(model, cameras, initial_params=p0, options=TrackerOptions(**{**ON, **options}))
    recs = [tracker.step(k, k, ch, sil) for k in range(6)]
    s2, c2 = later
    return recs + [tracker.step(k, k, c2, s2) for k in range(6, 6 + n_later)], tracker


def test_an_unexplained_outline_in_one_camera_fails_and_the_track_is_unchanged(scene):
    cameras, model, p0, ch, sil = scene
    s2, c2 = with_limb(sil, cameras)
    later = (s2, {n: c2[n] if c2[n] is not None else ch[n] for n in ch})
    recs, _ = track(scene, later)
    assert all(r["ok"] for r in recs[:6])
    assert not any(r["ok"] for r in recs[6:])
    assert all(r["failed"] == ["uncovered"] and cameras[0].name in r["reason"] for r in recs[6:])
    two, _ = track(scene, later, uncovered_frames=2)  # the default: the second frame in a row
    assert [r["ok"] for r in two[5:]] == [True, True, False, False]
    off, _ = track(scene, later, uncovered_margin=None)
    assert all(r["ok"] for r in off)
    for a, b in zip(recs, off):  # the check only reports
        np.testing.assert_array_equal(a["params"], b["params"])


def test_a_body_a_little_wider_everywhere_passes(scene):
    cameras, model, p0, ch, sil = scene
    wide = {k: cv2.dilate(s, np.ones((5, 5), np.uint8)) for k, s in sil.items()}
    later = (wide, {k: chamfer_images(s, cv2.Canny(s, 50, 150)) for k, s in wide.items()})
    recs, _ = track(scene, later)
    assert all(r["ok"] for r in recs)


def test_the_reference_follows_a_resized_body(scene):
    cameras, model, p0, ch, sil = scene
    tracker = Tracker(model, cameras, initial_params=p0, options=TrackerOptions(**ON))
    for k in range(6):
        tracker.step(k, k, ch, sil)
    assert tracker.uncovered.excess([c.name for c in cameras], np.zeros(4)).size == 4
    assert np.isfinite(tracker.uncovered.excess([cameras[0].name], np.zeros(1))).all()
    tracker.resize(model)
    assert np.isnan(tracker.uncovered.excess([cameras[0].name], np.zeros(1))).all()


def test_new_options_rebuild_the_watch_only_when_its_settings_change(scene):
    cameras, model, p0, ch, sil = scene
    tracker = Tracker(model, cameras, initial_params=p0, options=TrackerOptions(**ON))
    for k in range(6):
        tracker.step(k, k, ch, sil)
    watch = tracker.uncovered
    tracker.options = replace(tracker.options, n_samples=tracker.options.n_samples + 1)
    assert tracker.uncovered is watch  # another setting: the watch and its history kept
    assert np.isfinite(tracker.uncovered.excess([cameras[0].name], np.zeros(1))).all()
    tracker.options = replace(tracker.options, uncovered_margin=None)
    assert tracker.uncovered is None
    assert tracker.step(6, 6, ch, sil)["ok"]
    tracker.options = replace(tracker.options, uncovered_margin=0.07)
    assert tracker.uncovered is not watch and tracker.uncovered.margin == 0.07
    assert np.isnan(tracker.uncovered.excess([cameras[0].name], np.zeros(1))).all()  # a new watch starts empty


@pytest.mark.parametrize("seed", [0, 1])
def test_the_tolerance_is_a_share_of_the_body_in_each_camera(scene, seed):
    # shares = 1 - coverage within uncovered_tol x the body's height in pixels at the root's depth
    cameras, model, p0, ch, sil = scene
    p = perturb(model, p0, np.random.default_rng(seed), deg=8.0, root_m=0.03)
    tracker = Tracker(model, cameras, initial_params=p, options=TrackerOptions(uncovered_tol=0.02, **ON))
    t = _chamfer_cost(model, cameras, ch, TrackerOptions()).evaluate(p)
    seen = []
    tracker.uncovered.update = lambda names, shares: seen.append(np.asarray(shares))
    tracker._uncovered(cameras, t, passed=True)
    root = t.pose.translation[0]
    px = np.array([c.matrix[0, 0] * model.height_m / (c.rotation @ root + c.translation)[2] for c in cameras])
    np.testing.assert_allclose(seen[0], 1.0 - t.coverage_per_camera(len(cameras), tol_px=0.02 * px))
    assert not np.allclose(seen[0], 1.0 - t.coverage_per_camera(len(cameras), tol_px=8.0))
