"""Procedural motions on the CMU skeleton, for poses no bundled clip holds.

A motion is described per frame by where the body is (the ``Hips`` joint in the world: metres,
Z up, floor z = 0), which way it faces (``heading``, radians about +Z; 0 faces +X, the direction
a CMU subject facing BVH +Z faces after ``BVH_TO_WORLD``) and the world direction of each bone in
the body's heading frame (x forward, y to the subject's left, z up).  ``motion_to_bvh`` turns
that into channel values on the hierarchy of a CMU BVH (``tracker/data/scaled_131_01.bvh``):
every joint that drives a bone gets the smallest rotation that points the bone along its
direction (its twist is inherited from its parent), every other joint keeps its parent's
orientation.  The result is an ordinary ``tracker.synthetic.bvh.Bvh``, so the renderer and the ground
truth read it exactly as they read a recorded clip.

Clips (``MOTIONS``, each ``make(name, skeleton, frames=, fps=, rng=)``):

- ``walk_turn``: walking, then a 180° turn while walking, then walking back;
- ``crouch``: standing, a deep crouch (thighs near horizontal, as sitting), standing up;
- ``arms``: arms raised sideways overhead, lowered, then crossed over the chest;
- ``tpose_start``: a T-pose held ~1.2 s at a random place and heading, then the arms come down
  and the subject walks;
- ``nont_start``: starts mid-stride with the arms crossed (no T-pose), uncrosses and walks.

Randomness (place, heading, tempo) comes from the ``rng`` given.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from tracker.synthetic.bvh import Bvh, bvh_forward

__all__ = ["BVH_TO_WORLD", "BONES", "PoseTrack", "bone_direction", "motion_to_bvh", "MOTIONS", "make_motion", "standing_track",
           "resample_bvh"]

#: BVH (Y up) -> world (Z up): x_w = z_b, y_w = x_b, z_w = y_b (a proper rotation).
BVH_TO_WORLD = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

#: bone name -> (joint that rotates, child joint whose offset is the bone), both sides named with {s}
BONES = {
    "spine": ("lowerback", "Chest"), "spine2": ("Chest", "Chest2"), "neck": ("lowerneck", "Neck"),
    "head": ("Neck", "Head"), "head2": ("Head", "Head_End"),
    "{s}_thigh": ("{S}Hip", "{S}Knee"), "{s}_shank": ("{S}Knee", "{S}Ankle"), "{s}_foot": ("{S}Ankle", "{S}Toe"),
    "{s}_upper_arm": ("{S}Shoulder", "{S}Elbow"), "{s}_forearm": ("{S}Elbow", "{S}Wrist"),
}  # fmt: skip


def _bone_table() -> dict[str, tuple[str, str]]:
    out = {}
    for key, (j, c) in BONES.items():
        if "{s}" in key:
            for s, S in (("left", "Left"), ("right", "Right")):
                out[key.format(s=s)] = (j.format(S=S), c.format(S=S))
        else:
            out[key] = (j, c)
    return out


_BONES = _bone_table()


@dataclass
class PoseTrack:
    """A motion as world placement plus bone directions, per frame.

    Attributes
    ----------
    root : ndarray, shape (n, 3)
        World position of the ``Hips`` joint, metres (its height is only a hint: the renderer
        puts the feet on the floor).
    heading : ndarray, shape (n,)
        Facing direction, radians about +Z (0: facing +X).
    lean : ndarray, shape (n,)
        Forward lean of the pelvis, radians (positive: bent forward).
    dirs : dict of str -> ndarray, shape (n, 3)
        Bone directions in the heading frame (x forward, y left, z up); bones not given keep
        their parent's orientation.  Keys are ``BONES`` names (``left_thigh`` …).
    fps : float
    """

    root: np.ndarray
    heading: np.ndarray
    lean: np.ndarray
    dirs: dict
    fps: float

    @property
    def n_frames(self) -> int:
        return self.root.shape[0]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _dir(forward_deg, left_deg=0.0, down=True) -> np.ndarray:
    """Unit direction(s) tilted ``forward_deg`` towards +x and ``left_deg`` towards +y from
    straight down (``down``) or straight up, shape (..., 3)."""
    f, s = np.radians(np.asarray(forward_deg, float)), np.radians(np.asarray(left_deg, float))
    f, s = np.broadcast_arrays(f, s)
    z = -1.0 if down else 1.0
    v = np.stack([np.tan(f), np.tan(s), np.full(f.shape, z)], axis=-1)
    return _unit(v)


bone_direction = _dir
"""Public name of the bone-direction helper (for procedural tracks in other modules)."""


def _min_rotation(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The smallest rotations taking unit vectors u to v, shape (n, 3, 3)."""
    axis = np.cross(u, v)
    s = np.linalg.norm(axis, axis=-1)
    c = np.clip(np.sum(u * v, axis=-1), -1.0, 1.0)
    ang = np.arctan2(s, c)
    # antiparallel: any axis orthogonal to u
    alt = np.cross(u, np.array([1.0, 0.0, 0.0]))
    alt = np.where(np.linalg.norm(alt, axis=-1, keepdims=True) < 1e-6, np.cross(u, np.array([0.0, 1.0, 0.0])), alt)
    axis = np.where(s[:, None] > 1e-9, axis / np.maximum(s, 1e-12)[:, None], _unit(alt))
    return Rotation.from_rotvec(axis * ang[:, None]).as_matrix()


def motion_to_bvh(track: PoseTrack, skeleton: Bvh) -> Bvh:
    """Channel values on ``skeleton``'s hierarchy (a CMU BVH) that realise ``track``.

    Returns a ``Bvh`` with the skeleton's joints and offsets and ``track.n_frames`` frames at
    ``track.fps``.
    """
    n = track.n_frames
    W = BVH_TO_WORLD
    names = skeleton.names
    idx = {nm: i for i, nm in enumerate(names)}
    missing = [j for pair in _BONES.values() for j in pair if j not in idx]
    if missing or "Hips" not in idx:
        raise ValueError(f"{skeleton.source}: not a CMU skeleton (missing joints {sorted(set(missing))})")
    driven = {idx[j]: (idx[c], bone) for bone, (j, c) in _BONES.items() if bone in track.dirs}
    ch, hd = np.cos(track.heading), np.sin(track.heading)
    heading_R = np.zeros((n, 3, 3))
    heading_R[:, 0, 0], heading_R[:, 0, 1], heading_R[:, 1, 0], heading_R[:, 1, 1] = ch, -hd, hd, ch
    heading_R[:, 2, 2] = 1.0
    lean_R = Rotation.from_rotvec(np.outer(track.lean, [0.0, 1.0, 0.0])).as_matrix()  # about the left axis
    root_world = heading_R @ lean_R
    R_world = np.zeros((n, len(names), 3, 3))  # joint2world in BVH coordinates
    local = np.zeros((n, len(names), 3, 3))
    for j in range(len(names)):
        p = skeleton.parent[j]
        if p < 0:
            R_world[:, j] = W.T @ root_world @ W
            local[:, j] = R_world[:, j]
            continue
        Rp = R_world[:, p]
        if j in driven:
            c, bone = driven[j]
            off = skeleton.offset[c] / np.linalg.norm(skeleton.offset[c])
            want = np.einsum("ij,njk,nk->ni", W.T, heading_R, _unit(np.asarray(track.dirs[bone], float)))
            Q = _min_rotation(np.einsum("nij,j->ni", Rp, off), want)
            R_world[:, j] = Q @ Rp
        else:
            R_world[:, j] = Rp
        local[:, j] = np.swapaxes(Rp, 1, 2) @ R_world[:, j]
    motion = np.zeros((n, skeleton.motion.shape[1]))
    for j in range(len(names)):
        chans = skeleton.channels[j]
        if not chans:
            continue
        start = skeleton.channel_start[j]
        rot = [c for c in chans if c.endswith("rotation")]
        order = "".join(c[0] for c in rot)
        eul = Rotation.from_matrix(local[:, j]).as_euler(order.upper(), degrees=True)
        for k, c in enumerate(chans):
            if c.endswith("rotation"):
                motion[:, start + k] = eul[:, rot.index(c)]
            else:
                motion[:, start + k] = (track.root @ W)[:, "XYZ".index(c[0])] - skeleton.offset[j]["XYZ".index(c[0])]
    return Bvh(skeleton.names, skeleton.parent, skeleton.offset, skeleton.channels, skeleton.channel_start,
               motion, 1.0 / track.fps, f"{skeleton.source}:procedural")


def _stand_dirs(n: int) -> dict:
    """Standing: legs straight down, feet forward, spine and head up, arms down a little apart."""
    down = _dir(np.zeros(n))
    dirs = {"spine": _dir(np.zeros(n), down=False), "spine2": _dir(np.zeros(n), down=False),
            "neck": _dir(np.full(n, 8.0), down=False), "head": _dir(np.zeros(n), down=False),
            "head2": _dir(np.zeros(n), down=False)}  # fmt: skip
    for s, sign in (("left", 1.0), ("right", -1.0)):
        dirs[f"{s}_thigh"] = _dir(np.zeros(n), sign * 2.0)
        dirs[f"{s}_shank"] = down.copy()
        dirs[f"{s}_foot"] = _unit(np.tile([1.0, 0.0, -0.25], (n, 1)))
        dirs[f"{s}_upper_arm"] = _dir(np.zeros(n), sign * 10.0)
        dirs[f"{s}_forearm"] = _dir(np.full(n, 10.0), sign * 6.0)
    return dirs


def standing_track(n: int = 1, *, fps: float = 30.0, place=(0.0, 0.0), heading: float = 0.0) -> PoseTrack:
    """A subject standing still (arms down) for ``n`` frames."""
    root = np.tile([place[0], place[1], 0.95], (n, 1))
    return PoseTrack(root, np.full(n, float(heading)), np.zeros(n), _stand_dirs(n), fps)


def _blend(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Per-frame blend of directions (n, 3) by weight w (n,) in [0, 1], renormalised."""
    return _unit((1.0 - w)[:, None] * a + w[:, None] * b)


def _smoothstep(t: np.ndarray, t0: float, t1: float) -> np.ndarray:
    x = np.clip((t - t0) / max(t1 - t0, 1e-9), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _gait(track: PoseTrack, t: np.ndarray, weight: np.ndarray, *, phase0: float, stride_hz: float,
          speed: float) -> None:
    """Overlay walking on ``track`` where ``weight`` > 0: legs and arms swing, the root advances
    along the heading at ``speed`` × weight (m/s) and bobs."""
    n = t.size
    phi = 2 * np.pi * stride_hz * t + phase0
    for s, sign in (("left", 1.0), ("right", -1.0)):
        ph = phi if sign > 0 else phi + np.pi
        hip = 24.0 * np.sin(ph) * weight
        knee = (8.0 + 50.0 * np.clip(np.cos(ph), 0.0, None) ** 2) * weight
        stand = _stand_dirs(n)
        track.dirs[f"{s}_thigh"] = _blend(stand[f"{s}_thigh"], _dir(hip, sign * 2.0), weight)
        track.dirs[f"{s}_shank"] = _blend(stand[f"{s}_shank"], _dir(hip - knee, sign * 1.0), weight)
        foot_pitch = np.radians(np.clip(hip - knee, -40, 10) * 0.5)
        foot = np.stack([np.cos(foot_pitch), np.zeros(n), np.sin(foot_pitch) - 0.25], axis=-1)
        track.dirs[f"{s}_foot"] = _blend(stand[f"{s}_foot"], _unit(foot), weight)
        arm = -20.0 * np.sin(ph) * weight
        track.dirs[f"{s}_upper_arm"] = _blend(track.dirs[f"{s}_upper_arm"], _dir(arm, sign * 8.0), weight)
        track.dirs[f"{s}_forearm"] = _blend(track.dirs[f"{s}_forearm"], _dir(arm + 25.0, sign * 5.0), weight)
    step = speed * weight / track.fps
    dx = np.cumsum(step * np.cos(track.heading)) - step[0] * np.cos(track.heading[0])
    dy = np.cumsum(step * np.sin(track.heading)) - step[0] * np.sin(track.heading[0])
    track.root = track.root + np.stack([dx, dy, -0.02 * weight * (1 - np.cos(2 * phi))], axis=-1)


def _t_pose(n: int) -> dict:
    return {f"{s}_upper_arm": np.tile([0.0, sign, 0.0], (n, 1)) for s, sign in (("left", 1.0), ("right", -1.0))} | {
        f"{s}_forearm": np.tile([0.0, sign, 0.0], (n, 1)) for s, sign in (("left", 1.0), ("right", -1.0))}


def _crossed(n: int) -> dict:
    """Arms crossed over the chest (left forearm over the right one)."""
    return {"left_upper_arm": np.tile(_dir(25.0, 8.0), (n, 1)), "right_upper_arm": np.tile(_dir(25.0, -8.0), (n, 1)),
            "left_forearm": np.tile(_unit(np.array([0.45, -0.88, 0.15])), (n, 1)),
            "right_forearm": np.tile(_unit(np.array([0.35, 0.93, 0.05])), (n, 1))}  # fmt: skip


def _place(rng: np.random.Generator, spread_m: float) -> tuple[np.ndarray, float]:
    return rng.uniform(-spread_m, spread_m, 2), float(rng.uniform(-np.pi, np.pi))


def _walk_turn(n, fps, rng):
    t = np.arange(n) / fps
    (x, y), h0 = _place(rng, 0.3)
    tr = standing_track(n, fps=fps, place=(x - 0.6 * np.cos(h0), y - 0.6 * np.sin(h0)), heading=h0)
    T = t[-1]
    tr.heading = h0 + np.pi * _smoothstep(t, 0.3 * T, 0.75 * T)
    _gait(tr, t, _smoothstep(t, 0.0, 0.25), phase0=rng.uniform(0, np.pi), stride_hz=0.9, speed=0.9)
    return tr


def _crouch(n, fps, rng):
    t = np.arange(n) / fps
    (x, y), h0 = _place(rng, 0.4)
    tr = standing_track(n, fps=fps, place=(x, y), heading=h0)
    T = t[-1]
    d = _smoothstep(t, 0.15 * T, 0.45 * T) - _smoothstep(t, 0.6 * T, 0.9 * T)  # 0 stand .. 1 deepest
    thigh, shank = 80.0 * d, -40.0 * d
    for s, sign in (("left", 1.0), ("right", -1.0)):
        tr.dirs[f"{s}_thigh"] = _dir(thigh, sign * (2.0 + 12.0 * d))
        tr.dirs[f"{s}_shank"] = _dir(shank, sign * 3.0 * d)
        tr.dirs[f"{s}_upper_arm"] = _dir(10.0 + 60.0 * d, sign * 10.0)
        tr.dirs[f"{s}_forearm"] = _dir(15.0 + 70.0 * d, sign * 6.0)
    tr.lean = np.radians(35.0) * d
    return tr


def _arms(n, fps, rng):
    t = np.arange(n) / fps
    (x, y), h0 = _place(rng, 0.4)
    tr = standing_track(n, fps=fps, place=(x, y), heading=h0)
    T = t[-1]
    up = _smoothstep(t, 0.05 * T, 0.3 * T) - _smoothstep(t, 0.4 * T, 0.6 * T)
    cross = _smoothstep(t, 0.6 * T, 0.85 * T)
    crossed = _crossed(n)
    for s, sign in (("left", 1.0), ("right", -1.0)):
        ang = np.radians(10.0 + 165.0 * up)  # abduction from hanging (0) to overhead (180)
        side = np.stack([np.zeros(n), sign * np.sin(ang), -np.cos(ang)], axis=-1)
        tr.dirs[f"{s}_upper_arm"] = _blend(side, crossed[f"{s}_upper_arm"], cross)
        fore = _unit(side + np.array([0.15, 0.0, 0.0]))
        tr.dirs[f"{s}_forearm"] = _blend(fore, crossed[f"{s}_forearm"], cross)
    return tr


def _tpose_start(n, fps, rng):
    t = np.arange(n) / fps
    (x, y), h0 = _place(rng, 0.5)
    tr = standing_track(n, fps=fps, place=(x, y), heading=h0)
    tp = _t_pose(n)
    w = 1.0 - _smoothstep(t, 1.2, 1.7)
    for k, v in tp.items():
        tr.dirs[k] = _blend(tr.dirs[k], v, w)
    _gait(tr, t, _smoothstep(t, 1.5, 2.0), phase0=0.0, stride_hz=0.9, speed=0.8)
    return tr


def _nont_start(n, fps, rng):
    t = np.arange(n) / fps
    (x, y), h0 = _place(rng, 0.3)
    tr = standing_track(n, fps=fps, place=(x - 0.4 * np.cos(h0), y - 0.4 * np.sin(h0)), heading=h0)
    cr = _crossed(n)
    w = 1.0 - _smoothstep(t, 0.8, 1.4)
    # mid-stride from the first frame: the gait is on at full weight, the arms stay crossed meanwhile
    _gait(tr, t, np.full(n, 1.0), phase0=rng.uniform(0.3, 1.2), stride_hz=0.8, speed=0.7)
    for k, v in cr.items():
        tr.dirs[k] = _blend(tr.dirs[k], v, w)
    return tr


#: procedural clip name -> builder(n_frames, fps, rng) -> PoseTrack
MOTIONS: dict[str, Callable[[int, float, np.random.Generator], PoseTrack]] = {
    "walk_turn": _walk_turn, "crouch": _crouch, "arms": _arms, "tpose_start": _tpose_start, "nont_start": _nont_start,
}  # fmt: skip


def make_motion(name: str, skeleton: Bvh, *, frames: int, fps: float = 30.0,
                rng: np.random.Generator | None = None) -> Bvh:
    """A procedural clip (``MOTIONS``) of ``frames`` frames at ``fps`` on ``skeleton``'s hierarchy."""
    if name not in MOTIONS:
        raise ValueError(f"unknown motion {name!r}; available: {sorted(MOTIONS)}")
    if frames < 2 or not fps > 0:
        raise ValueError(f"frames must be >= 2 and fps > 0, got {frames}, {fps}")
    rng = np.random.default_rng(0) if rng is None else rng
    return motion_to_bvh(MOTIONS[name](int(frames), float(fps), rng), skeleton)


def resample_bvh(bvh: Bvh, *, fps: float, frames: int, start_s: float = 0.0) -> Bvh:
    """A recorded clip at ``fps`` (nearest source frame; CMU clips are 120 fps), ``frames`` long
    from ``start_s``; the root is moved so that its mean horizontal position is the origin."""
    src = np.round((start_s + np.arange(frames) / fps) * bvh.fps).astype(int)
    if src[-1] >= bvh.n_frames:
        raise ValueError(f"{bvh.source}: {frames} frames at {fps} fps from {start_s} s exceed the clip "
                         f"({bvh.n_frames / bvh.fps:.2f} s)")
    motion = bvh.motion[src].copy()
    P, _ = bvh_forward(Bvh(bvh.names, bvh.parent, bvh.offset, bvh.channels, bvh.channel_start, motion,
                           1.0 / fps, bvh.source))
    root = bvh.channel_start[0]
    centre = P[:, 0].mean(axis=0)
    pos = [k for k, c in enumerate(bvh.channels[0]) if c.endswith("position")]
    for k in pos:
        axis = "XYZ".index(bvh.channels[0][k][0])
        if axis != 1:  # Y is up in the BVH: keep the height
            motion[:, root + k] -= centre[axis]
    return Bvh(bvh.names, bvh.parent, bvh.offset, bvh.channels, bvh.channel_start, motion, 1.0 / fps, bvh.source)
