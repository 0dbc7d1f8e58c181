"""The operator's props (``tracker.fitting.props.PropBox``: a chair, a stool) in the blob tracker.

A prop is never body, so it acts twice, as in the contour tracker:

* **carved from the hull** (:func:`carve`): a voxel whose centre lies in a prop box is dropped before
  the EM, the part-support test and the unexplained volume (a seat's voxels attract no blob and are
  not counted as hull the body leaves unexplained);
* **a limit in the inverse kinematics**: the damped least squares gets the residuals of
  ``tracker.fitting.props.PropPenalty`` (points along each part's axis keep a part's radius from
  every box, the pelvis none: it rests on the seat), so a blob's goal cannot pull a limb into it.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from tracker.blobs.colour_hull import ColourHull

__all__ = ["carve", "in_props"]


def in_props(points: np.ndarray, props: Sequence) -> np.ndarray:
    """Whether each point (n, 3) lies in some box of ``props`` (objects with ``lo``, ``hi`` (3,)
    metres, e.g. ``PropBox``), faces included; (n,) bool."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    inside = np.zeros(len(P), bool)
    for box in props:
        inside |= np.all((P >= box.lo) & (P <= box.hi), axis=1)
    return inside


def carve(hull: ColourHull, props: Sequence) -> ColourHull:
    """``hull`` without the voxels whose centre lies in a prop box (:func:`in_props`); the same
    hull when none does."""
    if not len(props) or hull.n_voxels == 0:
        return hull
    keep = ~in_props(hull.centres, props)
    if keep.all():
        return hull
    return replace(hull, centres=hull.centres[keep], sizes=hull.sizes[keep], full=hull.full[keep],
                   colours=hull.colours[keep])
