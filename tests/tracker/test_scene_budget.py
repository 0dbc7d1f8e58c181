"""tracker.fitting.scene.RecoveryBudget: when a recovery search may run, and that the offline
default does not depend on how fast the machine is."""

from __future__ import annotations

import numpy as np

from tracker.fitting.scene import RecoveryBudget, SceneOptions


def _decisions(budget: RecoveryBudget, seconds, searched_at) -> list[bool]:
    """Feed frames taking ``seconds[i]``; a search runs on frame i when i is in ``searched_at`` and
    the budget allows it.  Returns the budget's answer before every frame."""
    out = []
    for i, dt in enumerate(seconds):
        allowed = budget.allows()
        out.append(allowed)
        ran = allowed and i in searched_at
        budget.frame(dt, searched=ran, restart=ran)
    return out


def test_frame_costs_make_the_decisions_independent_of_the_clock():
    rng = np.random.default_rng(3)
    wanted = set(range(0, 600, 7))  # the tracker would like a search every 7th frame
    fast = rng.uniform(0.005, 0.02, 600)
    slow = 3.0 * fast + rng.uniform(0.0, 0.5, 600)  # a loaded machine, searches timed long
    a = _decisions(RecoveryBudget(25, 0.2, 40.0), fast, wanted)
    b = _decisions(RecoveryBudget(25, 0.2, 40.0), slow, wanted)
    assert a == b
    runs = [i for i, ok in enumerate(a) if ok and i in wanted]
    # first search at once, then the share: 40 frames per search within 20 % of the frames tracked
    assert runs[0] == 0 and all(j - i >= 25 for i, j in zip(runs, runs[1:]))
    for k, i in enumerate(runs):
        assert 40.0 * k <= 0.2 * i + 1e-9, (k, i)
    assert len(runs) >= 0.2 * 600 / 40.0 - 1
    # measured seconds (None): the same frames, different decisions on the two machines
    c = _decisions(RecoveryBudget(25, 0.2, None), fast, wanted)
    d = _decisions(RecoveryBudget(25, 0.2, None), np.where(np.isin(np.arange(600), list(wanted)), 5.0, 0.01),
                   wanted)
    assert c != d


def test_gap_after_an_initialisation():
    b = RecoveryBudget(5, 1.0, 1.0)
    b.frame(0.01, searched=False, restart=True)  # the start search (not charged)
    seen = []
    for _ in range(6):
        seen.append(b.allows())
        b.frame(0.01, searched=False, restart=False)
    assert seen == [False, False, False, False, False, True]
    assert b.searching == 0.0 and b.tracking == 7.0


def test_offline_default_is_frame_counted():
    assert SceneOptions().recovery_cost_frames is not None and SceneOptions().recovery_cost_frames > 1
