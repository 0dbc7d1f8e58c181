"""Synthetic people that are not the tracker's body model: an independent test renderer.

The tracker fits truncated elliptical cones (``tracker.body.model``) and its own synthetic sessions are
rendered from those cones (``tracker.imaging.render``); a tracker judged only on them is judged on the
body it assumes.  This module draws a different body, driven directly by a BVH skeleton's joint
positions (``tracker.synthetic.bvh``), and uses neither the cone model nor its renderer:

- **Subject** (``make_subject``): per-segment proportions ``scale`` (BVH offsets of thigh, shank,
  foot, upper arm, forearm, hand, spine, neck, head, hip width and shoulder width each × U(0.85,
  1.15), and the whole body × U(1.0, 1.2): 1.5–1.9 m tall), limb and torso radii × U(0.75, 1.25) per kind,
  colours (skin, hair, shirt, trousers, shoes; shoes light or dark), short or long sleeves.
- **Body** (``body_primitives``): capsules (neck, upper arms, forearms, thighs, shanks, feet from
  heel to toe, pointing forward) and ellipsoids (a flattened chest and a flattened pelvis/abdomen,
  the head with hair over its top and back, flat hands), all placed from joint positions and
  orientations of the scaled skeleton (``subject_motion``) in the world frame: metres, Z up,
  floor z = 0 (a BVH's Y-up frame rotated by ``BVH_TO_WORLD``).  A hand points from the wrist along
  the BVH's wrist -> ``*Fingers_End`` direction; its length (wrist to fingertips) is anthropometric,
  ``HAND_LENGTH_H`` (Drillis & Contini's table as Winter gives it) × the subject's standing height ×
  its ``hand`` scale, because CMU skeletons' finger end sites stop at about half a hand.  The feet
  are put on the floor every frame (the lowest sole point at z = 0) unless ``ground="clip"``.
- **Ground truth** (``SubjectMotion.joints``): the contourcap joint centres (``JOINT_NAMES``) from
  the scaled skeleton's joints: pelvis = midpoint of the hip joints, spine = ``Chest``, neck =
  ``Neck``, head = midpoint of ``Head`` and its end site, shoulder, elbow, wrist, hip, knee, ankle
  = the CMU joints of those names (the same correspondence ``tracker.synthetic.retarget`` uses).
- **Studio** (``Studio``): N calibrated cameras (``capture.camera.Camera``), the textured room of
  ``tracker.synthetic.scene`` (floor light or dark), one directional light.  Per camera and frame every
  pixel of the body's image box is ray-cast against all primitives (vectorised: pixels ×
  primitives), shaded by a Lambert term; floor pixels near the body cast a ray to the light, and
  the hard shadow is blurred (soft shadow) and darkens the floor.  ``camera_output`` adds Gaussian
  sensor noise and JPEG compression (``cv2.imencode`` in memory, what an MJPG camera delivers).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from capture.camera import Camera
from tracker.synthetic.bvh import Bvh, bvh_forward
from tracker.synthetic.scene import RoomTexture, make_room_texture, render_background
from tracker.synthetic.motions import BVH_TO_WORLD, motion_to_bvh, standing_track

__all__ = ["JOINT_NAMES", "SEGMENTS", "Subject", "make_subject", "subject_skeleton", "SubjectMotion",
           "subject_motion", "Primitives", "body_primitives", "subject_height", "Studio", "joint_truth",
           "MATERIALS", "box_hits", "HAND_LENGTH_H"]

#: contourcap joint names (DESIGN.md pose record), the order of ``SubjectMotion.joints``
JOINT_NAMES = (
    "pelvis", "spine", "neck", "head",
    "left_shoulder", "left_elbow", "left_wrist", "right_shoulder", "right_elbow", "right_wrist",
    "left_hip", "left_knee", "left_ankle", "right_hip", "right_knee", "right_ankle",
)  # fmt: skip

_TRUTH = {
    "pelvis": ("LeftHip", "RightHip"), "spine": ("Chest",), "neck": ("Neck",), "head": ("Head", "Head_End"),
    "left_shoulder": ("LeftShoulder",), "left_elbow": ("LeftElbow",), "left_wrist": ("LeftWrist",),
    "right_shoulder": ("RightShoulder",), "right_elbow": ("RightElbow",), "right_wrist": ("RightWrist",),
    "left_hip": ("LeftHip",), "left_knee": ("LeftKnee",), "left_ankle": ("LeftAnkle",),
    "right_hip": ("RightHip",), "right_knee": ("RightKnee",), "right_ankle": ("RightAnkle",),
}  # fmt: skip

#: segment -> CMU joints whose OFFSET (the bone from their parent) the segment's scale multiplies
SEGMENTS = {
    "hip_width": ("LeftHip", "RightHip"), "thigh": ("LeftKnee", "RightKnee"),
    "shank": ("LeftAnkle", "RightAnkle"), "foot": ("LeftToe", "RightToe", "LeftToe_End", "RightToe_End"),
    "spine": ("Chest", "Chest2"), "neck": ("Neck",), "head": ("Head", "Head_End"),
    "shoulder_width": ("LeftShoulder", "RightShoulder"), "upper_arm": ("LeftElbow", "RightElbow"),
    "forearm": ("LeftWrist", "RightWrist"),
    "hand": ("LFingers", "LFingers_End", "RFingers", "RFingers_End", "LThumb_End", "RThumb_End"),
}  # fmt: skip

#: wrist to middle fingertip as a fraction of standing height (Drillis & Contini; Winter's anthropometric table)
HAND_LENGTH_H = 0.108

#: nominal radii at scale 1, metres (each × U(0.75, 1.25) per subject)
_RADII = {"upper_arm": 0.046, "forearm": 0.037, "thigh": 0.074, "shank": 0.050, "neck": 0.050, "foot": 0.040,
          "torso_width": 0.150, "torso_depth": 0.105, "hand": 0.045}  # fmt: skip

#: material index -> name (the columns of ``Subject.colours``)
MATERIALS = ("skin", "hair", "shirt", "trousers", "shoes")

_SKIN = [(196, 214, 245), (160, 190, 230), (120, 160, 210), (80, 120, 170), (55, 85, 125), (40, 60, 95)]  # BGR
_HAIR = [(20, 20, 25), (30, 45, 70), (60, 110, 160), (150, 150, 155), (25, 35, 110)]
_SHIRT = [(40, 40, 200), (200, 120, 40), (60, 170, 60), (235, 235, 235), (35, 35, 40), (150, 150, 150),
          (40, 160, 220), (130, 60, 120)]  # fmt: skip
_TROUSERS = [(120, 70, 40), (35, 35, 40), (90, 140, 160), (110, 110, 110), (60, 60, 90)]
_SHOES_DARK = [(25, 25, 28), (30, 35, 45), (40, 40, 40)]
_SHOES_LIGHT = [(235, 235, 235), (170, 200, 215), (200, 200, 200)]


@dataclass(frozen=True)
class Subject:
    """One synthetic person.

    Attributes
    ----------
    seed : int
    scale : dict of str -> float
        Per-segment factor on the BVH offsets (``SEGMENTS``) and ``"body"`` (all lengths).
    radius : dict of str -> float
        Radii in metres (``upper_arm``, ``forearm``, ``thigh``, ``shank``, ``neck``, ``foot``,
        ``hand``) and the torso's half width and half depth (``torso_width``, ``torso_depth``).
    colours : ndarray, shape (5, 3) uint8
        BGR per material (``MATERIALS``).
    long_sleeves : bool
    dark_shoes : bool
    """

    seed: int
    scale: dict
    radius: dict
    colours: np.ndarray = field(repr=False)
    long_sleeves: bool
    dark_shoes: bool


def make_subject(seed: int, *, dark_shoes: bool | None = None) -> Subject:
    """A seeded random subject (see the module docstring); ``dark_shoes`` None: drawn too."""
    rng = np.random.default_rng(int(seed))
    body = float(rng.uniform(1.0, 1.2))
    scale = {k: float(rng.uniform(0.85, 1.15)) for k in SEGMENTS}
    scale["body"] = body
    radius = {k: float(v * body * rng.uniform(0.75, 1.25)) for k, v in _RADII.items()}
    dark = bool(rng.random() < 0.5) if dark_shoes is None else bool(dark_shoes)
    pick = lambda table: table[int(rng.integers(len(table)))]  # noqa: E731
    colours = np.array([pick(_SKIN), pick(_HAIR), pick(_SHIRT), pick(_TROUSERS),
                        pick(_SHOES_DARK if dark else _SHOES_LIGHT)], dtype=np.uint8)  # fmt: skip
    return Subject(int(seed), scale, radius, colours, bool(rng.random() < 0.5), dark)


def subject_skeleton(skeleton: Bvh, subject: Subject) -> Bvh:
    """``skeleton`` with every offset scaled by the subject's segment factors and body scale."""
    off = skeleton.offset * subject.scale["body"]
    for seg, joints in SEGMENTS.items():
        for j in joints:
            if j in skeleton.names:
                off[skeleton.index(j)] *= subject.scale[seg]
    return Bvh(skeleton.names, skeleton.parent, off, skeleton.channels, skeleton.channel_start, skeleton.motion,
               skeleton.frame_time_s, skeleton.source)


@dataclass(frozen=True, eq=False)
class SubjectMotion:
    """A subject's skeleton moving in the world (metres, Z up, floor z = 0).

    Attributes
    ----------
    positions : ndarray, shape (n_frames, n_joints, 3)
        BVH joint origins.
    rotations : ndarray, shape (n_frames, n_joints, 3, 3)
        joint2world rotations (world frame).
    names : tuple of str
        BVH joint names.
    joints : ndarray, shape (n_frames, 16, 3)
        Ground-truth joint centres in ``JOINT_NAMES`` order.
    fps : float
    height_m : float
        The subject's standing height on this skeleton (``subject_height``), metres.
    """

    positions: np.ndarray
    rotations: np.ndarray
    names: tuple
    joints: np.ndarray
    fps: float
    height_m: float

    def joint(self, name: str) -> np.ndarray:
        """BVH joint ``name``'s positions, shape (n_frames, 3)."""
        return self.positions[:, self.names.index(name)]

    @property
    def n_frames(self) -> int:
        return self.positions.shape[0]


def joint_truth(positions: np.ndarray, names) -> np.ndarray:
    """Contourcap joint centres (n, 16, 3) from CMU BVH joint positions (n, n_joints, 3)."""
    names = tuple(names)
    try:
        cols = [[names.index(j) for j in _TRUTH[k]] for k in JOINT_NAMES]
    except ValueError as exc:
        raise ValueError(f"not a CMU skeleton: {exc}") from None
    return np.stack([positions[:, c].mean(axis=1) for c in cols], axis=1)


def subject_motion(motion: Bvh, subject: Subject, *, ground: str = "frame") -> SubjectMotion:
    """Forward kinematics of ``motion`` on the subject's scaled skeleton, placed in the world.

    The root's horizontal path is scaled about its mean by the legs' scale (strides follow leg
    length); vertically the body is shifted so that its lowest sole point touches z = 0 in every
    frame (``ground="frame"``) or over the clip (``"clip"``: airborne frames stay airborne).
    """
    if ground not in ("frame", "clip"):
        raise ValueError(f"ground must be 'frame' or 'clip', got {ground!r}")
    P, R = _placed(motion, subject, ground)
    Ps, Rs = _placed(motion_to_bvh(standing_track(1), motion), subject, "frame")
    c, axes, rad = _head_ellipsoid(Ps, Rs, tuple(motion.names))
    height = float(c[0, 2] + np.sqrt(np.sum((axes[0, :, 2] * np.asarray(rad)) ** 2)))
    return SubjectMotion(P, R, tuple(motion.names), joint_truth(P, motion.names), motion.fps, height)


def _placed(motion: Bvh, subject: Subject, ground: str) -> tuple[np.ndarray, np.ndarray]:
    """World joint positions (n, n_joints, 3) and rotations (n, n_joints, 3, 3) of ``subject_motion``."""
    skel = subject_skeleton(motion, subject)
    P, R = bvh_forward(skel)
    W = BVH_TO_WORLD
    P = P @ W.T
    R = np.einsum("ij,fnjk,lk->fnil", W, R, W)
    legs = 0.5 * (subject.scale["thigh"] + subject.scale["shank"])
    root = P[:, 0, :2]
    shift_xy = (root - root.mean(axis=0)) * (legs - 1.0)
    P[..., :2] += shift_xy[:, None, :]
    sole = _sole_height(P, R, tuple(motion.names), subject)
    dz = -sole if ground == "frame" else np.full(sole.shape, -sole.min())
    P[..., 2] += dz[:, None]
    return P, R


def _head_ellipsoid(P: np.ndarray, R: np.ndarray, names: tuple) -> tuple:
    """Head ellipsoid along ``Head`` -> ``Head_End``: centres (n, 3), axes (n, 3, 3), semi-axes (3,)."""
    head, end = P[:, names.index("Head")], P[:, names.index("Head_End")]
    hvec = end - head
    hlen = np.linalg.norm(hvec, axis=1).mean()
    axes = _frame_axes(hvec, R[:, names.index("Head"), :, 1])  # world +Y of the head frame = BVH +X = left
    return head + 0.55 * hvec + 0.1 * hlen * axes[:, 0], axes, (1.05 * hlen, 0.88 * hlen, 1.25 * hlen)


def _foot_ends(P, names, side: str, subject: Subject):
    """Heel and toe ends of a foot capsule, each (n, 3)."""
    ankle, toe, end = (P[:, names.index(f"{side}{j}")] for j in ("Ankle", "Toe", "Toe_End"))
    fwd = toe - ankle
    fwd[:, 2] = 0.0
    fwd /= np.maximum(np.linalg.norm(fwd, axis=1, keepdims=True), 1e-9)
    r = subject.radius["foot"]
    heel = ankle - fwd * (0.9 * r) + np.array([0.0, 0.0, -0.75 * r])
    tip = 0.5 * (toe + end) + np.array([0.0, 0.0, -0.2 * r])
    return heel, tip


def _sole_height(P, R, names, subject) -> np.ndarray:
    r = subject.radius["foot"]
    z = [np.minimum(a[:, 2], b[:, 2]) - r for a, b in (_foot_ends(P, names, s, subject) for s in ("Left", "Right"))]
    return np.minimum(*z)


@dataclass(frozen=True, eq=False)
class Primitives:
    """The body's geometry in every frame (world frame, metres).

    Attributes
    ----------
    cap_a, cap_b : ndarray, shape (n_frames, n_caps, 3)
        Capsule axis ends.
    cap_r : ndarray, shape (n_caps,)
    cap_mat : ndarray of int, shape (n_caps,)
        Material index (``MATERIALS``).
    ell_c : ndarray, shape (n_frames, n_ell, 3)
        Ellipsoid centres.
    ell_axes : ndarray, shape (n_frames, n_ell, 3, 3)
        Rows: unit axes (forward, left, up for the body parts) in the world.
    ell_r : ndarray, shape (n_ell, 3)
        Semi-axes along those rows.
    ell_mat : ndarray of int, shape (n_ell,)
    head : int
        Index of the head ellipsoid (hair over its top and back).
    colours : ndarray, shape (5, 3) uint8
        BGR per material (the subject's ``colours``).
    """

    cap_a: np.ndarray
    cap_b: np.ndarray
    cap_r: np.ndarray
    cap_mat: np.ndarray
    ell_c: np.ndarray
    ell_axes: np.ndarray
    ell_r: np.ndarray
    ell_mat: np.ndarray
    head: int
    colours: np.ndarray

    @property
    def n_frames(self) -> int:
        return self.cap_a.shape[0]

    def spheres(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """Two spheres per primitive (capsules, then ellipsoids) that hold it in ``frame``:
        centres (n_prim, 2, 3) and radii (n_prim, 2)."""
        ell = np.repeat(self.ell_c[frame][:, None], 2, axis=1)
        pts = np.concatenate([np.stack([self.cap_a[frame], self.cap_b[frame]], axis=1), ell])
        rad = np.concatenate([self.cap_r, self.ell_r.max(axis=1)])
        return pts, np.repeat(rad[:, None], 2, axis=1)


def _frame_axes(up: np.ndarray, side: np.ndarray) -> np.ndarray:
    """Rows (forward, left, up) from an up direction and a left-pointing side vector, (n, 3, 3)."""
    up = up / np.linalg.norm(up, axis=-1, keepdims=True)
    left = side - np.sum(side * up, axis=-1, keepdims=True) * up
    left /= np.maximum(np.linalg.norm(left, axis=-1, keepdims=True), 1e-9)
    fwd = np.cross(left, up)
    return np.stack([fwd, left, up], axis=1)


def body_primitives(sm: SubjectMotion, subject: Subject) -> Primitives:
    """Capsules and ellipsoids of ``subject`` in every frame of ``sm`` (see the module docstring)."""
    J = sm.joint
    r = subject.radius
    S = subject.scale
    body = S["body"]
    sleeve = 2 if subject.long_sleeves else 0
    caps = []  # (a, b, radius, material)
    up_chest = J("Neck") - J("Chest")
    neck_base = J("Chest2") + 0.35 * (J("Neck") - J("Chest2"))
    caps.append((neck_base, J("Head"), r["neck"], 0))
    for s, L in (("left", "Left"), ("right", "Right")):
        caps.append((J(f"{L}Shoulder"), J(f"{L}Elbow"), r["upper_arm"], 2))
        caps.append((J(f"{L}Elbow"), J(f"{L}Wrist"), r["forearm"], sleeve))
        caps.append((J(f"{L}Hip"), J(f"{L}Knee"), r["thigh"], 3))
        caps.append((J(f"{L}Knee"), J(f"{L}Ankle"), r["shank"], 3))
        heel, tip = _foot_ends(sm.positions, sm.names, L, subject)
        caps.append((heel, tip, r["foot"], 4))
    ells = []  # (centre, axes, radii, material)
    # chest: from Chest up past the shoulders, wide and flat
    lat = J("LeftShoulder") - J("RightShoulder")
    half_sh = 0.5 * np.linalg.norm(lat, axis=1).mean()
    chest_axes = _frame_axes(up_chest, lat)
    chest_c = J("Chest2") + 0.25 * (J("Neck") - J("Chest2")) - 0.15 * r["torso_depth"] * chest_axes[:, 0]
    chest_h = 0.5 * np.linalg.norm(J("Neck") - J("Chest"), axis=1).mean() + 0.04 * body
    ells.append((chest_c, chest_axes, (r["torso_depth"], max(r["torso_width"], 0.8 * half_sh), chest_h), 2))
    # pelvis / abdomen: from below the hip joints to Chest
    hips = 0.5 * (J("LeftHip") + J("RightHip"))
    pel_axes = _frame_axes(J("Chest") - hips, J("LeftHip") - J("RightHip"))
    half_hip = 0.5 * np.linalg.norm(J("LeftHip") - J("RightHip"), axis=1).mean()
    pel_c = 0.5 * (hips + J("Chest"))
    pel_h = 0.5 * np.linalg.norm(J("Chest") - hips, axis=1).mean() + 0.07 * body
    ells.append((pel_c, pel_axes, (0.95 * r["torso_depth"], max(0.9 * r["torso_width"], half_hip + 0.6 * r["thigh"]),
                                   pel_h), 3))  # fmt: skip
    # head: along Head -> Head_End, facing the Head joint's forward (BVH +Z -> world +X)
    ells.append((*_head_ellipsoid(sm.positions, sm.rotations, sm.names), 0))
    head = len(ells) - 1
    # hands: from 1 cm behind the wrist to the fingertips, HAND_LENGTH_H of the height along wrist -> finger end
    hand_len = HAND_LENGTH_H * sm.height_m * S["hand"]
    for L, F in (("Left", "LFingers"), ("Right", "RFingers")):
        a, b = J(f"{L}Wrist"), J(f"{F}_End")
        Rw = sm.rotations[:, sm.names.index(f"{L}Wrist")]
        ax = _frame_axes(b - a, Rw[:, :, 1])  # rows: (across the palm, lateral, along the hand)
        half = 0.5 * (hand_len + 0.01)
        ells.append((a + (half - 0.01) * ax[:, 2], ax, (0.45 * r["hand"], r["hand"], half), 0))
    return Primitives(
        cap_a=np.stack([c[0] for c in caps], axis=1), cap_b=np.stack([c[1] for c in caps], axis=1),
        cap_r=np.array([c[2] for c in caps], float), cap_mat=np.array([c[3] for c in caps], int),
        ell_c=np.stack([e[0] for e in ells], axis=1), ell_axes=np.stack([e[1] for e in ells], axis=1),
        ell_r=np.array([e[2] for e in ells], float), ell_mat=np.array([e[3] for e in ells], int), head=head,
        colours=np.asarray(subject.colours, np.uint8),
    )


def subject_height(skeleton: Bvh, subject: Subject) -> float:
    """Standing height (m): the top of the head above the floor, feet flat, arms down."""
    return subject_motion(motion_to_bvh(standing_track(1), skeleton), subject).height_m


# --------------------------------------------------------------------------- ray casting


def box_hits(origin: np.ndarray, rays: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameter of the first hit of rays ``origin + t d`` (``rays`` (..., 3) unit) with the box
    ``lo``-``hi`` ((...) inf: missed, or the origin inside) and the outward face normal there (..., 3)."""
    d = np.where(np.abs(rays) < 1e-12, 1e-12, rays)
    t1, t2 = (lo - origin) / d, (hi - origin) / d
    tmin, tmax = np.minimum(t1, t2), np.maximum(t1, t2)
    t_in, t_out = tmin.max(axis=-1), tmax.min(axis=-1)
    hit = (t_in <= t_out) & (t_in > 0)
    axis = np.argmax(tmin, axis=-1)
    normal = np.zeros(rays.shape)
    np.put_along_axis(normal, axis[..., None], -np.sign(np.take_along_axis(d, axis[..., None], axis=-1)), axis=-1)
    return np.where(hit, t_in, np.inf), normal


def _sphere_t(o, d, od, oo, c, r):
    """Nearest positive ray-sphere parameter (n, m); inf on a miss.

    o, d : (n|1, 3) ray origins and unit directions; od = o·d (n|1,), oo = |o|² (n|1,);
    c : (m, 3) centres; r : (m,) radii.
    """
    b = od[:, None] - d @ c.T
    h = b * b - (oo[:, None] - 2.0 * (o @ c.T) + np.sum(c * c, axis=1) - r * r)
    with np.errstate(invalid="ignore"):
        t = -b - np.sqrt(h)
    return np.where((h >= 0) & (t > 1e-6), t, np.inf)


def _capsule_t(o, d, a, b, r):
    """Nearest positive ray-capsule parameter (n, m); o, d (n|1, 3) with |d| = 1; a, b (m, 3); r (m,).

    The capsule is the union of a cylinder over the axis segment and two end spheres; the first
    hit of the union is the smallest of the three."""
    o, d = np.atleast_2d(o), np.atleast_2d(d)
    ba = b - a
    baba = np.sum(ba * ba, axis=1)
    od, oo = np.sum(o * d, axis=1), np.sum(o * o, axis=1)
    bard = d @ ba.T
    baoa = o @ ba.T - np.sum(a * ba, axis=1)
    rdoa = od[:, None] - d @ a.T
    oaoa = oo[:, None] - 2.0 * (o @ a.T) + np.sum(a * a, axis=1)
    A = baba - bard * bard
    B = baba * rdoa - baoa * bard
    C = baba * oaoa - baoa * baoa - r * r * baba
    h = B * B - A * C
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (-B - np.sqrt(h)) / A
    y = baoa + t * bard
    body = (h >= 0) & (A > 1e-12) & (y > 0) & (y < baba) & (t > 1e-6)
    t = np.where(body, t, np.inf)
    return np.minimum(t, np.minimum(_sphere_t(o, d, od, oo, a, r), _sphere_t(o, d, od, oo, b, r)))


def _ellipsoid_t(o, d, c, axes, rad):
    """Nearest positive ray-ellipsoid parameter (n, m) and the unit-sphere coordinates of the hit
    (n, m, 3); o, d (n|1, 3); c (m, 3); axes (m, 3, 3) rows; rad (m, 3)."""
    o, d = np.atleast_2d(o), np.atleast_2d(d)
    m = c.shape[0]
    M = (axes / rad[:, :, None]).reshape(3 * m, 3)  # world -> unit sphere, stacked
    op = (o @ M.T - np.sum(M * np.repeat(c, 3, axis=0), axis=1)).reshape(-1, m, 3)
    dp = (d @ M.T).reshape(-1, m, 3)
    aa = dp[..., 0] ** 2 + dp[..., 1] ** 2 + dp[..., 2] ** 2
    bb = op[..., 0] * dp[..., 0] + op[..., 1] * dp[..., 1] + op[..., 2] * dp[..., 2]
    cc = op[..., 0] ** 2 + op[..., 1] ** 2 + op[..., 2] ** 2 - 1.0
    h = bb * bb - aa * cc
    with np.errstate(invalid="ignore"):
        t = (-bb - np.sqrt(h)) / aa
    t = np.where((h >= 0) & (t > 1e-6), t, np.inf)
    return t, op + np.where(np.isfinite(t), t, 0.0)[..., None] * dp


class Studio:
    """Cameras, room and light: renders ``Primitives`` into camera images.

    Parameters
    ----------
    cameras : sequence of Camera
    seed : int
        Room texture (``tracker.synthetic.scene.make_room_texture``) and light direction.
    dark_floor : bool
        Floor texture darkened to 0.4 of its brightness (dark shoes on a dark floor).
    shadow_strength : float
        Fraction of the floor's brightness removed in full shadow.
    shadow_blur_px : float
        Gaussian sigma of the shadow's penumbra, pixels.
    noise : float
        Sensor noise, grey levels (standard deviation per pixel and channel).
    jpeg_quality : int
        JPEG quality of ``camera_output`` (1–100).
    """

    def __init__(self, cameras, *, seed: int = 0, dark_floor: bool = False, shadow_strength: float = 0.45,
                 shadow_blur_px: float = 1.5, noise: float = 2.0, jpeg_quality: int = 85) -> None:
        self.cameras = list(cameras)
        if not self.cameras or not all(isinstance(c, Camera) for c in self.cameras):
            raise ValueError("cameras: expected a non-empty sequence of Camera")
        if not 1 <= int(jpeg_quality) <= 100:
            raise ValueError(f"jpeg_quality must be in 1..100, got {jpeg_quality}")
        if noise < 0 or not 0 <= shadow_strength <= 1:
            raise ValueError("noise must be >= 0 and shadow_strength in [0, 1]")
        rng = np.random.default_rng(int(seed))
        reach = max(np.linalg.norm(c.center[:2]) for c in self.cameras)
        tex = make_room_texture(int(seed), wall_radius_m=max(7.0, reach + 2.0), extent_m=max(8.0, reach + 3.0))
        if dark_floor:
            tex = RoomTexture((tex.floor.astype(np.float32) * 0.4).astype(np.uint8), tex.wall, tex.extent_m,
                              tex.wall_radius_m, tex.wall_height_m)
        az = rng.uniform(-np.pi, np.pi)
        self.light = np.array([0.45 * np.cos(az), 0.45 * np.sin(az), 1.0])
        self.light /= np.linalg.norm(self.light)
        self.shadow_strength = float(shadow_strength)
        self.shadow_blur_px = float(shadow_blur_px)
        self.noise = float(noise)
        self.jpeg_quality = int(jpeg_quality)
        self.backgrounds, self._floor, self._rays = [], [], []
        for cam in self.cameras:
            bg, floor = render_background(cam, tex, with_floor_mask=True)
            w, h = cam.size
            u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
            self.backgrounds.append(bg)
            self._floor.append(floor)
            self._rays.append(cam.rays(np.stack([u.ravel(), v.ravel()], axis=-1)).reshape(h, w, 3))

    def _boxes(self, k: int, pts: np.ndarray, rad: np.ndarray) -> list:
        """Image boxes (rows, cols) of camera ``k`` holding groups of spheres, or None where a
        group is outside the image; pts (g, s, 3) centres, rad (g, s) radii of g groups."""
        cam = self.cameras[k]
        w, h = cam.size
        flat = pts.reshape(-1, 3)
        depth = cam.depth(flat).reshape(rad.shape)
        uv = cam.project(flat).reshape(rad.shape + (2,))
        pad = cam.matrix[0, 0] * rad / np.maximum(depth, 1e-6) + 3.0
        x0 = np.floor((uv[..., 0] - pad).min(axis=1)).clip(0, w).astype(int)
        x1 = (np.ceil((uv[..., 0] + pad).max(axis=1)) + 1).clip(0, w).astype(int)
        y0 = np.floor((uv[..., 1] - pad).min(axis=1)).clip(0, h).astype(int)
        y1 = (np.ceil((uv[..., 1] + pad).max(axis=1)) + 1).clip(0, h).astype(int)
        behind = (depth <= 0.05).any(axis=1)
        out = []
        for g in range(rad.shape[0]):
            if behind[g]:
                out.append((slice(0, h), slice(0, w)))
            elif x1[g] <= x0[g] or y1[g] <= y0[g]:
                out.append(None)
            else:
                out.append((slice(int(y0[g]), int(y1[g])), slice(int(x0[g]), int(x1[g]))))
        return out

    def _prim_t(self, i: int, o: np.ndarray, d: np.ndarray, prim: Primitives, frame: int) -> np.ndarray:
        """Ray parameters (n,) of primitive ``i`` (capsules first, then ellipsoids); inf on a miss."""
        nc = prim.cap_r.size
        if i < nc:
            return _capsule_t(o, d, prim.cap_a[frame, i:i + 1], prim.cap_b[frame, i:i + 1], prim.cap_r[i:i + 1])[:, 0]
        e = slice(i - nc, i - nc + 1)
        return _ellipsoid_t(o, d, prim.ell_c[frame, e], prim.ell_axes[frame, e], prim.ell_r[e])[0][:, 0]

    def _depth_buffer(self, k: int, prim: Primitives, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """Nearest body hit per pixel of camera ``k``: ray parameter (h, w) (inf: no body) and the
        primitive index (h, w) (-1: none).  Each primitive is cast only over its own image box."""
        cam = self.cameras[k]
        w, h = cam.size
        t_best = np.full((h, w), np.inf)
        which = np.full((h, w), -1, int)
        centre = cam.center[None]
        pts, rad = prim.spheres(frame)
        for i, box in enumerate(self._boxes(k, pts, rad)):
            if box is None:
                continue
            rays = self._rays[k][box]
            t = self._prim_t(i, centre, rays.reshape(-1, 3), prim, frame).reshape(rays.shape[:2])
            closer = t < t_best[box]
            t_best[box] = np.where(closer, t, t_best[box])
            which[box] = np.where(closer, i, which[box])
        return t_best, which

    def _shadow(self, k: int, prim: Primitives, frame: int) -> np.ndarray:
        """Soft shadow (h, w) in [0, 1] of camera ``k``: the floor point of every second pixel casts
        a ray to the light (per primitive, over the image box of its shadow), the hard result is
        upsampled and blurred."""
        cam = self.cameras[k]
        w, h = cam.size
        rays = self._rays[k][::2, ::2]
        floor = self._floor[k][::2, ::2]
        hard = np.zeros(floor.shape, bool)
        L = self.light
        pts, rad = prim.spheres(frame)
        foot = pts - (pts[..., 2:3] / L[2]) * L  # the spheres pushed along the light onto the floor
        boxes = self._boxes(k, np.concatenate([pts, foot], axis=1), np.concatenate([rad, rad / L[2]], axis=1))
        for i, box in enumerate(boxes):
            if box is None:
                continue
            hb = slice(box[0].start // 2, (box[0].stop + 1) // 2), slice(box[1].start // 2, (box[1].stop + 1) // 2)
            sel = floor[hb] & ~hard[hb]
            if not np.any(sel):
                continue
            d = rays[hb][sel]
            pf = cam.center[None] + (-cam.center[2] / d[:, 2])[:, None] * d
            blocked = np.isfinite(self._prim_t(i, pf, L[None], prim, frame))
            sub = hard[hb]
            sub[sel] = blocked
            hard[hb] = sub
        soft = cv2.resize(hard.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
        if self.shadow_blur_px > 0:
            soft = cv2.GaussianBlur(soft, (0, 0), self.shadow_blur_px)
        return soft

    def render(self, prim: Primitives, frame: int, *, boxes=()) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Clean images (BGR uint8, one per camera) and true silhouettes ((h, w) bool) of ``frame``;
        ``boxes``: props drawn with the body, occluding it where nearer, each ``(lo (3,), hi (3,),
        BGR colour)`` an axis-aligned world box (metres), Lambert-shaded, no shadow (the
        silhouettes stay the body's)."""
        if not 0 <= frame < prim.n_frames:
            raise ValueError(f"frame {frame} outside 0..{prim.n_frames - 1}")
        images, masks = [], []
        for k, cam in enumerate(self.cameras):
            t, which = self._depth_buffer(k, prim, frame)
            hit = which >= 0
            gain = 1.0 - self.shadow_strength * self._shadow(k, prim, frame) * (self._floor[k] & ~hit)
            img = np.clip(np.rint(self.backgrounds[k] * gain[..., None]), 0, 255).astype(np.uint8)
            if np.any(hit):
                d = self._rays[k][hit]
                img[hit] = np.clip(np.rint(self._shade(cam, d, t[hit], which[hit], prim, frame)), 0, 255)
            for lo, hi, colour in boxes:
                tb, normal = box_hits(cam.center, self._rays[k], np.asarray(lo, float), np.asarray(hi, float))
                front = tb < t
                if np.any(front):
                    lam = np.clip(normal[front] @ self.light, 0.0, None)
                    img[front] = np.clip(np.rint(np.asarray(colour, np.float32)[None] * (0.55 + 0.45 * lam)[:, None]),
                                         0, 255)
            images.append(img)
            masks.append(hit)
        return images, masks

    def _shade(self, cam, d, t, idx, prim: Primitives, frame: int) -> np.ndarray:
        """Lambert-shaded BGR colours (n, 3) of rays d (n, 3) hitting primitives idx (n,) at t (n,)."""
        nc = prim.cap_r.size
        p = cam.center[None] + t[:, None] * d
        normal = np.zeros_like(p)
        mat = np.zeros(idx.size, int)
        cap = idx < nc
        if np.any(cap):
            ci = idx[cap]
            a, b = prim.cap_a[frame, ci], prim.cap_b[frame, ci]
            ba = b - a
            s = np.clip(np.sum((p[cap] - a) * ba, axis=1) / np.maximum(np.sum(ba * ba, axis=1), 1e-12), 0, 1)
            normal[cap] = p[cap] - (a + s[:, None] * ba)
            mat[cap] = prim.cap_mat[ci]
        ell = ~cap
        if np.any(ell):
            ei = idx[ell] - nc
            ax, rad = prim.ell_axes[frame, ei], prim.ell_r[ei]
            # unit-sphere coordinates (forward, left, up) of the hit
            qq = np.einsum("nij,nj->ni", ax, p[ell] - prim.ell_c[frame, ei]) / rad
            normal[ell] = np.einsum("nij,ni->nj", ax, qq / rad)
            m = prim.ell_mat[ei].copy()
            hair = (ei == prim.head) & ((qq[:, 2] > 0.35) | ((qq[:, 0] < -0.1) & (qq[:, 2] > -0.55)))
            m[hair] = 1
            mat[ell] = m
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        lam = np.clip(normal @ self.light, 0.0, None)
        facing = np.clip(-np.sum(normal * d, axis=1), 0.0, 1.0)  # darker towards the outline
        gain = (0.55 + 0.45 * lam) * (0.82 + 0.18 * facing)
        return prim.colours[mat].astype(np.float32) * gain[:, None]

    def camera_output(self, image: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, bytes]:
        """What the camera delivers: ``image`` + sensor noise, JPEG-compressed; returns the decoded
        image (BGR uint8) and the JPEG bytes."""
        noisy = image.astype(np.float32)
        if self.noise > 0:
            noisy += rng.standard_normal(image.shape, dtype=np.float32) * np.float32(self.noise)
        noisy = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
        ok, buf = cv2.imencode(".jpg", noisy, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise RuntimeError("cv2.imencode failed to encode a JPEG")
        data = buf.tobytes()
        return cv2.imdecode(buf, cv2.IMREAD_COLOR), data
