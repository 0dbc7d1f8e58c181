"""Segmentation benchmark: per camera frame, single thread (cv2.setNumThreads(1)).

Prints median milliseconds per stage (background test, clean-up, edges, distance transforms,
quantisation, total = ``segment_frame``) at 800x600 and 644x486, full image and with an ROI
covering 30 % of the image; full vs diagonal covariance; precise vs 5x5 distance transform;
OpenCV's MOG2 as a baseline (time and IoU on the synthetic set); and, when ../shared/data is
there, the real uu_studio held-out background false-positive rate; and segmentation inside the
predicted pose's rectangle per camera (``tracker.imaging.roi``) on a rendered hop session.

    python bench/segmentation.py [--json] [--repeats N] [--roi-frames 20] [--only-pose-roi]
    python bench/segmentation.py --live-session DIR [--live-frames 40]   (the live worker's sequence)
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from service.blas import pin_blas_threads  # noqa: E402

pin_blas_threads()

import argparse
import json
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from machine_ref import machine_ref_ms  # noqa: E402

from segmentation import (BackgroundModel, SegmentationParams, chamfer_images, clean_silhouette,  # noqa: E402
                          distance_to_mask, segment_frame, silhouette_edges, silhouette_from_distance)
from segmentation.distance import content_box, quantise  # noqa: E402
from segmentation.synthetic import synthetic_scene  # noqa: E402

SHARED = Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def _iou(a, b) -> float:
    a, b = a > 0, b > 0
    return float(np.count_nonzero(a & b)) / max(np.count_nonzero(a | b), 1)


CLOCK = time.perf_counter  # --cpu switches to time.process_time (less sensitive to a busy machine)


def _ms(fn, repeats: int) -> tuple[float, object]:
    out = fn()
    ts = []
    for _ in range(repeats):
        t0 = CLOCK()
        out = fn()
        ts.append(CLOCK() - t0)
    return float(np.median(ts) * 1e3), out


def _roi_30(person: np.ndarray) -> tuple[int, int, int, int]:
    """A box of ~30 % of the image around the person."""
    h, w = person.shape
    ys, xs = np.nonzero(person)
    rh = min(h, int(ys.max() - ys.min()) + 40)
    rw = min(w, int(0.30 * w * h / rh))
    cx, cy = (xs.min() + xs.max()) // 2, (ys.min() + ys.max()) // 2
    x0 = int(np.clip(cx - rw // 2, 0, w - rw))
    y0 = int(np.clip(cy - rh // 2, 0, h - rh))
    return x0, y0, x0 + rw, y0 + rh


def stage_times(model, frame, params: SegmentationParams, roi, repeats: int) -> dict:
    """Median ms of each stage, called exactly as segment_frame calls them (``params.auto_roi`` off)."""
    w, h = model.size
    box = roi or (0, 0, w, h)
    x0, y0, x1, y1 = box
    t = {}
    t["background_ms"], d = _ms(lambda: model.distance(frame, roi=box), repeats)
    t["cleanup_ms"], sil = _ms(lambda: clean_silhouette(
        d, low=params.low, high=params.high, min_area_px=params.min_area_px((w, h)),
        max_hole_fraction=params.max_hole_fraction, open_px=params.open_px, close_px=params.close_px,
        max_components=params.max_components), repeats)
    t["edges_ms"], edges = _ms(lambda: silhouette_edges(
        frame[y0:y1, x0:x1], sil, low=params.canny_low, high=params.canny_high,
        dilate_px=params.edge_dilate_px, blur_sigma=params.blur_sigma), repeats)
    cx0, cy0, cx1, cy1 = content_box((sil, edges), margin_px=int(np.ceil(params.max_distance_px)) + 1,
                                     region=(0, 0, x1 - x0, y1 - y0))
    s_c, e_c = sil[cy0:cy1, cx0:cx1], edges[cy0:cy1, cx0:cx1]
    t["distance_ms"], (ds, de) = _ms(lambda: (
        distance_to_mask(s_c, max_distance_px=params.max_distance_px, precise=params.precise),
        distance_to_mask(e_c, max_distance_px=params.max_distance_px, precise=params.precise_edges)), repeats)
    t["quantise_ms"], _ = _ms(lambda: (quantise(ds, resolution_px=params.resolution_px, dtype=np.uint8),
                                       quantise(de, resolution_px=params.resolution_px, dtype=np.uint8)), repeats)
    t["total_ms"], seg = _ms(lambda: segment_frame(model, frame, roi=roi, params=params), repeats)
    t["chamfer_crop_wh"] = [int(cx1 - cx0), int(cy1 - cy0)]
    return t


def bench_size(size, repeats: int, seed: int) -> dict:
    scene = synthetic_scene(np.random.default_rng(seed), size=size, n_background=50, n_frames=5)
    out: dict = {"size": list(size)}
    for cov in ("full", "diag"):
        model = BackgroundModel.from_frames(scene.background_frames, covariance=cov)
        full = SegmentationParams(auto_roi=False)
        ious = [_iou(segment_frame(model, f, params=full).silhouette, p) for f, p in zip(scene.frames, scene.person_masks)]
        shadow_bg = [float(np.mean(segment_frame(model, f, params=full).silhouette[s] == 0))
                     for f, s in zip(scene.frames, scene.shadow_masks)]
        entry = {"iou_min": min(ious), "iou_mean": float(np.mean(ious)), "shadow_background_min": min(shadow_bg)}
        variants = (("default", SegmentationParams(auto_roi=False)),
                    ("all_precise", SegmentationParams(auto_roi=False, precise_edges=True)),
                    ("all_mask5", SegmentationParams(auto_roi=False, precise=False)))
        for label, params in variants:
            if cov == "full" and label != "default":
                continue
            for roi_label in ("full_image", "roi30"):
                per_frame = []
                for f, p in zip(scene.frames, scene.person_masks):
                    roi = _roi_30(p) if roi_label == "roi30" else None
                    per_frame.append(stage_times(model, f, params, roi, repeats))
                entry[f"{label}_{roi_label}"] = {k: float(np.median([t[k] for t in per_frame]))
                                                 for k in per_frame[0] if k.endswith("_ms")}
                if roi_label == "roi30":
                    r = _roi_30(scene.person_masks[0])
                    entry[f"{label}_{roi_label}"]["roi_fraction"] = (r[2] - r[0]) * (r[3] - r[1]) / (size[0] * size[1])
        if cov == "diag":
            auto = SegmentationParams()  # the default: automatic ROI
            per = [(_ms(lambda: model.coarse_distance(f), repeats)[0],
                    _ms(lambda: segment_frame(model, f, params=auto), repeats)[0],
                    _iou(segment_frame(model, f, params=auto).silhouette, p))
                   for f, p in zip(scene.frames, scene.person_masks)]
            entry["auto_roi"] = {"coarse_background_ms": float(np.median([x[0] for x in per])),
                                 "total_ms": float(np.median([x[1] for x in per])),
                                 "iou_mean": float(np.mean([x[2] for x in per]))}
        out[f"ours_{cov}"] = entry
    out["mog2"] = bench_mog2(scene, repeats)
    return out


def bench_mog2(scene, repeats: int) -> dict:
    """MOG2 (shadow detection on) trained on the background frames, then frozen (learningRate 0)."""
    mog = cv2.createBackgroundSubtractorMOG2(history=len(scene.background_frames), detectShadows=True)
    for f in scene.background_frames:
        mog.apply(f, learningRate=-1)
    ious, ious_clean, ms = [], [], []
    h, w = scene.frames.shape[1:3]
    min_area = SegmentationParams().min_area_px((w, h))
    for f, p in zip(scene.frames, scene.person_masks):
        t, mask = _ms(lambda: mog.apply(f, learningRate=0), repeats)
        ms.append(t)
        fg = (mask == 255).astype(np.float32) * 100.0  # 127 = shadow -> background
        ious.append(_iou(fg, p))
        ious_clean.append(_iou(silhouette_from_distance(fg, min_area_px=min_area), p))
    return {"apply_ms": float(np.median(ms)), "iou_mean_raw": float(np.mean(ious)),
            "iou_mean_with_our_cleanup": float(np.mean(ious_clean)), "iou_frames_with_our_cleanup": ious_clean,
            "iou_frames_raw": ious}


def bench_iou_over_scenes(n: int) -> dict:
    """IoU of ours (defaults) and MOG2 (+ our clean-up) over ``n`` random 640x480 scenes, with clothing
    colours that are never shadow-like (solvable) and with any random colours."""
    out = {}
    for avoid in (True, False):
        ours, mog, mog_raw = [], [], []
        for seed in range(n):
            scene = synthetic_scene(np.random.default_rng(1000 + seed), size=(640, 480), n_background=30,
                                    n_frames=4, avoid_shadow_like=avoid)
            model = BackgroundModel.from_frames(scene.background_frames)
            ours += [_iou(segment_frame(model, f).silhouette, p) for f, p in zip(scene.frames, scene.person_masks)]
            res = bench_mog2(scene, 1)
            mog.append(res["iou_frames_with_our_cleanup"])
            mog_raw.append(res["iou_frames_raw"])
        mog = [v for m in mog for v in m]
        mog_raw = [v for m in mog_raw for v in m]
        key = "solvable_colours" if avoid else "any_colours"
        out[key] = {
            "frames": len(ours),
            "ours_iou_median": float(np.median(ours)), "ours_frames_iou_ge_095": float(np.mean(np.array(ours) >= 0.95)),
            "ours_iou_min": float(np.min(ours)),
            "mog2_cleaned_iou_median": float(np.median(mog)),
            "mog2_cleaned_frames_iou_ge_095": float(np.mean(np.array(mog) >= 0.95)),
            "mog2_raw_iou_median": float(np.median(mog_raw)), "mog2_raw_iou_min": float(np.min(mog_raw)),
            "mog2_raw_frames_iou_ge_095": float(np.mean(np.array(mog_raw) >= 0.95)),
        }
    return out


def bench_real(repeats: int) -> dict:
    """uu_studio: model from background frames 0-49, held-out frames 104-133 and video frame timing."""
    root = SHARED / "uu_studio"
    if not root.is_dir():
        return {"skipped": f"{root} not found"}
    out = {}
    for cam in sorted(p.name for p in root.iterdir() if p.is_dir()):
        cap = cv2.VideoCapture(str(root / cam / "background.avi"))
        frames = []
        while True:
            ok, f = cap.read()
            if not ok:
                break
            frames.append(f)
        cap = cv2.VideoCapture(str(root / cam / "video.avi"))
        ok, video0 = cap.read()
        entry = {}
        for cov in ("full", "diag"):
            model = BackgroundModel.from_frames(frames[:50], covariance=cov)
            held = frames[-30:]
            d = np.stack([model.distance(f) for f in held])
            entry[cov] = {
                "heldout_pixels_d_gt_16": float(np.mean(d > 16)),
                "heldout_pixels_d_gt_64": float(np.mean(d > 64)),
                "heldout_foreground_fraction_max": max(segment_frame(model, f).foreground_fraction for f in held),
                "video_foreground_fraction": segment_frame(model, video0).foreground_fraction,
                "video_total_ms_auto_roi": _ms(lambda: segment_frame(model, video0), repeats)[0],
                "video_total_ms_full_image": _ms(lambda: segment_frame(
                    model, video0, params=SegmentationParams(auto_roi=False)), repeats)[0],
                "video_background_ms": _ms(lambda: model.distance(video0), repeats)[0],
            }
        cov = BackgroundModel.from_frames(frames[:50], covariance="full").cov_yuv.astype(np.float64)
        sd = np.sqrt(np.maximum(cov[..., :3], 0.0))
        noisy = (sd > 0.5).all(axis=-1)  # pixels with measurable noise in Y, U and V
        entry["fraction_pixels_sd_gt_0.5_all_channels"] = float(noisy.mean())
        entry["median_sd_yuv"] = [float(v) for v in np.median(sd.reshape(-1, 3), axis=0)]
        entry["median_abs_corr_yu_uv_yv_on_noisy_pixels"] = [
            float(np.median(np.abs(cov[..., 3 + k][noisy] / (sd[..., a][noisy] * sd[..., b][noisy]))))
            for k, (a, b) in enumerate(((0, 1), (1, 2), (0, 2)))]
        out[cam] = entry
    return out


def bench_distance_accuracy() -> dict:
    """Max error (px) of the 5x5 chamfer mask vs the precise L2 transform, on a person-sized mask."""
    m = np.zeros((600, 800), np.uint8)
    cv2.ellipse(m, (400, 300), (70, 200), 10, 0, 360, 255, -1)
    precise = distance_to_mask(m, max_distance_px=48.0, precise=True)
    mask5 = distance_to_mask(m, max_distance_px=48.0, precise=False)
    return {"mask5_max_abs_err_px": float(np.abs(precise - mask5).max())}


def bench_pose_roi(frames: int, cameras: int, size, repeats: int, session_dir: Path | None,
                   stages: bool = True) -> dict:
    """Segmentation where the body can be: per camera, the rectangle of ``tracker.imaging.roi.pose_rois``
    around the predicted pose (constant velocity from the two previous true poses, as the tracker
    predicts from its fits) against the full frame (``auto_roi`` off) and the default automatic
    ROI, on a rendered hop session (``tracker.synthetic.synth``, true silhouettes kept); also the rectangle
    with per-part margins from the predicted motion (``motion_margins``: 2 cm + the part's motion since
    the previous pose), and (``stages``) the time of each stage of the three.  Times are medians
    over cameras and frames of ``segment_frame``; IoU against the true silhouette and against the
    full-frame segmentation (1.0: the ROI lost nothing)."""
    import tempfile

    from capture.replay import iter_frame_sets
    from capture.session import load_session
    from service.offline import background_models, session_model
    from tracker.imaging.roi import motion_margins, pose_rois
    from tracker.synthetic.synth import bundled_motion

    from service.synthetic_session import make_synthetic_session

    with tempfile.TemporaryDirectory() as tmp:
        root = session_dir or Path(tmp) / "hop"
        if not (root / "session.toml").is_file():
            make_synthetic_session(bundled_motion("scaled_131_03"), root, cameras=cameras, size=tuple(size),
                                   frames=frames, seed=0, masks=True)
        session = load_session(root)
        truth = [json.loads(line)["params"] for line in (root / "ground_truth.jsonl").read_text().splitlines() if line]
        model = session_model(session, "knossow40")
        cams = list(session.calibration)
        names = [c.name for c in cams]
        bgs, _ = background_models(session, names)
        full_p, auto_p = SegmentationParams(auto_roi=False), SegmentationParams()
        rows, stage_rows = [], {}
        for fid, group in iter_frame_sets(session, frames=range(2, frames)):
            pred = model.clamp(2.0 * np.asarray(truth[fid - 1]) - np.asarray(truth[fid - 2]))
            rois = pose_rois(model, pred, cams)
            motion = pose_rois(model, pred, cams, margin_m=motion_margins(model, pred, np.asarray(truth[fid - 1])))
            for cam, roi, mroi in zip(cams, rois, motion):
                img, bg = group[cam.name].image, bgs[cam.name]
                mask_path = root / "masks" / cam.name / f"{fid:06d}.png"
                true = cv2.imread(str(mask_path), cv2.IMREAD_GRAYSCALE) if mask_path.is_file() else None
                t_full, seg_full = _ms(lambda: segment_frame(bg, img, params=full_p), repeats)
                t_auto, _ = _ms(lambda: segment_frame(bg, img, params=auto_p), repeats)
                t_roi, seg_roi = _ms(lambda: segment_frame(bg, img, roi=roi, params=full_p), repeats)
                t_motion, seg_motion = _ms(lambda: segment_frame(bg, img, roi=mroi, params=full_p), repeats)
                w, h = bg.size
                x0, y0, x1, y1 = roi or (0, 0, w, h)
                mx0, my0, mx1, my1 = mroi or (0, 0, w, h)
                if stages:
                    for key, box in (("full", None), ("roi", roi), ("motion_roi", mroi)):
                        stage_rows.setdefault(key, []).append(stage_times(bg, img, full_p, box, repeats))
                rows.append({"full_ms": t_full, "auto_ms": t_auto, "roi_ms": t_roi, "motion_roi_ms": t_motion,
                             "roi_fraction": (x1 - x0) * (y1 - y0) / (w * h),
                             "motion_roi_fraction": (mx1 - mx0) * (my1 - my0) / (w * h),
                             "iou_motion_roi_vs_full": _iou(seg_motion.silhouette, seg_full.silhouette),
                             "iou_roi_vs_full": _iou(seg_roi.silhouette, seg_full.silhouette),
                             "iou_full_vs_true": _iou(seg_full.silhouette, true) if true is not None else None,
                             "iou_roi_vs_true": _iou(seg_roi.silhouette, true) if true is not None else None})
    med = {k: float(np.median([r[k] for r in rows]))
           for k in ("full_ms", "auto_ms", "roi_ms", "motion_roi_ms", "roi_fraction", "motion_roi_fraction")}
    out = {"frames": frames - 2, "cameras": len(cams), "size": list(size), "camera_frames": len(rows), **med,
           "roi_over_full": med["roi_ms"] / med["full_ms"], "roi_over_auto": med["roi_ms"] / med["auto_ms"],
           "motion_roi_over_full": med["motion_roi_ms"] / med["full_ms"],
           "iou_roi_vs_full_min": min(r["iou_roi_vs_full"] for r in rows),
           "iou_motion_roi_vs_full_min": min(r["iou_motion_roi_vs_full"] for r in rows)}
    for key, per in stage_rows.items():  # median ms per stage, each stage timed alone (stage_times)
        out[f"stages_{key}"] = {k: float(np.median([t[k] for t in per])) for k in per[0] if k.endswith("_ms")}
    if rows[0]["iou_full_vs_true"] is not None:
        out["iou_full_vs_true_mean"] = float(np.mean([r["iou_full_vs_true"] for r in rows]))
        out["iou_roi_vs_true_mean"] = float(np.mean([r["iou_roi_vs_true"] for r in rows]))
    return out


def bench_live_sequence(root: Path, frames: int, passes: int = 3) -> dict:
    """The live segment worker's per-frame CPU on a session with ground truth (e.g. the cached
    ``bench/pipeline.py --size 640x480`` studio): every camera frame segmented once in sequence (cold
    caches, a new ROI shape each frame, as live), with the live fitter's ROI (the union of the pose two
    frames back and the current one, 0.16 m + 8 px: a pose every second frame) and without (the
    automatic box); CPU ms per frame, median over ``passes``, and each stage's CPU in one more pass."""
    from capture.replay import iter_frame_sets
    from capture.session import load_session
    from service.offline import background_models, session_model
    from tracker.imaging.roi import pose_rois

    session = load_session(root)
    truth = [json.loads(line)["params"] for line in (root / "ground_truth.jsonl").read_text().splitlines() if line]
    model = session_model(session, "knossow40")
    cams = list(session.calibration)
    bgs, _ = background_models(session, [c.name for c in cams])
    jobs = []
    for fid, group in iter_frame_sets(session, frames=range(2, frames)):
        now = pose_rois(model, np.asarray(truth[fid]), cams, margin_m=0.16, margin_px=8)
        then = pose_rois(model, np.asarray(truth[fid - 2]), cams, margin_m=0.16, margin_px=8)
        for cam, a, b in zip(cams, now, then):
            roi = (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))
            jobs.append((bgs[cam.name], group[cam.name].image.copy(), roi))
    params = SegmentationParams()
    out = {"camera_frames": len(jobs), "size": list(bgs[cams[0].name].size),
           "roi_px_mean": float(np.mean([(r[2] - r[0]) * (r[3] - r[1]) for _, _, r in jobs]))}
    for kind in ("roi", "whole"):
        per = []
        for _ in range(passes + 1):  # the first pass warms up (compiles, learns the coarse models)
            t0 = time.process_time()
            for bg, img, roi in jobs:
                segment_frame(bg, img, roi=roi if kind == "roi" else None, params=params)
            per.append(1e3 * (time.process_time() - t0) / len(jobs))
        out[f"{kind}_cpu_ms"] = float(np.median(per[1:]))
    stages: dict = {}
    for bg, img, roi in jobs:
        w, h = bg.size
        x0, y0, x1, y1 = roi
        t = [time.process_time()]
        d = bg.distance(img, roi=roi)
        t.append(time.process_time())
        sil = clean_silhouette(d, low=params.low, high=params.high, min_area_px=params.min_area_px((w, h)),
                               max_hole_fraction=params.max_hole_fraction, open_px=params.open_px,
                               close_px=params.close_px, max_components=params.max_components)
        t.append(time.process_time())
        edges = silhouette_edges(img[y0:y1, x0:x1], sil, low=params.canny_low, high=params.canny_high,
                                 dilate_px=params.edge_dilate_px, blur_sigma=params.blur_sigma)
        t.append(time.process_time())
        chamfer_images(sil, edges, max_distance_px=params.max_distance_px, resolution_px=params.resolution_px,
                       precise=params.precise, precise_edges=params.precise_edges, offset_xy=(x0, y0), image_size=(w, h))
        t.append(time.process_time())
        for name, a, b in zip(("background", "cleanup", "edges", "chamfer"), t, t[1:]):
            stages[name] = stages.get(name, 0.0) + 1e3 * (b - a) / len(jobs)
    out["roi_stage_cpu_ms"] = stages
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--cpu", action="store_true", help="time with process CPU time instead of wall time")
    ap.add_argument("--seeds", type=int, default=10, help="random scenes for the IoU comparison")
    ap.add_argument("--roi-frames", type=int, default=20, help="hop frames for the predicted-pose ROI (0: skip)")
    ap.add_argument("--roi-size", default="800x600")
    ap.add_argument("--roi-session", type=Path, default=None, help="reuse (or write) the hop session here")
    ap.add_argument("--only-pose-roi", action="store_true", help="run only the predicted-pose ROI part")
    ap.add_argument("--live-session", type=Path, default=None,
                    help="a session with ground_truth.jsonl: the live worker's per-frame CPU there (then exit)")
    ap.add_argument("--live-frames", type=int, default=40, help="frames of --live-session")
    args = ap.parse_args(argv)
    roi_size = [int(v) for v in args.roi_size.lower().split("x")]
    global CLOCK
    CLOCK = time.process_time if args.cpu else time.perf_counter
    cv2.setNumThreads(1)
    result = {
        "machine_ref_ms": machine_ref_ms(),
        "threads": 1,
        "clock": "process_time" if args.cpu else "perf_counter",
        "loadavg_at_start": list(os.getloadavg()),
        "opencv": cv2.__version__,
    }
    if args.live_session is not None:
        result["live_sequence"] = bench_live_sequence(args.live_session, args.live_frames)
        print(json.dumps(result, indent=1))
        return 0
    if args.roi_frames > 2:
        result["pose_roi"] = bench_pose_roi(args.roi_frames, 6, roi_size, args.repeats, args.roi_session)
    if args.only_pose_roi:
        print(json.dumps(result, indent=1) if args.json else "\n".join(f"{k}: {v}" for k, v in result.items()))
        return 0
    result.update({
        "iou_over_scenes": bench_iou_over_scenes(args.seeds),
        "sizes": [bench_size(s, args.repeats, args.seed) for s in ((800, 600), (644, 486))],
        "real_uu_studio": bench_real(args.repeats),
        "distance_accuracy": bench_distance_accuracy(),
    })
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        for s in result["sizes"]:
            print(f"== {s['size'][0]}x{s['size'][1]}")
            for key in ("ours_full", "ours_diag"):
                e = s[key]
                print(f"  {key}: IoU mean {e['iou_mean']:.4f} min {e['iou_min']:.4f}, "
                      f"shadow kept background >= {e['shadow_background_min']:.3f}")
                for k, v in e.items():
                    if isinstance(v, dict):
                        print(f"    {k}: " + ", ".join(f"{n}={x:.2f}" for n, x in v.items()))
            print(f"  mog2: " + ", ".join(f"{k}={v:.4f}" for k, v in s['mog2'].items() if not isinstance(v, list)))
        print("IoU over random scenes:", json.dumps(result["iou_over_scenes"], indent=1))
        print("real uu_studio:", json.dumps(result["real_uu_studio"], indent=1))
        print("distance accuracy:", result["distance_accuracy"])
        if "pose_roi" in result:
            print("predicted-pose ROI:", json.dumps(result["pose_roi"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
