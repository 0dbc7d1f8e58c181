"""Silhouette clean-up (hysteresis, specks, holes, ROI) and edges inside the silhouette."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from segmentation import silhouette_boundary, silhouette_edges, silhouette_from_distance


def _distance_image(h=200, w=240):
    d = np.zeros((h, w), np.float32)
    cv2.rectangle(d, (60, 40), (160, 180), 100.0, -1)  # strong body
    cv2.circle(d, (110, 80), 4, 0.0, -1)  # small hole (~50 px): filled
    cv2.rectangle(d, (80, 120), (130, 160), 0.0, -1)  # big hole (2500 px): kept
    cv2.rectangle(d, (200, 20), (230, 60), 30.0, -1)  # weak-only blob (between low and high): dropped
    cv2.rectangle(d, (10, 150), (14, 154), 100.0, -1)  # strong speck (25 px): dropped as too small
    cv2.rectangle(d, (161, 100), (190, 110), 20.0, -1)  # weak arm attached to the strong body: kept
    return d


def test_hysteresis_holes_and_small_components():
    d = _distance_image()
    sil = silhouette_from_distance(d, low=16, high=64, min_area_px=300, max_hole_fraction=0.05, open_px=1, close_px=0)
    assert sil.dtype == np.uint8 and set(np.unique(sil)) <= {0, 255}
    assert sil[80, 110] == 255  # small hole filled
    assert (sil[125:155, 85:125] == 0).all()  # big hole kept open
    assert (sil[20:61, 200:231] == 0).all()  # weak-only blob
    assert (sil[150:155, 10:15] == 0).all()  # speck
    assert (sil[102:109, 165:189] == 255).all()  # weak arm connected to strong body
    assert (sil[45:115, 65:155] == 255).all()


def test_max_components_keeps_the_largest():
    d = np.zeros((100, 200), np.float32)
    cv2.rectangle(d, (10, 10), (60, 90), 100.0, -1)  # 51 x 81
    cv2.rectangle(d, (120, 20), (160, 60), 100.0, -1)  # 41 x 41
    both = silhouette_from_distance(d, min_area_px=100)
    one = silhouette_from_distance(d, min_area_px=100, max_components=1)
    assert both[40, 140] == 255 and both[50, 30] == 255
    assert one[40, 140] == 0 and one[50, 30] == 255


def test_roi_restricts_processing():
    d = _distance_image()
    roi = (50, 30, 170, 190)
    sil = silhouette_from_distance(d, low=16, high=64, min_area_px=300, max_hole_fraction=0.05, roi=roi)
    full = silhouette_from_distance(d, low=16, high=64, min_area_px=300, max_hole_fraction=0.05)
    inside = np.zeros(d.shape, bool)
    inside[30:190, 50:170] = True
    assert not sil[~inside].any()
    assert np.mean(sil[45:175, 65:155] == full[45:175, 65:155]) > 0.99


def test_silhouette_bad_arguments():
    with pytest.raises(TypeError, match="distance"):
        silhouette_from_distance(np.zeros((4, 4)))
    with pytest.raises(ValueError, match="distance"):
        silhouette_from_distance(np.full((4, 4), np.nan, np.float32))
    with pytest.raises(ValueError, match="low, high"):
        silhouette_from_distance(np.zeros((4, 4), np.float32), low=10, high=5)
    with pytest.raises(ValueError, match="roi"):
        silhouette_from_distance(np.zeros((4, 4), np.float32), roi=(0, 0, 5, 4))
    with pytest.raises(ValueError, match="max_components"):  # 0 would silently keep nothing
        silhouette_from_distance(np.zeros((4, 4), np.float32), max_components=0)


@pytest.mark.parametrize("option, value", [("max_components", 0), ("person_area_px", -1.0),
                                           ("min_area_fraction", float("nan")), ("open_px", -1)])
def test_segmentation_params_refuse_values_that_empty_the_output(option, value):
    from segmentation import SegmentationParams

    with pytest.raises(ValueError, match=option):
        SegmentationParams(**{option: value})


def test_edges_inside_dilated_silhouette_plus_boundary(rng):
    h, w = 160, 200
    img = np.full((h, w), 90, np.uint8)
    img[:, 100:] = 200  # a strong vertical step edge at x = 100 everywhere
    sil = np.zeros((h, w), np.uint8)
    sil[40:120, 60:140] = 255
    edges = silhouette_edges(img, sil, low=30, high=90, dilate_px=3, blur_sigma=1.0)
    ys, xs = np.nonzero(edges)
    assert len(xs) > 0
    # nothing outside the silhouette dilated by 3 px
    assert ys.min() >= 37 and ys.max() <= 122 and xs.min() >= 57 and xs.max() <= 142
    # the step edge is found inside (rows 50..110 at x = 99 or 100)
    assert (edges[50:110, 99:101] > 0).any(axis=1).all()
    # the silhouette boundary is included
    assert (edges[silhouette_boundary(sil) > 0] > 0).all()
    # colour input gives the same result as its grey conversion
    bgr = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    np.testing.assert_array_equal(silhouette_edges(bgr, sil), silhouette_edges(img, sil))
    assert not silhouette_edges(img, np.zeros_like(sil)).any()


def test_edges_bad_arguments():
    with pytest.raises(ValueError, match="silhouette"):
        silhouette_edges(np.zeros((10, 10), np.uint8), np.zeros((10, 11), np.uint8))
    with pytest.raises(TypeError, match="image"):
        silhouette_edges(np.zeros((10, 10), np.float32), np.zeros((10, 10), np.uint8))
