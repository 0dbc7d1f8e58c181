"""Blob tracker benchmark (``tracker.blobs``, BMVC'04) on the synthetic hop: accuracy, mirrored frames, speed.

Two renderings of the same hop (CMU 131_03, ``tracker.synthetic.synth.make_synthetic_session``, seed 0):
bench/tracker.py's session (6 ring cameras, 800x600) and the paper's setting, 4 cameras at
320x240.  Each is tracked by ``tracker.blobs.BlobTracker`` from the ground-truth pose of the first
frame, with the frames decoded beforehand (decoding is not the tracker's cost; the blob tracker
needs no segmentation pass: its hull samples the background model itself).

Per session: MPJPE (mean joint error over the 16 DESIGN.md joints, mm), mirrored frames after the
first second (a frame is mirrored when its joints are closer to the truth's with left and right
swapped than to the truth), frames reported ``ok: false``, per-frame CPU time of the tracker's
``step`` (median, p90; the hull's share), and for 4 x 320x240 the frame rate that time allows on
one core.  BLAS/OpenMP threads and OpenCV are limited to one thread.  ``machine_ref_ms`` (bench/
machine_ref.py) is measured in this process: quote times as ratios to it.

    python bench/blobs.py [--json] [--frames 120] [--ik ccd|dls] [--cache DIR] [--blob-option NAME=NUMBER]
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from machine_ref import machine_ref_ms  # noqa: E402

from capture.replay import iter_frame_sets  # noqa: E402
from capture.session import load_session  # noqa: E402
from tracker.blobs import BlobOptions, BlobTracker  # noqa: E402
from tracker.search.mirror import mirror_joint_order  # noqa: E402
from service.offline import background_models, session_model  # noqa: E402
from tracker.synthetic.synth import bundled_motion  # noqa: E402
from service.synthetic_session import make_synthetic_session  # noqa: E402

SESSIONS = {"hop_6x800x600": (6, (800, 600)), "hop_4x320x240": (4, (320, 240))}


def run(root: Path, frames: int, options: BlobOptions) -> dict:
    session = load_session(root)
    truth = [json.loads(line) for line in (root / "ground_truth.jsonl").read_text().splitlines() if line]
    model = session_model(session)
    names = list(session.camera_names)
    backgrounds, _ = background_models(session, names)
    sets = [(fid, next(iter(g.values())).timestamp_ns, {n: f.image for n, f in g.items()})
            for fid, g in iter_frame_sets(session, frames=range(0, frames))]
    tracker = BlobTracker(model, [session.camera_model(n) for n in names], backgrounds,
                          initial_params=np.asarray(truth[0]["params"]), options=options, clock=time.process_time)
    swap = mirror_joint_order(model)
    joint_names = list(model.joint_names)
    errs, mirrored, bad, cpu, wall, hull = [], [], 0, [], [], []
    for fid, ts, images in sets:
        t0 = time.perf_counter()
        rec = tracker.step(fid, ts, images)
        wall.append(1e3 * (time.perf_counter() - t0))
        cpu.append(rec["latency_ms"])
        bad += not rec["ok"]
        if "joints" not in rec:
            continue
        hull.append(rec["hull_ms"])
        est = np.array([rec["joints"][n] for n in joint_names])
        gt = np.array([truth[fid]["joints"][n] for n in joint_names])
        e = np.linalg.norm(est - gt, axis=1).mean()
        errs.append(e)
        if fid >= session.fps:
            mirrored.append(np.linalg.norm(est - gt[swap], axis=1).mean() < e)
    ms = float(np.median(cpu))
    return {
        "frames": len(sets), "cameras": len(names), "size": list(session.camera_model(names[0]).size),
        "mpjpe_mm": 1e3 * float(np.mean(errs)), "mpjpe_median_mm": 1e3 * float(np.median(errs)),
        "mpjpe_max_mm": 1e3 * float(np.max(errs)),
        "mirrored_after_1s_percent": 100.0 * float(np.mean(mirrored)) if mirrored else 0.0,
        "not_ok_frames": bad,
        "cpu_ms_per_frame_median": ms, "cpu_ms_per_frame_p90": float(np.percentile(cpu, 90)),
        "wall_ms_per_frame_median": float(np.median(wall)), "hull_cpu_ms_median": float(np.median(hull)),
        "fps_one_core": 1e3 / ms if ms > 0 else float("nan"),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--ik", choices=("ccd", "dls"), default="dls")
    ap.add_argument("--only", choices=sorted(SESSIONS), default=None, help="one of the two sessions")
    ap.add_argument("--cache", type=Path, default=None, help="keep (or reuse) the rendered sessions here")
    ap.add_argument("--no-static-scene", action="store_true",
                    help="BlobOptions(static_scene=False): no static-scene voxel memory (for A/B)")
    ap.add_argument("--blob-option", action="append", default=[], metavar="NAME=NUMBER",
                    help="a numeric BlobOptions field for this run (e.g. walk_gain=0.1); repeatable")
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    options = replace(BlobOptions(), ik=args.ik, static_scene=not args.no_static_scene)
    numeric = {k: type(v) for k, v in vars(options).items() if type(v) in (int, float)}
    for pair in args.blob_option:
        name, _, value = pair.partition("=")
        if name not in numeric:
            ap.error(f"--blob-option {pair!r}: expected NAME=NUMBER with NAME one of {', '.join(sorted(numeric))}")
        try:
            options = replace(options, **{name: numeric[name](value)})
        except ValueError as exc:
            ap.error(f"--blob-option {pair!r}: {exc}")
    ref = machine_ref_ms()
    result = {"method": "blobs", "ik": args.ik, "init": "ground_truth_frame0", "machine_ref_ms": ref,
              "blob_options": args.blob_option, "sessions": {}}
    with tempfile.TemporaryDirectory() as tmp:
        base = args.cache or Path(tmp)
        for name, (n_cams, size) in SESSIONS.items():
            if args.only and name != args.only:
                continue
            root = base / f"{name}_{args.frames}"
            if not (root / "session.toml").is_file():
                make_synthetic_session(bundled_motion("scaled_131_03"), root, cameras=n_cams, size=size,
                                       frames=args.frames, seed=0)
            r = run(root, args.frames, options)
            r["cpu_ms_per_frame_over_machine_ref"] = r["cpu_ms_per_frame_median"] / ref
            r["wall_ms_per_frame_over_machine_ref"] = r["wall_ms_per_frame_median"] / ref
            result["sessions"][name] = r
    if args.json:
        print(json.dumps(result))
    else:
        print(f"machine_ref_ms {ref:.1f}")
        for name, r in result["sessions"].items():
            print(name)
            for key, val in r.items():
                print(f"  {key:34s} {val:.3f}" if isinstance(val, float) else f"  {key:34s} {val}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
