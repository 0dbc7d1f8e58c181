"""The real uu_studio session (a seated subject, the chair in every silhouette), tracked with the
scene handling of ``tracker.fitting.scene``: the body stays on the person, not on the chair.

The reference is independent of contourcap: BlazePose keypoints detected in the four cameras
and triangulated with the session's calibration (``bench/real_reference.py``), averaged over the
426 frames (the subject barely moves: every joint's spread is under 8 mm).  Keypoint hips lie on
the hip surface and are left out.  Measured on frames 0:60: mean error of these joints 79 mm
(the left knee, which the plain tracker fitted to the chair's legs at 420 mm off, 70 mm).
"""

from __future__ import annotations

import numpy as np
import pytest

from capture.session import load_session
from capture.uu_studio import import_uu_studio
from service.offline import track_session
from tracker.fitting.scene import SceneOptions

# mean BlazePose reference over the session, metres, world frame of the imported calibration
REFERENCE = {
    "left_shoulder": (-0.071, 0.551, 1.009), "right_shoulder": (-0.079, 0.159, 1.017),
    "left_elbow": (0.027, 0.612, 0.732), "right_elbow": (0.005, 0.101, 0.728),
    "left_wrist": (0.318, 0.510, 0.636), "right_wrist": (0.295, 0.195, 0.644),
    "left_knee": (0.443, 0.474, 0.513), "right_knee": (0.427, 0.208, 0.524),
    "left_ankle": (0.315, 0.436, 0.087), "right_ankle": (0.316, 0.250, 0.093),
}


@pytest.mark.slow
def test_seated_subject_is_tracked_on_the_person_not_the_chair(shared_data, tmp_path):
    src = shared_data / "uu_studio"
    if not src.is_dir():
        pytest.skip(f"{src} not found")
    root = tmp_path / "uu"
    import_uu_studio(src, root)
    firsts = []  # every frame's first fit (the records may hold refits made with the clutter learned since)
    records = list(track_session(load_session(root), frames=range(0, 60), scene=SceneOptions(), on_step=firsts.append))
    assert len(records) == 60 and all("joints" in r for r in records)
    err = {n: np.mean([np.linalg.norm(np.subtract(r["joints"][n], ref)) for r in records])
           for n, ref in REFERENCE.items()}
    assert 1e3 * np.mean(list(err.values())) < 95.0, {n: round(1e3 * e) for n, e in err.items()}
    assert 1e3 * err["left_knee"] < 120.0, {n: round(1e3 * e) for n, e in err.items()}
    # the chair and the board learned as clutter: the IoU checks rise (measured 0.69 -> 0.75-0.76)
    ious = [r["iou"] for r in firsts if "iou" in r]
    assert ious and ious[-1] > ious[0] + 0.03, ious


@pytest.mark.slow
def test_a_fit_started_on_the_chair_is_never_reported_ok(shared_data, tmp_path):
    """The gate keeps its job: the standing initialisation drapes the body over the chair (left
    knee ~0.4 m off); tracked from there with the scene handling, learning clutter from that fit
    must not make it pass (measured from that start: 0 of 150 frames ok, IoU 0.58 -> 0.73)."""
    from capture.replay import iter_frame_sets
    from segmentation.pipeline import segment_frame
    from service.offline import background_models, session_model
    from tracker.body.kinematics import forward, joint_centre_array
    from tracker.search.initialise import initialise

    src = shared_data / "uu_studio"
    if not src.is_dir():
        pytest.skip(f"{src} not found")
    root = tmp_path / "uu"
    import_uu_studio(src, root)
    session = load_session(root)
    names = list(session.camera_names)
    backgrounds, _ = background_models(session, names)
    model = session_model(session)
    _, group = next(iter_frame_sets(session, cameras=names, frames=range(0, 1)))
    segs = {n: segment_frame(backgrounds[n], f.image) for n, f in group.items()}
    start = initialise(model, [session.camera_model(n) for n in names], {n: s.silhouette for n, s in segs.items()},
                       {n: s.chamfer for n, s in segs.items()})
    at = model.joint_names.index("left_knee")
    start_knee = joint_centre_array(model, forward(model, np.asarray(start.params)))[at]
    assert 1e3 * np.linalg.norm(start_knee - REFERENCE["left_knee"]) > 200.0  # the start is on the chair
    records = list(track_session(session, frames=range(0, 100), initial_params=np.asarray(start.params),
                                 backgrounds=backgrounds, scene=SceneOptions()))
    knee = [1e3 * np.linalg.norm(np.subtract(r["joints"]["left_knee"], REFERENCE["left_knee"])) for r in records]
    false_ok = [(r["frame"], round(k)) for r, k in zip(records, knee) if r["ok"] and k > 150.0]
    assert false_ok == []


#: the chair's operator boxes (docs/real_floor.md: its feet picked in two cameras and intersected
#: with the floor, the seat's and the backrest's heights from one side view), metres
CHAIR = ((-0.29, 0.10, 0.0, 0.175, 0.59, 0.46), (-0.34, 0.10, 0.46, -0.25, 0.59, 0.86))


@pytest.mark.slow
def test_operator_chair_boxes_keep_the_knees_off_the_chair(shared_data, tmp_path):
    """With the chair given as props (``--prop``) no knee sinks onto the chair (measured on frames
    0:120 against the per-frame reference: right knee 115 mm, 251 mm without; judged 69 mm, 76
    without) and no frame is reported ok (none is within 40 mm)."""
    from tracker.fitting.props import PropBox

    src = shared_data / "uu_studio"
    if not src.is_dir():
        pytest.skip(f"{src} not found")
    root = tmp_path / "uu"
    import_uu_studio(src, root)
    records = list(track_session(load_session(root), frames=range(0, 120), scene=SceneOptions(),
                                 props=[PropBox.from_values(b) for b in CHAIR]))
    err = {n: np.mean([np.linalg.norm(np.subtract(r["joints"][n], ref)) for r in records])
           for n, ref in REFERENCE.items()}
    figures = {n: round(1e3 * e) for n, e in err.items()}
    assert 1e3 * max(err["left_knee"], err["right_knee"]) < 160.0, figures
    assert 1e3 * np.mean(list(err.values())) < 80.0, figures
    assert not any(r["ok"] for r in records)
