"""Automatic subject calibration: a bounded, diverse sample of tracked frame sets, and a subject
fitted to part of it and judged on the rest.

:class:`SubjectSample` keeps at most ``capacity`` frame sets (their fitted pose and each camera's
silhouette, packed one bit per pixel), at least ``min_gap`` frame ids apart; once full, a new set
replaces the kept set closest in pose to another kept set when that makes the sample more diverse
(the least joint-angle distance between two kept sets grows).  :func:`calibrate_sample` fits the
subject (``tracker.fitting.subject_size.estimate_segment_lengths``) to the sample's fit sets and
compares, on its held-out sets, the silhouette IoU of the current body and of the calibrated one,
each pose polished to its body the same way (``polish_iou``, from the set's pose and from the pose
the other body reached): the calibrated body is adopted only
when it explains the held-out silhouettes better by ``min_gain``.  Never a worse body.

The silhouettes should hold the body only: a prop in them is covered better by a bigger body, and the
held-out IoU would reward it too (``tracker.fitting.scene`` cuts clutter offline).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from capture.camera import Camera
from tracker.body.model import JOINT_ROTATION, BodyModel
from tracker.body.subject import Subject
from tracker.fitting.subject_size import RADIUS_ORDER, WIDTH_ORDER, SubjectFit, estimate_segment_lengths, pose_steps
from tracker.search.scoring import ScoreViews
from tracker.search.seated import polish_iou

__all__ = ["AutoSubjectOptions", "usable_record", "SubjectSample", "SampleCalibration", "calibrate_sample",
           "held_out_iou", "held_out_ious"]


@dataclass(frozen=True)
class AutoSubjectOptions:
    """How an automatic calibration samples and fits.

    Attributes
    ----------
    frames : int
        Frame sets kept (fit and held out together), >= 2.
    held_out : int
        Of those, kept aside to judge the result (1 <= held_out < frames).
    min_gap : int
        Least frame-id distance between two kept sets.
    offers : int
        Good frame sets seen before calibrating (the sample keeps the most diverse ``frames`` of them).
    rounds : int
        ``estimate_segment_lengths`` rounds.
    widths_and_radii : bool
        Fit the hip/shoulder widths and the radius factors too (else the segment lengths only).
    scale : float
        Image scale of the scoring views (fit and judge).
    judge_rounds : int
        ``polish_iou`` rounds per held-out pose and body.
    min_gain : float
        Least gain of the mean held-out IoU for the calibrated body to be adopted.
    min_iou : float
        A set not ok only for its silhouette IoU (a body that is not the model's fails the gate) or
        for an open front/back question (the silhouettes are the same) is sampled when its IoU, if
        measured, is at least this.
    inset_px : float
        ``ScoreViews.inset_px`` of the scoring views (fit and judge; ``SCORE_INSET_PX``: unbiased).
    """

    frames: int = 9
    held_out: int = 3
    min_gap: int = 10
    offers: int = 27
    rounds: int = 2
    widths_and_radii: bool = True
    scale: float = 0.5
    judge_rounds: int = 3
    min_gain: float = 0.005
    min_iou: float = 0.7
    inset_px: float = 0.0

    def __post_init__(self) -> None:
        if not (2 <= int(self.frames) <= 64 and 1 <= int(self.held_out) < int(self.frames)):
            raise ValueError(f"frames, held_out: expected 2 <= frames <= 64 and 1 <= held_out < frames, "
                             f"got {self.frames}, {self.held_out}")
        if int(self.min_gap) < 1 or int(self.offers) < int(self.frames) or int(self.rounds) < 1:
            raise ValueError("min_gap >= 1, offers >= frames and rounds >= 1 expected")
        if not (0.1 <= float(self.scale) <= 1.0) or int(self.judge_rounds) < 0 or not float(self.min_gain) >= 0:
            raise ValueError("scale in [0.1, 1], judge_rounds >= 0 and min_gain >= 0 expected")

    @classmethod
    def for_sample(cls, n: int, *, span: int | None = None, offers_per_set: int = 3,
                   **options) -> "AutoSubjectOptions":
        """Options for a sample of ``n`` sets, a third held out, calibrated after ``offers_per_set``
        × ``n`` offers; with ``span`` (frames the sample is drawn from) the sets at least a quarter
        of ``span / n`` apart.  ``options``: the other fields."""
        n = int(n)
        gap = {} if span is None else {"min_gap": max(1, int(span) // (4 * n))}
        return cls(frames=n, held_out=max(1, n // 3), offers=int(offers_per_set) * n, **gap, **options)


def usable_record(record: Mapping, min_iou: float) -> bool:
    """Whether a pose record's fit may be sampled (``AutoSubjectOptions.min_iou``): it has a pose and
    is ok, or failed (its ``failed`` limits) only the IoU limit or an open front/back question, with
    an IoU >= ``min_iou``."""
    if record.get("params") is None:
        return False
    if record.get("ok"):
        return True
    failed, iou = set(record.get("failed") or ()), record.get("iou")
    if not failed or not failed <= {"iou", "front_back"} or ("iou" in failed and iou is None):
        return False
    return iou is None or float(iou) >= float(min_iou)


@dataclass(frozen=True)
class _Kept:
    frame_id: int
    params: np.ndarray
    angles: np.ndarray
    packed: dict  # camera -> (shape, packed bits)


class SubjectSample:
    """A bounded, diverse sample of frame sets (see the module docstring).

    Parameters
    ----------
    model : BodyModel
        The tracker's model (which parameters are joint angles).
    capacity, min_gap : int
        Frame sets kept; least frame-id distance between two kept sets.
    """

    def __init__(self, model: BodyModel, capacity: int, min_gap: int) -> None:
        self.capacity, self.min_gap = int(capacity), int(min_gap)
        self._joints = np.flatnonzero(np.asarray(model.param_kind) == JOINT_ROTATION)
        self._n_params = int(model.n_params)
        self.kept: list[_Kept] = []
        self.offered = 0

    def __len__(self) -> int:
        return len(self.kept)

    def offer(self, frame_id: int, params, silhouettes: Mapping[str, np.ndarray]) -> bool:
        """Take a tracked frame set (pose ``(n_params,)``, camera -> mask ``(h, w)``, non-zero = body)
        if it is far enough in time from the kept ones and keeps the sample diverse; True when kept."""
        p = np.asarray(params, dtype=float)
        if p.shape != (self._n_params,) or not np.all(np.isfinite(p)) or not silhouettes:
            return False
        if any(abs(int(frame_id) - k.frame_id) < self.min_gap for k in self.kept):
            return False
        self.offered += 1
        angles = p[self._joints]
        if len(self.kept) >= self.capacity:
            ang = np.stack([k.angles for k in self.kept] + [angles])
            d = np.sqrt(((ang[:, None, :] - ang[None, :, :]) ** 2).sum(-1))
            np.fill_diagonal(d, np.inf)
            drop = int(np.argmin(d.min(axis=1)))  # the set nearest another (on a tie the older: argmin takes the first)
            if drop == len(self.kept):
                return False
            del self.kept[drop]
        # packed only once kept
        self.kept.append(_Kept(int(frame_id), p.copy(), angles.copy(),
                               {n: (np.shape(s), np.packbits(np.asarray(s) > 0)) for n, s in silhouettes.items()}))
        return True

    def sets(self) -> list[tuple[int, np.ndarray, dict]]:
        """The kept sets in frame order: ``(frame id, params, camera -> bool mask (h, w))``."""
        out = []
        for k in sorted(self.kept, key=lambda k: k.frame_id):
            sils = {n: np.unpackbits(bits, count=int(np.prod(shape))).reshape(shape).astype(bool)
                    for n, (shape, bits) in k.packed.items()}
            out.append((k.frame_id, k.params.copy(), sils))
        return out

    @property
    def nbytes(self) -> int:
        """Bytes held by the kept silhouettes and poses."""
        return int(sum(b.nbytes for k in self.kept for _, b in k.packed.values())
                       + sum(k.params.nbytes + k.angles.nbytes for k in self.kept))


@dataclass(frozen=True)
class SampleCalibration:
    """Result of :func:`calibrate_sample`.

    Attributes
    ----------
    subject : Subject
        The calibrated subject (adopted or not).
    adopted : bool
        Whether it explains the held-out sets better by ``min_gain``.
    iou_current, iou_calibrated : float
        Mean held-out silhouette IoU of the current and the calibrated body (poses polished to each).
    fit : SubjectFit
    fit_frames, held_out_frames : tuple of int
    cpu_s : float
        CPU seconds of the calling thread.
    held_out_ious : tuple of (float, float)
        Per held-out set (``held_out_frames`` order), its IoU with the current and the calibrated body.
    """

    subject: Subject
    adopted: bool
    iou_current: float
    iou_calibrated: float
    fit: SubjectFit
    fit_frames: tuple
    held_out_frames: tuple
    cpu_s: float
    held_out_ious: tuple = ()


def held_out_iou(models: Sequence[BodyModel], cameras: Sequence[Camera], sets, *, scale: float,
                 rounds: int, inset_px: float = 0.0) -> list[float]:
    """Mean silhouette IoU of each of ``models`` (same parameters, other sizes) over ``sets``
    (``(frame id, params, camera -> mask)``), each pose first polished to the model by ``rounds`` of
    ``polish_iou`` (scoring views drawn with ``inset_px``, ``ScoreViews``); one list entry per model."""
    return [float(v) for v in held_out_ious(models, cameras, sets, scale=scale, rounds=rounds,
                                            inset_px=inset_px).mean(axis=0)]


def held_out_ious(models: Sequence[BodyModel], cameras: Sequence[Camera], sets, *, scale: float,
                  rounds: int, inset_px: float = 0.0) -> np.ndarray:
    """:func:`held_out_iou` per set: ndarray ``(len(sets), len(models))``.

    Each body's pose is polished from the set's pose and, when another body's polish scored higher,
    again from that body's polished pose; the body keeps the better of the two.  A polish from a
    perturbed pose stops in a local optimum that depends on the body, so a body would otherwise win
    by where its polish happened to stop (a body judged by the best pose any of them found).
    """
    names = [c.name for c in cameras]
    ious = np.zeros((len(sets), len(models)))
    for i, (_, p, sils) in enumerate(sets):
        base = ScoreViews(models[0], cameras, [np.asarray(sils[n]) for n in names], scale=scale, inset_px=inset_px)
        views = [base if j == 0 else base.with_model(m) for j, m in enumerate(models)]
        if not rounds:
            ious[i] = [v.score(p) for v in views]
            continue
        polished = [polish_iou(m, v, p, steps=pose_steps(m, 0.5), rounds=rounds) for m, v in zip(models, views)]
        ious[i] = [s for _, s in polished]
        best = int(np.argmax(ious[i]))
        for j, (m, v) in enumerate(zip(models, views)):
            if j != best:
                again = polish_iou(m, v, polished[best][0], steps=pose_steps(m, 0.5), rounds=rounds)[1]
                ious[i, j] = max(ious[i, j], again)
    return ious


def calibrate_sample(model: BodyModel, cameras: Sequence[Camera], sets, options: AutoSubjectOptions,
                     *, where: str = "auto") -> SampleCalibration:
    """Fit a subject to ``sets`` minus the held-out ones and judge it on those (module docstring).

    Parameters
    ----------
    model : BodyModel
        The body the poses were tracked with (the current body).
    cameras : sequence of Camera
        Those the silhouettes are of.
    sets : sequence of (int, ndarray (n_params,), mapping camera -> ndarray (h, w))
        In frame order (``SubjectSample.sets``); every ``len / held_out``-th from the second is held out.
    options : AutoSubjectOptions
    where : str
        Provenance for the subject's ``fitted`` text.
    """
    c0 = time.thread_time()
    sets = list(sets)
    if len(sets) < 2:
        raise ValueError("calibrate_sample: need at least 2 frame sets (one to fit, one to judge)")
    n_held = min(int(options.held_out), len(sets) - 1)
    held_idx = set(np.unique(np.linspace(1, len(sets) - 1, n_held).round().astype(int)).tolist())
    fit_sets = [s for i, s in enumerate(sets) if i not in held_idx]
    held = [s for i, s in enumerate(sets) if i in held_idx]
    more = {"widths": WIDTH_ORDER, "radii": RADIUS_ORDER} if options.widths_and_radii else {}
    fit = estimate_segment_lengths(model, cameras, [s[1] for s in fit_sets], [s[2] for s in fit_sets],
                                   rounds=int(options.rounds), scale=float(options.scale),
                                   inset_px=float(options.inset_px), **more)
    per_set = held_out_ious([model, fit.model], cameras, held, scale=options.scale, rounds=options.judge_rounds,
                            inset_px=float(options.inset_px))
    before, after = (float(v) for v in per_set.mean(axis=0))
    adopted = after >= before + float(options.min_gain)
    subject = Subject(model.name, model.height_m, fit.segment_lengths,
                      f"{where}: {len(fit_sets)} frame sets fitted, held-out IoU {before:.3f} -> {after:.3f} "
                      f"on {len(held)}", fit.widths, fit.radius_scale)
    return SampleCalibration(subject, adopted, before, after, fit, tuple(s[0] for s in fit_sets),
                             tuple(s[0] for s in held), time.thread_time() - c0,
                             tuple((float(a), float(b)) for a, b in per_set))
