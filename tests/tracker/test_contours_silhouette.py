"""Contour points of a lone part land on the boundary of its rendered silhouette (tracker.imaging.render)."""

import cv2
import numpy as np
import pytest

from capture.camera import Camera
from tracker.imaging.contours import extremal_contours
from tracker.body.kinematics import forward
from tracker.body.model import JOINT_NAMES, load_model
from tracker.imaging.render import render_silhouettes


def lone_cone_model(tmp_path, *, a, b, k, z1, z2):
    """A one-part model (height_m = 1: lengths in metres); its frame is the root's (tx, ty, tz, rotation)."""
    joints = "\n".join(f'{name} = {{ part = "cone", point = [0.0, 0.0, 0.0] }}' for name in JOINT_NAMES)
    path = tmp_path / "lone.toml"
    path.write_text(
        f"""
[model]
name = "lone"

[[part]]
name = "cone"
joint = "free"
offset = [0.0, 0.0, 0.0]
cone = {{ a = {a}, b = {b}, k = {k}, z1 = {z1}, z2 = {z2} }}

[joints]
{joints}
"""
    )
    return load_model(path, height_m=1.0)


def signed_boundary_distance(mask, uv):
    """Approximate distance in pixels from uv (n, 2) to the mask's boundary (positive inside).

    Pixel-centre distance transforms of the inside and the outside, each moved half a pixel
    toward the boundary, then sampled bilinearly; accurate to about half a pixel."""
    inside = (mask > 0).astype(np.uint8)
    d_out = cv2.distanceTransform(inside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)  # inside pixels: to the outside
    d_in = cv2.distanceTransform(1 - inside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    sd = np.where(inside > 0, d_out - 0.5, -(d_in - 0.5)).astype(np.float32)
    maps = uv.astype(np.float32).reshape(-1, 1, 2)
    return cv2.remap(sd, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR).ravel()


@pytest.mark.parametrize(
    "shape", [dict(a=0.12, b=0.07, k=-1.2, z1=-0.3, z2=0.25), dict(a=0.05, b=0.09, k=0.8, z1=0.0, z2=0.6)]
)
def test_contour_points_lie_on_the_rendered_silhouette_boundary(tmp_path, rng, shape):
    model = lone_cone_model(tmp_path, **shape)
    cams = [
        Camera.look_at("near", [1.8, 0.7, 1.6], [0.0, 0.0, 1.0]),
        Camera.look_at("far", [-2.5, 2.5, 0.4], [0.0, 0.0, 1.1], distortion=(-0.08, 0.01, 0.0005, -0.0005, 0.0)),
    ]
    checked = 0
    for _ in range(4):
        params = model.zero()
        params[3:6] = rng.normal(0, 1.0, 3)  # any orientation
        params[:3] = [0.0, 0.0, 1.0] + rng.uniform(-0.1, 0.1, 3)
        pose = forward(model, params)
        ct = extremal_contours(model, pose, cams, n_samples=25)
        masks = render_silhouettes(model, pose, cams, n_theta=256, n_z=8)
        for c, mask in enumerate(masks):
            sel = ct.visible & (ct.cam == c)
            assert mask.any() and sel.sum() >= 25
            d = signed_boundary_distance(mask, ct.uv[sel])
            assert np.abs(d).max() < 1.0, np.abs(d).max()
            assert np.abs(d).mean() < 0.35
            # the check can fail: the part's axis projects well inside the silhouette
            axis_z = shape["z1"] + np.linspace(0.3, 0.7, 5) * (shape["z2"] - shape["z1"])
            axis = cams[c].project(pose.to_world(np.zeros(5, int), np.c_[np.zeros((5, 2)), axis_z]))
            assert signed_boundary_distance(mask, axis).min() > 3.0
            checked += sel.sum()
    assert checked > 200
