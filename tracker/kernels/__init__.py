"""Compiled (numba) kernels of the tracker's per-evaluation hot loops.

The cost of one frame is a few dozen evaluations of the chamfer cost, each made of many small
array operations over ~2000 contour points and ~900 silhouette boundary samples: the occlusion
tests of ``tracker.visibility`` (segment or ray against every other part's solid), the reverse
term's nearest contour point of every boundary sample (``tracker.cost``), the bilinear sampling
of the distance images and the forward kinematics.  Written as numpy, each is tens of calls whose
fixed overhead dominates; here each is one loop.  The maths is the one documented in the module
that calls the kernel (its docstring is the reference); these functions take plain arrays only.

Compiled on first use and cached on disk (``cache=True``): a process pays the compilation once per
installed version (a few seconds; ``warm_up`` triggers it, e.g. in a live worker before its first
frame), later processes load the cached machine code.
"""

from __future__ import annotations

import numpy as np

from tracker.kernels.kinematics import forward_kinematics
from tracker.kernels.occlusion import covered_mask, hidden_mask, part_boxes
from tracker.kernels.projection import contour_points, image_motion, projection_jacobians, ruling_angles
from tracker.kernels.residuals import assemble, nearest_rows, reverse_terms, sample_chamfer, screw_rows

__all__ = ["part_boxes", "hidden_mask", "covered_mask", "nearest_rows", "sample_chamfer", "forward_kinematics",
           "screw_rows", "image_motion", "contour_points", "ruling_angles", "projection_jacobians", "assemble",
           "reverse_terms", "warm_up"]


def warm_up() -> float:
    """Compile every kernel (or load it from numba's on-disk cache) by fitting one small rendered
    frame through the tracker's own code path (``tracker.tracking.fit_frame`` with the reverse
    term and its ray test); returns the seconds it took.  A live worker calls it before its first
    frame so that frame is not delayed by the compilation."""
    import time

    from segmentation.distance import chamfer_images
    from tracker.kinematics import forward as forward_pose
    from tracker.model import load_model
    from tracker.render import internal_edges, render_label_images
    from tracker.scene import ring_cameras
    from tracker.tracking import TrackerOptions, fit_frame

    t0 = time.perf_counter()
    model = load_model("knossow40")
    cams = ring_cameras(2, size=(160, 120))
    p = model.zero()
    labels = render_label_images(model, forward_pose(model, p), cams)
    chamfer = [chamfer_images(np.where(lab >= 0, 255, 0).astype(np.uint8), internal_edges(lab)) for lab in labels]
    fit_frame(model, cams, chamfer, p, options=TrackerOptions(max_iterations=2))
    return time.perf_counter() - t0
