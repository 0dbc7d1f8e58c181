"""The chamfer sampler protocol and its one convention (a mapping camera name -> sampler)."""

from __future__ import annotations

import numpy as np
import pytest

from segmentation.distance import chamfer_images
from tracker.body.model import load_model
from tracker.fitting.sampler import ChamferSampler, SilhouetteChamfer, in_camera_order
from tracker.fitting.tracking import fit_frame
from tracker.search.initialise import SearchOptions
from tracker.synthetic.scene import ring_cameras


def _square(size=(64, 48)):
    sil = np.zeros(size[::-1], np.uint8)
    sil[10:30, 20:40] = 255
    return chamfer_images(sil, sil, max_distance_px=8.0, resolution_px=0.25)


def test_chamfer_images_satisfy_the_protocol():
    ch = _square()
    assert isinstance(ch, ChamferSampler) and isinstance(ch, SilhouetteChamfer)
    assert not isinstance(object(), ChamferSampler)
    d_sil, g_sil, d_edge, g_edge = ch.sample(np.array([[30.0, 20.0], [5.0, 5.0]]))
    assert d_sil.shape == (2,) and g_sil.shape == (2, 2) and d_edge.shape == (2,) and g_edge.shape == (2, 2)
    assert d_sil[0] == 0.0 and d_sil[1] > 0.0


def test_in_camera_order_picks_by_name_and_names_the_missing_camera():
    cams = ring_cameras(3, size=(64, 48))
    a, b, c = _square(), _square(), _square()
    assert in_camera_order({"cam2": c, "cam0": a, "cam1": b, "extra": a}, cams) == [a, b, c]
    with pytest.raises(ValueError, match="cam1"):
        in_camera_order({"cam0": a, "cam2": c}, cams)
    with pytest.raises(TypeError, match="mapping"):
        in_camera_order([a, b, c], cams)


def test_fit_frame_takes_the_mapping_only():
    model = load_model("knossow40")
    cams = ring_cameras(2, size=(64, 48))
    with pytest.raises(TypeError, match="mapping"):
        fit_frame(model, cams, [_square(), _square()], model.zero())


def test_search_options_validate_and_recovery_defaults():
    with pytest.raises(ValueError, match="keep"):
        SearchOptions(keep=0)
    with pytest.raises(ValueError, match="min_voxel_m"):
        SearchOptions(min_voxel_m=0.0)
    rec = SearchOptions.for_recovery(accept_iou=0.9)
    assert (rec.keep, rec.prior_rad, rec.search_limbs, rec.elbows, rec.use_feet, rec.accept_iou) == \
        (2, 50.0, True, False, False, 0.9)
    assert SearchOptions().keep == 3 and not SearchOptions().search_limbs
