"""service.progress: the one progress line of the CLI (injected clock, a StringIO stream)."""

from __future__ import annotations

import io

from service.progress import Progress


def test_progress_line_rate_and_eta():
    now = [100.0]
    out = io.StringIO()
    bar = Progress(10, stream=out, clock=lambda: now[0], min_interval_s=0.0)
    now[0] += 2.0
    bar(4, label="cam0")  # 2 frames/s, 6 to go: 3 s
    assert "4/10 frames" in out.getvalue() and "2.0/s" in out.getvalue() and "ETA 00:03 cam0" in out.getvalue()
    bar.close()
    assert out.getvalue().endswith("\n")


def test_eta_over_an_hour_does_not_wrap():
    now = [0.0]
    out = io.StringIO()
    bar = Progress(10_000, stream=out, clock=lambda: now[0], min_interval_s=0.0)
    now[0] = 1.0
    bar(1)  # 1 frame/s, 9999 to go: 2 h 46 min 39 s (``%M:%S`` said "46:39")
    assert "ETA 2:46:39" in out.getvalue()


def test_disabled_and_throttled():
    now = [0.0]
    out = io.StringIO()
    Progress(5, stream=out, clock=lambda: now[0], enabled=False)(1)
    assert out.getvalue() == ""
    bar = Progress(5, stream=out, clock=lambda: now[0], min_interval_s=1.0)
    bar(1)
    bar(2)  # within the interval: not drawn
    assert "1/5" in out.getvalue() and "2/5" not in out.getvalue()
    bar(5)  # the last step is always drawn
    assert "5/5" in out.getvalue()
