"""Benchmark: subject calibration and tracking of a seated person on a chair, against the truth.

The scene of the real uu_studio take with ground truth: ``tracker.synthetic.seated.write_seated_session``
sits a ``tracker.synthetic.people`` subject (not the cone model; seeded proportions, radii, colours)
on a chair drawn in the frames only (not in the empty-room videos), the operator's chair boxes as
``[[prop]]``, cameras laid out as uu_studio's (three in front, one at the side: ``--layout studio``)
or a ring of four (``--layout ring``).  Per seed it runs what a user runs: ``contourcap calibrate
subject SESSION --frames 0:N``, then ``contourcap track`` with the subject file and without it (the
height-only body), and prints per-joint mean error against the truth (mm), the ok rate, the thigh and
shank lengths (hip–knee, knee–ankle of the tracked joints, median) and the thigh's slope below the
horizontal against the truth's, the knee's mean offset truth − ours along the subject's forward and up
axes, the calibrated segment lengths and radius factors, and the synthetic subject's radii against the
calibrated model's mean cone radius.  CPU seconds per run and machine_ref_ms.

    python bench/seated.py [--seeds 0,1,2] [--frames 60] [--layout studio|ring] [--size 320x240]
                           [--seat-sink-m 0.02] [--props bounding|parts] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from service.blas import pin_blas_threads  # noqa: E402

pin_blas_threads()

import numpy as np  # noqa: E402

from machine_ref import machine_ref_ms  # noqa: E402

JUDGED = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
          "left_knee", "right_knee", "left_ankle", "right_ankle")
SIDES = ("left", "right")


def build(args, seed: int) -> tuple[Path, np.ndarray, dict]:
    """The cached session of ``seed``; (root, truth (n, 16, 3), the subject's radii)."""
    from tracker.synthetic.seated import STUDIO_FRONT_SIDE, write_seated_session

    w, h = (int(v) for v in args.size.split("x"))
    sink = f"_sink{args.seat_sink_m:g}" if args.seat_sink_m else ""
    kind = "" if args.props == "bounding" else f"_{args.props}"
    root = Path(args.cache_dir) / f"seated_s{seed}_f{args.frames}_{args.layout}_{w}x{h}{sink}{kind}"
    done = root / "truth.npz"
    if not done.is_file():
        layout = STUDIO_FRONT_SIDE if args.layout == "studio" else None
        truth, subject, _ = write_seated_session(root, seed=seed, frames=args.frames, layout=layout, size=(w, h),
                                                 seat_sink_m=args.seat_sink_m, props=args.props)
        np.savez(done, truth=truth, radius=json.dumps(subject.radius))
    data = np.load(done)
    return root, data["truth"], json.loads(str(data["radius"]))


def leg_geometry(joints: dict, frames) -> dict:
    """Median thigh / shank length (m) and thigh slope below horizontal (degrees) over the frames,
    both sides pooled; ``joints[name]`` is (n, 3)."""
    th, sh, slope = [], [], []
    for s in SIDES:
        hip, knee, ank = joints[f"{s}_hip"][frames], joints[f"{s}_knee"][frames], joints[f"{s}_ankle"][frames]
        d = knee - hip
        th.append(np.linalg.norm(d, axis=1))
        sh.append(np.linalg.norm(ank - knee, axis=1))
        slope.append(np.degrees(np.arctan2(-d[:, 2], np.hypot(d[:, 0], d[:, 1]))))
    return {"thigh_m": round(float(np.median(th)), 4), "shank_m": round(float(np.median(sh)), 4),
            "thigh_slope_deg": round(float(np.median(slope)), 1)}


def mean_cone_radius(model, part: str) -> float:
    """Mean over the cone's length of the mean of its two radii (``a (1 + k z)``, ``b (1 + k z)``), metres."""
    a, b, k, z1, z2 = model.cones[model.part_index(part)]
    return float(0.5 * (a + b) * (1 + k * 0.5 * (z1 + z2)))


def evaluate(records: list[dict], truth: np.ndarray) -> dict:
    from tracker.synthetic.people import JOINT_NAMES

    idx = {n: i for i, n in enumerate(JOINT_NAMES)}
    recs = [r for r in records if "joints" in r]
    fr = np.array([r["frame"] for r in recs])
    ours = {n: np.array([r["joints"][n] for r in recs]) for n in idx if all(n in r["joints"] for r in recs)}
    true = {n: truth[fr, idx[n]] for n in idx}
    err = {n: round(1e3 * float(np.mean(np.linalg.norm(ours[n] - true[n], axis=1))), 1) for n in ours}
    judged = float(np.mean([err[j] for j in JUDGED]))
    hips = 0.5 * (true["left_hip"] + true["right_hip"])
    fwd = 0.5 * (true["left_knee"] + true["right_knee"]) - hips
    fwd[:, 2] = 0
    fwd /= np.linalg.norm(fwd, axis=1, keepdims=True)
    knee = {}
    for s in SIDES:
        d = true[f"{s}_knee"] - ours[f"{s}_knee"]
        knee[s] = {"forward_mm": round(1e3 * float(np.mean(np.sum(d * fwd, axis=1))), 1),
                   "up_mm": round(1e3 * float(np.mean(d[:, 2])), 1)}
    allf = np.arange(len(fr))
    return {"judged_mm": round(judged, 1), "hips_mm": round(0.5 * (err["left_hip"] + err["right_hip"]), 1),
            "ok_percent": round(100.0 * float(np.mean([bool(r.get("ok")) for r in records])), 1),
            "joints_mm": err, "legs": leg_geometry(ours, allf), "truth_legs": leg_geometry(true, allf),
            "knee_offset_truth_minus_ours": knee}


def cpu_run(argv: list[str]) -> float:
    from service.cli import main

    t0 = time.process_time()
    rc = main(argv)
    if rc != 0:
        raise SystemExit(f"bench/seated.py: {' '.join(argv)} exited {rc}")
    return time.process_time() - t0


def run_seed(args, seed: int) -> dict:
    from tracker.body.subject import read_subject

    root, truth, radius = build(args, seed)
    out = {"seed": seed}
    subj = root / "subject.toml"
    cal = ["calibrate", "subject", str(root), "--frames", f"0:{args.frames}", "--out", str(subj), "--quiet"]
    out["calibrate_cpu_s"] = round(cpu_run(cal), 1)
    s = read_subject(subj)
    model = s.body()
    out["subject"] = {"segment_lengths_m": s.segment_lengths, "radius_scale": s.radius_scale,
                         "thigh_radius_m": round(mean_cone_radius(model, "left_thigh"), 4),
                         "shank_radius_m": round(mean_cone_radius(model, "left_shank"), 4)}
    out["truth_radius_m"] = {"thigh": round(radius["thigh"], 4), "shank": round(radius["shank"], 4)}
    runs = [("calibrated", ["--subject", str(subj)])] + ([] if args.no_height_only else [("height_only", [])])
    for name, extra in runs:
        poses = root / f"poses_{name}.jsonl"
        cpu = cpu_run(["track", str(root), "--out", str(poses), *extra])
        recs = [json.loads(line) for line in poses.read_text().splitlines() if line.strip()]
        out[name] = {**evaluate(recs, truth), "cpu_s": round(cpu, 1)}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--layout", choices=("studio", "ring"), default="studio")
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--seat-sink-m", type=float, default=0.0,
                    help="the seat's top this far above the thigh capsules' underside (squashed flesh), metres")
    ap.add_argument("--props", choices=("bounding", "parts"), default="bounding",
                    help="the chair's [[prop]] boxes: the operator's bounding boxes or the chair's parts")
    ap.add_argument("--cache-dir", default="/tmp/contourcap_seated_bench")
    ap.add_argument("--no-height-only", action="store_true", help="skip the track without the subject file")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    ref = machine_ref_ms()
    seeds = [int(s) for s in args.seeds.split(",")]
    per = [run_seed(args, s) for s in seeds]
    summary = {"machine_ref_ms": round(ref, 2), "layout": args.layout, "frames": args.frames, "seeds": seeds,
               "seat_sink_m": args.seat_sink_m, "props": args.props,
               "judged_mm_mean": {k: round(float(np.mean([p[k]["judged_mm"] for p in per])), 1)
                                  for k in ("calibrated", "height_only") if k in per[0]},
               "knees_mm_mean": {k: round(float(np.mean([0.5 * (p[k]["joints_mm"]["left_knee"]
                                                               + p[k]["joints_mm"]["right_knee"]) for p in per])), 1)
                                 for k in ("calibrated", "height_only") if k in per[0]},
               "per_seed": per}
    print(json.dumps(summary, indent=None if args.json else 1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
