"""Synthetic frames (``tracker.synthetic.synth``): the cast shadow keeps the floor's chroma."""

from __future__ import annotations

import numpy as np

from tracker.body.kinematics import forward
from tracker.body.model import load_model
from tracker.synthetic.scene import make_room_texture, render_background, ring_cameras
from tracker.synthetic.synth import make_palette, render_frame


def test_shadow_darkens_floor_keeping_chroma():
    model = load_model("knossow40")
    pose = forward(model, model.zero())
    cams = ring_cameras(2, size=(320, 240))
    tex = make_room_texture(1)
    rendered = [render_background(c, tex, with_floor_mask=True) for c in cams]
    bgs = [b for b, _ in rendered]
    floors = [f.astype(np.float32) for _, f in rendered]
    pal = make_palette(model, np.random.default_rng(0))
    lit, labels = render_frame(model, pose, cams, bgs, floors, pal, shadow=False)
    dark, _ = render_frame(model, pose, cams, bgs, floors, pal, shadow=True)
    for a, b, lab, bg in zip(lit, dark, labels, bgs):
        assert np.array_equal(a[lab >= 0], b[lab >= 0])  # the body itself is untouched
        changed = np.any(a != b, axis=2)
        assert changed.sum() > 100
        ratio = b[changed].astype(float) / np.maximum(a[changed].astype(float), 1)
        core = np.all(bg[changed] > 40, axis=1) & (ratio.max(axis=1) < 0.7)  # the umbra, off its soft edge
        assert core.sum() > 50
        r = ratio[core]
        assert np.all((r > 0.5) & (r < 0.7))  # 30–50 % darker
        assert np.all(r.max(axis=1) - r.min(axis=1) < 0.05)  # same factor in B, G, R: chroma kept
