"""The live fitter replayed offline (``service.live_replay``): frame gaps and slow searches,
deterministic, no processes (issue 13's live losses)."""

from __future__ import annotations

import numpy as np
import pytest

from service.live_replay import HeldSearches, every_nth
from tracker.fitting.uncovered import fit_ok


def test_held_searches_hold_results_for_their_kind():
    runner = HeldSearches({"default": 3, "rejoin": 0})
    runner.start(lambda: "full", "s")
    busy = []
    for _ in range(5):
        busy.append(runner.busy())
        runner.advance()
    assert busy == [True, True, True, True, False]  # the starting set and 3 more
    runner.start(lambda: "rejoin", "s")
    assert runner.busy()
    runner.advance()
    assert not runner.busy()  # taken on the next set
    assert runner.held == [("full", 3), ("rejoin", 0)]
    ended = []
    runner.start(lambda: "full", "s", then=lambda: ended.append(runner.busy()))
    for _ in range(3):
        runner.advance()
    assert ended == []  # the search's last step runs when its hold ends, not before
    runner.advance()
    assert ended == [False]
    runner.advance()
    assert ended == [False]  # once
    with pytest.raises(ValueError):
        HeldSearches({"rejoin": 1})
    with pytest.raises(ValueError):
        HeldSearches(-1)


def test_every_nth_cycles_gaps():
    assert every_nth(5, [1, 2], start=3) == [3, 4, 6, 7, 9]
    assert every_nth(3, 2) == [0, 2, 4]
    with pytest.raises(ValueError):
        every_nth(3, [1, 0])


def _bad_runs(records) -> list[int]:
    """Lengths of the runs of records whose fit failed (``fit_ok``: what the fitter's recovery acts on, the
    unexplained-boundary check only reporting) after the first good one."""
    runs, n, started = [], 0, False
    for r in records:
        if fit_ok(r):
            started = True
            if n:
                runs.append(n)
            n = 0
        elif started:
            n += 1
    return runs + ([n] if n else [])


@pytest.fixture(scope="module")
def hop_clip(tmp_path_factory):
    from service.live_replay import load_clip
    from service.synthetic_session import make_synthetic_session
    from tracker.synthetic.synth import bundled_motion

    root = tmp_path_factory.mktemp("live") / "hop"
    make_synthetic_session(bundled_motion("scaled_131_03"), root, cameras=6, size=(320, 240), frames=60, fps=30.0,
                           seed=0, name="hop")
    return load_clip(root)


@pytest.mark.slow
def test_a_lost_track_rejoins_within_a_few_sets_while_the_full_search_is_slow(hop_clip):
    """Every 2nd frame of two loops of the hop (the loop's jump from the last frame to the first
    included), searches held back as if the full search took 15 sets: the cheap rejoin at once
    keeps every run of bad sets after the initialisation shorter than a full search (measured: 1
    set, 102 of 120 ok, 3.5 cm mean error over ok sets).  With it turned off, there are more bad
    sets after the initialisation (measured 4 against 1, 99 ok); run beside the stream instead,
    the longest run is 9 sets.

    The rejoin is measured here with the prediction's second start off (``restart_step`` None): with
    the live default (0.1) the same schedule keeps as many sets ok but their mean error is 6.7 cm,
    because after the loop's jump a lost right arm passes the gate and the better fits keep it
    passing, so no rejoin comes (docs/performance.md, "Round 12"; checked below)."""
    from service.live_replay import clip_joint_errors, replay_live
    from service.workers.live_fit import LIVE_RESTART_STEP, LiveTrackerFitter

    def run(**options):
        options.setdefault("restart_step", None)
        options.setdefault("uncovered", True)  # the unexplained-boundary check on, as offline (off live by default)
        fitter = LiveTrackerFitter.from_session(hop_clip.session, search_runner=HeldSearches({"default": 15,
                                                                                            "rejoin": 3}), **options)
        return replay_live(hop_clip, every_nth(120, 2), fitter=fitter), fitter

    rep, fitter = run()
    frames = [r["frame"] for r in rep.records]
    assert frames == every_nth(120, 2) and all("fit_ms" in r for r in rep.records)
    runs = _bad_runs(rep.records)
    assert max(runs, default=0) <= 8, runs
    ok = np.array([fit_ok(r) for r in rep.records])
    assert ok.sum() >= 0.75 * len(ok)
    err = clip_joint_errors(hop_clip, rep.records)
    assert np.nanmean(err[ok]) < 0.06
    # the sets the unexplained-boundary check refuses are the worse ones (measured: 11, among them 7 sets of an
    # arm lost 92-126 mm off; the ok sets' mean error 4.1 -> 3.6 cm)
    shown = np.array([bool(r.get("ok")) for r in rep.records])
    assert np.nanmean(err[shown]) < np.nanmean(err[ok])
    assert fitter.search_kinds.get("rejoin now", 0) >= 1
    assert fitter.tracker.uncovered is not None  # asked for; off by default live
    assert LiveTrackerFitter.from_session(hop_clip.session).tracker.uncovered is None
    # the sets that ran it say how long it took them
    rejoins = [r for r in rep.records if "rejoin_ms" in r]
    assert len(rejoins) == fitter.search_kinds["rejoin now"]
    assert all(0 < r["rejoin_ms"] <= r["fit_ms"] for r in rejoins)
    old, _ = run(rejoin_spacing=-1)
    assert sum(_bad_runs(old.records)) > sum(runs)
    beside, fitter = run(rejoin_beside=True)  # the cheap recovery in the background instead: no set waits for it
    assert "rejoin now" not in fitter.search_kinds and fitter.search_kinds.get("rejoin", 0) >= 1
    assert max(_bad_runs(beside.records), default=0) < 15  # shorter than a full search (measured 9 sets)
    live, _ = run(restart_step=LIVE_RESTART_STEP)  # the live default: the rejoin still bounds the bad runs
    assert max(_bad_runs(live.records), default=0) <= 8
    live_ok = np.array([fit_ok(r) for r in live.records])
    assert live_ok.sum() >= 0.75 * len(live_ok)


@pytest.mark.slow
def test_a_slow_initialisation_starts_tracking_on_the_newest_set(hop_clip):
    """The initialisation's pose is of the set it started on; held back for 20 sets (the hop's
    take-off: the subject moved on), it is fitted to the newest set and tracking starts from
    there (a poor fit rejoins at once): one initialisation, and the track is ok afterwards."""
    from service.live_replay import replay_live
    from service.workers.live_fit import LiveTrackerFitter

    fitter = LiveTrackerFitter.from_session(hop_clip.session, search_runner=HeldSearches({"default": 20,
                                                                                        "rejoin": 2}))
    rep = replay_live(hop_clip, every_nth(60, 1, start=35), fitter=fitter)
    assert fitter.search_kinds.get("initialise") == 1, fitter.search_kinds
    assert all(not r["ok"] for r in rep.records[:21])  # nothing to publish before the search's pose
    assert sum(bool(r.get("ok")) for r in rep.records[21:]) >= 0.8 * len(rep.records[21:])


@pytest.mark.slow
def test_a_stale_search_pose_is_brought_forward_through_the_sets_held_meanwhile(hop_clip):
    """An initialisation held back for 25 sets (the subject crouches and takes off meanwhile): its
    pose, fitted through the sets held while it searched, tracks from the set it is taken on
    (measured: 13 of 40 ok, no further search); fitted straight to the newest set it is lost
    (measured: 0 ok, a full recovery)."""
    from service.live_replay import replay_live
    from service.workers.live_fit import LiveTrackerFitter

    def run(catch_up_sets):
        fitter = LiveTrackerFitter.from_session(hop_clip.session, search_runner=HeldSearches({"default": 25,
                                                                                            "rejoin": 2}),
                                                catch_up_sets=catch_up_sets)
        return replay_live(hop_clip, every_nth(40, 1, start=20), fitter=fitter), fitter

    rep, fitter = run(8)
    ok = [bool(r.get("ok")) for r in rep.records]
    assert not any(ok[:26]) and sum(ok[26:]) >= 0.8 * len(ok[26:]), ok
    assert "full" not in fitter.search_kinds, fitter.search_kinds
    old, _ = run(0)
    assert sum(bool(r.get("ok")) for r in old.records) < sum(ok)


@pytest.mark.slow
def test_a_live_search_offers_its_refined_mirror_to_the_front_back_guard(hop_clip):
    """As ``Tracker.step`` does with its own searches, the live fitter's initialisation (run beside the
    stream, held 3 sets) hands the guard its refined mirror of the pose, brought forward through the held
    sets as the pose is: the guard's first mirror fit starts from it, not from the mirror of the pose
    fitted once; a rejoin taken in the set's time opens the question again with its own mirror."""
    from service.live_replay import replay_live
    from service.workers.live_fit import LiveTrackerFitter
    from tracker.search.mirror import pelvis_heading

    fitter = LiveTrackerFitter.from_session(hop_clip.session, search_runner=HeldSearches({"default": 3, "rejoin": 0}))
    guard, model = fitter.tracker.guard, fitter.tracker.model
    offers, starts, caught = [], [], []
    offer, ambiguous, catch_up = guard.offer_mirror, guard._ambiguous, fitter._catch_up
    guard.offer_mirror = lambda p: (offers.append(None if p is None else np.array(p)), offer(p))

    def spy(t_s, cams, chs, images, res, terms, fit, iou):
        def recorded(start, prediction, *more):
            starts.append(np.array(start))
            return fit(start, prediction, *more)
        return ambiguous(t_s, cams, chs, images, res, terms, recorded, iou)

    def spied_catch_up():
        before = fitter._found
        catch_up()
        caught.append((before, fitter._found))

    guard._ambiguous, fitter._catch_up = spy, spied_catch_up
    rep = replay_live(hop_clip, every_nth(12, 1), fitter=fitter)
    assert fitter.search_kinds.get("initialise") == 1 and caught
    (f0, pose0, _, mirror0), (f1, pose1, _, mirror1) = caught[0]
    assert mirror0 is not None and f1 > f0  # the search refined a mirror; brought forward with the pose
    assert not np.allclose(mirror1, mirror0)
    assert offers and offers[0] is not None
    np.testing.assert_allclose(offers[0], mirror1)
    np.testing.assert_allclose(starts[0], offers[0])
    first = next(r for r in rep.records if "params" in r and "searching" not in r.get("reason", ""))
    assert first["front_back"] == "ambiguous"
    assert pelvis_heading(model, np.asarray(first["params"])) @ pelvis_heading(model, offers[0]) < -0.5
    # a rejoin taken in the set's time (a frame after the replay's): the question opened again, with the
    # rejoin's own refined mirror offered
    from types import SimpleNamespace

    from service.workers.components import BackgroundSegmenter, message_to_chamfer, silhouette_mask

    k = 14
    chamfer = {n: message_to_chamfer(BackgroundSegmenter(model=hop_clip.backgrounds[n])(
        SimpleNamespace(camera=n, frame_id=k, timestamp_ns=0), hop_clip.images[n][k], roi=None))
        for n in hop_clip.images}
    n_offers, n_resolved = len(offers), guard.n_resolved
    record = fitter._rejoin_now(k, int(k * 1e9 / 30), chamfer, {n: silhouette_mask(c) for n, c in chamfer.items()})
    assert record is not None and len(offers) == n_offers + 1
    assert "fit" in record["front_back_cues"]  # the mirror weighed on the rejoin's set: the question was open
    assert record["front_back"] == "ambiguous" or guard.n_resolved == n_resolved + 1
