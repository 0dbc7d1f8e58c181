"""Apparent limb radii in the segmented silhouettes, measured across a reference's bones.

    python bench/limb_widths.py SESSION REFERENCE.jsonl [--frames 0:100] [--samples 6] [--subject S.toml]

The frames are tracked as ``contourcap calibrate subject`` tracks them (the scene tracker, the
session's props, clutter learned); at ``--samples`` trusted frame sets of the range's second half, for
each limb of the reference (``bench/real_reference.py``'s joints: thigh hip->knee, shank knee->ankle,
upper arm, forearm) and each camera, the run of body pixels through the points at 25 / 50 / 75 % of
the projected bone, perpendicular to it, is converted to a radius in metres at the point's depth
(:func:`apparent_radius`).  A run that reaches the search window's end is dropped (merged with
something else).  With ``--subject`` the model's cone radius at the same fractions is printed beside
(mean of the cone's two axes).  Prints JSON: per limb, fraction and camera the median radius (m), the
spread (max - min) and the count; ``machine_ref_ms``.  A diagnostic of the subject calibration's
radius factors (docs/subject_calibration.md, "Round 10").
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from machine_ref import machine_ref_ms  # noqa: E402
from real_reference import read_jsonl  # noqa: E402

#: Limb -> (proximal joint, distal joint, model part suffix).
LIMBS = {"thigh": ("hip", "knee", "thigh"), "shank": ("knee", "ankle", "shank"),
         "upper_arm": ("shoulder", "elbow", "upper_arm"), "forearm": ("elbow", "wrist", "forearm")}
FRACTIONS = (0.25, 0.5, 0.75)


def apparent_radius(mask: np.ndarray, camera, a: np.ndarray, b: np.ndarray, t: float, *,
                    window_px: int = 80) -> float | None:
    """Half the silhouette's width (metres) across the bone a->b at fraction ``t``, in one camera.

    Parameters
    ----------
    mask : ndarray (h, w), non-zero = body
    camera : capture.camera.Camera
    a, b : ndarray, shape (3,), world metres; the bone's ends
    t : float, fraction along a->b
    window_px : int, half-length of the pixel line searched

    Returns
    -------
    float or None
        Metres; None when the point is off the silhouette or the run reaches the window's end.
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    axis = (b - a) / max(float(np.linalg.norm(b - a)), 1e-9)
    p = a + t * (b - a)
    uv0, uv1 = camera.project(np.stack([p, p + 0.01 * axis]))
    d = uv1 - uv0
    if not np.linalg.norm(d) > 1e-6:
        return None
    d /= np.linalg.norm(d)
    perp = np.array([-d[1], d[0]])
    # metres per pixel at p, across the bone and the viewing ray
    side = np.cross(axis, p - camera.center)
    side /= max(float(np.linalg.norm(side)), 1e-9)
    mpp = 0.01 / max(float(np.linalg.norm(camera.project((p + 0.01 * side)[None])[0] - uv0)), 1e-9)
    ks = np.arange(-window_px, window_px + 1)
    pix = np.round(uv0 + ks[:, None] * perp).astype(int)
    h, w = mask.shape
    inside = (pix[:, 0] >= 0) & (pix[:, 0] < w) & (pix[:, 1] >= 0) & (pix[:, 1] < h)
    on = np.zeros(len(ks), bool)
    on[inside] = np.asarray(mask)[pix[inside, 1], pix[inside, 0]] > 0
    if not on[window_px]:
        return None
    off = np.flatnonzero(~on)
    below, above = off[off < window_px], off[off > window_px]
    if not len(below) or not len(above):
        return None
    return 0.5 * float(above[0] - below[-1] - 1) * mpp


def model_radius(model, part: str, t: float, length: float) -> float:
    """The model part's cone radius (metres, mean of the two axes) at ``t`` × ``length`` along it."""
    a, b, k, _, _ = model.cones[model.part_names.index(part)]
    return 0.5 * (a + b) * (1.0 + k * t * length)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session", type=Path)
    ap.add_argument("reference", type=Path)
    ap.add_argument("--frames", default="0:100")
    ap.add_argument("--samples", type=int, default=6)
    ap.add_argument("--subject", type=Path, default=None)
    args = ap.parse_args(argv)

    from capture.replay import parse_frame_range
    from capture.session import load_session
    from service.commands.calibrate_subject import track_range
    from service.offline import session_model
    from tracker.body.subject import read_subject

    session = load_session(args.session)
    frames = parse_frame_range(args.frames)
    names = list(session.camera_names)
    cams = {n: session.camera_model(n) for n in names}
    ref = {r["frame"]: r.get("joints") or {} for r in read_jsonl(args.reference, "reference")}
    half = frames.start + len(frames) // 2
    want = set(np.linspace(half, frames.stop - 1, args.samples).round().astype(int).tolist())
    found: dict[tuple, list] = {}

    def take(fid, rec, sils):
        if fid not in want or fid not in ref:
            return
        J = ref[fid]
        for limb, (ja, jb, _) in LIMBS.items():
            for side in ("left", "right"):
                a, b = J.get(f"{side}_{ja}"), J.get(f"{side}_{jb}")
                if a is None or b is None:
                    continue
                for t in FRACTIONS:
                    for n in names:
                        r = apparent_radius(sils[n], cams[n], np.asarray(a), np.asarray(b), t)
                        if r is not None:
                            found.setdefault((limb, t, n), []).append(r)

    track_range(session, names, frames, session_model(session), take)
    out = {"machine_ref_ms": machine_ref_ms(), "frames": args.frames, "limbs": {}}
    model = read_subject(args.subject).body() if args.subject else None
    for (limb, t, n), vals in sorted(found.items()):
        v = np.asarray(vals)
        row = out["limbs"].setdefault(limb, {}).setdefault(f"{t:g}", {})
        row[n] = {"radius_m": round(float(np.median(v)), 4), "spread_m": round(float(v.max() - v.min()), 4),
                  "n": int(len(v))}
    if model is not None:
        for limb, (_, _, part) in LIMBS.items():
            seg = model.segments.get(part)
            if seg is None:
                continue
            length = float(model.cones[seg][4] - model.cones[seg][3])
            out.setdefault("model_radius_m", {})[limb] = {
                f"{t:g}": round(model_radius(model, f"left_{part}", t, length), 4) for t in FRACTIONS}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
