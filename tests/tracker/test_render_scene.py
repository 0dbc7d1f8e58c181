"""The synthetic studio: pixel rays, a consistent ray-cast room, and rings fitted to a motion."""

from __future__ import annotations

import numpy as np
import pytest

from capture.camera import Camera
from tracker.synthetic.scene import fit_ring_cameras, make_room_texture, pixel_rays, render_background, ring_cameras


@pytest.mark.parametrize("distortion", [(0, 0, 0, 0, 0), (-0.3, 0.1, 0.002, -0.001, 0.01)])
def test_pixel_rays_project_back_to_their_pixels(distortion):
    cam = Camera.look_at("c", [3, 1, 2], [0, 0, 1], size=(64, 48), fov_deg=70, distortion=distortion)
    rays = pixel_rays(cam)
    assert np.allclose(np.linalg.norm(rays, axis=-1), 1.0)
    uv = cam.project(cam.center + 2.5 * rays)
    u, v = np.meshgrid(np.arange(64), np.arange(48))
    assert np.abs(uv[..., 0] - u).max() < 1e-6 and np.abs(uv[..., 1] - v).max() < 1e-6


def test_room_is_one_scene_seen_by_all_cameras():
    """A floor point has the same texture colour in every camera that sees it."""
    tex = make_room_texture(7)
    cams = ring_cameras(3, size=(160, 120))
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-0.8, 0.8, (200, 2)), np.zeros(200)]
    colours = []
    for cam in cams:
        img, floor = render_background(cam, tex, with_floor_mask=True)
        assert img.shape == (120, 160, 3) and img.dtype == np.uint8
        assert 0.2 < floor.mean() < 0.8  # the floor and the wall are both in view
        uv = np.rint(cam.project(pts)).astype(int)
        assert np.all(cam.in_image(uv))
        assert floor[uv[:, 1], uv[:, 0]].all()
        colours.append(img[uv[:, 1], uv[:, 0]].astype(float))
    # a pixel is 3-5 cm on the floor here, texels 1.6 cm, the noise 10 cm cells: agree up to sampling
    for c in colours[1:]:
        assert np.median(np.abs(c - colours[0])) < 6
    assert np.std(colours[0]) > 10  # textured, not flat
    # deterministic per seed, different across seeds
    assert np.array_equal(make_room_texture(7).floor, tex.floor)
    assert not np.array_equal(make_room_texture(8).floor, tex.floor)


def test_fit_ring_keeps_a_travelling_subject_in_view():
    rng = np.random.default_rng(1)
    # a "subject" walking 3 m along X: points from z = 0 to 1.8 m
    pts = np.c_[rng.uniform(-1.5, 1.5, 2000), rng.uniform(-0.3, 0.3, 2000), rng.uniform(0, 1.8, 2000)]
    cams = fit_ring_cameras(pts, 6, size=(320, 240), radius_m=3.0)
    radius = np.hypot(cams[0].center[0], cams[0].center[1])
    assert radius >= 1.5 + 2.0 - 0.1  # clearance beyond the farthest excursion
    for cam in cams:
        uv = cam.project(pts)
        assert np.all(cam.depth(pts) > 0)
        assert np.all((uv[:, 0] >= 0.05 * 320) & (uv[:, 0] <= 0.95 * 320))
        assert np.all((uv[:, 1] >= 0.05 * 240) & (uv[:, 1] <= 0.95 * 240))
    # the fit is tight: 2 degrees narrower no longer fits every point in every view
    fov = np.degrees(2 * np.arctan(0.5 * 320 / cams[0].matrix[0, 0]))
    narrower = ring_cameras(6, size=(320, 240), radius_m=radius, height_m=1.5, target=_target(pts), fov_deg=fov - 2)
    assert not all(np.all((c.project(pts)[:, 0] >= 16) & (c.project(pts)[:, 0] <= 304)
                          & (c.project(pts)[:, 1] >= 12) & (c.project(pts)[:, 1] <= 228)) for c in narrower)  # fmt: skip
    with pytest.raises(ValueError, match="points"):
        fit_ring_cameras(np.zeros((0, 3)), 3)


def _target(pts):
    return 0.5 * (pts.min(axis=0) + pts.max(axis=0))
