"""Frame-set synchroniser: unit behaviour and hypothesis properties (drops, duplicates, reorders)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from capture.sources import Frame
from capture.sync import FrameSynchronizer

IMG = np.zeros((1, 1, 3), np.uint8)
MS = 1_000_000


def fr(cam: str, fid: int) -> Frame:
    return Frame(cam, fid, fid * 40 * MS, IMG)


def ids(sets):
    return [s.frame_id for s in sets]


def test_complete_sets_in_order():
    sync = FrameSynchronizer(["a", "b"], timeout_ns=100 * MS)
    sync.push(fr("a", 0), 0)
    sync.push(fr("a", 1), 1)
    assert sync.poll(2) == []
    sync.push(fr("b", 0), 3)
    sync.push(fr("b", 1), 4)
    out = sync.poll(5)
    assert ids(out) == [0, 1] and all(s.complete and s.reason == "complete" for s in out)
    assert list(out[0].frames) == ["a", "b"] and out[0].frames["b"].frame_id == 0
    st_ = sync.stats
    assert (st_.emitted, st_.complete, st_.incomplete, st_.pending) == (2, 2, 0, 0)


def test_timeout_names_missing_camera():
    sync = FrameSynchronizer(["a", "b", "c"], timeout_ns=100 * MS, stop_after_ns=10**12)
    sync.push(fr("a", 3), 0)
    sync.push(fr("c", 3), 10 * MS)
    assert sync.poll(99 * MS) == []
    (s,) = sync.poll(100 * MS)
    assert s.frame_id == 3 and s.missing == ("b",) and s.reason == "timeout" and not s.complete
    assert s.wait_ns == 100 * MS and sync.stats.max_wait_ns == 100 * MS
    assert sorted(s.frames) == ["a", "c"]
    assert sync.stats.timeouts == 1 and sync.stats.missing_by_camera == {"a": 0, "b": 1, "c": 0}
    sync.push(fr("b", 3), 101 * MS)  # after its set left: late, dropped
    assert sync.stats.late == 1 and sync.pending == 0


def test_camera_that_moved_on_is_not_waited_for():
    sync = FrameSynchronizer(["a", "b"], timeout_ns=10**12)
    for cam, fid in [("a", 0), ("b", 0), ("a", 1), ("a", 2), ("b", 2)]:
        sync.push(fr(cam, fid), 0)
    out = sync.poll(1)
    assert ids(out) == [0, 1, 2]
    assert out[1].missing == ("b",) and out[1].reason == "skipped"


def test_bad_input_counted():
    sync = FrameSynchronizer(["a", "b"], timeout_ns=100 * MS)
    sync.push(fr("a", 5), 0)
    sync.push(fr("a", 5), 0)  # duplicate of the newest
    sync.push(fr("a", 4), 0)  # out of order, set 4 still pending: used
    sync.push(fr("a", 4), 0)  # duplicate inside a pending set
    sync.push(fr("zz", 4), 0)  # unknown camera
    sync.push(fr("b", 4), 0)
    sync.push(fr("b", 5), 0)
    out = sync.poll(1)
    assert ids(out) == [4, 5] and all(s.complete for s in out)
    sync.push(fr("b", 2), 2)  # late
    s = sync.stats
    assert (s.duplicates, s.out_of_order, s.unknown, s.late) == (2, 1, 1, 1)


def test_stopped_camera_detected_and_not_waited_for():
    sync = FrameSynchronizer(["a", "b"], timeout_ns=100 * MS, stop_after_ns=300 * MS)
    sync.poll(0)
    t = 0
    for fid in range(20):
        t = fid * 40 * MS
        sync.push(fr("a", fid), t)
        if fid < 3:
            sync.push(fr("b", fid), t)
        sync.poll(t)
    assert sync.stats.stopped == ("b",)
    # once stopped, a new set of the live camera leaves without waiting
    sync.push(fr("a", 20), t + 40 * MS)
    (s,) = sync.poll(t + 40 * MS)
    assert s.frame_id == 20 and s.missing == ("b",) and s.reason == "skipped"
    sync.push(fr("b", 21), t + 80 * MS)
    assert sync.stats.stopped == ()


def test_arrival_stamped_at_next_poll_when_not_given():
    sync = FrameSynchronizer(["a", "b"], timeout_ns=100 * MS, stop_after_ns=10**12)
    sync.poll(0)
    sync.push(fr("a", 0))
    assert sync.poll(50 * MS) == []  # arrival taken as 50 ms
    assert sync.poll(149 * MS) == []
    assert ids(sync.poll(150 * MS)) == [0]


def test_memory_bounded_by_max_pending():
    sync = FrameSynchronizer(["a", "b"], timeout_ns=10**12, max_pending=4)
    for fid in range(100):
        sync.push(fr("a", fid), 0)
        assert sync.pending <= 4
    s = sync.stats
    assert s.overflow == 96 and s.discarded_frames == 96
    assert ids(sync.flush()) == [96, 97, 98, 99]


def test_constructor_validation():
    with pytest.raises(ValueError, match="unique"):
        FrameSynchronizer(["a", "a"], timeout_ns=1)
    with pytest.raises(ValueError, match="timeout_ns"):
        FrameSynchronizer(["a"], timeout_ns=0)
    with pytest.raises(ValueError, match="max_pending"):
        FrameSynchronizer(["a"], timeout_ns=1, max_pending=0)


@st.composite
def arrivals(draw):
    """Random camera streams with drops, duplicates, local reorders, wild ids and stray cameras."""
    n_cams = draw(st.integers(1, 4))
    cams = [f"c{i}" for i in range(n_cams)]
    n_ids = draw(st.integers(1, 25))
    streams = []
    for cam in cams:
        keep = draw(st.lists(st.booleans(), min_size=n_ids, max_size=n_ids))
        stream = [fid for fid, k in zip(range(n_ids), keep) if k or draw(st.booleans())]
        for _ in range(draw(st.integers(0, 3))):  # duplicates
            if stream:
                i = draw(st.integers(0, len(stream) - 1))
                stream.insert(i, stream[i])
        for _ in range(draw(st.integers(0, 3))):  # adjacent swaps
            if len(stream) > 1:
                i = draw(st.integers(0, len(stream) - 2))
                stream[i], stream[i + 1] = stream[i + 1], stream[i]
        if draw(st.booleans()):
            stream.append(draw(st.integers(0, 10**6)))  # a wild id
        streams.append([(cam, fid) for fid in stream])
    if draw(st.booleans()):
        streams.append([("stray", 1)])
    events = []
    while any(streams):
        k = draw(st.sampled_from([i for i, s in enumerate(streams) if s]))
        events.append(streams[k].pop(0))
        if draw(st.integers(0, 3)) == 0:
            events.append(("poll", draw(st.integers(0, 60)) * MS))
    return cams, events, draw(st.integers(1, 8))


@given(arrivals())
def test_property_never_mixed_ordered_bounded_conserved(case):
    cams, events, max_pending = case
    sync = FrameSynchronizer(cams, timeout_ns=100 * MS, stop_after_ns=400 * MS, max_pending=max_pending)
    now, pushed, emitted = 0, 0, []
    for what, value in events:
        if what == "poll":
            now += value
            emitted += sync.poll(now)
        else:
            sync.push(fr(what, value), now if value % 2 else None)
            pushed += 1
        assert sync.pending <= max_pending
        assert sync.frames_held <= max_pending * len(cams)
    emitted += sync.poll(now + 1)  # stamps arrivals pushed without a time
    emitted += sync.poll(now + 10**12)
    assert sync.pending == 0
    emitted_ids = ids(emitted)
    assert all(np.diff(emitted_ids) > 0)
    seen = set()
    for s in emitted:
        assert set(s.frames).isdisjoint(s.missing) and set(s.frames) | set(s.missing) == set(cams)
        assert s.frames  # a set exists only because a frame arrived
        for cam, frame in s.frames.items():
            assert frame.camera == cam and frame.frame_id == s.frame_id
            assert (cam, s.frame_id) not in seen
            seen.add((cam, s.frame_id))
    stats = sync.stats
    used = sum(len(s.frames) for s in emitted)
    assert pushed == used + stats.duplicates + stats.late + stats.unknown + stats.discarded_frames
    assert stats.emitted == len(emitted) == stats.complete + stats.incomplete
    assert all(0 <= s.wait_ns <= stats.max_wait_ns for s in emitted)


@given(st.integers(1, 5), st.integers(1, 30), st.randoms(use_true_random=False))
def test_property_lossless_input_gives_complete_sets(n_cams, n_ids, random):
    cams = [f"c{i}" for i in range(n_cams)]
    queues = [[(c, fid) for fid in range(n_ids)] for c in cams]
    sync = FrameSynchronizer(cams, timeout_ns=100 * MS, max_pending=n_ids + 1)
    out = []
    while any(queues):
        q = random.choice([q for q in queues if q])
        sync.push(fr(*q.pop(0)), 0)
        out += sync.poll(0)
    assert ids(out) == list(range(n_ids)) and all(s.complete for s in out)
    assert sync.stats.timeouts == 0 and sync.stats.duplicates == 0


def test_live_assembler_newest_wins_in_camera_order():
    """Live mode on the same rules: the newest ready set leaves, older ones are stale; items keep the
    configured camera order; a duplicate keeps the first item."""
    from capture.sync import FrameSetAssembler

    asm = FrameSetAssembler(("a", "b"), mode="live", timeout_s=0.1, absent_after_s=1.0)
    asm.add("b", 1, "b1", 0.0)
    asm.add("a", 1, "a1", 0.0)
    asm.add("a", 1, "a1-again", 0.0)
    asm.add("b", 2, "b2", 0.01)
    asm.add("a", 2, "a2", 0.01)
    (fs,) = asm.pop_ready(0.01)
    assert fs.frame_id == 2 and list(fs.items) == ["a", "b"] and fs.reason == "complete"
    assert (asm.stale, asm.counts["duplicates"]) == (1, 1)
    assert asm.pop_ready(0.02) == [] and len(asm) == 0
