"""Measure a chair's parts in a real take: its legs found in the images, written as ``[[prop]]`` boxes.

The operator gives the chair's seat as a bounding box (``[[prop]]``: the seat with its legs, floor to
the seat's top) and the seat shell's underside height; the four legs are searched in the take's
frames: each leg is a segment from a foot on the floor to a top under the seat, the foot within
``--search-m`` of a corner of the box's footprint (inset by ``--inset-m``), the top within
``--search-m`` of the foot; the segment whose axis (z from 0.08 m to 3 cm under the seat's underside)
projects onto the most foreground in all cameras wins (foreground: the frame differs from the
empty-room plate's median by more than ``--diff`` in a colour channel, in every one of the frames
``0, --every, 2 --every, ...``; ties averaged).  Each leg's box is the segment's bounding box grown by
``--leg-margin-m``.  Prints the session.toml tables: the seat's bounding box as ``hollow = true``,
the seat shell (underside to top), the four legs, and the other boxes of the session as given;
``--draw PNG`` draws them on a frame of every camera (crops around the chair).

    python bench/chair_parts.py SESSION --seat-box x0,y0,z0,x1,y1,z1 --seat-underside-m 0.40 \
        [--draw parts.png --frame 200] [--json]
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import cv2  # noqa: E402
import numpy as np  # noqa: E402


def read_frame(path: Path, index: int) -> np.ndarray:
    cap = cv2.VideoCapture(str(path))
    cap.set(cv2.CAP_PROP_POS_FRAMES, index)
    ok, img = cap.read()
    cap.release()
    if not ok:
        raise SystemExit(f"bench/chair_parts.py: cannot read frame {index} of {path}")
    return img


def plate(path: Path, n: int = 15) -> np.ndarray:
    """The median of the first ``n`` frames of an empty-room video."""
    cap = cv2.VideoCapture(str(path))
    frames = []
    for _ in range(n):
        ok, img = cap.read()
        if not ok:
            break
        frames.append(img)
    cap.release()
    return np.median(np.array(frames), axis=0)


def foreground(session, name: str, frames, diff: float) -> np.ndarray:
    """(h, w) bool: foreground in every one of ``frames`` of camera ``name``."""
    cam = session.camera(name)
    bg = plate(session.root / cam.background)
    out = None
    for f in frames:
        m = np.abs(read_frame(session.root / cam.video, f).astype(float) - bg).max(axis=2) > diff
        out = m if out is None else out & m
    return out


def find_legs(cams, fg, seat_lo, seat_hi, underside: float, *, inset: float, search: float, step: float = 0.01):
    """Per corner of the footprint, (foot x, foot y, top x, top y) metres and the score (0..n cams)."""
    g = np.arange(-search, search + 0.5 * step, step)
    zs = np.linspace(0.08, underside - 0.03, 15)
    t = zs / underside
    legs = []
    corners = itertools.product((seat_lo[0] + inset, seat_hi[0] - inset), (seat_lo[1] + inset, seat_hi[1] - inset))
    for cx, cy in corners:
        cand = np.array([(cx + a, cy + b, dx, dy) for a in g for b in g for dx in g for dy in g])
        P = np.stack([cand[:, None, 0] + cand[:, None, 2] * t, cand[:, None, 1] + cand[:, None, 3] * t,
                      np.broadcast_to(zs, (len(cand), len(zs)))], axis=2)
        score = np.zeros(len(cand))
        for cam in cams:
            uv = np.round(cam.project(P.reshape(-1, 3))).astype(int)
            h, w = fg[cam.name].shape
            ok = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
            v = np.zeros(len(uv))
            v[ok] = fg[cam.name][uv[ok, 1], uv[ok, 0]]
            score += v.reshape(len(cand), -1).mean(axis=1)
        best = cand[score >= score.max() - 1e-9].mean(axis=0)
        legs.append(([float(best[0]), float(best[1]), float(best[0] + best[2]), float(best[1] + best[3])],
                     float(score.max())))
    return legs


def draw(out: Path, session, cams, boxes, frame: int) -> None:
    colours = [(0, 0, 255), (0, 255, 0), (255, 0, 0), (0, 255, 255), (255, 0, 255), (255, 255, 0), (255, 255, 255)]
    allc = np.array([b["box"] for b in boxes])
    lo, hi = allc[:, :3].min(axis=0) - 0.15, allc[:, 3:].max(axis=0) + [0.15, 0.15, 0.3]
    tiles = []
    for cam in cams:
        img = read_frame(session.root / session.camera(cam.name).video, frame)
        for i, b in enumerate(boxes):
            c = np.array([[x, y, z] for x in (b["box"][0], b["box"][3]) for y in (b["box"][1], b["box"][4])
                          for z in (b["box"][2], b["box"][5])])
            for a, e in itertools.combinations(range(8), 2):
                if bin(a ^ e).count("1") == 1:
                    P = c[a] + np.linspace(0, 1, 30)[:, None] * (c[e] - c[a])
                    cv2.polylines(img, [np.round(cam.project(P) * 4).astype(np.int32)], False,
                                  colours[i % len(colours)], 1, cv2.LINE_AA, shift=2)
        box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        uv = cam.project(box)
        u0, v0 = np.maximum(uv.min(axis=0).astype(int) - 10, 0)
        u1, v1 = uv.max(axis=0).astype(int) + 10
        crop = cv2.resize(img[v0:v1, u0:u1], None, fx=3, fy=3, interpolation=cv2.INTER_CUBIC)
        crop = cv2.resize(crop, (int(crop.shape[1] * 500 / crop.shape[0]), 500))
        cv2.putText(crop, cam.name, (10, 20), 0, 0.6, (255, 255, 255), 1)
        tiles.append(crop)
    cv2.imwrite(str(out), np.hstack(tiles))


def main() -> int:
    from capture.session import load_session

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("session")
    ap.add_argument("--seat-box", required=True, help="x0,y0,z0,x1,y1,z1: the seat with its legs (metres)")
    ap.add_argument("--seat-underside-m", type=float, required=True, help="the seat shell's underside height")
    ap.add_argument("--inset-m", type=float, default=0.015, help="the legs' centres this far inside the footprint")
    ap.add_argument("--search-m", type=float, default=0.06)
    ap.add_argument("--leg-margin-m", type=float, default=0.02)
    ap.add_argument("--diff", type=float, default=40.0)
    ap.add_argument("--every", type=int, default=100)
    ap.add_argument("--draw", help="PNG: the boxes on --frame of every camera")
    ap.add_argument("--frame", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    session = load_session(args.session)
    cams = list(session.calibration)
    seat = [float(v) for v in args.seat_box.split(",")]
    lo, hi = np.array(seat[:3]), np.array(seat[3:])
    from capture.replay import count_frames

    n = count_frames(session, session.camera_names[0]) or 1
    frames = list(range(0, n, args.every))
    fg = {c.name: foreground(session, c.name, frames, args.diff) for c in cams}
    legs = find_legs(cams, fg, lo, hi, args.seat_underside_m, inset=args.inset_m, search=args.search_m)
    r, zs = args.leg_margin_m, args.seat_underside_m
    boxes = [{"box": seat, "hollow": True}, {"box": [*lo[:2], zs, *hi]}]
    for (xf, yf, xt, yt), _ in legs:
        boxes.append({"box": [min(xf, xt) - r, min(yf, yt) - r, 0.0, max(xf, xt) + r, max(yf, yt) + r, zs]})
    others = [list(b) for b in session.props if not np.allclose(b, seat, atol=1e-6)]
    boxes += [{"box": b} for b in others]
    if args.draw:
        draw(Path(args.draw), session, cams, boxes, args.frame)
    if args.json:
        print(json.dumps({"legs": [{"foot_top_xy_m": [round(v, 3) for v in leg], "score": round(s, 2)}
                                   for leg, s in legs], "boxes": boxes}))
    else:
        for leg, s in legs:
            print(f"# leg foot ({leg[0]:.3f}, {leg[1]:.3f}) top ({leg[2]:.3f}, {leg[3]:.3f}) m, "
                  f"foreground {s:.2f} of {len(cams)} cameras")
        for b in boxes:
            print(f"\n[[prop]]\nbox = [{', '.join(f'{v:.3f}' for v in b['box'])}]" + ("\nhollow = true" if b.get("hollow") else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
