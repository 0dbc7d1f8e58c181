"""In a lost stretch, does the tracker's own objective prefer the truth? (docs/robustness.md, round 18)

Renders one ``bench/robustness.py`` clip and tracks it as the bench does; on every frame it scores,
with the tracker's own figures (RMS chamfer residual, silhouette IoU at half resolution, the
``hypothesis_cost`` the limb and front/back checks judge by, the robust data cost), three poses:

- ``tracked``: the pose the frame's record reports (the one the bench scores);
- ``ik``: the truth's IK pose (the tracker's height-sized model posed by inverse kinematics onto the
  true joints, as the bench's IK floor but in the render's world frame);
- ``ik_fit``: that pose polished by the tracker's fit (``fit_frame``, the tracker's options, its prior
  centred on the start), and ``ik_fit_prior``: the same with the prior on the tracker's last pose.

A frame far off (``--far``, mm) whose ``ik_fit`` scores a lower hypothesis cost than the tracked pose
is a *search* failure (the objective prefers a pose near the truth the searches did not reach); one
that scores higher is an *objective* failure.  ``--summary`` tabulates saved runs per clip and per
body part (the frame's exchanged or lost limbs, or the body turned).

usage: ``python bench/truth_basin.py SUBJECT CLIP CAMERAS --out F.json [--tracker-option k=v ...]``;
``python bench/truth_basin.py --summary F.json ...``
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import warnings
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import robustness as R  # noqa: E402
from capture.session import load_session  # noqa: E402
from tracker.body.kinematics import joint_centre_array  # noqa: E402
from tracker.fitting import tracking as TT  # noqa: E402
from tracker.fitting.solver import robust_cost  # noqa: E402
from tracker.search.mirror import hypothesis_cost  # noqa: E402
from tracker.search.scoring import ScoreViews  # noqa: E402
from tracker.synthetic.bvh import load_bvh  # noqa: E402
from tracker.synthetic.retarget import JOINT_MAP, _initial_root, _solve_frame  # noqa: E402
from tracker.synthetic.synth import bundled_motion  # noqa: E402

J = R.JOINT_NAMES
LEGS = [J.index(j) for j in J if j.endswith(("knee", "ankle"))]
ARMS = [J.index(j) for j in J if j.endswith(("elbow", "wrist"))]
TRUNK = [J.index(j) for j in ("pelvis", "spine", "neck", "head", "left_shoulder", "right_shoulder",
                              "left_hip", "right_hip")]


def ik_poses(model, truth: np.ndarray) -> np.ndarray:
    """(n, n_params): ``model`` posed by IK onto ``truth`` (n, 16, 3) frame by frame (``retarget``'s solver
    and regularisers, each frame from the last)."""
    names = tuple(n for n in model.joint_names if n in JOINT_MAP)
    ti = [J.index(n) for n in names]
    piv = model.pivots(names)
    p = _initial_root(model, truth[0][ti], names)
    out = []
    for k in range(len(truth)):
        p = _solve_frame(model, truth[k][ti], p, p.copy(), 0.01, 0.02 if k else 0.0, *piv)
        out.append(p.copy())
    return np.array(out)


def figures(model, cams, chs, views, params, options, truth) -> dict:
    """The tracker's figures of ``params`` on one frame, and its error against ``truth`` (16, 3)."""
    t = TT._chamfer_cost(model, cams, chs, options).evaluate(np.asarray(params))
    rms, iou = float(t.rms_px()), float(views.score(np.asarray(params)))
    err = np.linalg.norm(joint_centre_array(model, t.pose) - truth, axis=1)
    return {"rms": rms, "iou": iou, "hyp": hypothesis_cost(model, params, rms, iou),
            "data": robust_cost(np.asarray(t.residuals), loss=options.loss, f_scale=options.f_scale),
            "mpjpe": 1e3 * float(err.mean()), "joint_mm": [round(1e3 * float(e)) for e in err]}


def run(subject: int, clip: str, cameras: int) -> dict:
    """Render, track and score one clip (module docstring); the per-frame rows and the bench's series."""
    motion = R.clip_motion(clip, load_bvh(bundled_motion("scaled_131_01")), subject=subject, frames=75, fps=30.0)
    state: dict = {"rows": {}, "prior": None}
    step = TT.Tracker.step

    def hooked(self, frame_id, ts, chamfer, silhouettes=None, images=None):
        rec = step(self, frame_id, ts, chamfer, silhouettes, images)
        if "params" not in rec or silhouettes is None:
            return rec
        model, opts = self.model, self.options
        if "ik" not in state:
            state["ik"] = ik_poses(model, state["truth"])
        names = [n for n in self.cameras if n in chamfer and n in silhouettes and np.any(silhouettes[n])]
        cams, chs = [self.cameras[n] for n in names], {n: chamfer[n] for n in names}
        views = ScoreViews(model, cams, [silhouettes[n] for n in names], scale=0.5)
        truth, p, q0 = state["truth"][frame_id], np.asarray(rec["params"]), model.clamp(state["ik"][frame_id])
        row = {"tracked": figures(model, cams, chs, views, p, opts, truth),
               "ik": figures(model, cams, chs, views, q0, opts, truth)}
        fit = dict(sliding=self.sliding, solver=self.solver, options=opts, penalty=self.penalty)
        res, _ = TT.fit_frame(model, cams, chs, q0, prediction=q0, **fit)
        row["ik_fit"] = figures(model, cams, chs, views, np.asarray(res.params), opts, truth)
        if state["prior"] is not None:
            res, _ = TT.fit_frame(model, cams, chs, q0, prediction=state["prior"], **fit)
            row["ik_fit_prior"] = figures(model, cams, chs, views, np.asarray(res.params), opts, truth)
        state["prior"] = np.array(self.params)  # the tracker's own pose (the record may report the mirror)
        row["ok"], row["reason"] = bool(rec.get("ok")), rec.get("reason", "")
        state["rows"][str(int(frame_id))] = row
        return rec

    TT.Tracker.step = hooked
    try:
        with tempfile.TemporaryDirectory() as tmp:
            root = Path(tmp) / "c"
            truth, bgs, _, _, _ = R.render_session(root, motion, subject, cameras, (320, 240))
            state["truth"] = np.asarray(truth)
            records, _, _, _ = R._track(load_session(root), bgs, method="contours", budget_s=0)
    finally:
        TT.Tracker.step = step
    score, _, series = R._score(records, state["truth"], 30.0)
    return {"subject": subject, "clip": clip, "cameras": cameras, "mpjpe_mm": score["mpjpe_mm"], "ok": score["ok"],
            "series": series, "rows": state["rows"]}


def body_part(row: dict, series: dict, k: int, lost_mm: float = 150.0) -> str:
    """What is wrong on frame ``k``: turned, legs or arms exchanged, else the group (legs, arms, trunk)
    with a joint more than ``lost_mm`` off, else "broad"."""
    if series["mirrored"][k]:
        return "turned"
    ex = series["exchanged"][k]
    if "legs" in ex:
        return "legs exchanged"
    if any("arm" in e for e in ex):
        return "arms exchanged"
    jm = np.array(row["tracked"]["joint_mm"])
    worst = {"leg lost": jm[LEGS].max(), "arm lost": jm[ARMS].max(), "trunk off": jm[TRUNK].max()}
    top = max(worst, key=worst.get)
    return top if worst[top] > lost_mm else "broad"


def summary(runs: list[dict], far_mm: float) -> str:
    """Markdown table of saved runs: per clip, the frames more than ``far_mm`` off and how their
    truth-started fit scores against the tracked pose; then the split per body part."""
    lines = ["| clip | frames > %g mm | tracked / IK / IK fitted mm | search / objective failures | IoU higher | "
             "data cost lower | hypothesis cost tracked → IK fitted | IoU | RMS px |" % far_mm, "|---" * 9 + "|"]
    parts: dict = {}
    for d in runs:
        rows = [(int(k), r) for k, r in d["rows"].items() if r["tracked"]["mpjpe"] > far_mm]
        if not rows:
            continue
        t = np.array([[r["tracked"][f] for f in ("mpjpe", "hyp", "iou", "rms")] for _, r in rows])
        q = np.array([[r["ik_fit"][f] for f in ("mpjpe", "hyp", "iou", "rms")] for _, r in rows])
        ik = np.mean([r["ik"]["mpjpe"] for _, r in rows])
        search = int(np.sum(q[:, 1] < t[:, 1]))
        for (k, r), s in zip(rows, q[:, 1] < t[:, 1]):
            parts.setdefault(body_part(r, d["series"], k), [0, 0])[int(not s)] += 1
        n_data = sum(r["ik_fit"]["data"] < r["tracked"]["data"] for _, r in rows)
        lines.append(f"| s{d['subject']} {d['clip']} {d['cameras']} | {len(rows)} | {t[:, 0].mean():.0f} / {ik:.0f} / "
                     f"{q[:, 0].mean():.0f} | {search} / {len(rows) - search} | {int(np.sum(q[:, 2] > t[:, 2]))} | "
                     f"{n_data} | {t[:, 1].mean():.2f} → {q[:, 1].mean():.2f} | {t[:, 2].mean():.3f} → "
                     f"{q[:, 2].mean():.3f} | {t[:, 3].mean():.2f} → {q[:, 3].mean():.2f} |")
    lines += ["", "| body part | search failures | objective failures |", "|---|---|---|"]
    lines += [f"| {p} | {v[0]} | {v[1]} |" for p, v in sorted(parts.items())]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("clip", nargs="*", help="SUBJECT CLIP CAMERAS, or saved runs with --summary")
    ap.add_argument("--out", help="write the run's JSON here")
    ap.add_argument("--summary", action="store_true", help="tabulate the saved runs given")
    ap.add_argument("--far", type=float, default=100.0, help="frames further off than this (mm) are tabulated")
    ap.add_argument("--tracker-option", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args(argv)
    if args.summary:
        print(summary([json.loads(Path(f).read_text()) for f in args.clip], args.far))
        return 0
    warnings.filterwarnings("ignore")
    cv2.setNumThreads(1)
    R.TRACK_OPTIONS["options"] = R._tracker_options(args.tracker_option, ap, R.TRACK_OPTIONS["options"])
    out = run(int(args.clip[0]), args.clip[1], int(args.clip[2]))
    print(json.dumps({k: out[k] for k in ("subject", "clip", "cameras", "mpjpe_mm", "ok")}))
    if args.out:
        Path(args.out).write_text(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
