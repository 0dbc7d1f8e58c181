"""The body: the cone model as data (``models/*.toml``), its sizing and its zero-reference kinematics.

Names resolve lazily, so importing one module of the package stays light.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "tracker.body.model": ('BodyModel', 'ModelError', 'load_model', 'available_models', 'JOINT_NAMES'),
    "tracker.body.kinematics": ('Pose', 'forward', 'body_jacobian', 'point_jacobian', 'joint_centres', 'so3_exp'),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted(_WHERE)


def __getattr__(name: str):
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'tracker.body' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
