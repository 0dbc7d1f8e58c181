"""Fitting the body to chamfer images: the cost, the Levenberg-Marquardt solver, the frame-to-frame tracker.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "tracker.fitting.cost": ('ChamferCost', 'CostTerms', 'boundary_samples'),
    "tracker.fitting.solver": ('SolverResult', 'levenberg_marquardt', 'least_squares_fd', 'robust_cost', 'robust_weights'),
    "tracker.fitting.tracking": ('Tracker', 'TrackerOptions', 'fit_frame', 'prior_weights'),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted(_WHERE)


def __getattr__(name: str):
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'tracker.fitting' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
