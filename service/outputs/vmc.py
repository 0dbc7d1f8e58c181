"""VMC protocol (Virtual Motion Capture, OSC over UDP): contourcap as a Performer for Unity, Unreal,
Blender and VTubing Marionettes (python-osc).

Per ok pose, one OSC bundle:

- ``/VMC/Ext/OK 1 3 0 1`` (loaded, calibrated, normal calibration mode, tracking) and ``/VMC/Ext/T
  <seconds since the take's first frame>``;
- ``/VMC/Ext/Root/Pos "root" 0 0 0  0 0 0 1`` (the root stays at the origin);
- ``/VMC/Ext/Bone/Pos <Unity humanoid bone> px py pz qx qy qz qw`` for every mapped body part: the local
  rotation of :mod:`tracker.body.joint_frames` (T-pose relative, the same retargeting as the BVH export)
  relative to the nearest mapped ancestor, in Unity's left-handed Y-up frame
  (:data:`tracker.body.joint_frames.AXES_UNITY`: tracker ``(x, y, z)`` -> Unity ``(-y, z, x)``; the subject's
  T-pose faces Unity +Z), and its position: for ``Hips`` the pelvis joint centre (metres, Unity axes), for
  the others the T-pose offset from that ancestor.

A pose that is not ok sends no bones, only ``/VMC/Ext/OK 1 3 0 0`` (tracking lost) and ``/VMC/Ext/T``.
Quaternions are ``(x, y, z, w)`` as Unity's ``Quaternion``.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from service.wire.records import PoseRecord
from tracker.body.joint_frames import AXES_UNITY, joint_frames

INSTALL_HINT = "the VMC stream needs python-osc: pip install python-osc"

UNITY_BONES: Mapping[str, str] = {
    "pelvis": "Hips", "abdomen": "Spine", "torso": "Chest", "neck": "Neck", "head": "Head",
    "left_clavicle": "LeftShoulder", "left_upper_arm": "LeftUpperArm", "left_forearm": "LeftLowerArm",
    "left_hand": "LeftHand", "right_clavicle": "RightShoulder", "right_upper_arm": "RightUpperArm",
    "right_forearm": "RightLowerArm", "right_hand": "RightHand", "left_thigh": "LeftUpperLeg",
    "left_shank": "LeftLowerLeg", "left_foot": "LeftFoot", "right_thigh": "RightUpperLeg",
    "right_shank": "RightLowerLeg", "right_foot": "RightFoot",
}
"""Model part -> Unity ``HumanBodyBones`` name (parts not listed are not sent)."""


class VmcFrames:
    """Turns pose records into VMC bone transforms for one body model.

    Parameters
    ----------
    model : BodyModel
        The model the records' ``params`` drive.
    """

    def __init__(self, model) -> None:
        self.model = model
        self.parts = [p for p, name in enumerate(model.part_names) if name in UNITY_BONES]
        if not self.parts or self.parts[0] != 0:
            raise ValueError(f"model {model.name!r}: its root part must map to a Unity bone (Hips)")
        mapped = set(self.parts)
        anc = np.full(model.n_parts, -1)
        for p in range(1, model.n_parts):
            a = int(model.parent[p])
            while a >= 0 and a not in mapped:
                a = int(model.parent[a])
            anc[p] = a
        self.ancestor = anc
        self.names = [UNITY_BONES[model.part_names[p]] for p in self.parts]
        rest = joint_frames(model, model.zero()[None], AXES_UNITY)
        # T-pose origins in Unity axes: the root's, plus the chain of rest offsets
        origin = np.zeros((model.n_parts, 3))
        for p in range(model.n_parts):
            par = int(model.parent[p])
            origin[p] = rest.rest_offset[p] + (origin[par] if par >= 0 else 0.0)
        self.rest_position = np.array([origin[p] - origin[anc[p]] if anc[p] >= 0 else origin[p] for p in self.parts])

    def bones(self, params, pelvis=None) -> tuple[list[str], np.ndarray, np.ndarray]:
        """Unity bone names, positions (n_bones, 3) metres and local rotations (n_bones, 4) ``(x, y, z, w)``.

        Parameters
        ----------
        params : array_like, shape (n_params,)
        pelvis : array_like, shape (3,), optional
            The record's pelvis joint centre (tracker world, metres); default: the root part's origin.
        """
        from scipy.spatial.transform import Rotation

        jf = joint_frames(self.model, np.asarray(params, float)[None], AXES_UNITY)
        W = jf.world[0]
        idx = np.array(self.parts)
        anc = self.ancestor[idx]
        local = W[idx].copy()
        has = anc >= 0
        local[has] = np.swapaxes(W[anc[has]], -1, -2) @ W[idx[has]]
        quat = Rotation.from_matrix(local).as_quat()  # (x, y, z, w)
        pos = self.rest_position.copy()
        pos[0] = AXES_UNITY @ np.asarray(pelvis, float) if pelvis is not None else jf.root_position[0]
        return self.names, pos, quat


class VmcSender:
    """Sends pose records to a VMC Marionette at ``host:port`` (UDP)."""

    def __init__(self, host: str, port: int, model) -> None:
        try:
            from pythonosc.udp_client import SimpleUDPClient
        except ImportError:
            raise RuntimeError(INSTALL_HINT) from None
        self.client = SimpleUDPClient(host, int(port))
        self.frames = VmcFrames(model)
        self.sent = self.lost = 0

    def send(self, rec: PoseRecord, t_s: float, *, params=None, pelvis=None) -> None:
        """Send one record (``params``/``pelvis``: smoothed values to use instead of the record's)."""
        from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
        from pythonosc.osc_message_builder import OscMessageBuilder

        def msg(address: str, *args) -> object:
            b = OscMessageBuilder(address=address)
            for a in args:
                b.add_arg(a)
            return b.build()

        params = params if params is not None else rec.get("params")
        bundle = OscBundleBuilder(IMMEDIATELY)
        ok = bool(rec.ok and params is not None and len(params) == self.frames.model.n_params)
        bundle.add_content(msg("/VMC/Ext/OK", 1, 3, 0, 1 if ok else 0))
        bundle.add_content(msg("/VMC/Ext/T", float(t_s)))
        if ok:
            if pelvis is None:
                pelvis = (rec.get("joints") or {}).get("pelvis")
            names, pos, quat = self.frames.bones(params, pelvis)
            bundle.add_content(msg("/VMC/Ext/Root/Pos", "root", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0))
            for name, p, q in zip(names, pos.tolist(), quat.tolist()):
                bundle.add_content(msg("/VMC/Ext/Bone/Pos", name, *p, *q))
            self.sent += 1
        else:
            self.lost += 1
        self.client.send(bundle.build())


def run_bridge(poses, sender_for, *, smoother=None) -> VmcSender | None:
    """Send ``poses`` (``(record, take_time_s)`` pairs) as VMC; returns the sender (counts) or None if
    no pose came.

    Parameters
    ----------
    sender_for : callable
        ``sender_for(record) -> VmcSender`` for the first record that names a model (or is ok).
    smoother : RecordSmoother, optional
        Smooths params and the pelvis before sending (the records are not changed).
    """
    sender = None
    for rec, t in poses:
        if sender is None:
            if not rec.ok and rec.get("model") is None:
                continue
            sender = sender_for(rec)
        joints, params = smoother.update(rec) if smoother is not None else (None, None)
        sender.send(rec, t, params=params, pelvis=joints.get("pelvis") if joints else None)
    return sender
