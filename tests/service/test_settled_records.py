"""``service.offline.settled_records``, ``SceneTracker.retrack`` and ``ImageTracker.retrack``: the warm-up's
frames and the refused stretches of an offline take are fitted again backwards from the next accepted
frame, and only their records change."""

from __future__ import annotations

import numpy as np
import pytest

from capture.session import load_session
from service.offline import session_model, settled_records, track_session
from service.smoothed import SMOOTH_WINDOW_S
from service.synthetic_session import make_synthetic_session
from tracker.fitting.scene import SceneOptions
from tracker.synthetic.synth import bundled_motion


class _Scripted:
    """A stand-in for SceneTracker: ``warm[i]`` whether frame i is in a warm-up, ``ok[i]`` its first
    fit's verdict, ``refit_ok[i]`` the verdict of fitting it again and ``refit_failed[i]`` the limits
    that refit failed when it is not ok."""

    def __init__(self, warm, ok, refit_ok, refit_failed):
        self.warm, self.ok, self.refit_ok, self.refit_failed = warm, ok, refit_ok, refit_failed
        self.warming = False
        self.retracked: list[list[int]] = []

    def step(self, fid, ts, images):
        self.warming = self.warm[fid]
        return {"frame": fid, "ok": self.ok[fid], "pass": "first", "iou": 0.5 + 0.01 * (fid % 7)}

    def retrack(self, frames):
        self.retracked.append([f for f, _, _ in frames])
        return [{"frame": f, "ok": self.refit_ok[f], "pass": "refit", "params": [0.0], "iou": 0.5 + 0.01 * (f % 5)}
                | ({} if self.refit_ok[f] else {"failed": self.refit_failed[f]}) for f, _, _ in frames]


@pytest.mark.parametrize("tail", [False, True])
@pytest.mark.parametrize("refused", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_held_frames_are_refitted_latest_first_and_kept_in_order(seed, refused, tail):
    rng = np.random.default_rng(seed)
    n = 40
    warm = rng.random(n) < 0.5
    warm[-3:] = True  # every take here ends in a held run
    ok, refit_ok = rng.random(n) < 0.5, rng.random(n) < 0.5
    kinds = (["uncovered"], ["iou"], ["iou", "uncovered"], ["limb_colour"])
    refit_failed = [kinds[k] for k in rng.integers(0, len(kinds), n)]
    st = _Scripted(warm, ok, refit_ok, refit_failed)
    seen = []  # on_step: every first fit as it is made, held or not (what progress shows)
    out = []
    for r in settled_records(st, ((i, 1000 * i, {}) for i in range(n)), refused=refused, tail=tail,
                             on_step=lambda rec: seen.append(rec["frame"])):
        assert seen[-1] >= r["frame"]  # a record is yielded only after its frame was fitted
        out.append(r)
    assert seen == list(range(n))
    assert [r["frame"] for r in out] == list(range(n))
    # every maximal run of held frames (warm, or refused when asked) followed by an accepted frame is
    # refitted once, latest first; with ``tail`` the run the take ends in too, from the last frame's state
    held = warm | (~ok if refused else False)
    runs, cur = [], []
    for i in range(n):
        if held[i]:
            cur.append(i)
        elif cur:
            runs.append(cur[::-1])
            cur = []
    if tail:
        runs, cur = runs + [cur[::-1]], []
    assert st.retracked == runs
    refitted = {f for run in runs for f in run}
    for r in out:
        f = r["frame"]
        if f not in refitted:
            assert r["pass"] == "first"
        else:  # a refit is published when the gate passes it (or refuses it only for the uncovered check),
            # or when the first fit was refused too and covers the silhouettes no better
            passed = refit_ok[f] or refit_failed[f] == ["uncovered"]
            kept = passed or (not ok[f] and f % 5 >= f % 7)
            assert r["pass"] == ("refit" if kept else "first")
    # without ``tail`` the held frames at the end (no accepted frame after them) keep their first records
    assert all(out[f]["pass"] == "first" for f in cur)


@pytest.mark.parametrize("max_held", [0, 1, 3, 7])  # 0: every frame once, as live (track_session(retrack=False))
def test_a_long_refused_stretch_holds_at_most_max_held_frames(max_held):
    n = 20
    ok = np.zeros(n, bool)
    ok[[0, 12, 19]] = True  # refused stretches 1-11 and 13-18, both followed by an accepted frame
    st = _Scripted(np.zeros(n, bool), ok, np.ones(n, bool), [[]] * n)
    out = list(settled_records(st, ((i, 1000 * i, {}) for i in range(n)), max_held=max_held))
    assert [r["frame"] for r in out] == list(range(n))
    runs = [list(range(11, max(0, 11 - max_held), -1)), list(range(18, max(12, 18 - max_held), -1))]
    assert st.retracked == [r for r in runs if r]
    refitted = {f for run in st.retracked for f in run}
    assert [r["pass"] for r in out] == ["refit" if f in refitted else "first" for f in range(n)]


class _Records:
    """A stand-in tracker whose first records and refits are given per frame id (dicts), and that can raise."""

    warming = False

    def __init__(self, firsts, refits, raise_at=None):
        self.firsts, self.refits, self.raise_at = firsts, refits, raise_at
        self.retracked: list[list[int]] = []

    def step(self, fid, ts, images):
        if fid == self.raise_at:
            raise KeyboardInterrupt
        return {"frame": fid, **self.firsts[fid]}

    def retrack(self, frames):
        self.retracked.append([f for f, _, _ in frames])
        return [{"frame": f, **self.refits[f]} for f, _, _ in frames]


def _sets(n):
    return ((i, 1000 * i, {}) for i in range(n))


def test_refit_rules_without_a_pose_without_an_iou_and_for_the_uncovered_check_alone():
    refused = {"ok": False, "failed": ["iou"], "params": [1.0]}
    firsts = {0: {"ok": True, "params": [0.0]},
              1: {**refused, "iou": 0.7},  # a refit without a pose is never kept
              2: refused,  # no IoU on the first fit: the refit (refused too) is kept
              3: {**refused, "iou": 0.75},  # both refused, the refit's IoU lower: the first kept
              4: {"ok": False, "failed": ["uncovered"], "params": [1.0]},  # passes the gate: not held, an anchor
              5: {**refused, "iou": 0.7},
              6: {"ok": True, "params": [0.0]}}
    refits = {1: {"ok": False, "failed": ["rms"]}, 2: {**refused, "params": [2.0], "iou": 0.6},
              3: {**refused, "params": [2.0], "iou": 0.74}, 5: {"ok": True, "params": [2.0], "iou": 0.9}}
    st = _Records(firsts, refits)
    out = list(settled_records(st, _sets(7)))
    assert st.retracked == [[3, 2, 1], [5]]
    assert [r["frame"] for r in out] == list(range(7))
    assert [r.get("refit", False) for r in out] == [False, False, True, False, False, True, False]
    assert out[2]["params"] == [2.0] and out[3]["params"] == [1.0] and out[5]["ok"]


@pytest.mark.parametrize("how", ["interrupt", "stop", "retrack"])
def test_held_frames_are_yielded_with_their_first_fits_when_the_run_ends_early(how):
    n = 12
    firsts = {i: {"ok": i < 3, "params": [0.0]} | ({} if i < 3 else {"failed": ["iou"]}) for i in range(n)}
    st = _Records(firsts, {}, raise_at=9 if how == "interrupt" else None)
    if how == "retrack":  # the tail's refit is interrupted: nothing held is lost, nothing refitted published
        n = 9

        def retrack(frames):
            st.retracked.append([f for f, _, _ in frames])
            raise KeyboardInterrupt
        st.retrack = retrack
    steps = []
    out = []
    stop = (lambda: len(steps) >= 9) if how == "stop" else None
    st_step = st.step
    st.step = lambda *a: steps.append(a[0]) or st_step(*a)
    gen = settled_records(st, _sets(n), stop=stop)
    if how != "stop":
        with pytest.raises(KeyboardInterrupt):
            for r in gen:
                out.append(r)
    else:
        out = list(gen)  # a stop (the CPU budget) does not refit the frames still held
    # frames 3-8 were held (refused, no accepted frame after them yet): they leave with their first fits
    assert [r["frame"] for r in out] == list(range(9))
    assert not any(r.get("refit") for r in out)
    assert st.retracked == ([[8, 7, 6, 5, 4, 3]] if how == "retrack" else [])


def test_an_interrupted_refit_loses_neither_the_held_frames_nor_the_accepted_frame_after_them():
    firsts = {i: {"ok": i in (0, 1, 2, 6), "params": [0.0]} | ({} if i in (0, 1, 2, 6) else {"failed": ["iou"]})
              for i in range(9)}
    st = _Records(firsts, {})

    def retrack(frames):
        st.retracked.append([f for f, _, _ in frames])
        raise KeyboardInterrupt
    st.retrack = retrack
    out = []
    with pytest.raises(KeyboardInterrupt):
        for r in settled_records(st, _sets(9)):
            out.append(r)
    # frames 3-5 were held; accepted frame 6 started their refit, which was interrupted: 0-6 all written, in order
    assert [r["frame"] for r in out] == list(range(7)) and not any(r.get("refit") for r in out)
    assert st.retracked == [[5, 4, 3]]


def test_the_tail_is_not_refitted_once_stop_says_so():
    firsts = {i: {"ok": i < 3, "params": [0.0]} | ({} if i < 3 else {"failed": ["iou"]}) for i in range(6)}
    st = _Records(firsts, {})
    calls = []
    out = list(settled_records(st, _sets(6), stop=lambda: calls.append(1) is None and len(calls) > 6))
    # stop() is asked before each of the 6 frames (False) and once more before the tail's refit (True)
    assert len(calls) == 7 and [r["frame"] for r in out] == list(range(6)) and st.retracked == []


@pytest.fixture(scope="module")
def hop(tmp_path_factory):
    out = tmp_path_factory.mktemp("hop")
    make_synthetic_session(bundled_motion("scaled_131_03"), out, cameras=4, size=(320, 240), frames=12,
                           n_background=5, seed=3)
    return out


def test_retrack_refits_the_warm_up_on_a_copy(hop):
    from service.offline import background_models
    from capture.replay import iter_frame_sets
    from tracker.fitting.scene import SceneTracker
    from service.offline import session_model
    from tracker.fitting.tracking import Tracker

    session = load_session(hop)
    names = list(session.camera_names)
    backgrounds, _ = background_models(session, names)
    cams = [session.camera_model(n) for n in names]
    st = SceneTracker(Tracker(session_model(session), cams), backgrounds, options=SceneOptions(warmup_frames=4))
    sets = [(fid, next(iter(g.values())).timestamp_ns, {n: f.image for n, f in g.items()})
            for fid, g in iter_frame_sets(session, cameras=names)]
    warm = []
    for item in sets[:7]:
        st.step(*item)
        warm.append(st.warming)
    k = warm.index(False)  # the start frame and the warm-up's frames after it
    assert k in (4, 5) and not any(warm[k:]), warm
    before = st.tracker.params.copy(), st.tracker.previous.copy() if st.tracker.previous is not None else None
    learned = {n: l.mask.copy() for n, l in st.learners.items()}
    base = st._base_options
    again = st.retrack(sets[k - 1::-1])
    assert [r["frame"] for r in again] == list(range(k))[::-1]
    # the copy checks the IoU on every frame (tracker.fitting.tracking.refit_options); this tracker does not
    assert all(r.get("iou") is not None for r in again), [r.get("iou") for r in again]
    assert st._base_options is base and st.tracker.options.iou_every == base.iou_every > 1
    # every refit is a pose the gate passes, or refuses only for a hand on the trunk's colour (the limb
    # colour check: in this 4-camera warm-up both wrists are 200-300 mm off the truth)
    assert all("params" in r and (r["ok"] or r["failed"] == ["limb_colour"]) for r in again), \
        [r.get("reason") for r in again]
    assert sum(r["ok"] for r in again) >= len(again) - 1
    # the tracker itself is where it was: the refit ran on a copy
    np.testing.assert_array_equal(st.tracker.params, before[0])
    assert (st.tracker.previous is None) == (before[1] is None)
    assert all(np.array_equal(st.learners[n].mask, m) for n, m in learned.items())
    assert not st.warming


def test_track_session_retrack_changes_only_the_warm_up_and_refused_frames(hop):
    session = load_session(hop)
    opts = SceneOptions(warmup_frames=4)
    plain = list(track_session(session, scene=opts, retrack=False))
    settled = list(track_session(session, scene=opts, smooth_s=0.0))
    assert [r["frame"] for r in settled] == [r["frame"] for r in plain]
    k = 5  # the start frame and the 4 warm-up frames after it
    for a, b in zip(plain[k:], settled[k:]):
        if a["ok"]:  # an accepted frame after the warm-up is never fitted again
            np.testing.assert_array_equal(a["params"], b["params"])
    # measured: the first two frames' first fits are not ok (front/back still ambiguous), every
    # refit from the settled, resolved state is
    assert not all(r["ok"] for r in plain[:k])
    assert all(r["ok"] for r in settled[:k]), [r.get("reason") for r in settled[:k]]
    assert any(a["params"] != b["params"] for a, b in zip(plain[:k], settled[:k]))


@pytest.mark.parametrize("flag", [[], ["--no-retrack"], ["--no-smooth"], ["--smooth-window", "0.3"]])
def test_track_cli_no_retrack_reaches_track_session(hop, tmp_path, monkeypatch, flag):
    """``--no-retrack`` (as live: every frame fitted once, unsmoothed), ``--no-smooth`` and ``--smooth-window``
    reach ``track_session``."""
    import service.commands.track as track_cmd
    from service.cli import main

    seen = {}

    def spy(*args, **kwargs):
        seen.update(kwargs)
        return track_session(*args, **kwargs)

    monkeypatch.setattr(track_cmd, "track_session", spy)
    out = tmp_path / "poses.jsonl"
    assert main(["track", str(hop), "--out", str(out), "--frames", "0:3", *flag]) == 0
    assert seen["retrack"] is ("--no-retrack" not in flag)
    assert seen["smooth_s"] == (0.0 if {"--no-retrack", "--no-smooth"} & set(flag) else
                                0.3 if "--smooth-window" in flag else SMOOTH_WINDOW_S)
    assert len(out.read_text().splitlines()) == 3


def test_image_tracker_retrack_refits_on_a_copy_that_checks_the_iou_every_frame(hop):
    from capture.replay import iter_frame_sets
    from service.offline import ImageTracker, background_models, session_model
    from tracker.fitting.tracking import Tracker, TrackerOptions

    session = load_session(hop)
    names = list(session.camera_names)
    backgrounds, _ = background_models(session, names)
    it = ImageTracker(Tracker(session_model(session), [session.camera_model(n) for n in names]), backgrounds)
    sets = [(fid, next(iter(g.values())).timestamp_ns, {n: f.image for n, f in g.items()})
            for fid, g in iter_frame_sets(session, cameras=names)]
    first = [it.step(*item) for item in sets[:6]]
    params, previous = it.tracker.params.copy(), it.tracker.previous
    guard = (it.tracker.guard.state, list(it.tracker.guard._pelvis))
    again = it.retrack(sets[4::-1])
    assert [r["frame"] for r in again] == [4, 3, 2, 1, 0]
    assert all(r.get("iou") is not None for r in again), [r.get("iou") for r in again]
    # from the accepted frame 5 the refits are poses of the same frames, near the first fits' where those passed
    for a, b in zip(first[4::-1], again):
        if a["ok"]:
            assert np.max(np.abs(np.subtract(a["joints"]["left_wrist"], b["joints"]["left_wrist"]))) < 0.05
    # the tracker itself is where it was and keeps its own options
    np.testing.assert_array_equal(it.tracker.params, params)
    assert (it.tracker.previous is None) == (previous is None)
    assert (it.tracker.guard.state, it.tracker.guard._pelvis) == guard  # the copy is deep: its guard walked alone
    assert it.tracker.options.iou_every == TrackerOptions().iou_every


def test_track_session_without_scene_refits_only_refused_frames(hop):
    session = load_session(hop)
    plain = list(track_session(session, retrack=False))
    settled = list(track_session(session, smooth_s=0.0))
    assert [r["frame"] for r in settled] == [r["frame"] for r in plain]
    for a, b in zip(plain, settled):
        if a["ok"]:
            np.testing.assert_array_equal(a["params"], b["params"])
    # measured: the first frame's front/back question is still open (refused); fitted again from the
    # accepted frame after it, the gate passes it
    assert not plain[0]["ok"] and settled[0]["ok"], (plain[0].get("reason"), settled[0].get("reason"))
    assert settled[0]["params"] != plain[0]["params"]


def test_track_session_smooths_the_poses_and_keeps_every_verdict(hop):
    """The default offline path smooths the settled records' poses (``service.smoothed``): the same frames in the
    same order, every verdict and quality figure the fit's, each pose a model pose (joints by forward kinematics
    of its params, inside the joint limits)."""
    from tracker.body.kinematics import forward, joint_centre_array

    session = load_session(hop)
    fitted = list(track_session(session, smooth_s=0.0))
    smoothed = list(track_session(session))
    assert [r["frame"] for r in smoothed] == [r["frame"] for r in fitted]
    model = session_model(session)
    moved = 0
    for a, b in zip(fitted, smoothed):
        assert {k: v for k, v in b.items() if k not in ("params", "joints", "smoothed", "latency_ms")} == \
            {k: v for k, v in a.items() if k not in ("params", "joints", "latency_ms")}
        if b.get("smoothed"):
            moved += 1
            J = joint_centre_array(model, forward(model, np.asarray(b["params"])))
            np.testing.assert_allclose([b["joints"][n] for n in model.joint_names], J, atol=1e-9)
            assert model.within_limits(np.asarray(b["params"]))
            assert max(np.linalg.norm(np.subtract(a["joints"][n], b["joints"][n])) for n in model.joint_names) < 0.1
    assert moved >= len(smoothed) // 2


@pytest.mark.parametrize("bad", ["-1", "nan", "inf"])
def test_track_cli_refuses_a_bad_smoothing_window(hop, tmp_path, capsys, bad):
    from service.cli import main

    assert main(["track", str(hop), "--out", str(tmp_path / "p.jsonl"), "--smooth-window", bad]) == 2
    assert "--smooth-window" in capsys.readouterr().err


def test_the_blob_tracker_stops_too(hop):
    """``track_session``'s ``stop`` ends a blob take as it ends a contour one (the bench's CPU budget)."""
    session = load_session(hop)
    asked = []
    assert list(track_session(session, method="blobs", stop=lambda: asked.append(1) is None)) == []
    assert asked == [1]
