"""Tracker benchmark on a synthetic session (hop, CMU 131_03): iterations, accuracy, speed.

A session is rendered with ``service.synthetic_session.make_synthetic_session`` (6 ring cameras, 800x600,
textured room, shadows, pixel noise; FFV1 video) into a temporary folder (or ``--session``), each
frame is segmented once (``segmentation.pipeline.segment_frame`` against a background model from
the session's background videos) and the same chamfer images are then tracked three ways:

- LM with the sliding term (the tracker), from the ground-truth pose of the first frame
  (``--auto-init``: from ``tracker.search.initialise`` instead);
- LM without the sliding term (iterations only);
- (for reference) the same quality figures at the ground-truth poses: with real segmentation the
  RMS is dominated by the few contour points where the images show no edge (``rms_px`` of
  ``tracker.fitting.cost.CostTerms``); the inlier RMS (residuals up to the robust loss's scale, 3 px) and
  the outlier fraction are given beside it;
- scipy ``least_squares`` with a finite-difference Jacobian (the baseline) on the first
  ``--lsq-frames`` frames, warm-started from the same ground-truth poses as the LM run on them.

Where the slow frames' time goes (hop, knossow40, instrumented run): the slowest decile takes
7.8 LM iterations and 15 cost evaluations against 2.3 and 4.6 in the faster half (the airborne
frames, where the constant-velocity prediction is off), and every per-evaluation part (contours,
occlusion, sampling, reverse term, Jacobian) grows in proportion; IoU renders add ~1 ms on
average there, garbage collection nothing; the front/back check (every 60 frames, ~2.4 median
frames) makes those frames the slowest but stays out of the 90th percentile.

``"methods"`` sets the two tracking methods side by side on the same session: ``contours`` (the LM
run above; its CPU per frame set adds segmenting every camera) and ``blobs`` (``tracker.blobs``, the
BMVC'04 tracker on the colour frames: its step includes its own sampled background test), each with
MPJPE, ok frames, mirrored frames after the first second, false ok / false alarm
(``tracker.synthetic.evaluation``), CPU ms per frame set and the frame rate that allows on one core
(``--cameras 4 --size 320x240`` for the paper's setting; ``--no-blobs`` skips the blob run).

Timings are the tracker's per-frame latency (fit only, segmentation excluded) on one core:
BLAS/OpenMP threads are limited to 1 before numpy is imported.  ``ms_per_frame_*`` are wall-clock,
``cpu_ms_per_frame_*`` this process's CPU time (steadier on a machine shared with other work).

    python bench/tracker.py [--json] [--frames 120] [--model knossow40] [--lsq-frames 8]
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from service.blas import pin_blas_threads  # noqa: E402

pin_blas_threads()

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from machine_ref import machine_ref_ms  # noqa: E402
from segmented_frames import segment_session  # noqa: E402

from capture.replay import iter_frame_sets  # noqa: E402
from capture.session import load_session  # noqa: E402
from service.offline import background_models, session_model  # noqa: E402
from service.synthetic_session import make_synthetic_session  # noqa: E402
from tracker.synthetic.synth import bundled_motion  # noqa: E402
from tracker.fitting.cost import ChamferCost  # noqa: E402
from tracker.fitting.tracking import Tracker, TrackerOptions  # noqa: E402


def track(model, cameras, frames, *, initial, sliding=True, solver="lm"):
    """Pose records; ``latency_ms`` is the tracker's own figure on the process CPU clock (this
    process's time only: on a shared machine the wall clock also counts other processes), and
    ``wall_ms`` the wall-clock time of the same ``step`` call."""
    tr = Tracker(model, cameras, sliding=sliding, solver=solver, initial_params=initial, clock=time.process_time)
    out = []
    for fid, ts, ch, sil in frames:
        t0 = time.perf_counter()
        rec = tr.step(fid, ts, ch, silhouettes=sil)
        rec["wall_ms"] = 1e3 * (time.perf_counter() - t0)
        out.append(rec)
    return out


def mpjpe_mm(records, truth) -> float:
    errs = []
    for rec in records:
        if not rec.get("joints"):
            continue
        g = truth[rec["frame"]]["joints"]
        errs.append(np.mean([np.linalg.norm(np.subtract(rec["joints"][k], g[k])) for k in g]))
    return 1e3 * float(np.mean(errs)) if errs else float("nan")


def residual_figures(model, cameras, frames, params_list):
    """Per frame at the given poses: RMS (both terms), median |residual|, inlier RMS and outlier
    fraction (residuals above the robust loss's scale ``TrackerOptions.f_scale``) over the used
    contour points, as ``tracker.fitting.cost.CostTerms`` computes them; returns the medians over frames."""
    rms, med, inl, out = [], [], [], []
    scale = TrackerOptions().f_scale
    for (fid, ts, ch, _), p in zip(frames, params_list):
        names = [c.name for c in cameras if c.name in ch]
        terms = ChamferCost(model, [c for c in cameras if c.name in ch], [ch[n] for n in names],
                            n_samples=TrackerOptions().n_samples).evaluate(np.asarray(p, dtype=float))
        rms.append(terms.rms_px())
        med.append(float(np.median(np.abs(np.concatenate([terms.d_sil[terms.used], terms.d_edge[terms.used]])))))
        inl.append(terms.rms_px(max_px=scale))
        out.append(terms.outlier_fraction(max_px=scale))
    return float(np.median(rms)), float(np.median(med)), float(np.median(inl)), float(np.median(out))


def score(records, truth, fps: float) -> dict:
    """``tracker.synthetic.evaluation.score_clip`` of pose records against the session's truth
    (MPJPE, mirrored frames after the first second, false ok / false alarm)."""
    from tracker.synthetic.evaluation import score_clip
    from tracker.synthetic.people import JOINT_NAMES

    pred = np.full((len(records), len(JOINT_NAMES), 3), np.nan)
    for i, rec in enumerate(records):
        if rec.get("joints"):
            pred[i] = [rec["joints"][j] for j in JOINT_NAMES]
    gt = np.array([[truth[r["frame"]]["joints"][j] for j in JOINT_NAMES] for r in records])
    return score_clip(pred, [bool(r.get("ok")) for r in records], gt, fps=fps)


def blob_run(session, model, frames: int, *, initial) -> list:
    """Pose records of ``tracker.blobs.BlobTracker`` on the session's frames; ``latency_ms`` on this
    thread's CPU clock (the video decoder's threads are no tracker's cost; OpenCV runs one thread here),
    ``wall_ms`` beside it."""
    from tracker.blobs import BlobTracker, initialise_from_images

    names = list(session.camera_names)
    bgs, _ = background_models(session, names)
    cams = [session.camera_model(n) for n in names]
    tr = BlobTracker(model, cams, bgs, initial_params=initial, clock=time.thread_time,
                     initialiser=lambda cs, images: initialise_from_images(model, cs, images, bgs))
    out = []
    for fid, group in iter_frame_sets(session, frames=range(0, frames)):
        ts, images = next(iter(group.values())).timestamp_ns, {n: f.image for n, f in group.items()}
        t0 = time.perf_counter()
        rec = tr.step(fid, ts, images)
        rec["wall_ms"] = 1e3 * (time.perf_counter() - t0)
        out.append(rec)
    return out


def method_figures(records, truth, fps: float, *, extra_cpu_ms: float = 0.0) -> dict:
    """The ``"methods"`` entry of one tracking method: accuracy, honesty of ``ok`` and CPU per frame
    set (``extra_cpu_ms``: work outside the tracker's step, e.g. segmenting every camera)."""
    sc = score(records, truth, fps)
    cpu = float(np.median([r["latency_ms"] for r in records])) + extra_cpu_ms
    return {"mpjpe_mm": sc["mpjpe_mm"], "mpjpe_ok_mm": sc["mpjpe_ok_mm"], "ok_frames": sc["ok"],
            "frames": sc["frames"], "mirrored_frames_after_1s": sc["mirrored_after"],
            "mirrored_after_1s_percent": 100.0 * sc["mirrored_after"] / max(sc["frames_after"], 1),
            "false_ok": sc["false_ok"], "false_alarm": sc["false_alarm"],
            "cpu_ms_per_frame_median": cpu,
            "wall_ms_per_frame_median": float(np.median([r["wall_ms"] for r in records])) + extra_cpu_ms,
            "fps_one_core": 1e3 / cpu if cpu > 0 else float("nan")}


def median(records, key) -> float:
    vals = [r[key] for r in records if r.get("ok") and r.get(key) is not None]
    return float(np.median(vals)) if vals else float("nan")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--model", default="knossow40")
    ap.add_argument("--cameras", type=int, default=6)
    ap.add_argument("--size", default="800x600")
    ap.add_argument("--lsq-frames", type=int, default=8)
    ap.add_argument("--session", type=Path, default=None, help="reuse (or write) the session here")
    ap.add_argument("--auto-init", action="store_true", help="initialise from the silhouettes, not the truth")
    ap.add_argument("--no-blobs", action="store_true", help="skip the blob tracker's run (\"methods\")")
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    ref_ms = machine_ref_ms()
    w, h = (int(v) for v in args.size.lower().split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        root = args.session or Path(tmp) / "hop"
        t0 = time.perf_counter()
        if not (root / "session.toml").is_file():
            make_synthetic_session(bundled_motion("scaled_131_03"), root, cameras=args.cameras, size=(w, h),
                                   frames=args.frames, model=args.model, seed=0)
        synth_s = time.perf_counter() - t0
        session = load_session(root)
        truth = [json.loads(line) for line in (root / "ground_truth.jsonl").read_text().splitlines() if line]
        model = session_model(session, args.model)
        cameras = list(session.calibration)
        seg_cpu: list = []
        frames, seg_ms = segment_session(session, args.frames, seg_cpu)
        initial = None if args.auto_init else np.asarray(truth[0]["params"])
        main_run = track(model, cameras, frames, initial=initial)
        methods = {"contours": method_figures(main_run, truth, session.fps, extra_cpu_ms=float(np.median(seg_cpu)))}
        if not args.no_blobs:
            methods["blobs"] = method_figures(blob_run(session, model, args.frames, initial=initial), truth,
                                              session.fps)
        no_slide = track(model, cameras, frames, initial=initial, sliding=False)
        k = min(args.lsq_frames, len(frames))
        lm_sub = [track(model, cameras, frames[i:i + 1], initial=np.asarray(truth[max(i - 1, 0)]["params"]))[0]
                  for i in range(k)]
        lsq_sub = [track(model, cameras, frames[i:i + 1], initial=np.asarray(truth[max(i - 1, 0)]["params"]),
                         solver="lsq")[0] for i in range(k)]
    lost = sum(not r["ok"] for r in main_run)
    truth_rms, truth_med, truth_inl, truth_out = residual_figures(model, cameras, frames,
                                                                  [truth[f[0]]["params"] for f in frames])
    fit_rms, fit_med, fit_inl, fit_out = residual_figures(model, cameras, frames,
                                                          [r.get("params", truth[r["frame"]]["params"])
                                                           for r in main_run])
    lm_ms = median(lm_sub, "latency_ms")
    lsq_ms = median(lsq_sub, "latency_ms")
    result = {
        "machine_ref_ms": ref_ms,
        "model": model.name, "dof": model.n_params, "frames": len(main_run), "cameras": len(cameras),
        "size": [w, h], "init": "auto" if args.auto_init else "ground_truth_frame0",
        "iterations_median": median(main_run, "iterations"),
        "iterations_no_sliding_median": median(no_slide, "iterations"),
        "rms_px_median": median(main_run, "rms_px"),
        "rms_px_at_truth_median": truth_rms,
        "abs_residual_px_median": fit_med,
        "abs_residual_px_at_truth_median": truth_med,
        "rms_inlier_px_median": fit_inl, "outlier_fraction_median": fit_out,
        "rms_inlier_px_at_truth_median": truth_inl, "outlier_fraction_at_truth_median": truth_out,
        "mpjpe_mm": mpjpe_mm(main_run, truth),
        "mpjpe_no_sliding_mm": mpjpe_mm(no_slide, truth),
        "lost_frames": lost,
        "ms_per_frame_median": median(main_run, "wall_ms"),
        "cpu_ms_per_frame_median": median(main_run, "latency_ms"),
        "cpu_ms_per_frame_p90": float(np.percentile([r["latency_ms"] for r in main_run], 90)),
        "iou_checks": sum("iou" in r for r in main_run),
        "ms_per_frame_no_sliding_median": median(no_slide, "wall_ms"),
        "lsq_frames": k,
        "ms_per_frame_lm_subset_median": lm_ms,
        "ms_per_frame_lsq_median": lsq_ms,
        "lsq_speedup": lsq_ms / lm_ms if lm_ms > 0 else float("nan"),
        "lsq_mpjpe_mm": mpjpe_mm(lsq_sub, truth),
        "lsq_iterations_median": median(lsq_sub, "iterations"),
        "segmentation_ms_per_camera_median": seg_ms,
        "synthesis_s": synth_s,
        "methods": methods,
    }
    if args.json:
        print(json.dumps(result))
    else:
        for key, val in result.items():
            if key == "methods":
                for name, figs in val.items():
                    print(f"methods.{name}: " + ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}"
                                                         for k, v in figs.items()))
                continue
            print(f"{key:34s} {val:.3f}" if isinstance(val, float) else f"{key:34s} {val}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
