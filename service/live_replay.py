"""Replay a session through the live fitter offline, deterministically (issue 13's live losses).

Live, the track worker fits only the sets it has time for (frame gaps), segments them in the
regions of interest it demanded, and runs its searches beside tracking for as long as they take.
:func:`replay_live` reproduces that in one process without clocks or threads: the frame ids to
fit are given (``schedule``: e.g. every n-th frame, or the frame ids of a live run's
``poses.jsonl``), each set is segmented as the segment worker would (``BackgroundSegmenter``,
within :meth:`LiveTrackerFitter.rois`), and a search's result is held back for
``search_frames`` sets (:class:`HeldSearches`) as if it had taken that long.  The clip loops
(frame id ``f`` shows clip frame ``f mod n``) as the live demo's replay does.

The same frames, schedule and options always give the same records, so a test can guard the
live fitter's behaviour under frame gaps and slow searches.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Callable, Iterable, Sequence

import numpy as np

__all__ = ["HeldSearches", "LiveReplay", "replay_live", "every_nth", "load_clip", "clip_joint_errors"]


class HeldSearches:
    """Runs a search at once, but reports it busy for the next ``frames`` sets (``advance()`` per set).

    ``frames``: an int, or a mapping from what the search function returned (the live fitter's
    search kind: ``"initialise"``, ``"rejoin"``, ``"full"``; None when it failed) to an int, with
    ``"default"`` for the rest.  0: the result is taken on the next set.  With ``sets_per_cpu_s``
    instead, a search is held for ``ceil(sets_per_cpu_s × its CPU seconds)`` sets (not
    deterministic: for benchmarks, not tests).
    """

    def __init__(self, frames: int | dict = 0, *, sets_per_cpu_s: float | None = None) -> None:
        table = dict(frames) if isinstance(frames, dict) else {"default": frames}
        if "default" not in table or any(int(v) < 0 for v in table.values()):
            raise ValueError(f"frames: expected counts >= 0 with a default, got {frames!r}")
        if sets_per_cpu_s is not None and not sets_per_cpu_s > 0:
            raise ValueError(f"sets_per_cpu_s: expected > 0, got {sets_per_cpu_s!r}")
        self.frames, self._left, self.sets_per_cpu_s = {k: int(v) for k, v in table.items()}, 0, sets_per_cpu_s
        self._then: Callable[[], None] | None = None
        self.held: list[tuple[object, int]] = []  # (kind, sets) of every search

    def start(self, fn: Callable[[], object], name: str, then: Callable[[], None] | None = None) -> None:
        """Run ``fn()`` now; its result is held for the sets its kind (or its CPU time) takes, and
        ``then()`` runs when the hold ends (the search's last step, on the sets that came meanwhile)."""
        c0 = time.process_time()
        kind = fn()
        if self.sets_per_cpu_s is not None:
            sets = int(np.ceil(self.sets_per_cpu_s * (time.process_time() - c0)))
        else:
            sets = self.frames.get(kind, self.frames["default"])
        self.held.append((kind, sets))
        self._left = sets + 1  # the set that started it is the first
        self._then = then

    def busy(self) -> bool:
        """Whether the last search is (deemed) still running."""
        return self._left > 0

    def advance(self) -> None:
        """One set passed."""
        self._left = max(0, self._left - 1)
        if not self._left and self._then is not None:
            then, self._then = self._then, None
            then()


@dataclass
class LiveReplay:
    """One replay's records and counters."""

    records: list[dict] = field(default_factory=list)
    searches: int = 0
    rejoined: int = 0
    roi_sets: int = 0

    @property
    def ok(self) -> int:
        """Records with ``ok`` true."""
        return sum(bool(r.get("ok")) for r in self.records)


@dataclass(frozen=True)
class Clip:
    """A session's frames in memory: ``images[camera][k]`` (h, w, 3) uint8 BGR of clip frame ``k``,
    the background models, the calibration and the true joints per clip frame (may be empty)."""

    session: object
    images: dict
    backgrounds: dict
    truth: dict

    @property
    def n_frames(self) -> int:
        """Clip length, frames."""
        return len(next(iter(self.images.values())))


def load_clip(root: str | Path) -> Clip:
    """Read a session (every camera's frames, background models, ``ground_truth.jsonl`` if any)."""
    import json

    from capture.replay import iter_frame_sets
    from capture.session import load_session
    from service.backgrounds import background_models

    session = load_session(Path(root))
    names = list(session.camera_names)
    images: dict[str, list] = {n: [] for n in names}
    for _, group in iter_frame_sets(session, cameras=names):
        if set(group) != set(names):
            raise ValueError(f"{root}: a camera dropped a frame; the replay needs complete sets")
        for n in names:
            images[n].append(group[n].image)
    backgrounds, _ = background_models(session, names)
    truth = {}
    gt = Path(root) / "ground_truth.jsonl"
    if gt.is_file():
        for line in gt.read_text().splitlines():
            if line.strip():
                rec = json.loads(line)
                truth[int(rec["frame"])] = rec.get("joints", {})
    return Clip(session, images, backgrounds, truth)


def every_nth(n_sets: int, gap: int | Sequence[int], *, start: int = 0) -> list[int]:
    """``n_sets`` frame ids from ``start``, ``gap`` apart (a sequence of gaps is cycled)."""
    gaps = [int(gap)] if np.ndim(gap) == 0 else [int(g) for g in gap]
    if not gaps or min(gaps) < 1:
        raise ValueError(f"gap: expected positive frame gaps, got {gap!r}")
    out, f = [], int(start)
    for i in range(int(n_sets)):
        out.append(f)
        f += gaps[i % len(gaps)]
    return out


def replay_live(clip: Clip, schedule: Iterable[int], *, search_frames: int | dict = 0, fitter=None, model: str = "knossow40",
                effort_level: int | None = 0, use_rois: bool = True,
                progress: Callable[[dict], None] | None = None) -> LiveReplay:
    """Fit the frame ids of ``schedule`` (increasing) through a :class:`LiveTrackerFitter`.

    Parameters
    ----------
    clip : Clip
        From :func:`load_clip`; frame id ``f`` is clip frame ``f mod clip.n_frames``.
    schedule : iterable of int
        The frame ids the tracker gets, in order.
    search_frames : int or dict
        Sets a search takes (:class:`HeldSearches`).
    fitter : LiveTrackerFitter, optional
        Default: one on the clip's session and ``model``, with ``HeldSearches(search_frames)``.
    effort_level : int or None
        Fix the adaptive effort at this level (None: adapt on the fitter's clock).
    use_rois : bool
        Segment in the fitter's regions of interest (else whole frames).
    progress : callable, optional
        Called with each record.

    Returns
    -------
    LiveReplay
    """
    from service.workers.components import BackgroundSegmenter
    from service.workers.live_fit import LiveTrackerFitter

    runner = HeldSearches(search_frames)
    if fitter is None:
        fitter = LiveTrackerFitter.from_session(clip.session, model=model, search_runner=runner)
    else:
        runner = fitter.search_runner
    segmenters = {n: BackgroundSegmenter(model=clip.backgrounds[n]) for n in clip.images}
    period_ns = int(round(1e9 / float(clip.session.fps or 30.0)))
    out = LiveReplay()
    last = None
    for fid in schedule:
        fid = int(fid)
        if last is not None and fid <= last:
            raise ValueError(f"schedule: frame ids must increase ({last} then {fid})")
        last = fid
        if effort_level is not None:
            fitter.effort.level = int(effort_level)
        rois = fitter.rois(fid) if use_rois else None
        out.roi_sets += rois is not None
        k, ts = fid % clip.n_frames, fid * period_ns
        chamfer = {}
        for name, seg in segmenters.items():
            image = clip.images[name][k]
            chamfer[name] = seg(SimpleNamespace(camera=name, frame_id=fid, timestamp_ns=ts), image, roi=None if rois is None else rois.get(name))
        record = fitter(fid, ts, chamfer)
        out.records.append(record)
        if progress is not None:
            progress(record)
        if hasattr(runner, "advance"):
            runner.advance()
    out.searches, out.rejoined = fitter.searches, fitter.rejoined
    return out


def clip_joint_errors(clip: Clip, records: Sequence[dict]) -> np.ndarray:
    """Per-record mean joint error (m) against the clip's truth, NaN where a record has no joints
    or the clip no truth; shape (len(records),)."""
    out = np.full(len(records), np.nan)
    if not clip.truth:
        return out
    first = min(clip.truth)
    for i, r in enumerate(records):
        gt = clip.truth.get(first + (int(r["frame"]) - first) % clip.n_frames)
        joints = r.get("joints")
        if gt and joints:
            names = [n for n in joints if n in gt]
            if names:
                out[i] = float(np.linalg.norm(np.array([joints[n] for n in names])
                                              - np.array([gt[n] for n in names]), axis=1).mean())
    return out
