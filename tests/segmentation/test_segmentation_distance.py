"""Chamfer images: exactness against scipy's EDT, truncation, quantisation, bilinear sampling + gradient."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.ndimage import distance_transform_edt

from segmentation import ChamferImages, chamfer_images, distance_to_mask, sample_bilinear


def _random_masks(rng, h=90, w=120):
    sil = np.zeros((h, w), np.uint8)
    yy, xx = np.mgrid[0:h, 0:w]
    for _ in range(3):
        cx, cy, r = rng.uniform(25, w - 25), rng.uniform(20, h - 20), rng.uniform(5, 15)
        sil[(xx - cx) ** 2 + (yy - cy) ** 2 < r * r] = 255
    edges = ((rng.random((h, w)) < 0.01) * 255).astype(np.uint8) & sil
    return sil, edges


def test_distance_equals_scipy_edt_within_quantisation(rng):
    sil, edges = _random_masks(rng)
    max_d, res = 30.0, 0.25
    ch = chamfer_images(sil, edges, max_distance_px=max_d, resolution_px=res, crop=False)
    ds, de = ch.dequantised()
    ref_s = np.minimum(distance_transform_edt(sil == 0), max_d)
    ref_e = np.minimum(distance_transform_edt(edges == 0), max_d)
    # exact L2 (OpenCV's precise mask is float32) + rounding to the resolution
    assert np.abs(ds - ref_s).max() <= res / 2 + 1e-3
    assert np.abs(de - ref_e).max() <= res / 2 + 1e-3
    assert (ds[sil > 0] == 0).all()
    # the float path is exact
    assert np.abs(distance_to_mask(sil, max_distance_px=max_d) - ref_s).max() < 1e-3


def test_crop_is_exact_and_offset(rng):
    sil, edges = _random_masks(rng, 200, 260)
    full = chamfer_images(sil, edges, max_distance_px=20.0, crop=False, offset_xy=(7, 3), image_size=(400, 300))
    crop = chamfer_images(sil, edges, max_distance_px=20.0, crop=True, offset_xy=(7, 3), image_size=(400, 300))
    assert crop.silhouette_q.size < full.silhouette_q.size
    pts = np.column_stack([rng.uniform(-20, 420, 3000), rng.uniform(-20, 320, 3000)])
    a, b = full.sample(pts), crop.sample(pts)
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, atol=1e-9)


@pytest.mark.parametrize("which", ["silhouette", "edges", "both"])
def test_empty_masks_give_truncation_everywhere(rng, which):
    sil, edges = _random_masks(rng)
    if which in ("silhouette", "both"):
        sil = np.zeros_like(sil)
    if which in ("edges", "both"):
        edges = np.zeros_like(edges)
    for crop in (False, True):
        ch = chamfer_images(sil, edges, max_distance_px=40.0, resolution_px=0.5, crop=crop)
        ds, de = ch.dequantised()
        if which != "edges":
            assert (ds == 40.0).all()
        if which != "silhouette":
            assert (de == 40.0).all()
        s = ch.sample(rng.uniform(0, 120, (50, 2)))
        for v in s:
            assert np.isfinite(v).all()
        if which != "edges":
            assert (s.d_sil == 40.0).all() and (s.grad_sil == 0).all()
    assert (distance_to_mask(np.zeros((5, 7), np.uint8), max_distance_px=9.0) == 9.0).all()


@given(st.floats(0.05, 2.0), st.integers(10, 300), st.integers(0, 2**32 - 1))
def test_quantisation_error_within_resolution(res, steps, seed):
    rng = np.random.default_rng(seed)
    sil, edges = _random_masks(rng, 60, 80)
    max_d = res * steps
    ch = chamfer_images(sil, edges, max_distance_px=max_d, resolution_px=res, crop=False)
    assert ch.silhouette_q.dtype == (np.uint8 if steps <= 255 else np.uint16)
    exact = distance_to_mask(sil, max_distance_px=max_d)
    ds, _ = ch.dequantised()
    assert np.abs(ds - exact).max() <= res * 0.5 + 1e-4 * max(1.0, max_d)
    assert ds.max() <= max_d * (1 + np.finfo(np.float32).eps)  # float32 images: half an ulp over at most


def test_sample_gradient_matches_central_differences(rng):
    sil, edges = _random_masks(rng)
    ch = chamfer_images(sil, edges, max_distance_px=24.0, resolution_px=0.25, offset_xy=(11, 5),
                        image_size=(200, 150), crop=False)
    uv = np.column_stack([rng.uniform(0, 140, 400), rng.uniform(0, 100, 400)])
    frac = uv - np.floor(uv)
    uv = np.floor(uv) + np.clip(frac, 0.1, 0.9)  # away from cell boundaries
    s = ch.sample(uv)
    h = 1e-5
    for k in range(2):
        e = np.zeros(2)
        e[k] = h
        plus, minus = ch.sample(uv + e), ch.sample(uv - e)
        np.testing.assert_allclose(s.grad_sil[:, k], (plus.d_sil - minus.d_sil) / (2 * h), atol=1e-5)
        np.testing.assert_allclose(s.grad_edge[:, k], (plus.d_edge - minus.d_edge) / (2 * h), atol=1e-5)
    # not a trivial check: gradients are non-zero near the shapes
    assert np.abs(s.grad_sil).max() > 0.5 and np.abs(s.grad_edge).max() > 0.5


def test_sample_at_pixel_centres_and_outside():
    sil = np.zeros((30, 40), np.uint8)
    sil[10:20, 15:25] = 1
    ch = chamfer_images(sil, sil, max_distance_px=8.0, resolution_px=0.125, offset_xy=(100, 50),
                        image_size=(300, 200), crop=False)
    ds, _ = ch.dequantised()
    ii, jj = np.mgrid[0:30, 0:40]
    s = ch.sample(np.column_stack([jj.ravel() + 100.0, ii.ravel() + 50.0]))
    np.testing.assert_allclose(s.d_sil, ds.ravel())
    far = np.array([[0.0, 0.0], [98.9, 60.0], [140.5, 80.0], [1e12, -1e12], [-5e300, 3.0]])
    out = ch.sample(far)
    assert (out.d_sil == 8.0).all() and (out.grad_sil == 0).all() and (out.d_edge == 8.0).all()
    # continuity across the stored region's rim: halfway to the outside is halfway to the truncation
    rim = ch.sample(np.array([[99.5, 60.0]]))
    np.testing.assert_allclose(rim.d_sil, 0.5 * (ds[10, 0] + 8.0))


def test_float_path_agrees_with_quantised(rng):
    sil, edges = _random_masks(rng)
    ch = chamfer_images(sil, edges, max_distance_px=32.0, resolution_px=1 / 64, offset_xy=(3, 4), crop=False)
    exact = distance_to_mask(sil, max_distance_px=32.0)
    uv = rng.uniform(-5, 130, (500, 2))
    v, g = sample_bilinear(exact, uv, offset_xy=(3, 4), fill=32.0)
    s = ch.sample(uv)
    np.testing.assert_allclose(s.d_sil, v, atol=1 / 128 + 1e-4)
    assert np.abs(s.grad_sil - g).max() <= 2 / 64 + 1e-4


def test_bad_arguments_are_named():
    sil = np.zeros((10, 10), np.uint8)
    with pytest.raises(ValueError, match="max_distance_px"):
        chamfer_images(sil, sil, max_distance_px=10.1, resolution_px=0.25)
    with pytest.raises(ValueError, match="edges"):
        chamfer_images(sil, np.zeros((10, 11), np.uint8))
    with pytest.raises(TypeError, match="silhouette"):
        chamfer_images(sil.astype(np.float32), sil)
    ch = chamfer_images(sil, sil)
    with pytest.raises(ValueError, match="uv"):
        ch.sample(np.array([[np.nan, 1.0]]))
    with pytest.raises(ValueError, match="uv"):
        ch.sample(np.zeros((4, 3)))
    with pytest.raises(TypeError, match="silhouette_q"):
        ChamferImages(np.zeros((2, 2)), np.zeros((2, 2)), (0, 0), 0.25, 8.0, (2, 2))
