"""Benchmark: front/back — how many frames are tracked turned round (prints figures; --json for JSON).

    python bench/mirror.py [--json] [--seeds 1 2 3] [--cameras 6] [--size 320 240] [--hold 1.5]
                           [--move 1.5] [--shoes dark|shadow] [--no-colour] [--no-guard] [--cache DIR]

Per seed a subject whose segment lengths differ ±15 % from the tracking model
(``tracker.synthetic.tpose``) stands in a T-pose at a random place and heading for ``--hold`` s,
lowers the arms with straight legs (0.5 s), then blends into the bundled CMU hop for ``--move`` s;
rendered (``--cameras`` × ``--size``, FFV1, hair on the back of the head and a shirt back unlike its
front) and tracked by ``contourcap track``'s pipeline (``service.offline.track_session``, automatic
initialisation).  A frame is mirrored when its joints are clearly nearer the left/right-swapped
truth (``tracker.synthetic.tpose.mirrored_frames``).  ``--no-colour`` tracks without the frames'
colours (the silhouettes only).

Prints per seed and overall: mirrored frames (all, after the first second), mirrored frames
reported ok, ok frames, mean joint error of the frames after the first second, milliseconds per
frame (median of the tracker's CPU time per frame, segmentation excluded; robust to other load on
the machine), and ``machine_ref_ms``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from service.blas import pin_blas_threads  # noqa: E402

pin_blas_threads()

import numpy as np  # noqa: E402

from machine_ref import machine_ref_ms  # noqa: E402


def run_seed(seed: int, args) -> dict:
    from capture.session import load_session
    from service.offline import track_session
    from service.synthetic_session import make_synthetic_session
    from tracker.synthetic.tpose import mean_error_m, mirrored_frames, tpose_subject

    root = Path(args.cache) / (f"tpose_{seed}_{args.cameras}_{args.size[0]}x{args.size[1]}_{args.hold}_{args.move}"
                               f"_{args.shoes}")
    if not (root / "ground_truth.jsonl").is_file():
        motion, palette = tpose_subject(seed, hold_s=args.hold, move_s=args.move, shoes=args.shoes)
        make_synthetic_session(f"tpose_{seed}", root, cameras=args.cameras, size=tuple(args.size), seed=seed,
                               n_background=10, retargeted=motion, palette=palette)
    truth = [json.loads(line) for line in (root / "ground_truth.jsonl").read_text().splitlines() if line]
    fps = 1e9 / max(truth[1]["timestamp_ns"] - truth[0]["timestamp_ns"], 1)
    t0 = time.perf_counter()
    records = list(track_session(load_session(root), colour=not args.no_colour, clock=time.process_time,
                                 retrack=not args.no_retrack, **({"front_back": None} if args.no_guard else {})))
    wall = time.perf_counter() - t0
    first_s = int(round(fps))
    mirrored = set(mirrored_frames(records, truth))
    late = [r for r in records if r["frame"] >= first_s]
    errs = [mean_error_m(r, truth[r["frame"]]) for r in late if "joints" in r]
    return {
        "seed": seed, "frames": len(records),
        "mirrored": len(mirrored), "mirrored_after_1s": len([f for f in mirrored if f >= first_s]),
        "mirrored_ok": len([r for r in records if r["frame"] in mirrored and r["ok"]]),
        "ok": sum(bool(r["ok"]) for r in records),
        "reasons": sorted({r.get("reason", "").split(":")[0] for r in records if not r["ok"]}),
        "mean_error_mm_after_1s": 1e3 * float(np.mean(errs)) if errs else None,
        "ms_per_frame_median": float(np.median([r["latency_ms"] for r in records[1:]])),
        "first_frame_ms": float(records[0]["latency_ms"]), "wall_s": wall,
        "mirrored_frame_ids": sorted(mirrored),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--cameras", type=int, default=6)
    ap.add_argument("--size", type=int, nargs=2, default=[320, 240])
    ap.add_argument("--hold", type=float, default=1.5)
    ap.add_argument("--move", type=float, default=1.5)
    ap.add_argument("--shoes", choices=("dark", "shadow"), default="dark",
                    help="shadow: shoes the segmentation takes for shadow (no feet in the silhouettes)")
    ap.add_argument("--no-colour", action="store_true")
    ap.add_argument("--no-guard", action="store_true", help="without the front/back guard (the tracker before it)")
    ap.add_argument("--no-retrack", action="store_true",
                    help="fit every frame once, as live (default: refused stretches fitted again backwards, as "
                         "contourcap track does)")
    ap.add_argument("--cache", default=str(Path.home() / ".cache" / "contourcap" / "bench_mirror"))
    args = ap.parse_args(argv)
    ref = machine_ref_ms()
    runs = [run_seed(s, args) for s in args.seeds]
    frames = sum(r["frames"] for r in runs)
    fps_frames = sum(r["frames"] for r in runs)
    out = {
        "seeds": args.seeds, "cameras": args.cameras, "size": args.size, "colour": not args.no_colour,
        "guard": not args.no_guard, "retrack": not args.no_retrack, "shoes": args.shoes,
        "frames": frames,
        "mirrored_frames_percent": 100.0 * sum(r["mirrored"] for r in runs) / max(frames, 1),
        "mirrored_after_1s": sum(r["mirrored_after_1s"] for r in runs),
        "mirrored_ok": sum(r["mirrored_ok"] for r in runs),
        "ok_percent": 100.0 * sum(r["ok"] for r in runs) / max(fps_frames, 1),
        "ms_per_frame_median": float(np.median([r["ms_per_frame_median"] for r in runs])),
        "machine_ref_ms": ref,
        "runs": runs,
    }
    out["ms_per_frame_ratio"] = out["ms_per_frame_median"] / ref
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        for r in runs:
            print(f"seed {r['seed']}: {r['mirrored']}/{r['frames']} mirrored ({r['mirrored_after_1s']} after 1 s, "
                  f"{r['mirrored_ok']} reported ok), {r['ok']} ok, error after 1 s "
                  f"{r['mean_error_mm_after_1s']:.0f} mm, {r['ms_per_frame_median']:.1f} ms/frame, "
                  f"first frame {r['first_frame_ms']:.0f} ms, not ok: {r['reasons']}")
        print(f"mirrored {out['mirrored_frames_percent']:.1f} % of {frames} frames, {out['mirrored_after_1s']} after "
              f"1 s, {out['mirrored_ok']} reported ok; ok {out['ok_percent']:.1f} %; "
              f"{out['ms_per_frame_median']:.1f} ms/frame = {out['ms_per_frame_ratio']:.2f} x machine_ref_ms "
              f"({ref:.1f} ms)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
