"""A lost track's search also from the silhouettes alone (``TrackerOptions.recover_full``, ``Tracker._full_search``)."""

from __future__ import annotations

import numpy as np

from tests.tracker.test_limbs import MODEL, _render, _stride
from tracker.body.kinematics import forward, joint_centre_array
from tracker.fitting.tracking import Tracker, TrackerOptions
from tracker.search.mirror import hypothesis_cost
from tracker.search.scoring import ScoreViews
from tracker.synthetic.scene import ring_cameras


def _error_m(params, truth) -> float:
    a = joint_centre_array(MODEL, forward(MODEL, np.asarray(params)))
    return float(np.mean(np.linalg.norm(a - joint_centre_array(MODEL, forward(MODEL, truth)), axis=1)))


def test_the_full_search_keeps_the_fit_of_lower_hypothesis_cost():
    """At seeded mid-stride poses: a fit from a start turned 90° and 0.5 m off is replaced by the search's
    (nearer the truth by half at least, within 15 cm); a fit from the truth is kept as it is; either way the
    fit kept costs no more than the one offered."""
    cams = ring_cameras(4, size=(320, 240))
    for seed in range(3):
        truth = _stride(seed)
        chs, sils = _render(truth, cams)
        tr = Tracker(MODEL, cams, initial_params=truth, front_back=None, options=TrackerOptions(recover_full=True))
        views = ScoreViews(MODEL, cams, [sils[c.name] for c in cams], scale=0.5)

        def cost(f):
            q = np.asarray(f[0].params)
            return hypothesis_cost(MODEL, q, f[2], float(views.score(q)))

        wrong = truth.copy()
        wrong[:2] += 0.5
        wrong[5] += np.pi / 2
        for start, far in ((wrong, True), (truth, False)):
            offered = tr._fit(cams, chs, MODEL.clamp(start))
            assert (_error_m(offered[0].params, truth) > 0.15) == far
            kept, _ = tr._full_search(cams, chs, sils, chs, lambda: views, offered, None)
            before, after = _error_m(offered[0].params, truth), _error_m(kept[0].params, truth)
            if far:  # the search's pose, fitted once (12 LM steps): near the truth, not on it
                assert after < min(0.15, 0.5 * before), (seed, before, after)
            else:
                assert kept is offered and after < 0.01, (seed, after)
            assert cost(kept) <= cost(offered) + 1e-9


def test_the_option_runs_the_full_search_when_a_track_is_lost():
    """Tracked from a start turned 90° and 0.5 m off with a last good pose: the search from the silhouettes
    alone runs beside the recovery with ``recover_full`` and never without it."""
    cams = ring_cameras(4, size=(320, 240))
    truth = _stride(0)
    chs, sils = _render(truth, cams)
    wrong = truth.copy()
    wrong[:2] += 0.5
    wrong[5] += np.pi / 2
    for on in (False, True):
        tr = Tracker(MODEL, cams, initial_params=MODEL.clamp(wrong), patience=1, front_back=None,
                     options=TrackerOptions(recover_full=on))
        tr.last_good = MODEL.clamp(wrong)
        calls, full = [], tr._full_search
        tr._full_search = lambda *a: (calls.append(1), full(*a))[1]
        records = [tr.step(k, k, chs, silhouettes=sils) for k in range(3)]
        assert tr.n_initialisations >= 1  # the track was lost and searched
        assert bool(calls) == on, (on, calls)
        if on:
            assert _error_m(records[-1]["params"], truth) < 0.15
