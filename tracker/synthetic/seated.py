"""A seated subject on a rendered chair: the scene of a real seated take, with ground truth.

``seated_track`` is a procedural motion (``tracker.synthetic.motions.PoseTrack``): sitting with
the thighs near horizontal, the shanks down, the hands resting on the thighs, small movements
of the arms and head (a seated subject is nearly still).  ``chair_boxes`` builds a chair under
that subject's rendered body (``tracker.synthetic.people``): a seat slab, four legs and a
backrest, each an axis-aligned world box for ``Studio.render(boxes=...)``.  The chair is drawn
in the frames only, never in the background: it is in every silhouette, as the chair of a real
take recorded after its empty-room plate.  ``chair_props`` are the boxes an operator would
measure for ``--prop``: the seat with its legs (footprint × seat height) and the backrest;
``chair_parts`` the chair part by part (what is solid); ``write_seated_session(props="parts")``
writes the seat's bounding box as a ``hollow`` outline and the parts as solid boxes.
"""

from __future__ import annotations

import numpy as np

from tracker.synthetic.motions import PoseTrack, standing_track
from tracker.synthetic.motions import bone_direction as _dir
from tracker.synthetic.people import JOINT_NAMES, SubjectMotion

__all__ = ["seated_track", "chair_boxes", "chair_props", "chair_parts"]

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


def chair_boxes(sm: SubjectMotion, thigh_radius: float, *, colour=(40, 40, 45), sink_m: float = 0.0) -> list[tuple]:
    """A chair under the seated subject ``sm`` (``seated_track`` with heading 0 or π: the boxes are
    axis-aligned): ``(lo, hi, colour)`` boxes of the seat slab (3 cm), its four legs (3 cm square)
    and the backrest.  The seat's top is ``thigh_radius`` − ``sink_m`` below the lowest hip joint
    (``sink_m`` > 0: the thighs' flesh squashed on the seat, the capsules sunk in it); it reaches
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
    top = hz - float(thigh_radius) + float(sink_m)
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


def chair_parts(boxes: list[tuple]) -> list[list[float]]:
    """The operator's boxes for ``chair_boxes``' chair part by part, ``[x0, y0, z0, x1, y1, z1]``
    metres: the seat slab, the four legs and the backrest, each as drawn (what is solid)."""
    return [list(map(float, np.concatenate([lo, hi]))) for lo, hi, _ in boxes]


#: a studio like the real uu_studio take's, seen from the seated subject (facing azimuth 0): three
#: cameras in front (azimuth degrees, horizontal distance metres) and one at the subject's right side
STUDIO_FRONT_SIDE = ((37.0, 4.2), (0.0, 3.6), (-40.0, 4.2), (-86.0, 2.8))


def studio_cameras(points: np.ndarray, layout=STUDIO_FRONT_SIDE, *, size=(320, 240), height_m: float = 1.4,
                   margin: float = 0.05) -> list:
    """Cameras ``cam0``… at ``layout``'s (azimuth degrees, distance metres) around the centre of
    ``points`` (..., 3) (world, metres; azimuth 0 = +x), ``height_m`` above the floor, looking at that
    centre, each with the narrowest horizontal field of view (1° steps, 30°–110°) that keeps every
    point inside the image's ``margin``."""
    from capture.camera import Camera

    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    target = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    w, h = size
    cams = []
    for i, (az_deg, dist) in enumerate(layout):
        az = np.radians(az_deg)
        eye = np.array([target[0] + dist * np.cos(az), target[1] + dist * np.sin(az), height_m])
        for fov in np.arange(30.0, 110.5, 1.0):
            cam = Camera.look_at(f"cam{i}", eye, target, size=tuple(size), fov_deg=float(fov))
            uv = cam.project(pts)
            if np.all((uv >= margin * np.array([w, h])) & (uv <= (1 - margin) * np.array([w, h]))):
                break
        cams.append(cam)
    return cams


def write_seated_session(root, *, seed: int, frames: int, layout=None, size=(320, 240), n_background: int = 8,
                         seat_sink_m: float = 0.0, props: str = "bounding"):
    """Render ``seated_track`` on ``make_subject(seed)`` sitting on ``chair_boxes``' chair into a session
    directory at ``root`` (JPEG frames ``camK/%06d.jpg``, an empty-room MJPG video per camera without the
    chair, calibration.toml, session.toml with the subject's height and the chair's ``[[prop]]`` boxes).
    ``layout`` None: a ring of four cameras (``fit_ring_cameras``), else ``studio_cameras``' layout;
    ``seat_sink_m``: ``chair_boxes``' ``sink_m``; ``props``: the ``[[prop]]`` boxes written, ``"bounding"``
    (``chair_props``) or ``"parts"`` (``chair_props``' seat with its legs as a ``hollow`` outline, then
    ``chair_parts``).  Returns (the subject's joint truth (frames, 16, 3) metres, the ``Subject``, the
    boxes written, the seat's bounding box first)."""
    from pathlib import Path

    import cv2

    from capture.calibration import save_calibration
    from capture.session import write_session_toml
    from tracker.synthetic.bvh import load_bvh
    from tracker.synthetic.motions import motion_to_bvh
    from tracker.synthetic.people import Studio, body_primitives, make_subject, subject_height, subject_motion
    from tracker.synthetic.scene import fit_ring_cameras
    from tracker.synthetic.synth import bundled_motion

    if props not in ("bounding", "parts"):
        raise ValueError(f"props: expected 'bounding' or 'parts', got {props!r}")
    root = Path(root)
    rng = np.random.default_rng(seed)
    bvh = motion_to_bvh(seated_track(frames, fps=25.0, rng=rng), load_bvh(bundled_motion("scaled_131_01")))
    subject = make_subject(seed)
    sm = subject_motion(bvh, subject)
    prim = body_primitives(sm, subject)
    boxes = chair_boxes(sm, subject.radius["thigh"], sink_m=seat_sink_m)
    pts = np.concatenate([prim.spheres(f)[0].reshape(-1, 3) for f in range(prim.n_frames)])
    cams = (fit_ring_cameras(pts, 4, size=tuple(size)) if layout is None
            else studio_cameras(pts, layout, size=tuple(size)))
    studio = Studio(cams, seed=seed)
    for c, bg in zip(cams, studio.backgrounds):
        (root / c.name).mkdir(parents=True, exist_ok=True)
        (root / "background").mkdir(parents=True, exist_ok=True)
        out = cv2.VideoWriter(str(root / "background" / f"{c.name}.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 25.0,
                              tuple(size))
        for _ in range(n_background):
            out.write(studio.camera_output(bg, rng)[0])
        out.release()
    for f in range(frames):
        images, _ = studio.render(prim, f, boxes=boxes)
        for c, img in zip(cams, images):
            (root / c.name / f"{f:06d}.jpg").write_bytes(studio.camera_output(img, rng)[1])
    save_calibration(root / "calibration.toml", cams)
    hollow = 1 if props == "parts" else 0
    props = chair_props(boxes)[:1] + chair_parts(boxes) if hollow else chair_props(boxes)
    write_session_toml(root, name="seated", fps=25.0, height_m=subject_height(bvh, subject),
                       cameras=[{"name": c.name, "images": f"{c.name}/%06d.jpg",
                                 "background": f"background/{c.name}.avi"} for c in cams])
    with open(root / "session.toml", "a") as fh:
        fh.writelines(f"\n[[prop]]\nbox = [{', '.join(f'{v:.4f}' for v in box)}]\n"
                      + ("hollow = true\n" if i < hollow else "") for i, box in enumerate(props))
    return sm.joints, subject, props
