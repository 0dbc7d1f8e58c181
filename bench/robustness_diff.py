"""Paired comparison of two ``bench/robustness.py --json`` results: is a change bigger than the set's noise?

The same clip (subject, motion, camera count) tracked by two trees is a pair; a per-frame change of the
tracker moves single clips by tens of millimetres both ways (a track that takes another limb or front/back
hypothesis), so the difference of the two sets' means is read against its own spread: the mean of the
per-clip MPJPE differences (B − A), its 95 % bootstrap interval (clips resampled with replacement, seeded),
how many clips got better or worse by more than ``--tie-mm``, the clips that moved most each way, and the pooled
frame counts behind ``ok``, ``false ok``, ``false alarm`` and ``mirrored after 1 s`` in both results.
``--calibrated`` compares the calibrated tracks (``per_clip[i]["calibrated"]``) instead.

    python bench/robustness_diff.py A.json B.json [--json] [--tie-mm 0.5] [--top 5] [--calibrated]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

MAX_BYTES = 256 * 1024 * 1024
COUNTS = ("frames", "ok", "false_ok", "false_alarm", "mirrored_after", "posed_after")


def read_result(path: Path):
    """One result file's JSON value; ``ValueError`` naming the file when it is too large or not JSON."""
    path = Path(path)
    if path.stat().st_size > MAX_BYTES:
        raise ValueError(f"{path}: larger than {MAX_BYTES} bytes")
    try:
        return json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not JSON ({exc})") from None


def load_clips(path: Path, *, calibrated: bool = False, data=None) -> dict:
    """``{(subject, clip, cameras): {"mpjpe_mm": float, "frames": int, ...}}`` of one result file (``data``:
    its ``read_result`` value, when already read).

    Raises ``ValueError`` naming the file and the key when the file is not a robustness result (too
    large, not JSON, no ``per_clip`` list, a clip without a needed key or with a value of the wrong type)."""
    path = Path(path)
    data = read_result(path) if data is None else data
    clips = data.get("per_clip") if isinstance(data, dict) else None
    if not isinstance(clips, list):
        raise ValueError(f"{path}: key 'per_clip': expected a list of clips")
    out = {}
    for i, clip in enumerate(clips):
        where = f"{path}: per_clip[{i}]"
        if not isinstance(clip, dict):
            raise ValueError(f"{where}: expected an object")
        rec = clip.get("calibrated") if calibrated else clip
        if calibrated and rec is None:
            continue  # a clip whose calibration did not run
        if not isinstance(rec, dict):
            raise ValueError(f"{where}: key 'calibrated': expected an object")
        key = []
        for name, kind in (("subject", int), ("clip", str), ("cameras", int)):
            value = clip.get(name)
            if not isinstance(value, kind) or isinstance(value, bool):
                raise ValueError(f"{where}: key {name!r}: expected {kind.__name__}, got {value!r}")
            key.append(value)
        mm = rec.get("mpjpe_mm")
        if not isinstance(mm, (int, float)) or isinstance(mm, bool) or not np.isfinite(mm):
            raise ValueError(f"{where}: key 'mpjpe_mm': expected a finite number, got {mm!r}")
        row = {"mpjpe_mm": float(mm)}
        for name in COUNTS:
            value = rec.get(name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ValueError(f"{where}: key {name!r}: expected a count, got {value!r}")
            row[name] = value
        out[tuple(key)] = row
    return out


def bootstrap_interval(diffs: np.ndarray, *, resamples: int = 10000, seed: int = 0,
                       level: float = 0.95) -> tuple[float, float]:
    """The ``level`` percentile interval of the mean of ``diffs`` (n,) over ``resamples`` resamplings
    with replacement (NaN, NaN for no diffs)."""
    diffs = np.asarray(diffs, dtype=float)
    if not diffs.size:
        return float("nan"), float("nan")
    idx = np.random.default_rng(seed).integers(0, diffs.size, size=(resamples, diffs.size))
    means = diffs[idx].mean(axis=1)
    tail = 50.0 * (1.0 - level)
    lo, hi = np.percentile(means, [tail, 100.0 - tail])
    return float(lo), float(hi)


def compare(a: dict, b: dict, *, tie_mm: float = 0.5, top: int = 5, seed: int = 0) -> dict:
    """The paired comparison of two ``load_clips`` results (B − A; negative MPJPE: B better)."""
    keys = sorted(set(a) & set(b))
    diffs = np.array([b[k]["mpjpe_mm"] - a[k]["mpjpe_mm"] for k in keys])
    lo, hi = bootstrap_interval(diffs, seed=seed)
    order = np.argsort(diffs)

    def row(i: int) -> dict:
        k = keys[i]
        return {"clip": f"s{k[0]} {k[1]} c{k[2]}", "a_mm": round(a[k]["mpjpe_mm"], 1), "b_mm": round(b[k]["mpjpe_mm"], 1)}

    def pooled(side: dict) -> dict:
        tot = {name: sum(side[k][name] for k in keys) for name in COUNTS}
        frames, after = max(tot["frames"], 1), max(tot["posed_after"], 1)
        return {"mpjpe_mm_mean": float(np.mean([side[k]["mpjpe_mm"] for k in keys])) if keys else float("nan"),
                **{f"{name}_frames": tot[name] for name in ("ok", "false_ok", "false_alarm", "mirrored_after")},
                "ok_percent": 100.0 * tot["ok"] / frames, "false_ok_percent": 100.0 * tot["false_ok"] / frames,
                "false_alarm_percent": 100.0 * tot["false_alarm"] / frames,
                "mirrored_after_percent": 100.0 * tot["mirrored_after"] / after}

    return {"clips": len(keys), "only_in_a": len(set(a) - set(b)), "only_in_b": len(set(b) - set(a)),
            "mpjpe_mm_diff_mean": float(diffs.mean()) if keys else float("nan"),
            "mpjpe_mm_diff_median": float(np.median(diffs)) if keys else float("nan"),
            "mpjpe_mm_diff_sd": float(diffs.std(ddof=1)) if len(keys) > 1 else float("nan"),
            "mpjpe_mm_diff_ci95": [lo, hi],
            "better": int(np.count_nonzero(diffs < -tie_mm)), "worse": int(np.count_nonzero(diffs > tie_mm)),
            "tie_mm": float(tie_mm),
            "most_better": [row(i) for i in order if diffs[i] < -tie_mm][:top],
            "most_worse": [row(i) for i in order[::-1] if diffs[i] > tie_mm][:top],
            "a": pooled(a), "b": pooled(b)}


#: run settings a comparison should hold equal, with the value a result file without the key was run at
#: (``smooth_s``, ``calibrate_from`` and ``scene`` are newer than the oldest results; None: not recorded)
SETTINGS = {"method": None, "size": None, "fps": None, "frames_per_clip": None, "clip_budget_s": None,
            "retrack": None, "smooth_s": 0.0, "calibrate_from": None, "scene": False}


def settings_of(data: dict) -> dict:
    """The run settings (``SETTINGS``) of a result (``read_result``'s value, checked by ``load_clips``), a
    missing key at its default."""
    return {k: data.get(k, default) for k, default in SETTINGS.items()}


def differing_settings(a: dict, b: dict) -> dict:
    """``{key: [a's, b's]}`` for the settings (``settings_of``) that differ between two runs."""
    return {k: [a[k], b[k]] for k in SETTINGS if a[k] != b[k]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("a", type=Path, help="the reference result (A)")
    ap.add_argument("b", type=Path, help="the result compared with it (B)")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--tie-mm", type=float, default=0.5, help="a clip moved by less is neither better nor worse")
    ap.add_argument("--top", type=int, default=5, help="clips listed that moved most each way")
    ap.add_argument("--calibrated", action="store_true", help="compare the calibrated tracks")
    args = ap.parse_args(argv)
    try:
        data = [read_result(p) for p in (args.a, args.b)]
        a, b = (load_clips(p, calibrated=args.calibrated, data=d) for p, d in zip((args.a, args.b), data))
        differ = differing_settings(*(settings_of(d) for d in data))
    except (OSError, ValueError) as exc:
        print(f"robustness_diff: {exc}", file=sys.stderr)
        return 2
    out = compare(a, b, tie_mm=args.tie_mm, top=max(0, args.top))
    out["settings_differ"] = differ
    if args.json:
        print(json.dumps(out))
        return 0
    lo, hi = out["mpjpe_mm_diff_ci95"]
    if differ:
        print("settings differ (A vs B): " + ", ".join(f"{k} {va!r} vs {vb!r}" for k, (va, vb) in differ.items()))
    print(f"{out['clips']} clips paired ({out['only_in_a']} only in A, {out['only_in_b']} only in B)")
    print(f"MPJPE B - A: mean {out['mpjpe_mm_diff_mean']:+.2f} mm (95 % bootstrap {lo:+.2f} .. {hi:+.2f}), "
          f"median {out['mpjpe_mm_diff_median']:+.2f}, sd {out['mpjpe_mm_diff_sd']:.2f}; "
          f"{out['better']} clips better, {out['worse']} worse (by > {out['tie_mm']:g} mm)")
    for side in ("a", "b"):
        s = out[side]
        print(f"{side.upper()}: MPJPE {s['mpjpe_mm_mean']:.1f} mm, ok {s['ok_percent']:.1f} %, false ok "
              f"{s['false_ok_percent']:.2f} % ({s['false_ok_frames']}), false alarm {s['false_alarm_percent']:.2f} % "
              f"({s['false_alarm_frames']}), mirrored after 1 s {s['mirrored_after_percent']:.2f} % "
              f"({s['mirrored_after_frames']})")
    for title, rows in (("most better", out["most_better"]), ("most worse", out["most_worse"])):
        print(f"{title}: " + ", ".join(f"{r['clip']} {r['a_mm']} -> {r['b_mm']}" for r in rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
