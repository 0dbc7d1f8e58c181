"""bench/limb_widths.py: the apparent radius across a bone recovers a rendered cylinder's radius."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from tracker.body.model import load_model
from tracker.synthetic.scene import ring_cameras

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from limb_widths import apparent_radius, model_radius  # noqa: E402


def _cylinder_mask(cam, a, b, r):
    """The silhouette of a capped cylinder a->b of radius r: the hull of dense surface points."""
    axis = (b - a) / np.linalg.norm(b - a)
    u = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    th = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    ring = r * (np.cos(th)[:, None] * u + np.sin(th)[:, None] * v)
    pts = np.concatenate([a + ring, b + ring])
    mask = np.zeros((cam.height, cam.width), np.uint8)
    cv2.fillConvexPoly(mask, cv2.convexHull(np.round(cam.project(pts) * 16).astype(np.int32)), 1, shift=4)
    return mask


def test_cylinder_radius_recovered_at_random_bones():
    rng = np.random.default_rng(5)
    cams = ring_cameras(4, size=(1280, 960), radius_m=3.0, target=(0.0, 0.0, 0.6))
    measured = 0
    for _ in range(8):
        a = rng.normal([0.0, 0.0, 0.6], 0.1)
        direction = rng.normal(size=3)
        b = a + 0.4 * direction / np.linalg.norm(direction)
        r = rng.uniform(0.04, 0.09)
        for cam in cams:
            mask = _cylinder_mask(cam, a, b, r)
            got = apparent_radius(mask, cam, a, b, 0.5, window_px=300)
            if got is None:  # a bone seen nearly end-on: no width across it
                continue
            measured += 1
            # the run's ends are whole pixels: half a pixel on the radius, in metres at the point's depth
            px = cam.depth((0.5 * (a + b))[None])[0] / cam.matrix[0, 0]
            assert abs(got - r) <= 0.75 * px + 0.02 * r
    assert measured >= 24


def test_runs_off_the_body_or_through_the_window_are_dropped():
    cam = ring_cameras(1, size=(640, 480), radius_m=3.0, target=(0.0, 0.0, 0.6))[0]
    a, b = np.array([0.0, 0.0, 0.4]), np.array([0.0, 0.0, 0.8])
    assert apparent_radius(np.zeros((480, 640)), cam, a, b, 0.5) is None
    assert apparent_radius(np.ones((480, 640)), cam, a, b, 0.5) is None


def test_model_radius_follows_the_cone_taper():
    m = load_model("knossow40", height_m=1.75)
    i = m.part_names.index("left_shank")
    a, b, k, z1, z2 = m.cones[i]
    assert np.isclose(model_radius(m, "left_shank", 0.0, z2 - z1), 0.5 * (a + b))
    assert np.isclose(model_radius(m, "left_shank", 1.0, z2 - z1), 0.5 * (a + b) * (1 + k * (z2 - z1)))
    assert model_radius(m, "left_shank", 1.0, z2 - z1) < model_radius(m, "left_shank", 0.0, z2 - z1)
