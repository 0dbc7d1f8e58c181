"""The body: the cone model as data (``models/*.toml``), its sizing and its zero-reference kinematics.

Names resolve lazily, so importing one module of the package stays light.
"""

from __future__ import annotations

from tracker.lazy import lazy_face

_EXPORTS = {
    "tracker.body.model": ('BodyModel', 'ModelError', 'load_model', 'available_models', 'JOINT_NAMES'),
    "tracker.body.kinematics": ('Pose', 'forward', 'body_jacobian', 'point_jacobian', 'joint_centres', 'so3_exp'),
}
__all__, __getattr__, __dir__ = lazy_face(__name__, _EXPORTS)
