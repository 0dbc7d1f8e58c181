"""The body seen by cameras: extremal contours, their visibility, their Jacobian, and renders.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "tracker.imaging.contours": ('Contours', 'extremal_contours', 'camera_centres'),
    "tracker.imaging.visibility": ('hidden_points', 'covered_rays'),
    "tracker.imaging.jacobian": ('contour_jacobian', 'contour_image_motion', 'apply_screws'),
    "tracker.imaging.render": ('body_points', 'cone_points', 'render_labels', 'render_label_images', 'render_silhouettes', 'internal_edges'),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted(_WHERE)


def __getattr__(name: str):
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'tracker.imaging' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
