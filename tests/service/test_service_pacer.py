"""EpochPacer: live replay pacing on an injected clock."""

from service.workers.loops import EpochPacer

MS = 1_000_000


class Clock:
    def __init__(self, t_ns: int) -> None:
        self.t = t_ns
        self.slept = []

    def __call__(self) -> int:
        return self.t

    def sleep(self, s: float) -> None:
        self.slept.append(s)
        self.t += int(s * 1e9)


def test_on_time_frames_wait_for_their_due_time():
    clock = Clock(1_000 * MS)
    pace = EpochPacer(1_000 * MS, wall_ns=clock, sleep=clock.sleep)
    assert pace(0) and pace(33 * MS) and pace(66 * MS)
    assert clock.t == 1_066 * MS and len(clock.slept) == 2


def test_a_restarted_worker_skips_to_the_present():
    clock = Clock(5_000 * MS)  # 4 s after the epoch: frames of session time < ~3.98 s are stale
    pace = EpochPacer(1_000 * MS, wall_ns=clock, sleep=clock.sleep)
    assert not pace(0) and not pace(2_000 * MS)
    assert pace(4_000 * MS)


def test_an_overloaded_reader_still_streams_late_frames():
    """Reading takes 50 ms a frame at 30 fps: every frame is late, yet one goes out every max_gap."""
    clock = Clock(1_000 * MS)
    pace = EpochPacer(1_000 * MS, wall_ns=clock, sleep=clock.sleep, max_gap_ns=200 * MS)
    sent = []
    for k in range(60):
        clock.t += 50 * MS  # decoding the frame
        if pace(round(k * 1e9 / 30)):
            sent.append(k)
    assert 12 <= len(sent) <= 16  # 3 s of reading, one frame per ~200 ms
    assert all(b - a >= 3 for a, b in zip(sent[1:], sent[2:]))  # the rest are skipped
