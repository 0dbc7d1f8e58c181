"""Fitting the body to chamfer images: the cost, the Levenberg-Marquardt solver, the frame-to-frame tracker.
"""

from __future__ import annotations

from tracker.lazy import lazy_face

_EXPORTS = {
    "tracker.fitting.boundary": ('boundary_samples', 'boundary_rays'),
    "tracker.fitting.cost": ('ChamferCost', 'CostTerms'),
    "tracker.fitting.screw_jacobian": ('ScrewJacobian',),
    "tracker.fitting.solver": ('SolverResult', 'levenberg_marquardt', 'least_squares_fd', 'robust_cost', 'robust_weights'),
    "tracker.fitting.tracking": ('Tracker', 'TrackerOptions', 'fit_frame', 'prior_weights'),
}
__all__, __getattr__, __dir__ = lazy_face(__name__, _EXPORTS)
