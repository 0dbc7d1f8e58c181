"""A realistic take for the output tests: the bundled CMU hop retargeted onto knossow40 at 30 fps (the
demo's motion), with seeded tracking noise, not-ok frames and frame-id gaps, as pose records."""

from __future__ import annotations

import functools

import numpy as np

from service.wire.records import PoseRecord

FPS = 30.0
FIRST_ID = 13
NOT_OK = (20, 21, 60)           # frame ids the tracker lost
MISSING = (40, 41, 42, 43, 70)  # frame ids never delivered


@functools.lru_cache(maxsize=4)  # one retargeting per test process; callers must not modify the result
def make_take(n_frames: int = 90, *, noise_m: float = 0.003, noise_rad: float = np.radians(1.0), seed: int = 7):
    """Pose records and the noise-free joint centres.

    Returns
    -------
    records : list of PoseRecord
        Frame ids ``FIRST_ID .. FIRST_ID + n_frames - 1`` less ``MISSING``; ``NOT_OK`` ids not ok.
    truth : dict
        ``frames`` (n_frames,) ids, ``joints`` (n_frames, n_joints, 3) metres, ``names``, ``params``
        (n_frames, n_params) noise-free, ``model``.
    """
    from tracker.synthetic.bvh import load_bvh
    from tracker.body.kinematics import forward, joint_centre_array
    from tracker.body.model import ROOT_TRANSLATION
    from tracker.synthetic.retarget import retarget_bvh
    from tracker.synthetic.synth import bundled_motion

    ret = retarget_bvh(load_bvh(bundled_motion()), fps=FPS, frames=n_frames)
    model = ret.model
    rng = np.random.default_rng(seed)
    is_t = model.param_kind == ROOT_TRANSLATION
    sigma = np.where(is_t, noise_m, noise_rad)
    noisy = model.clamp(ret.params + rng.normal(size=ret.params.shape) * sigma)
    frames = FIRST_ID + np.arange(n_frames)
    truth_j = np.stack([joint_centre_array(model, forward(model, p)) for p in ret.params])
    records = []
    for k, fid in enumerate(frames):
        if fid in MISSING:
            continue
        base = {"frame": int(fid), "timestamp_ns": int(round(fid * 1e9 / FPS)), "model": model.name,
                "cameras": 6, "latency_ms": float(40 + 5 * rng.random())}
        if fid in NOT_OK:
            records.append(PoseRecord.from_dict({**base, "ok": False, "reason": "lost"}))
            continue
        J = joint_centre_array(model, forward(model, noisy[k]))
        records.append(PoseRecord.from_dict({
            **base, "ok": True, "params": noisy[k].tolist(),
            "joints": {n: J[i].tolist() for i, n in enumerate(model.joint_names)},
            "rms_px": 1.4, "iterations": 3}))
    truth = {"frames": frames, "joints": truth_j, "names": list(model.joint_names), "params": ret.params,
             "model": model}
    return records, truth
