"""Cost of the outputs per pose: VMC bone transforms + OSC bundle (to a closed local UDP port), 1€
smoothing of one record, and TRC / C3D / BVH export per frame, on the retargeted hop (90 frames).

    python bench/outputs.py [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from machine_ref import machine_ref_ms  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    from outputs_fixture import make_take
    from service.wire.bus import free_port
    from service.cli import main as cli
    from service.export import write_pose_records
    from service.outputs.smoothing import RecordSmoother
    from service.outputs.vmc import VmcSender

    ref = machine_ref_ms()
    records, truth = make_take()
    ok = [r for r in records if r.ok]
    sender = VmcSender("127.0.0.1", free_port(), truth["model"])
    t = time.perf_counter()
    for _ in range(3):
        for r in ok:
            sender.send(r, 0.0)
    vmc_ms = (time.perf_counter() - t) * 1000 / (3 * len(ok))
    sm = RecordSmoother(1.0, 10.0, 30.0)
    t = time.perf_counter()
    for _ in range(3):
        sm.reset()
        for r in ok:
            sm.update(r)
    smooth_ms = (time.perf_counter() - t) * 1000 / (3 * len(ok))
    out = {"machine_ref_ms": round(ref, 2), "vmc_ms_per_pose": round(vmc_ms, 3), "smooth_ms_per_pose": round(smooth_ms, 3)}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "poses.jsonl"
        write_pose_records(path, records)
        for kind in ("trc", "c3d", "bvh"):
            t = time.perf_counter()
            import contextlib
            import io

            with contextlib.redirect_stdout(io.StringIO()):
                assert cli(["export", str(path), f"--{kind}", str(Path(tmp) / f"o.{kind}")]) == 0
            out[f"export_{kind}_ms_per_frame"] = round((time.perf_counter() - t) * 1000 / truth["frames"].size, 3)
    for k, v in list(out.items()):
        if k != "machine_ref_ms":
            out[k.replace("_ms", "_ratio")] = round(v / ref, 4)
    print(json.dumps(out) if args.json else "\n".join(f"{k}: {v}" for k, v in out.items()))


if __name__ == "__main__":
    main()
