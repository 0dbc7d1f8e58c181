"""Finding the body without a warm start: visual hull, pose candidates, front/back, initialisation, recovery.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "tracker.search.hull": ('VoxelHull', 'visual_hull', 'common_view_bounds', 'render_hull', 'silhouette_iou'),
    "tracker.search.initialise": ('InitResult', 'initialise', 'refine', 'ScoreViews', 'prepare_inputs', 'pose_candidates', 'estimate_height', 'sized_model'),
    "tracker.search.mirror": ('FrontBack', 'mirror_params', 'mirror_map', 'front_back_cost', 'hypothesis_cost', 'resolve_front_back'),
    "tracker.search.recovery": ('LossMonitor', 'LossState', 'recover', 'local_search', 'limb_search'),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted(_WHERE)


def __getattr__(name: str):
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'tracker.search' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
