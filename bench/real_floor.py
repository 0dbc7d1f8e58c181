"""How near can the body model come to the real-footage reference, and does the fit prefer that pose?

    python bench/real_floor.py SESSION REFERENCE.jsonl [--frames A:B] [--every K] [--height H] [--model M]
                               [--prop x0,y0,z0,x1,y1,z1 ...] [--json]

Splits contourcap's error against ``bench/real_reference.py`` into what the tracker could fix and
what it cannot.  ``contourcap track``'s scene tracker (``tracker.fitting.scene``: clutter learned,
seated or standing start) runs over the frames; at every K-th frame:

* **floor**: the model's pose fitted to the reference's 3D joints (inverse kinematics, least squares
  over every parameter within the joint limits, best of several starts): the judged error left then
  is what the model's proportions and the reference's keypoint definitions allow, whatever the
  images say;
* **objective**: the tracker's own figures (silhouette IoU at half resolution, chamfer RMS) at its
  pose and at the floor pose, on the silhouettes the tracker saw (clutter cut): when the floor pose
  scores worse, the fit's objective, not its start, keeps the tracker away;
* **basin**: the frame fitted by the tracker's fit (``fit_frame``, 30 iterations) from the floor
  pose, and the judged error where it settles: the error the objective's nearest minimum has.

Prints means over the sampled frames (judged joints, hips apart; millimetres), per joint, with
``machine_ref_ms``.  An evaluation tool: nothing under ``tracker/`` or ``service/`` uses it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

sys.path.append(str(Path(__file__).resolve().parent))  # machine_ref, real_reference
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from capture.replay import iter_frame_sets, parse_frame_range  # noqa: E402
from capture.session import load_session  # noqa: E402
from real_reference import HIPS, JUDGED, read_jsonl  # noqa: E402
from tracker.body.kinematics import forward, joint_centres  # noqa: E402
from tracker.body.model import ROOT_ROTATION, ROOT_TRANSLATION, BodyModel  # noqa: E402

FIT_JOINTS: tuple[str, ...] = JUDGED + HIPS


def heading_from_hips(joints: Mapping[str, Sequence[float]]) -> float:
    """Heading (radians about +Z) the body faces, from the reference's hips: forward is the
    left-hip-minus-right-hip direction (the body's +Y) crossed with +Z."""
    left = np.asarray(joints["left_hip"], float)
    right = np.asarray(joints["right_hip"], float)
    y = left - right
    fwd = np.array([y[1], -y[0]])  # (y x z) in the floor plane
    return float(np.arctan2(fwd[1], fwd[0]))


def model_joints(model: BodyModel, params: np.ndarray, names: Sequence[str]) -> np.ndarray:
    """Joint centres ``names`` of ``model`` at ``params``, shape (len(names), 3), metres."""
    jc = joint_centres(model, forward(model, np.asarray(params, float)))
    return np.array([jc[n] for n in names], float)


def fit_to_joints(model: BodyModel, targets: Mapping[str, Sequence[float]], starts: Sequence[np.ndarray], *,
                  max_nfev: int = 400) -> tuple[np.ndarray, dict[str, float]]:
    """The pose of ``model`` whose joint centres are nearest (least squares) the ``targets``
    (joint name -> xyz metres; names of ``FIT_JOINTS`` that are present are used), within the
    joint limits, best over ``starts`` (each (n_params,)).  Returns ``(params, error per joint in
    mm)``."""
    from scipy.optimize import least_squares

    names = [j for j in FIT_JOINTS if targets.get(j) is not None]
    if not names:
        raise ValueError("fit_to_joints: no target joint")
    tgt = np.array([targets[j] for j in names], float)

    def residual(p):
        return (model_joints(model, p, names) - tgt).ravel()

    lo = np.where(np.isfinite(model.lower), model.lower, -1e3)
    hi = np.where(np.isfinite(model.upper), model.upper, 1e3)
    best = None
    for p0 in starts:
        x0 = np.clip(np.asarray(p0, float), lo + 1e-9, hi - 1e-9)
        sol = least_squares(residual, x0, bounds=(lo, hi), x_scale=0.1, max_nfev=max_nfev)
        if best is None or sol.cost < best.cost:
            best = sol
    err = np.linalg.norm(model_joints(model, best.x, names) - tgt, axis=1)
    return best.x, {j: 1e3 * float(e) for j, e in zip(names, err)}


def reference_starts(model: BodyModel, joints: Mapping[str, Sequence[float]],
                     extra: Sequence[np.ndarray] = ()) -> list[np.ndarray]:
    """Starts for ``fit_to_joints``: the T-pose and the seated posture (``tracker.search.seated``)
    with the pelvis at the reference's mid-hip and its heading, plus ``extra`` poses."""
    from tracker.search.seated import seated_params

    mid = 0.5 * (np.asarray(joints["left_hip"], float) + np.asarray(joints["right_hip"], float))
    psi = heading_from_hips(joints)
    t = np.flatnonzero(model.param_kind == ROOT_TRANSLATION)
    r = np.flatnonzero(model.param_kind == ROOT_ROTATION)
    out = []
    for p in (model.zero(), seated_params(model)):
        p = p.copy()
        p[r] = [0.0, 0.0, psi]
        rest = model_joints(model, p, ["left_hip", "right_hip"]).mean(axis=0)
        p[t] += mid - rest
        out.append(p)
    return out + [np.asarray(e, float) for e in extra]


def judged_error(model: BodyModel, params: np.ndarray, joints: Mapping[str, Sequence[float]]) -> dict[str, float]:
    """Error (mm) of ``model``'s joint centres at ``params`` per ``FIT_JOINTS`` name the reference has."""
    names = [j for j in FIT_JOINTS if joints.get(j) is not None]
    err = np.linalg.norm(model_joints(model, params, names) - np.array([joints[j] for j in names]), axis=1)
    return {j: 1e3 * float(e) for j, e in zip(names, err)}


def _means(rows: list[dict[str, float]]) -> dict:
    per = {j: round(float(np.mean([r[j] for r in rows if j in r])), 1) for j in FIT_JOINTS
           if any(j in r for r in rows)}
    return {"judged_mm": round(float(np.mean([per[j] for j in JUDGED if j in per])), 1),
            "hips_mm": round(float(np.mean([per[j] for j in HIPS if j in per])), 1), "joint_mm": per}


def run(session_dir: Path, reference_path: Path, *, frames: range | None, every: int,
        height_m: float | None, model_name: str | None = None, props: Sequence[str] = ()) -> dict:
    """Track ``frames`` with the scene tracker; floor, objective and basin at every ``every``-th.
    ``model_name``: a bundled model or a model TOML file (default: the session's knossow40);
    ``props``: ``--prop`` boxes (with the session's ``[[prop]]`` ones: as ``contourcap track``)."""
    from service.offline import background_models, session_model, session_props
    from tracker.body.model import load_model
    from tracker.fitting.cost import ChamferCost
    from tracker.fitting.props import parse_prop
    from tracker.fitting.scene import SceneOptions, SceneTracker
    from tracker.fitting.tracking import Tracker, TrackerOptions, fit_frame
    from tracker.search.scoring import ScoreViews

    session = load_session(session_dir)
    names = list(session.camera_names)
    reference = {r["frame"]: r["joints"] for r in read_jsonl(reference_path, "reference")}
    model = session_model(session) if model_name is None else load_model(model_name, height_m=session.height_m)
    if height_m is not None:
        model = model.with_height(height_m)
    cams = [session.camera_model(n) for n in names]
    backgrounds, _ = background_models(session, names, frames=frames)
    boxes = session_props(session) + [parse_prop(t) for t in props]
    scene = SceneTracker(Tracker(model, cams), backgrounds, options=SceneOptions(), props=boxes)
    rows = {"tracker": [], "floor": [], "basin": []}
    objective = {k: {"iou": [], "rms_px": []} for k in rows}
    n = 0
    t0 = time.perf_counter()
    for fid, group in iter_frame_sets(session, cameras=names, frames=frames):
        rec = scene.step(fid, next(iter(group.values())).timestamp_ns, {c: f.image for c, f in group.items()})
        n += 1
        ref = reference.get(fid)
        if (n - 1) % every or ref is None or "params" not in rec or any(ref.get(j) is None for j in HIPS):
            continue
        m = scene.tracker.model
        segs = scene.last_segmentation
        views = ScoreViews(m, cams, [segs[c].silhouette for c in names], scale=0.5)
        cost = ChamferCost(m, cams, [segs[c].chamfer for c in names], n_samples=8)
        p_track = np.asarray(rec["params"], float)
        p_floor, _ = fit_to_joints(m, ref, reference_starts(m, ref, [p_track]))
        res, _ = fit_frame(m, cams, {c: segs[c].chamfer for c in names}, p_floor,
                           options=TrackerOptions(max_iterations=30), penalty=scene.tracker.penalty)
        for key, p in (("tracker", p_track), ("floor", p_floor), ("basin", np.asarray(res.params))):
            rows[key].append(judged_error(m, p, ref))
            objective[key]["iou"].append(float(views.score(p)))
            objective[key]["rms_px"].append(float(cost.evaluate(p).rms_px()))
    wall = time.perf_counter() - t0
    if not rows["tracker"]:
        raise SystemExit("bench/real_floor.py: no sampled frame has both a tracked pose and the reference's hips")
    out = {"session": str(session_dir), "frames_tracked": n, "frames_sampled": len(rows["tracker"]),
           "height_m": round(float(scene.tracker.model.height_m), 3), "wall_s": round(wall, 1)}
    for key in rows:
        out[key] = _means(rows[key]) | {k: round(float(np.mean(v)), 4) for k, v in objective[key].items()}
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session", type=Path)
    ap.add_argument("reference", type=Path, help="bench/real_reference.py's reference.jsonl")
    ap.add_argument("--frames", default=None, metavar="A:B")
    ap.add_argument("--every", type=int, default=25, help="sample every K-th tracked frame (default 25)")
    ap.add_argument("--height", type=float, default=None, help="subject height in metres (default: the session's)")
    ap.add_argument("--model", default=None, help="body model name or TOML file (default: the session's knossow40)")
    ap.add_argument("--prop", action="append", default=[], metavar="x0,y0,z0,x1,y1,z1",
                    help="a prop box, metres (as contourcap track --prop; repeatable)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if args.every < 1:
        ap.error("--every must be >= 1")
    from machine_ref import machine_ref_ms

    ref_ms = machine_ref_ms()
    frames = parse_frame_range(args.frames)
    out = run(args.session, args.reference, frames=frames, every=args.every, height_m=args.height, model_name=args.model,
              props=args.prop)
    out["machine_ref_ms"] = round(ref_ms, 2)
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"{out['frames_sampled']} frames sampled of {out['frames_tracked']} tracked "
          f"(height {out['height_m']} m, machine_ref_ms {out['machine_ref_ms']})")
    print(f"{'pose':<8} {'judged mm':>9} {'hips mm':>8} {'IoU':>7} {'rms px':>7}")
    for key in ("tracker", "floor", "basin"):
        r = out[key]
        print(f"{key:<8} {r['judged_mm']:>9} {r['hips_mm']:>8} {r['iou']:>7} {r['rms_px']:>7}")
    print("per joint (tracker / floor / basin), mm:")
    for j in FIT_JOINTS:
        print(f"  {j:<15} " + " / ".join(str(out[k]["joint_mm"].get(j)) for k in ("tracker", "floor", "basin")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
