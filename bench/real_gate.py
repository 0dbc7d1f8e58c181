"""Is the ok flag honest on real footage?  Per-frame judged-joint error against the reference.

    python bench/real_gate.py REFERENCE.jsonl POSES.jsonl [--json]

``REFERENCE.jsonl`` is ``bench/real_reference.py``'s cached ``reference.jsonl``; ``POSES.jsonl`` is
``contourcap track``'s output.  Per frame, the error is the mean over the judged joints (shoulders,
elbows, wrists, knees, ankles) the reference has.  Rates as ``tracker.synthetic.evaluation`` defines
them: false ok = reported ok with an error above 80 mm, false alarm = reported not ok with an error
below 40 mm, both in percent of the compared frames.  It also prints the error of the frames reported
ok and of the others, so that a gate change can be judged by what it lets through.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from real_reference import JUDGED, compare, read_jsonl  # noqa: E402
from tracker.synthetic.evaluation import FALSE_ALARM_M, FALSE_OK_M  # noqa: E402


def frame_errors(reference: list[dict], poses: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-frame judged-joint error and ok flag.

    Returns
    -------
    frames : ndarray of int, shape (n,)
    error_mm : ndarray, shape (n,)
        Mean over the judged joints present in both, millimetres (NaN when none).
    ok : ndarray of bool, shape (n,)
    """
    by_frame = {r["frame"]: r for r in reference}
    fids, errs, oks = [], [], []
    for p in poses:
        ref = by_frame.get(p.get("frame"))
        joints = p.get("joints") or {}
        if ref is None or not joints:
            continue
        e = [np.linalg.norm(np.asarray(joints[j], float) - np.asarray(ref["joints"][j], float))
             for j in JUDGED if ref["joints"].get(j) is not None and joints.get(j) is not None]
        fids.append(p["frame"])
        errs.append(1e3 * float(np.mean(e)) if e else np.nan)
        oks.append(bool(p.get("ok")))
    return np.array(fids, int), np.array(errs), np.array(oks, bool)


def gate_report(reference: list[dict], poses: list[dict]) -> dict:
    """ok rate, false-ok and false-alarm rates (percent), and the error of ok / not-ok frames (mm)."""
    _, err, ok = frame_errors(reference, poses)
    valid = np.isfinite(err)
    err, ok = err[valid], ok[valid]
    n = max(len(err), 1)

    def med(x):
        return round(float(np.median(x)), 1) if len(x) else None

    out = {
        "frames": int(len(err)), "ok_percent": round(100.0 * ok.sum() / n, 1),
        "false_ok_percent": round(100.0 * np.sum(ok & (err > 1e3 * FALSE_OK_M)) / n, 1),
        "false_alarm_percent": round(100.0 * np.sum(~ok & (err < 1e3 * FALSE_ALARM_M)) / n, 1),
        "error_mm_median_ok": med(err[ok]), "error_mm_median_not_ok": med(err[~ok]),
        "frames_under_40mm_percent": round(100.0 * np.sum(err < 40) / n, 1),
        "frames_under_80mm_percent": round(100.0 * np.sum(err < 80) / n, 1),
    }
    cmp = compare(reference, poses)
    out.update({k: cmp[k] for k in ("judged_mean_mm", "hips_mean_mm", "ok_only_judged_mean_mm", "joint_error_mm")})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("reference", type=Path)
    ap.add_argument("poses", type=Path)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rep = gate_report(read_jsonl(args.reference, "reference"), read_jsonl(args.poses, "poses"))
    if args.json:
        print(json.dumps(rep))
    else:
        for k, v in rep.items():
            print(f"{k}: {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
