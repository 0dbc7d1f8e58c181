"""Background model and the whole per-frame chain: synthetic scenes with known masks, real uu_studio."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from segmentation import (BackgroundModel, SegmentationParams, bgr_to_yuv, evenly_spaced, largest_components,
                          segment_frame)
from segmentation.synthetic import synthetic_scene
from tests.support.segmentation import frame_count, iou, read_frames


@pytest.fixture(scope="module")
def scene():
    return synthetic_scene(np.random.default_rng(2024), size=(480, 360), n_background=40, n_frames=5)


@pytest.fixture(scope="module")
def models(scene):
    return {cov: BackgroundModel.from_frames(scene.background_frames, covariance=cov) for cov in ("full", "diag")}


@pytest.mark.parametrize("cov, auto_roi", [("full", False), ("diag", False), ("diag", True)])
def test_synthetic_silhouette_iou_and_shadow(scene, models, cov, auto_roi):
    model = models[cov]
    for frame, person, shadow in zip(scene.frames, scene.person_masks, scene.shadow_masks):
        seg = segment_frame(model, frame, params=SegmentationParams(auto_roi=auto_roi))
        assert iou(seg.silhouette, person) >= 0.95
        assert shadow.sum() > 500  # the fixture really has a shadow
        assert np.mean(seg.silhouette[shadow] == 0) >= 0.90


def test_without_shadow_relaxation_the_shadow_is_foreground(scene):
    """The shadow axis is what keeps the shadow out: the plain Mahalanobis test fails on it."""
    plain = BackgroundModel.from_frames(scene.background_frames, shadow_range=(1.0, 1.0))
    seg = segment_frame(plain, scene.frames[0])
    assert np.mean(seg.silhouette[scene.shadow_masks[0]] > 0) > 0.5


def test_median_background_from_session_frames(scene):
    model = BackgroundModel.from_median(scene.frames)
    assert model.covariance == "diag"
    # the person moves, so the median is the empty scene
    assert np.median(np.abs(model.mean_yuv - bgr_to_yuv(scene.clean_background.astype(np.uint8)))) < 2.0
    ious = [iou(segment_frame(model, f).silhouette, p) for f, p in zip(scene.frames, scene.person_masks)]
    assert min(ious) >= 0.9


def test_distance_matches_direct_formula(models, rng):
    full = models["full"]
    model = BackgroundModel(full.mean_yuv, full.cov_yuv, covariance="full", window_px=0)  # the camouflage test: below
    img = rng.integers(0, 256, (model.size[1], model.size[0], 3), dtype=np.uint8)
    d = model.distance(img).astype(np.float64)
    inv = model._inv.astype(np.float64)
    mu = model.mean_yuv.astype(np.float64)
    p = bgr_to_yuv(img).astype(np.float64)
    a = np.einsum("hwi,hwij,hwj->hw", mu, inv, mu)
    b = np.einsum("hwi,hwij,hwj->hw", p, inv, mu)
    s = np.clip(b / a, *model.shadow_range)
    r = p - s[..., None] * mu
    ref = np.einsum("hwi,hwij,hwj->hw", r, inv, r) / np.minimum(s, 1.0) ** 2
    np.testing.assert_allclose(d, ref, rtol=1e-4, atol=1e-2)
    x0, y0, x1, y1 = 30, 40, 200, 90
    np.testing.assert_allclose(model.distance(img, roi=(x0, y0, x1, y1)), d[y0:y1, x0:x1], rtol=1e-5, atol=1e-4)


def test_save_load_roundtrip(models, scene, tmp_path):
    model = models["full"]
    path = model.save(tmp_path / "bg.npz")
    back = BackgroundModel.load(path)
    assert back.covariance == "full" and back.shadow_range == model.shadow_range
    np.testing.assert_array_equal(back.distance(scene.frames[1]), model.distance(scene.frames[1]))
    (tmp_path / "junk.npz").write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="junk.npz"):
        BackgroundModel.load(tmp_path / "junk.npz")


def test_update_adapts_where_background_only(scene):
    model = BackgroundModel.from_frames(scene.background_frames[:10])
    h, w = model.mean_yuv.shape[:2]
    shifted = np.clip(scene.background_frames[0].astype(int) + (25, -15, 0), 0, 255).astype(np.uint8)
    fg = np.zeros((h, w), np.uint8)
    fg[:, : w // 2] = 255  # pretend the left half is a person: no learning there
    before = np.mean(model.distance(shifted) > 16)
    assert before > 0.9
    assert np.mean(model.coarse_distance(shifted) > 16) > 0.9  # builds the coarse model too
    for _ in range(60):
        model.update(shifted, fg, rate=0.1)
    d = model.distance(shifted)
    assert np.mean(d[:, w // 2:] > 16) < 0.01
    assert np.mean(d[:, : w // 2] > 16) > 0.9
    dc = model.coarse_distance(shifted)
    assert np.mean(dc[:, (w // 2 + 2) // 2:] > 16) < 0.01
    assert np.mean(dc[:, : w // 4 - 1] > 16) > 0.9


def test_malformed_input_names_argument(models):
    model = models["diag"]
    w, h = model.size
    good = np.zeros((h, w, 3), np.uint8)
    with pytest.raises(TypeError, match="image_bgr"):
        model.distance(good.astype(np.float32))
    with pytest.raises(ValueError, match="image_bgr"):
        model.distance(np.zeros((h, w + 1, 3), np.uint8))
    with pytest.raises(ValueError, match="image_bgr"):
        segment_frame(model, np.zeros((h, w), np.uint8))
    with pytest.raises(ValueError, match="roi"):
        model.distance(good, roi=(10, 10, 5, 20))
    with pytest.raises(ValueError, match="mean_yuv"):
        BackgroundModel(np.full((4, 4, 3), np.nan), np.zeros((4, 4, 6)))
    with pytest.raises(ValueError, match="frames"):
        BackgroundModel.from_frames([good])
    with pytest.raises(ValueError, match=r"frames\[1\]"):
        BackgroundModel.from_frames([good, good[:-1]])
    with pytest.raises(ValueError, match="foreground"):
        model.update(good, np.zeros((h - 1, w), np.uint8))


def test_roi_only_processes_the_box(scene, models):
    model = models["full"]
    frame, person = scene.frames[2], scene.person_masks[2]
    ys, xs = np.nonzero(person)
    roi = (int(xs.min()) - 10, int(ys.min()) - 10, int(xs.max()) + 11, int(ys.max()) + 11)
    seg = segment_frame(model, frame, roi=roi)
    assert seg.roi == roi
    np.testing.assert_array_equal(seg.silhouette_roi, seg.silhouette[roi[1]:roi[3], roi[0]:roi[2]])
    assert iou(seg.silhouette, person) >= 0.95
    outside = np.ones_like(person)
    outside[roi[1]:roi[3], roi[0]:roi[2]] = False
    assert not seg.silhouette[outside].any()


@pytest.mark.parametrize("cov", ["full", "diag"])
def test_distance_in_boxes_of_changing_shapes_as_in_a_fresh_model(scene, models, cov, rng):
    # the scratch buffers are reused across box shapes, growing and shrinking: a box's result must not
    # depend on the boxes before it (a fresh model has no history)
    model, frame = models[cov], scene.frames[1]
    w, h = model.size
    for _ in range(12):
        x0, x1 = sorted(int(v) for v in rng.choice(w + 1, 2, replace=False))
        y0, y1 = sorted(int(v) for v in rng.choice(h + 1, 2, replace=False))
        fresh = BackgroundModel(model.mean_yuv, model.cov_yuv, covariance=cov)
        np.testing.assert_array_equal(model.distance(frame, roi=(x0, y0, x1, y1)),
                                      fresh.distance(frame, roi=(x0, y0, x1, y1)))
        for got, ref in zip(model.distance_terms(frame, roi=(x0, y0, x1, y1)),
                            fresh.distance_terms(frame, roi=(x0, y0, x1, y1))):
            np.testing.assert_array_equal(got, ref)


def test_auto_roi_matches_full_image(scene, models):
    """The half-resolution first pass finds the person; the full-resolution result inside its box
    is the same as processing the whole image."""
    model = models["diag"]
    auto = SegmentationParams(auto_roi=True)
    for frame, person in zip(scene.frames, scene.person_masks):
        seg = segment_frame(model, frame, params=auto)
        full = segment_frame(model, frame, params=SegmentationParams(auto_roi=False))
        x0, y0, x1, y1 = seg.roi
        assert 0 < (x1 - x0) * (y1 - y0) < 0.5 * person.size
        assert iou(seg.silhouette, full.silhouette) > 0.995
        assert iou(seg.silhouette, person) >= 0.95
    empty = segment_frame(model, scene.background_frames[0], params=auto)
    assert empty.roi == (0, 0, 0, 0) and not empty.silhouette.any() and empty.chamfer.silhouette_q.size == 0
    assert (empty.chamfer.sample(np.array([[10.0, 10.0]])).d_sil == 48.0).all()


def test_coarse_distance_is_half_resolution_block_test(models, scene):
    model = models["diag"]
    frame = scene.frames[0]
    small = model.coarse_distance(frame)
    h, w = frame.shape[:2]
    assert small.shape == ((h + 1) // 2, (w + 1) // 2)
    person_small = cv2.resize(scene.person_masks[0].astype(np.uint8), (small.shape[1], small.shape[0]),
                              interpolation=cv2.INTER_AREA) > 0
    core = cv2.erode(person_small.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    assert np.mean(small[core] > 16) > 0.9  # the person's core is foreground at half resolution
    assert np.mean(small[~cv2.dilate(person_small.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)] > 16) < 0.01


def test_real_uu_studio_background_and_person(shared_data):
    """Model from the first 50 background frames: < 1 % foreground on the last 30 (held out);
    on video.avi one dominant person-sized component per camera."""
    params = SegmentationParams()
    for cam in ("cam1", "cam2", "cam3", "cam4"):
        bg_path = shared_data / "uu_studio" / cam / "background.avi"
        n = frame_count(bg_path)
        frames = read_frames(bg_path, list(range(50)) + list(range(n - 30, n, 3)))
        model = BackgroundModel.from_frames(frames[:50])
        held_out = [segment_frame(model, f, params=params).foreground_fraction for f in frames[50:]]
        assert max(held_out) < 0.01, (cam, held_out)
        for frame in read_frames(shared_data / "uu_studio" / cam / "video.avi", [0, 200]):
            seg = segment_frame(model, frame, params=params)
            first, second = largest_components(seg.silhouette, count=2)
            area = frame.shape[0] * frame.shape[1]
            assert 0.015 * area < first < 0.10 * area, (cam, first)  # a seated person at 4-9 m
            assert second < 0.35 * first, (cam, first, second)


@given(st.integers(0, 500), st.integers(1, 40))
def test_evenly_spaced_bounded_and_spread(n, count):
    picked = evenly_spaced(iter(range(n)), count)
    assert len(picked) == min(n, count) or (n > count and count // 2 < len(picked) <= count)
    assert picked == sorted(set(picked))
    if n:
        assert picked[0] == 0
    if n > 2 * count and count >= 2:  # spread over the whole sequence, not just its start
        assert picked[-1] >= n // 2


@pytest.mark.parametrize("cov", ["full", "diag"])
def test_camouflage_window_matches_direct_formula(models, scene, cov):
    """``window_px``: the relaxed residuals averaged over the window, their Mahalanobis norm times
    area / WINDOW_CORRELATION, grey-eroded, raise pixels already above WINDOW_GATE."""
    from segmentation.background import WINDOW_CORRELATION, WINDOW_GATE

    base = models[cov]
    plain = BackgroundModel(base.mean_yuv, base.cov_yuv, covariance=cov, window_px=0)
    model = BackgroundModel(base.mean_yuv, base.cov_yuv, covariance=cov, window_px=1)
    img = scene.frames[2]
    d0 = plain.distance(img).astype(np.float64)
    inv = plain._inv.astype(np.float64)
    mu = plain.mean_yuv.astype(np.float64)
    p = bgr_to_yuv(img).astype(np.float64)
    s = np.clip(np.einsum("hwi,hwij,hwj->hw", p, inv, mu) / np.einsum("hwi,hwij,hwj->hw", mu, inv, mu),
                *plain.shadow_range)
    r = np.pad(p - s[..., None] * mu, ((1, 1), (1, 1), (0, 0)), mode="symmetric")
    h, w = d0.shape
    mean = sum(r[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)) / 9.0
    win = np.pad(np.einsum("hwi,hwij,hwj->hw", mean, inv, mean) * 9.0 / WINDOW_CORRELATION, 1, mode="symmetric")
    eroded = np.min([win[1:-1, 1:-1], win[:-2, 1:-1], win[2:, 1:-1], win[1:-1, :-2], win[1:-1, 2:]], axis=0)
    ref = np.where(d0 > WINDOW_GATE, np.maximum(d0, eroded), d0)
    np.testing.assert_allclose(model.distance(img), ref, rtol=1e-3, atol=1e-2)
    with pytest.raises(ValueError, match="window_px"):
        BackgroundModel(base.mean_yuv, base.cov_yuv, window_px=-1)
