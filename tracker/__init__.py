"""Tracker: body model, kinematics, extremal contours, Jacobians, chamfer cost, solver, initialisation, renderer.

The package face (names resolve lazily, so ``import tracker.body.model`` stays light)::

    model = load_model("knossow40", height_m=1.75)
    pose = forward(model, params)                                  # part2world of every part
    contours = extremal_contours(model, pose, cameras)             # closed-form contour generators
    J = contour_jacobian(model, pose, cameras, contours)           # dx/dΦ = J_I (A + B) J_H
    tracker = Tracker(model, cameras)                              # warm-started LM per frame
    record = tracker.step(frame_id, timestamp_ns, chamfer_images)  # a DESIGN.md pose record
"""

from __future__ import annotations

from tracker.lazy import lazy_face

_EXPORTS = {
    "tracker.body.model": ("BodyModel", "ModelError", "load_model", "available_models", "JOINT_NAMES"),
    "tracker.body.kinematics": ("Pose", "forward", "body_jacobian", "point_jacobian", "joint_centres"),
    "tracker.imaging.contours": ("Contours", "extremal_contours"),
    "tracker.imaging.jacobian": ("contour_jacobian",),
    "tracker.imaging.visibility": ("hidden_points",),
    "tracker.fitting.cost": ("ChamferCost", "CostTerms"),
    "tracker.fitting.solver": ("SolverResult", "levenberg_marquardt", "least_squares_fd"),
    "tracker.fitting.tracking": ("Tracker", "TrackerOptions"),
    "tracker.imaging.roi": ("pose_rois",),
    "tracker.search.hull": ("VoxelHull", "visual_hull"),
    "tracker.search.refine": ("InitResult",),
    "tracker.search.initialise": ("SearchOptions", "initialise"),
    "tracker.search.recovery": ("LossMonitor", "recover"),
    "tracker.search.mirror": ("mirror_params", "resolve_front_back"),
    "tracker.imaging.render": ("render_labels", "render_silhouettes", "internal_edges"),
    "tracker.synthetic.scene": ("ring_cameras",),
    "tracker.synthetic.bvh": ("Bvh", "BvhError", "load_bvh"),
    "tracker.synthetic.retarget": ("retarget_bvh",),
    "tracker.synthetic.synth": ("bundled_motion",),
}
__all__, __getattr__, __dir__ = lazy_face(__name__, _EXPORTS)
