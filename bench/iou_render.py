"""Benchmark: the search's silhouette IoU (``ScoreViews.ious``), CPU time per call (JSON).

    python bench/iou_render.py [--cameras 6] [--size 320x240] [--poses 300] [--repeat 5] [--rejoin [HEADINGS]]

Random knossow40 poses (place, heading and joint angles jittered around a standing pose) scored
against the rendered silhouettes of the standing pose by ``--cameras`` ring cameras; prints the
best of ``--repeat`` passes' mean thread CPU per call (``ious_cpu_ms``), the sum of all the IoUs
(``iou_sum``: equal before and after a change that keeps the scores), the same poses scored
together (``ious_many_cpu_ms`` per pose) and ``machine_ref_ms``.  ``--rejoin``: also the live
fitter's cheap recovery (``tracker.search.recovery.rejoin``, 12 headings or HEADINGS) on 9 frames of the
bundled hop seen by the ring cameras, seeded with the true poses 6 and 3 frames before:
``rejoin_cpu_ms`` (summed CPU) and the IoUs it returns (``rejoin_scores``).
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

from tracker.body.model import load_model  # noqa: E402
from tracker.search.scoring import ScoreViews, rendered_views  # noqa: E402
from tracker.synthetic.scene import ring_cameras  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cameras", type=int, default=6)
    parser.add_argument("--size", default="320x240", help="camera image size WxH (pixels)")
    parser.add_argument("--poses", type=int, default=300)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--rejoin", type=int, nargs="?", const=12, default=None, metavar="HEADINGS",
                        help="also time the cheap recovery on hop frames, with this many headings per seed (12)")
    opts = parser.parse_args(argv)
    w, h = (int(v) for v in opts.size.lower().split("x"))
    ref = machine_ref_ms()
    model = load_model("knossow40")
    cams = ring_cameras(opts.cameras, size=(w, h))
    truth = model.zero()
    sils, _ = rendered_views(model, truth, cams)
    views = ScoreViews(model, cams, list(sils.values()))
    rng = np.random.default_rng(0)
    poses = []
    for _ in range(opts.poses):
        p = truth.copy()
        p[:2] += rng.uniform(-0.5, 0.5, 2)
        p[5] = rng.uniform(-3.0, 3.0)
        poses.append(model.clamp(p + np.where(model.param_kind == 2, rng.normal(0.0, 0.5, model.n_params), 0.0)))
    total = float(sum(views.ious(p).sum() for p in poses))  # also the warm-up
    passes = []
    for _ in range(opts.repeat):
        t = time.thread_time()
        for p in poses:
            views.ious(p)
        passes.append(1e3 * (time.thread_time() - t) / len(poses))
    t = time.thread_time()
    views.ious_many(poses)
    out = {"cameras": opts.cameras, "size": [w, h], "poses": opts.poses,
           "ious_cpu_ms": round(min(passes), 3), "ious_cpu_ms_passes": [round(v, 3) for v in passes],
           "ious_many_cpu_ms": round(1e3 * (time.thread_time() - t) / len(poses), 3),
           "iou_sum": round(total, 9), "machine_ref_ms": round(ref, 2)}
    if opts.rejoin is not None:
        out.update(time_rejoin(cams, opts.rejoin))
    print(json.dumps(out))
    return 0


def time_rejoin(cams, n_headings: int = 12) -> dict:
    """CPU of ``rejoin`` on 9 hop frames with ``n_headings`` per seed (see the module docstring)."""
    from tracker.search.initialise import SearchOptions
    from tracker.search.recovery import rejoin
    from tracker.synthetic.bvh import load_bvh
    from tracker.synthetic.retarget import retarget_bvh
    from tracker.synthetic.synth import bundled_motion

    mot = retarget_bvh(load_bvh(bundled_motion("scaled_131_03")), frames=120, start_s=0.0)
    cpu, scores = 0.0, []
    for k in range(10, 110, 12):
        sils, chamfer = rendered_views(mot.model, mot.params[k + 6], cams)
        t = time.thread_time()
        res = rejoin(mot.model, cams, sils, chamfer, [mot.params[k], mot.params[k + 3]],
                     options=SearchOptions.for_recovery(), n_headings=n_headings)
        cpu += time.thread_time() - t
        scores.append(None if res is None else round(float(res.score), 9))
    return {"rejoin_cpu_ms": round(1e3 * cpu, 1), "rejoin_scores": scores}


if __name__ == "__main__":
    sys.exit(main())
