"""A seated subject on a rendered chair: the scene of a real seated take, with ground truth.

``seated_track`` is a procedural motion (``tracker.synthetic.motions.PoseTrack``): sitting with
the thighs near horizontal, the shanks down, the hands resting on the thighs, small movements
of the arms and head (a seated subject is nearly still).  ``chair_boxes`` builds a chair under
that subject's rendered body (``tracker.synthetic.people``): a seat slab, four legs and a
backrest, each an axis-aligned world box for ``Studio.render(boxes=...)``.  The chair is drawn
in the frames only, never in the background: it is in every silhouette, as the chair of a real
take recorded after its empty-room plate.  ``chair_props`` are the boxes an operator would
measure for ``--prop``: the seat with its legs (footprint × seat height) and the backrest.
"""

from __future__ import annotations

import numpy as np

from tracker.synthetic.motions import PoseTrack, standing_track
from tracker.synthetic.motions import bone_direction as _dir
from tracker.synthetic.people import JOINT_NAMES, SubjectMotion

__all__ = ["seated_track", "chair_boxes", "chair_props"]

_J = {n: i for i, n in enumerate(JOINT_NAMES)}


def seated_track(n: int, *, fps: float = 30.0, place=(0.0, 0.0), heading: float = 0.0,
                 rng: np.random.Generator | None = None) -> PoseTrack:
    """Sitting for ``n`` frames at ``place`` (x, y metres) facing ``heading`` (radians): thighs
    5° below horizontal, shanks down, hands on the thighs; the forearms and the head sway a little
    (random phases from ``rng``)."""
    rng = np.random.default_rng(0) if rng is None else rng
    t = np.arange(n) / float(fps)
    tr = standing_track(n, fps=fps, place=place, heading=heading)
    ph = rng.uniform(0, 2 * np.pi, 4)
    sway = np.sin(2 * np.pi * 0.4 * t + ph[0])
    for s, sign in (("left", 1.0), ("right", -1.0)):
        tr.dirs[f"{s}_thigh"] = _dir(np.full(n, 85.0), sign * 6.0)
        tr.dirs[f"{s}_shank"] = _dir(np.full(n, 8.0), sign * 2.0)
        tr.dirs[f"{s}_upper_arm"] = _dir(20.0 + 4.0 * sway, sign * 12.0)
        tr.dirs[f"{s}_forearm"] = _dir(75.0 + 8.0 * np.sin(2 * np.pi * 0.3 * t + ph[1 if sign > 0 else 2]), sign * 4.0)
    tr.dirs["neck"] = _dir(np.full(n, 8.0) + 5.0 * np.sin(2 * np.pi * 0.2 * t + ph[3]), down=False)
    return tr


def _heading_frame(sm: SubjectMotion) -> tuple[np.ndarray, np.ndarray]:
    """Mid-hip point (3,) and forward unit vector (3,) in the floor plane, over the clip."""
    hips = 0.5 * (sm.joints[:, _J["left_hip"]] + sm.joints[:, _J["right_hip"]]).mean(axis=0)
    knees = 0.5 * (sm.joints[:, _J["left_knee"]] + sm.joints[:, _J["right_knee"]]).mean(axis=0)
    fwd = np.array([knees[0] - hips[0], knees[1] - hips[1], 0.0])
    return hips, fwd / max(np.linalg.norm(fwd), 1e-9)


def _axis_box(centre: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return centre - half, centre + half


def chair_boxes(sm: SubjectMotion, thigh_radius: float, *, colour=(40, 40, 45)) -> list[tuple]:
    """A chair under the seated subject ``sm`` (``seated_track`` with heading 0 or π: the boxes are
    axis-aligned): ``(lo, hi, colour)`` boxes of the seat slab (3 cm), its four legs (3 cm square)
    and the backrest.  The seat's top is ``thigh_radius`` below the lowest hip joint; it reaches
    from 12 cm behind the hips to 12 cm short of the knees, 10 cm beyond the hips at the sides."""
    hips, fwd = _heading_frame(sm)
    if abs(fwd[1]) > 0.2:
        raise ValueError("chair_boxes: the subject must face along the x axis")
    s = float(np.sign(fwd[0]))
    hz = float(min(sm.joints[:, _J["left_hip"], 2].min(), sm.joints[:, _J["right_hip"], 2].min()))
    knee_x = 0.5 * (sm.joints[:, _J["left_knee"], 0] + sm.joints[:, _J["right_knee"], 0]).mean()
    ys = sm.joints[:, [_J["left_hip"], _J["right_hip"]], 1]
    y0, y1 = float(ys.min()) - 0.10, float(ys.max()) + 0.10
    back_x, front_x = hips[0] - s * 0.12, knee_x - s * 0.12
    x0, x1 = min(back_x, front_x), max(back_x, front_x)
    top = hz - float(thigh_radius)
    boxes = [(np.array([x0, y0, top - 0.03]), np.array([x1, y1, top]))]
    for x in (x0, x1 - 0.03):
        for y in (y0, y1 - 0.03):
            boxes.append((np.array([x, y, 0.0]), np.array([x + 0.03, y + 0.03, top - 0.03])))
    bx = x0 if s > 0 else x1 - 0.03
    boxes.append((np.array([bx, y0, top]), np.array([bx + 0.03, y1, top + 0.40])))
    return [(lo, hi, tuple(colour)) for lo, hi in boxes]


def chair_props(boxes: list[tuple]) -> list[list[float]]:
    """The operator's boxes for ``chair_boxes``' chair, ``[x0, y0, z0, x1, y1, z1]`` metres: the
    seat with its legs (the bounding box of the floor footprint up to the seat's top) and the
    backrest."""
    seat = boxes[:5]
    lo = np.min([b[0] for b in seat], axis=0)
    hi = np.max([b[1] for b in seat], axis=0)
    back = boxes[5]
    return [list(map(float, np.concatenate([lo, hi]))), list(map(float, np.concatenate([back[0], back[1]])))]
