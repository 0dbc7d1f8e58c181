"""Synthetic people for tests and benchmarks: camera rings and rooms, BVH motion, retargeting, rendered frames.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "tracker.synthetic.scene": ('ring_cameras', 'fit_ring_cameras', 'make_room_texture', 'render_background', 'pixel_rays'),
    "tracker.synthetic.bvh": ('Bvh', 'BvhError', 'load_bvh', 'parse_bvh', 'bvh_forward'),
    "tracker.synthetic.retarget": ('Retargeted', 'retarget_bvh', 'JOINT_MAP', 'BVH_TO_WORLD'),
    "tracker.synthetic.synth": ('bundled_motion', 'render_frame', 'make_palette', 'synthetic_studio',
                                'SyntheticStudio', 'ground_truth_record', 'add_noise'),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted(_WHERE)


def __getattr__(name: str):
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'tracker.synthetic' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
