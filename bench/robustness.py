"""Robustness benchmark: track people the tracker's body model was not rendered from.

Every clip is one subject × one motion × one camera ring:

- subjects ``tracker.synthetic.people.make_subject(i)`` for i = 0 … ``--subjects`` − 1 (segment
  proportions ±15 %, radii ±25 %, own colours; shoes dark for even i, floor dark for i % 4 in
  {0, 3}: dark shoes on a dark floor for i = 0, 4);
- motions: the procedural clips of ``tracker.synthetic.motions`` (``walk_turn``, ``crouch``,
  ``arms``, ``tpose_start``, ``nont_start``; place and heading drawn per subject and clip) and
  ``cmu_walk`` (CMU 131_01, the bundled start–walk clip, from 1 s), resampled to ``--fps``;
- cameras: a ring of 4 and one of 6 (``tracker.synthetic.scene.fit_ring_cameras``: the subject stays in
  view), ``--size`` pixels.

Per clip the frames are rendered (``tracker.synthetic.people.Studio``, sensor noise, JPEG
quality 85) into a temporary session (JPEG image sequences, calibration, ``[subject] height_m`` =
the subject's standing height measured on the rendered body), background models are learned from
10 rendered empty-room frames per camera, and the session is tracked by
``service.offline.track_session`` (segmentation, ``Tracker`` with automatic initialisation, the
``knossow40`` model sized from the height) exactly as ``contourcap track --floor-test --no-scene`` does
(the stretches the gate refused fitted again backwards from the next accepted frame, the poses smoothed over a
centred window, ``service.smoothed``; ``--no-smooth``: as fitted; ``--no-retrack``: every frame once, unsmoothed,
as live; ``--scene``: the scene tracker, as ``contourcap track`` without ``--no-scene``, ``--scene-option``
its ``SceneOptions``; ``--no-floor-test``: without ``segmentation.floor``; ``--method blobs``: the blob tracker
``tracker.blobs`` on the colour frames, initialised by the same silhouette search).  The poses are
scored against the BVH joint centres by ``tracker.synthetic.evaluation`` (its docstring defines
mirrored, false ok, false alarm and PCK).  Per clip also: the median IoU of the segmented
silhouettes with the rendered ones (every 15th frame: how much of a failure is segmentation) and
the IK floor (the height-sized model posed onto the true joints by ``tracker.synthetic.retarget``: the
error a perfect tracker with that model would still have), and ``error_parts`` (``error_parts``: per joint its IK
floor, the mean offset in the truth's pelvis heading frame, the rest and the lost stretches; the torso's yaw, lean
and height errors; the summary's ``error_parts`` is their mean over the clips).

A tracker that has lost the body searches again on every bad frame (1–10 s each here), so a clip
it cannot track would dominate the run: tracking a clip stops once it has used ``--clip-budget-s``
CPU seconds (reading, segmenting and tracking), and its remaining frames are scored as not ok
without a pose (``unprocessed``; a live system would not have delivered them either).

Timings: ``ms_per_frame_median`` is the tracker's own per-frame latency (fit, wall clock, one
BLAS thread), ``pipeline_ms_per_frame_median`` adds reading and segmenting the frame set, and
``pipeline_cpu_ms_per_frame_median`` is the same on this process's CPU clock (steadier on a shared
machine); quote them as ratios to ``machine_ref_ms``.

    python bench/robustness.py [--json] [--quick] [--subjects 6] [--clips walk_turn,crouch]
                               [--cameras 4,6] [--all-cameras] [--frames 75] [--size 320x240]
                               [--fps 30] [--clip-budget-s 20] [--method contours|blobs] [--calibrate 100]
                               [--calibrate-from tpose_start] [--out result.json]

``--calibrate N``: per clip, the subject is also calibrated as ``contourcap track --calibrate-subject
0:N`` does (``calibrate_clip``: the product's sampling, fit and held-out check; never the truth); an
adopted body tracks the clip again, a body not adopted leaves the height-only track standing; the
summary gives both (``mpjpe_mm_mean_height_only`` and the ``*_calibrated`` figures, per-joint means
``joint_mm_height_only`` / ``joint_mm_calibrated``, ``calibration_adopted_percent``).

``--calibrate-from MOTION``: as a studio works, each subject is calibrated once, on its MOTION clip (the same
``calibrate_clip``, frames 0:N with ``--calibrate N``, default 100), and every clip of that subject is tracked
again with the adopted calibration's subject file (the height-only track stands when it is not adopted); the
``*_calibrated`` figures cover every clip, the ``*_calibrated_held_out`` and ``*_height_only_held_out`` ones
only the clips of the other motions (a body judged on the take it was fitted on is flattered), and
``calibration_bodies`` lists each subject's fitted body beside the rendered subject's lengths. Each clip's
``calibrated.calibration`` says which calibration it used (``own``, ``source``).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import datetime  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from capture.calibration import save_calibration  # noqa: E402
from capture.tomlio import loads as toml_loads  # noqa: E402
from capture.session import load_session, write_session_toml  # noqa: E402
from machine_ref import machine_ref_ms  # noqa: E402
from subject_frame_offsets import decompose  # noqa: E402
from segmentation.background import BackgroundModel  # noqa: E402
from segmentation.pipeline import SegmentationParams, segment_frame  # noqa: E402
from tracker.synthetic.bvh import load_bvh  # noqa: E402
from service.commands.calibrate_subject import auto_calibrate, within_take  # noqa: E402
from tracker.fitting.subject_auto import AutoSubjectOptions  # noqa: E402
from tracker.body.model import JOINT_NAMES as MODEL_JOINTS  # noqa: E402
from tracker.body.subject import parse_subject, subject_toml  # noqa: E402
from service.offline import floor_test, session_model, track_session, warm_up_kernels  # noqa: E402
from service.smoothed import SMOOTH_WINDOW_S  # noqa: E402
from tracker.fitting.scene import SceneOptions  # noqa: E402
from tracker.fitting.tracking import TrackerOptions  # noqa: E402
from tracker.synthetic.retarget import retarget_bvh  # noqa: E402
from tracker.synthetic.scene import fit_ring_cameras  # noqa: E402
from tracker.synthetic.synth import bundled_motion  # noqa: E402
from tracker.synthetic.evaluation import frame_errors, mirrored_frames, score_clip, summarise_clips  # noqa: E402
from tracker.synthetic.motions import MOTIONS, make_motion, resample_bvh  # noqa: E402
from tracker.synthetic.people import (JOINT_NAMES, Studio, body_primitives, make_subject,  # noqa: E402
                                      subject_height, subject_motion, subject_skeleton)

CLIPS = tuple(MOTIONS) + ("cmu_walk",)
QUICK = {"subjects": 2, "clips": "tpose_start,crouch,walk_turn", "cameras": "6", "frames": 60}
N_BACKGROUND = 10
#: the settings for bodies that are not the model, off by default in contourcap (docs/robustness.md,
#: round 2): the camouflage window of the background test and the IoU gate's lost limit
WINDOW_PX = 1
LOST_IOU_MARGIN = 0.04
IOU_EVERY = 15
assert tuple(MODEL_JOINTS) == JOINT_NAMES


def clip_motion(name: str, skeleton, *, subject: int, frames: int, fps: float):
    """The BVH motion of clip ``name`` for subject index ``subject`` (seeded per subject and clip)."""
    if name == "cmu_walk":
        return resample_bvh(skeleton, fps=fps, frames=frames, start_s=1.0)
    rng = np.random.default_rng(1000 * subject + CLIPS.index(name))
    return make_motion(name, skeleton, frames=frames, fps=fps, rng=rng)


def bench_subject(index: int):
    """Subject ``index`` of the benchmark: shoes dark for even indices."""
    return make_subject(index, dark_shoes=index % 2 == 0)


def render_session(root: Path, motion, subject_index: int, n_cameras: int, size, *, ground: str = "frame") -> tuple:
    """Render one clip into a session at ``root``; returns (truth (n, 16, 3), background models,
    height_m, render ms per frame, median IoU of the segmented silhouettes with the true ones on
    every ``IOU_EVERY``-th frame)."""
    subject = bench_subject(subject_index)
    sm = subject_motion(motion, subject, ground=ground)
    prim = body_primitives(sm, subject)
    pts = np.concatenate([prim.spheres(f)[0].reshape(-1, 3) for f in range(prim.n_frames)])
    cams = fit_ring_cameras(pts, n_cameras, size=tuple(size))
    studio = Studio(cams, seed=subject_index, dark_floor=subject_index % 4 in (0, 3))
    rng = np.random.default_rng(7919 * subject_index + n_cameras)
    backgrounds = {c.name: BackgroundModel.from_frames([studio.camera_output(bg, rng)[0] for _ in range(N_BACKGROUND)],
                                                       window_px=WINDOW_PX)
                   for c, bg in zip(cams, studio.backgrounds)}  # fmt: skip
    floor = floor_test(cams, backgrounds, TRACK_OPTIONS.get("segmentation"))
    for c in cams:
        (root / c.name).mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    ious = []
    for f in range(prim.n_frames):
        images, masks = studio.render(prim, f)
        decoded_set = {}
        for c, img in zip(cams, images):
            decoded, jpeg = studio.camera_output(img, rng)
            (root / c.name / f"{f:06d}.jpg").write_bytes(jpeg)
            decoded_set[c.name] = decoded
        if f % IOU_EVERY == 0:
            for c, mask in zip(cams, masks):
                fl = None if floor is None else floor.for_camera(c.name, decoded_set)
                sil = segment_frame(backgrounds[c.name], decoded_set[c.name], floor=fl).silhouette > 0
                ious.append(np.sum(sil & mask) / max(np.sum(sil | mask), 1))
    render_ms = 1e3 * (time.perf_counter() - t0) / prim.n_frames
    save_calibration(root / "calibration.toml", cams)
    height = subject_height(motion, subject)
    write_session_toml(root, name=root.name, fps=float(sm.fps),
                       cameras=[{"name": c.name, "images": f"{c.name}/%06d.jpg"} for c in cams], height_m=height)
    return sm.joints, backgrounds, height, render_ms, float(np.median(ious))


_REASONS = (("silhouette IoU", "iou"), ("rms", "rms"), ("contour on the silhouettes", "inside"),
            ("initialisation failed", "initialisation"), ("no camera", "no_camera"),
            ("limb off its silhouette", "limb_coverage"), ("limbs: ", "limbs_unsure"),
            ("front/back", "front_back"), ("limb colour: ", "limb_colour"), ("boundary unexplained", "uncovered"))


def _reason_keys(reason: str) -> list[str]:
    """Short names of the checks a not-ok record failed (its ``reason`` text from the tracker)."""
    keys = [key for text, key in _REASONS if text in reason]
    return keys or ["other"]


def ik_floor_joints_m(motion, subject_index: int, height_m: float, *, fps: float, every: int = 3,
                      model: str = "knossow40") -> np.ndarray:
    """Per-frame, per-joint error (m, shape (n, 16), columns ``JOINT_NAMES``) of the height-sized
    model posed by inverse kinematics onto the true joints (``tracker.synthetic.retarget``) on every
    ``every``-th frame: what a perfect tracker with that model could reach on this subject."""
    skel = subject_skeleton(motion, bench_subject(subject_index))
    n = (skel.n_frames - 1) // every + 1
    rt = retarget_bvh(skel, model=model, fps=fps / every, frames=n, height_m=height_m)
    return rt.residual_m[:, [rt.joint_names.index(j) for j in JOINT_NAMES]]


#: extra ``service.offline.track_session`` keywords (``--no-front-back``: ``front_back=None``; the
#: floor test of ``segmentation.floor`` unless ``--no-floor-test``: ``contourcap track --floor-test``;
#: ``--no-retrack``: ``retrack=False`` and ``smooth_s=0``; ``--no-smooth``: ``smooth_s=0``)
TRACK_OPTIONS: dict = {"segmentation": SegmentationParams(floor_test=True),
                       "options": TrackerOptions(lost_iou_margin=LOST_IOU_MARGIN)}


def _track(session, backgrounds, *, method: str, budget_s: float, model=None) -> tuple[list, list, list, float]:
    """Track ``session`` (``service.offline.track_session`` with ``TRACK_OPTIONS``; ``model``: a
    sized BodyModel, default the session's height-sized knossow40) until ``budget_s`` CPU seconds
    (0: no limit); returns (records, wall ms per frame, CPU ms per frame, CPU seconds).  The tracker is
    stopped by ``track_session``'s ``stop`` (the frames held for a refit keep their first fits, the smoother's
    look-ahead is written); its
    per-frame figures are per record yielded, which a refit yields in bursts."""
    records, pipe_ms, pipe_cpu_ms, cpu_s = [], [], [], 0.0
    extra = {"model": MODEL[0] if model is None else model}
    if budget_s:
        c_start = time.process_time()
        extra["stop"] = lambda: time.process_time() - c_start > budget_s
    it = track_session(session, backgrounds=backgrounds, method=method, **TRACK_OPTIONS, **extra)
    while True:  # the budget ends the records through ``stop``
        t0, c0 = time.perf_counter(), time.process_time()
        rec = next(it, None)
        if rec is None:
            break
        pipe_cpu_ms.append(1e3 * (time.process_time() - c0))
        cpu_s += pipe_cpu_ms[-1] / 1e3
        pipe_ms.append(1e3 * (time.perf_counter() - t0))
        records.append(rec)
    it.close()
    return records, pipe_ms, pipe_cpu_ms, cpu_s


def _score(records: list, truth: np.ndarray, fps: float) -> tuple[dict, dict, dict]:
    """(``score_clip`` figures, per-joint mean error in mm, per-frame series) of ``records``."""
    pred, ok = _pred(records, truth)
    score = score_clip(pred, ok, truth, fps=fps)
    err = frame_errors(pred, truth)
    series = {"mpjpe_mm": [None if not np.isfinite(v) else round(1e3 * v, 1) for v in err["mpjpe"]],
              "mirrored": [bool(v) for v in mirrored_frames(err)], "ok": [bool(v) for v in ok]}
    per_joint = np.linalg.norm(pred - truth, axis=-1)  # (n, 16), NaN without a pose
    # diagnostics of the limb failures (docs/robustness.md, round 7): every frame's per-joint error and
    # whether one pair of limbs is exchanged (the frame's limb nearer to the other side's truth)
    series["joint_mm"] = [None if not np.isfinite(row).all() else [round(1e3 * float(v)) for v in row]
                          for row in per_joint]
    series["exchanged"] = [_exchanged(pred[k], truth[k]) for k in range(len(truth))]
    posed = np.isfinite(per_joint).all(axis=1)
    joint_mm = {j: round(1e3 * float(per_joint[posed, i].mean()), 1) if posed.any() else None
                for i, j in enumerate(JOINT_NAMES)}
    return score, joint_mm, series


def _add_quality(series: dict, records: list, n: int) -> None:
    """Add to ``series`` each of the ``n`` frames' quality figures (IoU, RMS, inside fraction, coverage
    and the not-ok ``reason`` of ``records``; None for a frame without a record), for gate studies."""
    by_frame = {rec["frame"]: rec for rec in records}
    for key in ("iou", "rms_px", "inside_fraction", "coverage", "reason"):
        series[key] = [by_frame.get(k, {}).get(key) for k in range(n)]


def _pred(records: list, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(joints (n, 16, 3) m, NaN without a pose; ok flags (n,)) of ``records`` on ``truth``'s frames."""
    pred = np.full(truth.shape, np.nan)
    ok = np.zeros(len(truth), bool)
    for rec in records:
        k = rec["frame"]
        ok[k] = bool(rec.get("ok"))
        if rec.get("joints"):
            pred[k] = [rec["joints"][j] for j in JOINT_NAMES]
    return pred, ok


def error_parts(records: list, truth: np.ndarray, floor_m: np.ndarray | None) -> dict:
    """``subject_frame_offsets.decompose`` of ``records`` against ``truth`` (per joint: constant offset
    in the body's frame, the rest, the lost stretches; the torso's yaw, lean and height), with each
    joint's IK floor (mm, ``ik_floor_joints_m``'s mean) beside it when ``floor_m`` is given."""
    parts = decompose(_pred(records, truth)[0], truth, JOINT_NAMES)
    if floor_m is not None:
        for k, j in enumerate(JOINT_NAMES):
            if j in parts["joints"]:
                parts["joints"][j]["ik_floor"] = round(1e3 * float(floor_m[:, k].mean()), 1)
    return parts


def error_parts_means(clips: list[dict]) -> dict:
    """Per joint and torso figure, the mean over ``clips`` of their ``error_parts`` (clips without one skipped)."""
    parts = [c["error_parts"] for c in clips if c.get("error_parts", {}).get("frames")]
    if not parts:
        return {}
    joints = {j: {key: round(float(np.mean([p["joints"][j][key] for p in parts if key in p["joints"][j]])), 1)
                  for key in parts[0]["joints"][j]} for j in parts[0]["joints"]}
    torso = {key: round(float(np.mean([p["torso"][key] for p in parts])), 2) for key in parts[0]["torso"]}
    return {"joints": joints, "torso": torso, "clips": len(parts)}


#: limb chains compared by ``_exchanged`` (their joints, left side; the right side's by name)
LIMB_CHAINS = {"legs": ("left_knee", "left_ankle"), "arms": ("left_elbow", "left_wrist")}


def _exchanged(pred: np.ndarray, truth: np.ndarray) -> list[str]:
    """The limb pairs (``LIMB_CHAINS``) whose left and right chains are each nearer to the other side's
    truth than to their own, by at least 50 mm in the sum over both chains; [] without a pose."""
    if not np.isfinite(pred).all():
        return []
    out = []
    for name, joints in LIMB_CHAINS.items():
        li = [JOINT_NAMES.index(j) for j in joints]
        ri = [JOINT_NAMES.index(j.replace("left_", "right_")) for j in joints]
        own = np.linalg.norm(pred[li] - truth[li], axis=1).sum() + np.linalg.norm(pred[ri] - truth[ri], axis=1).sum()
        other = np.linalg.norm(pred[li] - truth[ri], axis=1).sum() + np.linalg.norm(pred[ri] - truth[li], axis=1).sum()
        if other < own - 0.05:
            out.append(name)
    return out


def calibrate_clip(session, backgrounds, *, frames: int, samples: int) -> tuple:
    """The subject calibrated as ``contourcap track --calibrate-subject 0:FRAMES --calibrate-samples
    SAMPLES [--floor-test]`` does (``service.commands.calibrate_subject.auto_calibrate``: the window cut to the
    clip, its second half tracked by the scene tracker, ``samples`` trusted frame sets spread in time
    and pose, a third held out, the body adopted only when it explains those better), with the
    clip's learned background models.  Nothing of the truth is used.  Returns (the adopted BodyModel
    or None, info dict: adopted, held-out IoU before/after, frames fitted/held out, CPU seconds of
    the whole calibration and of the fit and judgement alone)."""
    c0 = time.process_time()
    names = list(session.camera_names)
    window = within_take(session, names, range(0, frames))
    options = AutoSubjectOptions.for_sample(samples, span=len(window), offers_per_set=1)
    res = auto_calibrate(session, names, window, session_model(session, MODEL[0]), options, backgrounds=backgrounds,
                         segmentation=TRACK_OPTIONS.get("segmentation"))
    info = {"window": [window.start, window.stop], "adopted": bool(res is not None and res.adopted)}
    if res is not None:
        info.update({"held_out_iou": [res.iou_current, res.iou_calibrated], "frames_fitted": list(res.fit_frames),
                     "frames_held_out": list(res.held_out_frames), "fit_cpu_s": res.cpu_s,
                     "held_out_ious": [list(v) for v in res.held_out_ious],
                     "segment_lengths_m": res.fit.segment_lengths, "widths_m": res.fit.widths,
                     "radius_scale": res.fit.radius_scale})
    if info["adopted"]:  # the subject file contourcap track --calibrate-subject writes (``--calibrate-from``)
        info["subject_toml"] = subject_toml(res.subject)
    info["cpu_s"] = time.process_time() - c0
    return (res.fit.model if info["adopted"] else None), info


def subject_body(info: dict):
    """The BodyModel of a calibration's subject file (``info["subject_toml"]``, ``calibrate_clip``'s
    info: the file a studio keeps and tracks other takes with, ``--subject``), None when not adopted."""
    text = info.get("subject_toml") if info.get("adopted") else None
    return None if text is None else parse_subject(toml_loads(text), "calibration").body()


def truth_lengths(truth: np.ndarray) -> dict:
    """The rendered subject's joint-centre distances (m, medians over the frames of ``truth`` (n, 16, 3),
    the BVH joint centres): thigh, shank, upper arm, forearm (left and right averaged), pelvis to neck,
    hip and shoulder widths.  Compare them with a model's same joint-centre distances, not with its
    ``segment_lengths`` / ``widths`` entries (the model's ``hip_width`` spaces the thighs' origins)."""
    j = {name: truth[:, i] for i, name in enumerate(JOINT_NAMES)}

    def dist(a: str, b: str) -> float:
        return float(np.median(np.linalg.norm(j[a] - j[b], axis=-1)))

    pairs = {"thigh": ("hip", "knee"), "shank": ("knee", "ankle"), "upper_arm": ("shoulder", "elbow"),
             "forearm": ("elbow", "wrist")}
    out = {k: round(0.5 * (dist(f"left_{a}", f"left_{b}") + dist(f"right_{a}", f"right_{b}")), 4)
           for k, (a, b) in pairs.items()}
    out.update({"pelvis_to_neck": round(dist("pelvis", "neck"), 4),
                "hip_width": round(dist("left_hip", "right_hip"), 4),
                "shoulder_width": round(dist("left_shoulder", "right_shoulder"), 4)})
    return out


#: the body model tracked (``--model``: a bundled name or a model file)
MODEL = ["knossow40"]

def run_clip(name: str, skeleton, subject_index: int, n_cameras: int, *, frames: int, fps: float, size,
             ik_floor: bool = True, budget_s: float = 0.0, method: str = "contours",
             calibrate_frames: int = 0, calibrate_samples: int = 9, calibration: dict | None = None) -> dict:
    """Render, track and score one clip; returns its per-clip record.

    ``budget_s`` > 0: stop tracking once reading, segmenting and tracking this clip has used that
    much CPU time; the frames left are scored as not ok without a pose (``unprocessed``).
    ``calibrate_frames`` > 0: also calibrate the subject on frames 0:that (``calibrate_clip``) and,
    when adopted, track the whole clip again with the calibrated body (``"calibrated"``).
    ``calibration``: instead, a calibration made on another clip of the subject (``calibrate_clip``'s
    info, ``--calibrate-from``): the clip is tracked again with its subject file's body when adopted;
    the record's ``calibrated.calibration`` is that info with ``own`` false."""
    t_clip = time.perf_counter()
    motion = clip_motion(name, skeleton, subject=subject_index, frames=frames, fps=fps)
    calibrated = None
    with tempfile.TemporaryDirectory(prefix="robustness_") as tmp:
        root = Path(tmp) / f"s{subject_index}_{name}_{n_cameras}"
        truth, backgrounds, height, render_ms, seg_iou = render_session(root, motion, subject_index, n_cameras, size)
        session = load_session(root)
        records, pipe_ms, pipe_cpu_ms, cpu_s = _track(session, backgrounds, method=method, budget_s=budget_s)
        if calibrate_frames > 0 or calibration is not None:
            if calibration is None:
                body, info = calibrate_clip(session, backgrounds, frames=calibrate_frames, samples=calibrate_samples)
                info["own"] = True
            else:
                body, info = subject_body(calibration), {**calibration, "own": False}
            if body is not None:
                rec_c, _, _, cpu_c = _track(session, backgrounds, method=method, budget_s=budget_s, model=body)
            else:  # not adopted (or no trusted fit): the height-only track stands
                rec_c, cpu_c = records, cpu_s
            score_c, joint_c, series_c = _score(rec_c, truth, fps)
            _add_quality(series_c, rec_c, len(truth))
            calibrated = {**score_c, "joint_mm": joint_c, "unprocessed": len(truth) - len(rec_c), "cpu_s": cpu_c,
                          "calibration": info, "series": series_c}
    score, joint_mm, series = _score(records, truth, fps)
    _add_quality(series, records, len(truth))
    floor_m = ik_floor_joints_m(motion, subject_index, height, fps=fps, model=MODEL[0]) if ik_floor else None
    floor_mm = None if floor_m is None else float(1e3 * floor_m.mean())
    lat = [r["latency_ms"] for r in records]
    reasons: dict[str, int] = {}
    for r in records:
        if not r.get("ok"):
            for key in _reason_keys(r.get("reason", "")):
                reasons[key] = reasons.get(key, 0) + 1
    out = {"subject": subject_index, "clip": name, "cameras": n_cameras, "method": method,
           "height_m": round(height, 3), "truth_lengths_m": truth_lengths(truth),
           **score, "segmentation_iou_median": seg_iou, "unprocessed": len(truth) - len(records), "cpu_s": cpu_s, "ik_floor_mm": floor_mm,
           "not_ok_reasons": reasons, "joint_mm": joint_mm, "ms_per_frame_median": float(np.median(lat)),
           "pipeline_ms_per_frame_median": float(np.median(pipe_ms)), "render_ms_per_frame": render_ms,
           "wall_s": time.perf_counter() - t_clip,
           "latencies_ms": lat, "pipeline_ms": pipe_ms, "pipeline_cpu_ms": pipe_cpu_ms, "series": series}
    out["error_parts"] = error_parts(records, truth, floor_m)
    if calibrated is not None:
        calibrated["error_parts"] = error_parts(rec_c, truth, None)
        out["calibrated"] = calibrated
    return out


def summarise(per_clip: list[dict]) -> dict:
    """The headline figures over per-clip records (``run_clip``)."""
    summary = summarise_clips(per_clip)
    floors = [r["ik_floor_mm"] for r in per_clip if r["ik_floor_mm"] is not None]
    lat = [v for r in per_clip for v in r["latencies_ms"]]
    pipe = [v for r in per_clip for v in r["pipeline_ms"]]
    pipe_cpu = [v for r in per_clip for v in r.get("pipeline_cpu_ms", [])]
    cal = [r["calibrated"] for r in per_clip if "calibrated" in r]
    if cal:  # the same clips tracked with the calibrated subject (``--calibrate``, ``--calibrate-from``)
        cal_summary = summarise_clips(cal)
        own = [c["calibration"] for c in cal if c["calibration"].get("own", True)]  # the calibrations run
        summary = {**summary, "mpjpe_mm_mean_height_only": summary["mpjpe_mm_mean"],
                   **{f"{k}_calibrated": v for k, v in cal_summary.items()},
                   "calibrations": len(own), "calibration_cpu_s_total": float(sum(c["cpu_s"] for c in own)),
                   "calibration_cpu_s_median": float(np.median([c["cpu_s"] for c in own])) if own else None,
                   "calibration_adopted_percent": 100.0 * float(np.mean([bool(c.get("adopted", True)) for c in own]))
                   if own else None,
                   "joint_mm_height_only": _joint_means(per_clip), "joint_mm_calibrated": _joint_means(cal)}
        summary.update(held_out_summary(per_clip))
    summary["error_parts"] = error_parts_means(per_clip)
    if cal:
        summary["error_parts_calibrated"] = error_parts_means(cal)
    return {"subjects": len({r["subject"] for r in per_clip}), "clips": len(per_clip), **summary,
            "ik_floor_mm_mean": float(np.mean(floors)) if floors else None,
            "unprocessed_percent": 100.0 * sum(r["unprocessed"] for r in per_clip) / summary["frames"],
            "ms_per_frame_median": float(np.median(lat)) if lat else None,
            "pipeline_ms_per_frame_median": float(np.median(pipe)) if pipe else None,
            "pipeline_cpu_ms_per_frame_median": float(np.median(pipe_cpu)) if pipe_cpu else None}


def held_out_summary(per_clip: list[dict]) -> dict:
    """``--calibrate-from MOTION``'s figures: ``calibrate_from``, the ``summarise_clips`` figures of the
    clips of other motions (the takes the body was not fitted on) with the suffixes ``_calibrated_held_out``
    and ``_height_only_held_out``, and per subject the calibration's body beside the rendered subject's
    lengths (``calibration_bodies``); {} for records without ``calibrate_from`` (``--calibrate N``)."""
    froms = {r["calibrated"]["calibration"].get("calibrate_from") for r in per_clip if "calibrated" in r} - {None}
    if not froms:
        return {}
    if len(froms) > 1:
        raise ValueError(f"clips calibrated from different motions: {sorted(froms)}")
    motion = froms.pop()
    held = [r for r in per_clip if "calibrated" in r and r["clip"] != motion]
    out: dict = {"calibrate_from": motion, "clips_held_out": len(held)}
    if held:
        out.update({f"{k}_calibrated_held_out": v for k, v in summarise_clips([r["calibrated"] for r in held]).items()})
        out.update({f"{k}_height_only_held_out": v for k, v in summarise_clips(held).items()})
    keys = ("adopted", "held_out_iou", "segment_lengths_m", "widths_m", "radius_scale", "cpu_s")
    out["calibration_bodies"] = [{"subject": r["subject"], "clip": r["clip"], "cameras": r["cameras"],
                                  **{k: r["calibrated"]["calibration"].get(k) for k in keys},
                                  "truth_lengths_m": r.get("truth_lengths_m")}
                                 for r in per_clip if r.get("calibrated", {}).get("calibration", {}).get("own")]
    return out


def _joint_means(clips: list[dict]) -> dict:
    """Per joint, the mean over clips of the clips' mean error (mm)."""
    return {j: round(float(np.mean([c["joint_mm"][j] for c in clips if c["joint_mm"][j] is not None] or [np.nan])), 1)
            for j in JOINT_NAMES}


def merge(paths) -> dict:
    """One result from several ``--out`` files (e.g. subjects run in separate processes)."""
    runs = [json.loads(Path(p).read_text()) for p in paths]
    per_clip = [c for r in runs for c in r["per_clip"]]
    for c in per_clip:  # records written before ``posed_after`` existed
        if "posed_after" not in c and c["posed"] + c["unprocessed"] == c["frames"]:
            # the frames without a pose are the trailing unprocessed ones
            c["posed_after"] = max(0, c["posed"] - (c["frames"] - c["frames_after"]))
    drop = ("per_clip", "subject_ids", "wall_s", "machine_ref_ms", "motions", "cameras", "partial")
    head = {k: v for k, v in runs[0].items() if k not in drop}
    return {**head, "subject_ids": sorted({c["subject"] for c in per_clip}), **summarise(per_clip),
            "motions": [m for m in CLIPS if any(c["clip"] == m for c in per_clip)],
            "cameras": sorted({c["cameras"] for c in per_clip}),
            "machine_ref_ms": float(np.median([r["machine_ref_ms"] for r in runs])),
            "wall_s": max(r.get("wall_s", float("nan")) for r in runs), "partial": any(r.get("partial") for r in runs),
            "merged": [str(p) for p in paths], "per_clip": per_clip}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--quick", action="store_true",
                    help=f"a small subset: {QUICK['subjects']} subjects, clips {QUICK['clips']}, "
                         f"{QUICK['cameras']} cameras, {QUICK['frames']} frames")
    ap.add_argument("--subjects", type=int, default=6, help="subjects 0 .. N-1")
    ap.add_argument("--subject-ids", default=None, help="comma-separated subject indices (instead of --subjects)")
    ap.add_argument("--clips", default=",".join(CLIPS), help=f"comma-separated, from {','.join(CLIPS)}")
    ap.add_argument("--cameras", default="4,6", help="comma-separated camera counts")
    ap.add_argument("--frames", type=int, default=75)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--all-cameras", action="store_true",
                    help="every clip with every camera count (default: balanced, clip j of subject s uses "
                         "cameras[(s + j) %% len(cameras)])")
    ap.add_argument("--clip-budget-s", type=float, default=20.0,
                    help="CPU seconds of tracking per clip after which its remaining frames count as not ok "
                         "without a pose (0: no limit)")
    ap.add_argument("--method", choices=("contours", "blobs"), default="contours",
                    help="contours: the Knossow contour tracker; blobs: the BMVC'04 blob tracker (tracker.blobs)")
    ap.add_argument("--no-ik-floor", action="store_true", help="skip the inverse-kinematics floor per clip")
    ap.add_argument("--no-front-back", action="store_true",
                    help="track without the front/back guard (tracker.fitting.hypotheses), for comparison")
    ap.add_argument("--scene", action="store_true",
                    help="track with the scene tracker (tracker.fitting.scene: clutter learned, seated start), as "
                         "contourcap track does without --no-scene (default: every foreground pixel is body)")
    ap.add_argument("--scene-option", action="append", default=[], metavar="NAME=VALUE",
                    help="with --scene: a tracker.fitting.scene.SceneOptions field (repeatable)")
    ap.add_argument("--no-floor-test", action="store_true",
                    help="segment each camera alone (no segmentation.floor test), as the live workers do")
    ap.add_argument("--no-retrack", action="store_true",
                    help="fit every frame once, as a live tracker does (contourcap track --no-retrack; default: "
                         "the stretches the gate refused are fitted again backwards from the next accepted frame)")
    ap.add_argument("--no-smooth", action="store_true",
                    help="score the poses as fitted (contourcap track --no-smooth; default: smoothed over "
                         "contourcap track's window, service.smoothed; --no-retrack implies it)")
    ap.add_argument("--tracker-option", action="append", default=[], metavar="NAME=VALUE",
                    help="a TrackerOptions field for this run (e.g. min_iou=0.7, iou_every=1); repeatable")
    ap.add_argument("--calibrate", type=int, default=0, metavar="FRAMES",
                    help="also calibrate the subject (lengths, widths, radii) as contourcap track "
                         "--calibrate-subject 0:FRAMES does (100: its default; cut to the clip) and track each "
                         "clip again with it when adopted: figures with the suffix _calibrated "
                         "beside the height-only ones (0: off)")
    ap.add_argument("--calibrate-from", default=None, metavar="MOTION",
                    help="per subject, calibrate once on its MOTION clip (e.g. tpose_start; frames 0:N with "
                         "--calibrate N, default 100, cut to the clip) and track every clip of the subject again "
                         "with that body: the _calibrated figures, and _held_out ones without the MOTION clips")
    ap.add_argument("--model", default="knossow40",
                    help="body model: a bundled name or a model TOML file (sized by each clip's height; "
                         "--calibrate needs a bundled one)")
    ap.add_argument("--calibrate-samples", type=int, default=9,
                    help="frame sets the calibration samples, a third held out (default 9, as contourcap track's)")
    ap.add_argument("--blob-option", action="append", default=[], metavar="NAME=VALUE",
                    help="a tracker.blobs.BlobOptions field for --method blobs (e.g. colour_weight=2); repeatable")
    ap.add_argument("--out", type=Path, default=None, help="also write the JSON result here")
    ap.add_argument("--merge", nargs="+", type=Path, default=None, metavar="RESULT_JSON",
                    help="combine the --out files of several runs (nothing is run)")
    args = ap.parse_args(argv)
    if args.merge:
        return _emit(merge(args.merge), args)
    MODEL[0] = args.model
    if (args.calibrate or args.calibrate_from) and Path(args.model).suffix:
        ap.error("--calibrate and --calibrate-from need a bundled --model name")
    if args.no_front_back:
        TRACK_OPTIONS["front_back"] = None
    if args.no_floor_test:
        TRACK_OPTIONS["segmentation"] = SegmentationParams(floor_test=False)
    if args.scene_option and not args.scene:
        ap.error("--scene-option needs --scene")
    if args.scene:
        TRACK_OPTIONS["scene"] = _tracker_options(args.scene_option, ap, SceneOptions(), flag="--scene-option")
    if args.no_retrack:
        TRACK_OPTIONS["retrack"] = False
    if args.no_smooth or args.no_retrack:
        TRACK_OPTIONS["smooth_s"] = 0.0
    if args.tracker_option:
        TRACK_OPTIONS["options"] = _tracker_options(args.tracker_option, ap, TRACK_OPTIONS["options"])
    if args.blob_option:
        from tracker.blobs import BlobOptions
        TRACK_OPTIONS["blob_options"] = _tracker_options(args.blob_option, ap, BlobOptions(), flag="--blob-option")
    if args.quick:
        for k, v in QUICK.items():
            setattr(args, k, v)
        args.subject_ids = None
    clips = [c for c in args.clips.split(",") if c]
    unknown = [c for c in clips if c not in CLIPS]
    if unknown or not clips:
        ap.error(f"--clips: unknown {unknown}; available: {','.join(CLIPS)}")
    if args.calibrate_from is not None and args.calibrate_from not in clips:
        ap.error(f"--calibrate-from {args.calibrate_from!r}: not one of --clips {','.join(clips)}")
    try:
        cams = [int(c) for c in args.cameras.split(",") if c]
        w, h = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        ap.error("--cameras takes integers (e.g. 4,6) and --size WxH (e.g. 320x240)")
    try:
        subjects = ([int(v) for v in args.subject_ids.split(",") if v] if args.subject_ids
                    else list(range(args.subjects)))
    except ValueError:
        ap.error("--subject-ids takes comma-separated integers")
    if not subjects or min(subjects) < 0 or args.frames < 2 or not cams or min(cams) < 2 or w < 64 or h < 48:
        ap.error("need --subjects >= 1, --frames >= 2, --cameras >= 2 each and --size at least 64x48")
    warnings.filterwarnings("ignore", message="Gimbal lock")
    cv2.setNumThreads(1)
    ref = machine_ref_ms()
    # numba's first compilation in a fresh checkout must not count in the first clip's CPU budget
    warm_s = warm_up_kernels(args.method)
    skeleton = load_bvh(bundled_motion("scaled_131_01"))
    t_start = time.perf_counter()
    header = {"machine_ref_ms": ref, "kernel_warm_up_s": round(warm_s, 2), "size": [w, h], "fps": args.fps,
              "frames_per_clip": args.frames, "cameras": cams, "motions": clips, "clip_budget_s": args.clip_budget_s,
              "retrack": not args.no_retrack, "smooth_s": TRACK_OPTIONS.get("smooth_s", SMOOTH_WINDOW_S),
              "scene": dataclasses.asdict(TRACK_OPTIONS["scene"]) if args.scene else False,
              "date": datetime.date.today().isoformat()}
    if args.calibrate_from is not None:
        header["calibrate_from"] = args.calibrate_from
    per_clip = []
    for s in subjects:
        calibration = None  # --calibrate-from: the subject's calibration, made on its first MOTION clip
        for j, name in calibration_order(clips, args.calibrate_from):
            for n in (cams if args.all_cameras else [cams[(s + j) % len(cams)]]):
                own = args.calibrate_from is not None and calibration is None
                rec = run_clip(name, skeleton, s, n, frames=args.frames, fps=args.fps, size=(w, h),
                               ik_floor=not args.no_ik_floor, budget_s=args.clip_budget_s, method=args.method,
                               calibrate_frames=(args.calibrate or 100) if own else
                               0 if args.calibrate_from else args.calibrate,
                               calibrate_samples=args.calibrate_samples, calibration=calibration)
                if own:
                    calibration = rec["calibrated"]["calibration"]
                    calibration.update(calibrate_from=name, source={"subject": s, "clip": name, "cameras": n})
                per_clip.append(rec)
                if args.out is not None:  # a partial result after every clip (a long run can be read while it runs)
                    args.out.write_text(json.dumps({"partial": True, "subject_ids": subjects, **summarise(per_clip),
                                                    **header, "wall_s": time.perf_counter() - t_start,
                                                    "per_clip": per_clip}, indent=1) + "\n")
                print(f"subject {s} {name:12s} {n} cams  MPJPE {rec['mpjpe_mm'] or float('nan'):7.1f} mm  "
                      f"ok {rec['ok']:3d}/{rec['frames']}  mirrored {rec['mirrored']:3d} (after 1 s "
                      f"{rec['mirrored_after']:3d})  false ok {rec['false_ok']:3d}  false alarm "
                      f"{rec['false_alarm']:3d}  IK floor {rec['ik_floor_mm'] or float('nan'):5.1f} mm  "
                      f"{rec['ms_per_frame_median']:.0f} ms/frame  {rec['cpu_s']:.0f} s CPU  unprocessed "
                      f"{rec['unprocessed']}" + (f"  calibrated: MPJPE {rec['calibrated']['mpjpe_mm'] or float('nan'):7.1f} mm "
                                                 f"ok {rec['calibrated']['ok']:3d}  calibration "
                                                 f"{_calibration_text(rec['calibrated']['calibration'])}"
                                                 if "calibrated" in rec else ""),
                      flush=True, file=sys.stderr if args.json else sys.stdout)
    result = {"method": args.method, "subject_ids": subjects, **summarise(per_clip), **header, "wall_s": time.perf_counter() - t_start,
              "per_clip": per_clip}
    return _emit(result, args)


def calibration_order(clips: list[str], motion: str | None) -> list[tuple[int, str]]:
    """(index in ``clips``, name) in the order a subject's clips run: ``motion``'s first (the calibration
    take of ``--calibrate-from``), the others as given; the index keeps each clip's camera count."""
    return sorted(enumerate(clips), key=lambda jn: jn[1] != motion)


def _calibration_text(info: dict) -> str:
    """One line of a clip's calibration (``calibrate_clip``'s info): adopted or not, held-out IoU, CPU s."""
    iou = info.get("held_out_iou")
    held = "no trusted fits" if iou is None else f"held-out IoU {iou[0]:.3f} -> {iou[1]:.3f}"
    src = info.get("source")
    where = "" if info.get("own", True) or src is None else f" from s{src['subject']} {src['clip']} c{src['cameras']}"
    return f"{'adopted' if info.get('adopted') else 'not adopted'}{where} ({held}), {info['cpu_s']:.0f} s CPU"


def _tracker_options(pairs, ap, base, flag: str = "--tracker-option"):
    """``base`` (a ``TrackerOptions`` or ``BlobOptions``) with ``NAME=VALUE`` fields replaced (numbers,
    true/false, none; text for a field whose default is text, e.g. ``arm_goals_move=all``)."""
    fields = {f.name: f for f in dataclasses.fields(base)}
    changes = {}
    for pair in pairs:
        name, _, text = pair.partition("=")
        if name not in fields or not text:
            ap.error(f"{flag} {pair!r}: expected NAME=VALUE with NAME a {type(base).__name__} field")
        low = text.lower()
        if isinstance(getattr(base, name), str):
            changes[name] = text
            continue
        changes[name] = (None if low == "none" else low == "true" if low in ("true", "false")
                         else int(text) if text.lstrip("-").isdigit() else float(text))
    return dataclasses.replace(base, **changes)


def _emit(result: dict, args) -> int:
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    if args.json:
        print(json.dumps(result))
    else:
        for key, val in result.items():
            if key not in ("per_clip", "merged"):
                print(f"{key:48s} {val:.2f}" if isinstance(val, float) else f"{key:48s} {val}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
