"""Compiling the numba kernels before the first frame (a live worker calls `warm_up` at start)."""

from __future__ import annotations

import time

import numpy as np

__all__ = ["warm_up"]


def warm_up() -> float:
    """Compile every kernel (or load it from numba's on-disk cache) by fitting one small rendered
    frame through the tracker's own code path (``tracker.fitting.tracking.fit_frame`` with the reverse
    term and its ray test); returns the seconds it took.  A live worker calls it before its first
    frame so that frame is not delayed by the compilation.  Read-only inputs are distinct numba
    signatures, so the fit runs twice: on writable chamfer arrays (offline) and on read-only ones
    with a read-only pose (what a live worker decodes from the wire)."""
    from segmentation.distance import chamfer_images
    from tracker.body.kinematics import forward as forward_pose
    from tracker.body.model import load_model
    from tracker.imaging.render import internal_edges, render_label_images
    from tracker.synthetic.scene import ring_cameras
    from tracker.fitting.tracking import TrackerOptions, fit_frame

    t0 = time.perf_counter()
    import scipy.ndimage  # noqa: F401  (the searches' hull labelling: a first import mid-initialisation delays it)

    model = load_model("knossow40")
    cams = ring_cameras(2, size=(160, 120))
    p = model.zero()
    labels = render_label_images(model, forward_pose(model, p), cams)
    chamfer = {cam.name: chamfer_images(np.where(lab >= 0, 255, 0).astype(np.uint8), internal_edges(lab))
               for cam, lab in zip(cams, labels)}
    fit_frame(model, cams, chamfer, p, options=TrackerOptions(max_iterations=2))
    for ci in chamfer.values():
        ci.silhouette_q.setflags(write=False)
        ci.edges_q.setflags(write=False)
    frozen = p.copy()
    frozen.setflags(write=False)
    forward_pose(model, frozen)
    fit_frame(model, cams, chamfer, frozen, options=TrackerOptions(max_iterations=2))
    return time.perf_counter() - t0
