"""BVH motion files: parsing and forward kinematics, vectorised over frames.

Format (Biovision hierarchy)::

    HIERARCHY
    ROOT Hips
    {
        OFFSET x y z
        CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
        JOINT LeftHip
        {
            OFFSET ...
            CHANNELS 3 Zrotation Xrotation Yrotation      # any order
            End Site
            {
                OFFSET ...
            }
        }
    }
    MOTION
    Frames: N
    Frame Time: 0.008333
    <N lines, one value per channel in hierarchy order>

Conventions used here (those of the common exporters and of CMU's files): rotations are in
degrees and compose in the order listed, each about the joint's *local* (parent-relative) axis,
so ``Zrotation Yrotation Xrotation`` means ``R = Rz · Ry · Rx``; position channels add to the
joint's OFFSET.  A joint's local transform is ``Trans(offset + position) · R``, and
``joint2world = parent2world · local``.  End sites become joints named ``<parent>_End`` with no
channels.  Units are whatever the file uses (CMU files here: metres, Y up).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tracker.errors import TrackerError

__all__ = ["Bvh", "BvhError", "load_bvh", "parse_bvh", "bvh_forward", "euler_channels_to_matrix"]

_ROT = {"Xrotation": 0, "Yrotation": 1, "Zrotation": 2}
_POS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}


class BvhError(TrackerError, ValueError):
    """A BVH file is malformed; the message names the file and the line."""


@dataclass(frozen=True, eq=False)
class Bvh:
    """A parsed BVH file.

    Attributes
    ----------
    names : tuple of str, length n_joints
        Joints in file order (parents before children), end sites included.
    parent : ndarray of int, shape (n_joints,)
        -1 for a root.
    offset : ndarray, shape (n_joints, 3)
        OFFSET of each joint in its parent's frame (file units).
    channels : tuple of tuple of str
        Channel names of each joint (empty for end sites).
    channel_start : ndarray of int, shape (n_joints,)
        Column of each joint's first channel in ``motion``.
    motion : ndarray, shape (n_frames, n_channels)
        Channel values, degrees for rotations.
    frame_time_s : float
    source : str
        The file the data came from (for messages).
    """

    names: tuple
    parent: np.ndarray
    offset: np.ndarray
    channels: tuple
    channel_start: np.ndarray
    motion: np.ndarray
    frame_time_s: float
    source: str = "<string>"

    @property
    def n_joints(self) -> int:
        return len(self.names)

    @property
    def n_frames(self) -> int:
        return self.motion.shape[0]

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time_s

    def index(self, name: str) -> int:
        """Index of a joint by name; KeyError naming the file when absent."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"{self.source}: no joint {name!r}") from None

    def is_end_site(self) -> np.ndarray:
        """Whether each joint is an end site (no channels), shape (n_joints,) bool."""
        return np.array([len(c) == 0 for c in self.channels])


def load_bvh(path) -> Bvh:
    """Read and parse a BVH file.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    Bvh

    Raises
    ------
    BvhError
        Unreadable or malformed (the file and line named).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise BvhError(f"{path}: cannot read BVH file: {exc.strerror or exc}") from None
    return parse_bvh(text, source=str(path))


def parse_bvh(text: str, *, source: str = "<string>") -> Bvh:
    """Parse BVH text (see the module docstring).

    Parameters
    ----------
    text : str
    source : str
        Named in errors, with the line.

    Returns
    -------
    Bvh
    """
    lines = text.splitlines()
    names: list[str] = []
    parent: list[int] = []
    offset: list[np.ndarray] = []
    channels: list[tuple] = []
    stack: list[int] = []
    pending: int | None = None  # joint whose "{" is expected next
    n_channels = 0
    i = 0

    def fail(msg: str, lineno: int):
        raise BvhError(f"{source}:{lineno + 1}: {msg}")

    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines) or lines[i].split()[0].upper() != "HIERARCHY":
        fail("expected HIERARCHY", min(i, max(len(lines) - 1, 0)))
    i += 1
    while i < len(lines):
        tok = lines[i].split()
        if not tok:
            i += 1
            continue
        key = tok[0]
        if key in ("ROOT", "JOINT", "End") and pending is not None:
            fail(f"joint {names[pending]!r} has no '{{'", i)
        if key in ("ROOT", "JOINT"):
            if len(tok) < 2:
                fail(f"{key} without a name", i)
            if key == "JOINT" and not stack:
                fail("JOINT outside any ROOT", i)
            if key == "ROOT" and stack:
                fail("ROOT inside another joint", i)
            name = " ".join(tok[1:])
            if name in names:
                fail(f"duplicate joint name {name!r}", i)
            names.append(name)
            parent.append(stack[-1] if stack else -1)
            offset.append(None)
            channels.append(())
            pending = len(names) - 1
        elif key == "End":
            if not stack:
                fail("End Site outside any joint", i)
            names.append(f"{names[stack[-1]]}_End")
            parent.append(stack[-1])
            offset.append(None)
            channels.append(())
            pending = len(names) - 1
        elif key == "{":
            if pending is None:
                fail("unexpected '{'", i)
            stack.append(pending)
            pending = None
        elif key == "}":
            if not stack:
                fail("unbalanced '}'", i)
            j = stack.pop()
            if offset[j] is None:
                fail(f"joint {names[j]!r} has no OFFSET", i)
        elif key == "OFFSET":
            if not stack:
                fail("OFFSET outside a joint", i)
            try:
                offset[stack[-1]] = np.array([float(v) for v in tok[1:4]])
            except ValueError:
                fail("OFFSET needs three numbers", i)
            if len(tok) != 4 or not np.all(np.isfinite(offset[stack[-1]])):
                fail("OFFSET needs three (finite) numbers", i)
        elif key == "CHANNELS":
            if not stack:
                fail("CHANNELS outside a joint", i)
            try:
                n = int(tok[1])
            except (IndexError, ValueError):
                fail("CHANNELS needs a count", i)
            chans = tuple(tok[2:])
            if len(chans) != n:
                fail(f"CHANNELS says {n} but lists {len(chans)}", i)
            bad = [c for c in chans if c not in _ROT and c not in _POS]
            if bad:
                fail(f"unknown channel(s) {bad}", i)
            channels[stack[-1]] = chans
            n_channels += n
        elif key == "MOTION":
            break
        else:
            fail(f"unexpected {key!r} in HIERARCHY", i)
        i += 1
    if stack or pending is not None:
        fail("HIERARCHY ends inside an unclosed joint", min(i, len(lines) - 1))
    if i >= len(lines):
        fail("no MOTION section", len(lines) - 1)
    if not names:
        fail("no joints in HIERARCHY", i)
    motion, frame_time = _parse_motion(lines, i + 1, n_channels, fail)
    starts = np.cumsum([0] + [len(c) for c in channels[:-1]]).astype(int)
    return Bvh(
        names=tuple(names),
        parent=np.array(parent, dtype=int),
        offset=np.array(offset, dtype=float),
        channels=tuple(channels),
        channel_start=starts,
        motion=motion,
        frame_time_s=frame_time,
        source=source,
    )


def _parse_motion(lines, i, n_channels, fail):
    def header(prefix, i):
        while i < len(lines) and not lines[i].strip():
            i += 1
        if i >= len(lines) or not lines[i].strip().startswith(prefix):
            fail(f"expected '{prefix}'", min(i, len(lines) - 1))
        return lines[i].strip()[len(prefix):].strip(), i + 1

    value, i = header("Frames:", i)
    try:
        n_frames = int(value)
    except ValueError:
        fail(f"bad frame count {value!r}", i - 1)
    value, i = header("Frame Time:", i)
    try:
        frame_time = float(value)
    except ValueError:
        fail(f"bad frame time {value!r}", i - 1)
    if not (frame_time > 0 and np.isfinite(frame_time)):
        fail(f"frame time must be positive, got {frame_time}", i - 1)
    rows = [ln for ln in lines[i:] if ln.strip()]
    if len(rows) < n_frames:
        fail(f"Frames: {n_frames} but only {len(rows)} motion lines", len(lines) - 1)
    try:
        motion = np.array(" ".join(rows[:n_frames]).split(), dtype=float)
    except ValueError:
        fail("non-numeric value in MOTION data", i)
    if motion.size != n_frames * n_channels:
        # find the first bad line for the message
        for k, ln in enumerate(rows[:n_frames]):
            if len(ln.split()) != n_channels:
                fail(f"motion frame {k} has {len(ln.split())} values, expected {n_channels}", i + k)
    motion = motion.reshape(n_frames, n_channels)
    if not np.all(np.isfinite(motion)):
        fail("non-finite value in MOTION data", i)
    return motion, frame_time


def _axis_rotation(axis: int, angle_rad: np.ndarray) -> np.ndarray:
    """Rotations about a coordinate axis, shape (n, 3, 3)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    R = np.zeros(angle_rad.shape + (3, 3))
    a, b = [(1, 2), (2, 0), (0, 1)][axis]
    R[..., axis, axis] = 1.0
    R[..., a, a] = c
    R[..., b, b] = c
    R[..., a, b] = -s
    R[..., b, a] = s
    return R


def euler_channels_to_matrix(channel_names, degrees: np.ndarray) -> np.ndarray:
    """Compose rotation channels in the listed order: ``R = R_c1 · R_c2 · R_c3``.

    Parameters
    ----------
    channel_names : sequence of str
        Rotation channel names (``Xrotation`` …), position channels skipped.
    degrees : ndarray, shape (n_frames, len(channel_names))

    Returns
    -------
    ndarray, shape (n_frames, 3, 3)
    """
    degrees = np.asarray(degrees, dtype=float)
    R = np.broadcast_to(np.eye(3), (degrees.shape[0], 3, 3)).copy()
    for c, name in enumerate(channel_names):
        if name in _ROT:
            R = R @ _axis_rotation(_ROT[name], np.radians(degrees[:, c]))
    return R


def bvh_forward(bvh: Bvh, frames=None) -> tuple[np.ndarray, np.ndarray]:
    """World positions and orientations of every joint.

    Parameters
    ----------
    frames : array-like of int, optional
        Frame indices (default: all).

    Returns
    -------
    positions : ndarray, shape (n_frames, n_joints, 3)
        Joint origins in the file's world frame and units.
    rotations : ndarray, shape (n_frames, n_joints, 3, 3)
        joint2world rotations.
    """
    motion = bvh.motion if frames is None else bvh.motion[np.asarray(frames, dtype=int)]
    n = motion.shape[0]
    P = np.zeros((n, bvh.n_joints, 3))
    R = np.zeros((n, bvh.n_joints, 3, 3))
    for j in range(bvh.n_joints):
        chans = bvh.channels[j]
        vals = motion[:, bvh.channel_start[j] : bvh.channel_start[j] + len(chans)]
        local_t = np.broadcast_to(bvh.offset[j], (n, 3)).copy()
        for c, name in enumerate(chans):
            if name in _POS:
                local_t[:, _POS[name]] += vals[:, c]
        local_R = euler_channels_to_matrix(chans, vals)
        p = bvh.parent[j]
        if p < 0:
            P[:, j] = local_t
            R[:, j] = local_R
        else:
            P[:, j] = np.einsum("nij,nj->ni", R[:, p], local_t) + P[:, p]
            R[:, j] = R[:, p] @ local_R
    return P, R
