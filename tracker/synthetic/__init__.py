"""Synthetic people for tests and benchmarks: camera rings and rooms, BVH motion, retargeting, rendered frames.
"""

from __future__ import annotations

from tracker.lazy import lazy_face

_EXPORTS = {
    "tracker.synthetic.scene": ('ring_cameras', 'fit_ring_cameras', 'make_room_texture', 'render_background', 'pixel_rays'),
    "tracker.synthetic.bvh": ('Bvh', 'BvhError', 'load_bvh', 'parse_bvh', 'bvh_forward'),
    "tracker.synthetic.retarget": ('Retargeted', 'retarget_bvh', 'JOINT_MAP', 'BVH_TO_WORLD'),
    "tracker.synthetic.synth": ('bundled_motion', 'render_frame', 'make_palette', 'synthetic_studio',
                                'SyntheticStudio', 'ground_truth_record', 'add_noise'),
}
__all__, __getattr__, __dir__ = lazy_face(__name__, _EXPORTS)
