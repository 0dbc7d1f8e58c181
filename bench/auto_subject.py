"""Benchmark: the live tracker's automatic subject calibration on a rendered body of other proportions.

A synthetic session (``service.synthetic_session.make_proportioned_session``: every segment length
drawn within ±15 % of the model's, seeded; session.toml gives the height only) is replayed through
the live fitter (``service.live_replay.replay_live``, every set, searches taken at once) twice:
without and with an ``AutoSubject`` (its calibration run in the replay's own time, so the run is
deterministic).  Prints the segment-length error of the default and the calibrated body against the
rendered truth, the held-out IoU it was judged by, whether it was adopted and at which frame, the
poses' mean joint error (MPJPE) on the frames after the swap in both runs, and the calibration's CPU
seconds (and as a ratio to ``machine_ref_ms``).  ``--live``: the fitter is instead fed in real time
(the session's fps) with the calibration in its thread, and the sets fitted per second before,
while it runs and after are printed.  ``--offline``: ``contourcap track`` with and without
``--calibrate-subject 0:N`` on the session (MPJPE of both, whether it was adopted, CPU seconds).

    python bench/auto_subject.py [--json] [--seed 0] [--frames 150] [--cameras 4] [--size 320x240]
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


def build(args) -> tuple:
    from service.synthetic_session import make_proportioned_session

    w, h = (int(v) for v in args.size.split("x"))
    root = Path(args.cache_dir) / f"prop_s{args.seed}_f{args.frames}_c{args.cameras}_{w}x{h}"
    truth_file = root / "true_segment_lengths.json"
    if not truth_file.is_file():
        _, true = make_proportioned_session(root, seed=args.seed, frames=args.frames, cameras=args.cameras,
                                            size=(w, h), codec="png", n_background=5)
        truth_file.write_text(json.dumps(true))
    return root, json.loads(truth_file.read_text())


def fitter_for(clip, auto: bool, background: bool, options):
    from service.live_replay import HeldSearches
    from service.workers.auto_subject import AutoSubject
    from service.workers.live_fit import LiveTrackerFitter

    fit = LiveTrackerFitter.from_session(clip.session, search_runner=None if background else HeldSearches(0))
    if auto:
        fit.auto_subject = AutoSubject(fit.tracker.model, list(fit.tracker.cameras.values()), options,
                                       background=background)
    return fit


def _model_lengths(model) -> dict:
    from tracker.fitting.subject_size import nominal_segment_lengths

    return nominal_segment_lengths(model)


def replay(args, clip, true, options) -> dict:
    from service.live_replay import clip_joint_errors, replay_live

    sched = list(range(clip.n_frames))
    base = replay_live(clip, sched, fitter=fitter_for(clip, False, False, options))
    fit = fitter_for(clip, True, False, options)
    auto = replay_live(clip, sched, fitter=fit)
    st = fit.auto_subject.state
    swap = next((i for i, r in enumerate(auto.records) if r.get("subject")), None)
    e_base, e_auto = clip_joint_errors(clip, base.records), clip_joint_errors(clip, auto.records)
    res = st.result
    out = {"state": st.state, "swap_frame": None if swap is None else auto.records[swap]["frame"],
           "ok_base": base.ok, "ok_auto": auto.ok, "sets": len(sched)}
    if res is not None:
        nominal = _model_lengths(clip_model(clip))  # the default body's (height only)
        out.update(
            held_out_iou_current=round(res.iou_current, 4), held_out_iou_calibrated=round(res.iou_calibrated, 4),
            fit_frames=list(res.fit_frames), held_out_frames=list(res.held_out_frames),
            calibration_cpu_s=round(res.cpu_s, 2),
            length_err_cm_default={k: round(100 * abs(nominal[k] - true[k]), 2) for k in true},
            length_err_cm_calibrated={k: round(100 * abs(res.fit.segment_lengths[k] - true[k]), 2) for k in true})
        out["length_err_cm_mean_default"] = round(float(np.mean(list(out["length_err_cm_default"].values()))), 2)
        out["length_err_cm_mean_calibrated"] = round(float(np.mean(list(out["length_err_cm_calibrated"].values()))), 2)
    if swap is not None:
        out["mpjpe_mm_after_swap_default"] = round(1e3 * float(np.nanmean(e_base[swap:])), 1)
        out["mpjpe_mm_after_swap_calibrated"] = round(1e3 * float(np.nanmean(e_auto[swap:])), 1)
    out["mpjpe_mm_all_default"] = round(1e3 * float(np.nanmean(e_base)), 1)
    out["mpjpe_mm_all_auto"] = round(1e3 * float(np.nanmean(e_auto)), 1)
    return out


def clip_model(clip):
    from service.offline import session_model

    return session_model(clip.session)


def live(args, clip, options) -> dict:
    """Feed the fitter at the session's fps in real time; sets fitted per second before / while calibrating."""
    from service.workers.components import BackgroundSegmenter
    from types import SimpleNamespace

    fit = fitter_for(clip, True, True, options)
    segs = {n: BackgroundSegmenter(model=clip.backgrounds[n]) for n in clip.images}
    period = 1.0 / float(clip.session.fps or 30.0)
    t0 = time.perf_counter()
    log, fid = [], 0
    deadline = t0 + args.live_s
    while time.perf_counter() < deadline:
        if fit.auto_subject.state.state in ("adopted", "rejected", "failed"):  # then 10 s more with the result
            deadline = min(deadline, time.perf_counter() + 10.0) if log[-1][1] == "fitting" else deadline
        now = time.perf_counter()
        fid = max(fid + 1, int((now - t0) / period))  # the newest frame, as a live tracker demands it
        k = fid % clip.n_frames
        chamfer = {n: s(SimpleNamespace(camera=n, frame_id=fid, timestamp_ns=int(fid * period * 1e9)),
                        clip.images[n][k]) for n, s in segs.items()}
        c0 = time.thread_time()
        rec = fit(fid, int(fid * period * 1e9), chamfer)
        log.append((time.perf_counter() - t0, fit.auto_subject.state.state, time.thread_time() - c0, rec.get("ok")))
    fit.auto_subject.join(1.0)
    out = {"live_s": args.live_s}
    for state in ("sampling", "fitting", "adopted", "rejected"):
        rows = [r for r in log if r[1] == state]
        if len(rows) > 1:
            out[f"sets_per_s_{state}"] = round((len(rows) - 1) / (rows[-1][0] - rows[0][0]), 2)
            out[f"fit_cpu_ms_{state}"] = round(1e3 * float(np.median([r[2] for r in rows])), 1)
    st = fit.auto_subject.state
    out["state"] = st.state
    if st.result is not None:
        out["calibration_cpu_s"] = round(st.result.cpu_s, 2)
        out["calibration_wall_s"] = round(st.wall_s, 2)
    return out


def offline(args, root: Path, true: dict) -> dict:
    """``contourcap track`` without and with ``--calibrate-subject``: MPJPE against the rendered truth."""
    import contextlib
    import io
    import tempfile

    from service.cli import main as cli

    truth = {json.loads(line)["frame"]: json.loads(line)["joints"]
             for line in (root / "ground_truth.jsonl").read_text().splitlines() if line.strip()}
    out = {}
    with tempfile.TemporaryDirectory(prefix="autocal_") as tmp:
        for name, extra in (("default", []), ("calibrated", ["--calibrate-subject", f"0:{args.frames}",
                                                             "--calibrate-samples", str(args.sample)])):
            poses = Path(tmp) / f"{name}.jsonl"
            err = io.StringIO()
            c0 = time.process_time()
            with contextlib.redirect_stderr(err):
                rc = cli(["track", str(root), "--out", str(poses), *extra])
            out[f"cpu_s_{name}"] = round(time.process_time() - c0, 1)
            recs = [json.loads(line) for line in poses.read_text().splitlines() if line.strip()] if rc == 0 else []
            e = [np.mean([np.linalg.norm(np.subtract(r["joints"][k], truth[r["frame"]][k])) for k in truth[r["frame"]]])
                 for r in recs if r.get("joints")]
            out[f"mpjpe_mm_{name}"] = round(1e3 * float(np.mean(e)), 1) if e else None
            out[f"ok_{name}"] = sum(bool(r.get("ok")) for r in recs)
            line = next((x for x in err.getvalue().splitlines() if "subject" in x and "contourcap track:" in x), "")
            if name == "calibrated":
                out["calibration"] = line[:400]
                sub = Path(tmp) / "calibrated.subject.toml"
                if sub.is_file():
                    from tracker.body.subject import read_subject

                    cal = read_subject(sub).segment_lengths
                    out["length_err_cm_mean_calibrated"] = round(100 * float(np.mean([abs(cal[k] - true[k])
                                                                                       for k in true])), 2)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--cameras", type=int, default=4)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--sample", type=int, default=9, help="frame sets sampled (a third held out)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--lengths-only", action="store_true")
    ap.add_argument("--live", action="store_true")
    ap.add_argument("--offline", action="store_true")
    ap.add_argument("--live-s", type=float, default=400.0,
                    help="--live: at most this long (else until 10 s after the result)")
    ap.add_argument("--cache-dir", default="/tmp/contourcap_auto_subject")
    args = ap.parse_args(argv)
    from service.live_replay import load_clip
    from tracker.fitting.subject_auto import AutoSubjectOptions

    ref = machine_ref_ms()
    root, true = build(args)
    clip = load_clip(root)
    options = AutoSubjectOptions.for_sample(args.sample, span=clip.n_frames, rounds=args.rounds,
                                            widths_and_radii=not args.lengths_only)
    out = {"machine_ref_ms": round(ref, 1), "seed": args.seed, "frames": clip.n_frames, "cameras": args.cameras,
           "size": args.size, "sample": args.sample, "rounds": args.rounds, "lengths_only": args.lengths_only}
    if args.offline:
        out.update(offline(args, root, true))
    else:
        out.update(live(args, clip, options) if args.live else replay(args, clip, true, options))
    if out.get("calibration_cpu_s") is not None:
        out["calibration_cpu_per_ref"] = round(1e3 * out["calibration_cpu_s"] / ref, 1)
    print(json.dumps(out) if args.json else json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
