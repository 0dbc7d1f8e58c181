"""The coloured hull of one frame on the wire (``contourcap/<studio>/hull``): the blob tracker's voxels.

Binary, in the layout of :mod:`service.wire.messages` (magic ``CCAP``, type 3, version 1, JSON meta,
payload), readable without this package::

    meta    {"frame_id", "timestamp_ns", "count": n, "min_voxel_m"}
    payload centres float32 (n, 3) metres, world frame, Z up   (12 n bytes, little-endian, C order)
            sizes   float32 (n,)   cube edges, metres          (4 n bytes)
            colours uint8   (n, 3) mean colour over the views, BGR (3 n bytes)

At most :data:`HULL_MAX_VOXELS` voxels (a hull is a few thousand; the sender keeps the largest and
reports the count it had in ``meta["dropped"]``), so a record is at most ~1.2 MB.  ``from_bytes``
validates every field (finite centres, edges in ``(0, 1]`` m, sizes that add up) and raises only
:class:`~service.wire.messages.MessageError`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.wire.messages import MessageError, meta_float, meta_int, pack_message, unpack_message

__all__ = ["TYPE_HULL", "HULL_MAX_VOXELS", "HULL_MAX_BYTES", "HullMessage", "hull_message"]

TYPE_HULL = 3
HULL_MAX_VOXELS = 65536
_VOXEL_BYTES = 12 + 4 + 3
HULL_MAX_BYTES = 16 + 4096 + HULL_MAX_VOXELS * _VOXEL_BYTES
_MAX_EDGE_M = 1.0


def _frozen(arr: np.ndarray, dtype) -> np.ndarray:
    out = np.array(arr, dtype=dtype, copy=True, order="C")
    out.flags.writeable = False
    return out


@dataclass(frozen=True, eq=False)
class HullMessage:
    """One frame's coloured voxels.

    Attributes
    ----------
    frame_id, timestamp_ns : int
    centres : ndarray, shape (n, 3), float32
        Cube centres, metres, world frame.
    sizes : ndarray, shape (n,), float32
        Cube edges, metres.
    colours : ndarray, shape (n, 3), uint8
        Mean BGR colour of each cube over the views.
    min_voxel_m : float
        The finest cube edge of the reconstruction, metres.
    dropped : int
        Voxels the sender left out to stay within :data:`HULL_MAX_VOXELS`.
    """

    frame_id: int
    timestamp_ns: int
    centres: np.ndarray
    sizes: np.ndarray
    colours: np.ndarray
    min_voxel_m: float
    dropped: int = 0

    TYPE = TYPE_HULL

    def __post_init__(self) -> None:
        c = np.asarray(self.centres)
        n = c.shape[0] if c.ndim == 2 else -1
        if c.shape != (n, 3) or np.shape(self.sizes) != (n,) or np.shape(self.colours) != (n, 3):
            raise MessageError(f"hull: centres (n, 3), sizes (n,), colours (n, 3) expected, got "
                               f"{np.shape(self.centres)}, {np.shape(self.sizes)}, {np.shape(self.colours)}")
        if n > HULL_MAX_VOXELS:
            raise MessageError(f"hull: {n} voxels exceeds the maximum of {HULL_MAX_VOXELS}")
        object.__setattr__(self, "centres", _frozen(c, np.float32))
        object.__setattr__(self, "sizes", _frozen(self.sizes, np.float32))
        object.__setattr__(self, "colours", _frozen(np.clip(np.rint(self.colours), 0, 255), np.uint8))
        if not (np.all(np.isfinite(self.centres)) and np.all(self.sizes > 0) and np.all(self.sizes <= _MAX_EDGE_M)):
            raise MessageError(f"hull: centres must be finite and edges in (0, {_MAX_EDGE_M}] m")

    @property
    def count(self) -> int:
        """Number of voxels."""
        return int(self.sizes.shape[0])

    def rgb(self) -> np.ndarray:
        """Colours as RGB (n, 3) uint8 (for viewers)."""
        return self.colours[:, ::-1]

    def to_bytes(self) -> bytes:
        """The wire bytes (see the module docstring)."""
        meta = {"frame_id": int(self.frame_id), "timestamp_ns": int(self.timestamp_ns), "count": self.count,
                "min_voxel_m": float(self.min_voxel_m), "dropped": int(self.dropped)}
        payload = (self.centres.astype("<f4").tobytes() + self.sizes.astype("<f4").tobytes()
                   + self.colours.tobytes())
        return pack_message(TYPE_HULL, meta, payload)

    @classmethod
    def from_bytes(cls, data: bytes, *, max_bytes: int = HULL_MAX_BYTES) -> "HullMessage":
        """Decode and validate untrusted wire bytes; MessageError names the field at fault."""
        meta, payload = unpack_message(data, TYPE_HULL, max_bytes)
        n = meta_int(meta, "count", hi=HULL_MAX_VOXELS)
        if len(payload) != n * _VOXEL_BYTES:
            raise MessageError(f"hull: count {n} needs {n * _VOXEL_BYTES} payload bytes, got {len(payload)}")
        min_voxel = meta_float(meta, "min_voxel_m")
        if not 0 < min_voxel <= _MAX_EDGE_M:
            raise MessageError(f"min_voxel_m: expected in (0, {_MAX_EDGE_M}], got {min_voxel}")
        buf = bytes(payload)
        centres = np.frombuffer(buf, "<f4", count=3 * n).reshape(n, 3)
        sizes = np.frombuffer(buf, "<f4", count=n, offset=12 * n)
        colours = np.frombuffer(buf, np.uint8, count=3 * n, offset=16 * n).reshape(n, 3)
        return cls(meta_int(meta, "frame_id"), meta_int(meta, "timestamp_ns"), centres, sizes, colours, min_voxel,
                   meta_int(meta, "dropped", hi=2**31))


def hull_message(frame_id: int, timestamp_ns: int, hull, *, max_voxels: int = HULL_MAX_VOXELS) -> HullMessage:
    """The message of a ``tracker.blobs.ColourHull`` (colours averaged over the views); beyond
    ``max_voxels`` the largest cubes are kept (the coarse interior before the fine surface)."""
    centres, sizes, colours = hull.centres, hull.sizes, hull.mean_colours()
    dropped = 0
    if len(sizes) > max_voxels:
        keep = np.sort(np.argsort(-np.asarray(sizes), kind="stable")[:max_voxels])
        dropped = len(sizes) - max_voxels
        centres, sizes, colours = centres[keep], sizes[keep], colours[keep]
    return HullMessage(int(frame_id), int(timestamp_ns), centres, sizes, colours, float(hull.min_voxel_m), dropped)
