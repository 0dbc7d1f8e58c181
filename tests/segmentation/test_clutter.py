"""segmentation.clutter: ignore regions, the static-clutter learner, the cut."""

from __future__ import annotations

import numpy as np
import pytest

from segmentation.clutter import (StaticClutter, ignore_mask, ignore_masks, parse_ignore_region,
                                  session_ignore_regions, without_clutter)

W, H = 64, 48


def test_parse_ignore_region():
    assert parse_ignore_region("cam2:10,20,30,40") == ("cam2", (10, 20, 30, 40))
    assert parse_ignore_region(" cam0 : -5, 0, 3, 4 ") == ("cam0", (-5, 0, 3, 4))
    for bad in ("cam0:1,2,3", "1,2,3,4", "cam0:1,2,0,4", "cam0:a,b,c,d"):
        with pytest.raises(ValueError, match="ignore-region"):
            parse_ignore_region(bad)


def test_ignore_mask_clips_to_the_image():
    m = ignore_mask((W, H), [(-10, -10, 15, 12), (60, 40, 100, 100)])
    assert m.shape == (H, W)
    assert m[:2, :5].all() and not m[2, 0] and not m[0, 5]
    assert m[40:, 60:].all() and m.sum() == 5 * 2 + 4 * 8
    with pytest.raises(ValueError, match="unknown camera"):
        ignore_masks({"cam0": (W, H)}, {"cam9": [(0, 0, 1, 1)]})


def _frame(rng, value=100):
    return np.clip(rng.normal(value, 2.0, (H, W, 3)), 0, 255).astype(np.uint8)


def test_static_unexplained_foreground_is_learned_after_learn_frames(rng):
    fg = np.zeros((H, W), np.uint8)
    fg[10:30, 10:20] = 255  # the body
    fg[10:30, 40:50] = 255  # a prop
    explained = np.zeros((H, W), bool)
    explained[8:32, 8:22] = True
    learner = StaticClutter((W, H), learn_frames=5)
    for k in range(4):
        assert not learner.update(_frame(rng), fg, explained).any(), k
    mask = learner.update(_frame(rng), fg, explained)
    assert mask[10:30, 40:50].all() and mask.sum() == 200  # the prop, nothing of the body


def test_a_change_restarts_the_count_and_background_releases(rng):
    fg = np.zeros((H, W), np.uint8)
    fg[0:10, 0:10] = 255
    none = np.zeros((H, W), bool)
    learner = StaticClutter((W, H), learn_frames=3, colour_tol=40.0)
    learner.update(_frame(rng, 100), fg, none)
    learner.update(_frame(rng, 100), fg, none)
    assert not learner.update(_frame(rng, 160), fg, none).any()  # the pixels changed colour: count restarts
    assert not learner.update(_frame(rng, 160), fg, none).any()
    assert not learner.update(_frame(rng, 160), fg, none).any()
    assert learner.update(_frame(rng, 160), fg, none).sum() == 100
    # covered by the body: held, still clutter; gone from the foreground: released at once
    assert learner.update(_frame(rng, 160), fg, np.ones((H, W), bool)).sum() == 100
    assert not learner.update(_frame(rng, 160), np.zeros((H, W), np.uint8), none).any()


def test_without_clutter_keeps_the_body_and_drops_fragments():
    sil = np.zeros((H, W), np.uint8)
    sil[5:40, 5:30] = 255
    clutter = np.zeros((H, W), bool)
    clutter[5:40, 20:30] = True
    keep = np.zeros((H, W), bool)
    keep[5:40, 20:24] = True  # a limb of the body in front of the clutter
    out = without_clutter(sil, clutter, keep=keep)
    assert out[5:40, 5:24].all() and not out[5:40, 24:30].any()
    # a sliver left by the cut is dropped
    clutter2 = np.zeros((H, W), bool)
    clutter2[5:40, 8:30] = True
    out2 = without_clutter(sil, clutter2, min_area_px=200)
    assert not out2.any()
    assert without_clutter(sil, None) is sil


def test_session_ignore_regions(tmp_path):
    toml = tmp_path / "session.toml"
    toml.write_text('[[camera]]\nname = "cam1"\nvideo = "a.avi"\nignore = [[1, 2, 3, 4], [0, 0, 5, 5]]\n'
                    '[[camera]]\nname = "cam2"\nvideo = "b.avi"\n')
    assert session_ignore_regions(toml) == {"cam1": [(1, 2, 3, 4), (0, 0, 5, 5)]}
    toml.write_text('[[camera]]\nname = "cam1"\nvideo = "a.avi"\nignore = [[1, 2, 3]]\n')
    with pytest.raises(ValueError, match="ignore"):
        session_ignore_regions(toml)
