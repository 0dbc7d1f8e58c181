"""The body seen by cameras: extremal contours, their visibility, their Jacobian, and renders.
"""

from __future__ import annotations

from tracker.lazy import lazy_face

_EXPORTS = {
    "tracker.imaging.contours": ('Contours', 'extremal_contours', 'camera_centres'),
    "tracker.imaging.visibility": ('hidden_points', 'covered_rays'),
    "tracker.imaging.jacobian": ('contour_jacobian', 'contour_image_motion', 'apply_screws'),
    "tracker.imaging.render": ('body_points', 'cone_points', 'render_labels', 'render_label_images', 'render_silhouettes', 'internal_edges'),
}
__all__, __getattr__, __dir__ = lazy_face(__name__, _EXPORTS)
