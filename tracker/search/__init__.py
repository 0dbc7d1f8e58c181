"""Finding the body without a warm start, as a bottom-up chain of modules (each imports only those above it):

``hull`` (visual hull) -> ``scoring`` (validated views, IoU of a pose) -> ``candidates`` (hypotheses
placed on the hull, limb search) -> ``refine`` (staged LM, elbows) -> ``mirror`` (front or back)
-> ``initialise`` (``SearchOptions``, the T/A-pose search) -> ``recovery`` (loss detection, any-pose
search from the last good pose).
"""

from __future__ import annotations

from tracker.lazy import lazy_face

_EXPORTS = {
    "tracker.search.hull": ('VoxelHull', 'visual_hull', 'common_view_bounds', 'render_hull', 'silhouette_iou'),
    "tracker.search.scoring": ('ScoreViews', 'SearchInputs', 'prepare_inputs', 'chamfer_from_silhouette',
                               'rendered_views'),
    "tracker.search.candidates": ('pose_candidates', 'feet_direction', 'estimate_height', 'sized_model',
                                  'limb_search', 'limb_chains', 'turn_about_vertical'),
    "tracker.search.refine": ('InitResult', 'refine_best', 'elbow_search'),
    "tracker.search.mirror": ('FrontBack', 'mirror_params', 'mirror_map', 'front_back_cost', 'hypothesis_cost',
                              'compare_front_back', 'resolve_front_back'),
    "tracker.search.initialise": ('SearchOptions', 'search_candidates'),
    "tracker.search.recovery": ('LossMonitor', 'LossState', 'recover', 'local_search'),
}
# the functions ``refine`` and ``initialise`` share their modules' names, which Python binds on the package
# when the module is imported: import them from their modules (``from tracker.search.refine import refine``).
__all__, __getattr__, __dir__ = lazy_face(__name__, _EXPORTS)
