"""Adapters between the wire messages and the real components (segmentation, tracker).

- :func:`chamfer_to_message` / :func:`message_to_chamfer`: ``segmentation.ChamferImages`` <->
  :class:`~service.wire.messages.ChamferMessage` (arrays ``silhouette`` and ``edges``, ``scale`` =
  1 / ``resolution_px``, ``truncation_px`` = ``max_distance_px``); exact round trip.
- :class:`BackgroundSegmenter`: the segment worker's per-camera callable.  It learns its background
  model from ``learn_frames`` frames it is given (an empty studio at start-up) unless a model is
  supplied (e.g. ``service.offline.background_models`` of a replayed session).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from service.wire.messages import ChamferMessage, FrameMessage, MessageError


def chamfer_to_message(camera: str, frame_id: int, timestamp_ns: int, chamfer, *,
                       attrs: dict[str, float] | None = None) -> ChamferMessage:
    """Wrap ``segmentation.ChamferImages`` for the wire."""
    return ChamferMessage(camera, int(frame_id), int(timestamp_ns), tuple(chamfer.image_size),
                          tuple(int(v) for v in chamfer.offset_xy), float(chamfer.max_distance_px),
                          1.0 / float(chamfer.resolution_px),
                          (("silhouette", chamfer.silhouette_q), ("edges", chamfer.edges_q)), attrs or {})


def message_to_chamfer(msg: ChamferMessage):
    """``segmentation.ChamferImages`` of a received message; MessageError if it is not one."""
    from segmentation.distance import ChamferImages

    try:
        sil, edges = msg.array("silhouette"), msg.array("edges")
        return ChamferImages(sil, edges, msg.roi_xy, 1.0 / msg.scale, msg.truncation_px, msg.image_size)
    except (KeyError, TypeError, ValueError, ZeroDivisionError) as exc:
        raise MessageError(f"camera {msg.camera}: not segmentation chamfer images: {exc}") from None


class BackgroundSegmenter:
    """``(FrameMessage, image_bgr (h, w, 3) uint8) -> ChamferMessage | None`` for one camera.

    Returns None while it is still learning its background (the first ``learn_frames`` frames).
    ``on_result(frame, FrameSegmentation)`` is called after each segmented frame (viewer taps).
    """

    def __init__(self, *, model=None, params=None, learn_frames: int = 30,
                 on_result: Callable | None = None) -> None:
        self.model, self.params, self.learn_frames = model, params, int(learn_frames)
        self.on_result = on_result
        self._learning: list[np.ndarray] = []

    takes_roi = True

    def warm_up(self) -> None:
        """Compile (or load) the segmentation's numba kernel before the first frame, not on it."""
        from segmentation.edt import warm_up

        warm_up()

    def __call__(self, frame: FrameMessage, image: np.ndarray, *,
                 roi: tuple[int, int, int, int] | None = None) -> ChamferMessage | None:
        """Chamfer images of ``image`` (h, w, 3) uint8 BGR, or None while learning; MessageError if
        the image is not BGR or not the background model's size.

        ``roi`` ``(x0, y0, x1, y1)``: only that box is segmented (clipped to the image); the message's
        ``roi_clipped`` attribute is 1 when the silhouette touches a side of the box that is not an
        image border (the body may reach beyond it)."""
        from segmentation.background import BackgroundModel
        from segmentation.pipeline import segment_frame

        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise MessageError(f"camera {frame.camera}: segmentation needs (h, w, 3) uint8 BGR, got "
                               f"{image.shape} {image.dtype}")
        if self.model is None:
            self._learning.append(image)
            if len(self._learning) >= self.learn_frames:
                self.model = BackgroundModel.from_frames(self._learning)
                self._learning = []
            return None
        if tuple(self.model.size) != (image.shape[1], image.shape[0]):
            raise MessageError(f"camera {frame.camera}: frame {image.shape[1]}x{image.shape[0]} does not match "
                               f"the background model {self.model.size[0]}x{self.model.size[1]}")
        attrs = {}
        if roi is not None:
            w, h = self.model.size
            x0, y0 = min(max(int(roi[0]), 0), w - 1), min(max(int(roi[1]), 0), h - 1)
            roi = (x0, y0, min(max(int(roi[2]), x0 + 1), w), min(max(int(roi[3]), y0 + 1), h))
        seg = segment_frame(self.model, image, roi=roi, params=self.params)
        if roi is not None:
            attrs["roi_clipped"] = float(roi_clipped_crop(seg.silhouette_roi, roi, self.model.size))
        if self.on_result is not None:
            self.on_result(frame, seg)
        return chamfer_to_message(frame.camera, frame.frame_id, frame.timestamp_ns, seg.chamfer,
                                  attrs={"foreground_fraction": seg.foreground_fraction, **attrs})


def roi_clipped(silhouette: np.ndarray, roi: tuple[int, int, int, int], size: tuple[int, int]) -> bool:
    """Whether the silhouette ``(h, w)`` touches a side of ``roi`` ``(x0, y0, x1, y1)`` that is not a
    border of the image of ``size`` ``(w, h)``."""
    x0, y0, x1, y1 = roi
    w, h = size
    sides = ((x0 > 0, silhouette[y0:y1, x0]), (x1 < w, silhouette[y0:y1, x1 - 1]),
             (y0 > 0, silhouette[y0, x0:x1]), (y1 < h, silhouette[y1 - 1, x0:x1]))
    return any(inner and bool(line.any()) for inner, line in sides)


def roi_clipped_crop(silhouette_roi: np.ndarray, roi: tuple[int, int, int, int], size: tuple[int, int]) -> bool:
    """:func:`roi_clipped` of the silhouette of the box only, ``(y1 - y0, x1 - x0)`` (no full-size image)."""
    x0, y0, x1, y1 = roi
    w, h = size
    if silhouette_roi.shape != (y1 - y0, x1 - x0):
        raise ValueError(f"silhouette_roi: shape {silhouette_roi.shape} does not match roi {roi!r}")
    sides = ((x0 > 0, silhouette_roi[:, 0]), (x1 < w, silhouette_roi[:, -1]),
             (y0 > 0, silhouette_roi[0, :]), (y1 < h, silhouette_roi[-1, :]))
    return any(inner and bool(line.any()) for inner, line in sides)


def silhouette_mask(chamfer) -> np.ndarray:
    """Full-image silhouette ``(h, w)`` uint8 0/255 from ChamferImages (distance 0 = inside)."""
    w, h = chamfer.image_size
    mask = np.zeros((h, w), np.uint8)
    rh, rw = chamfer.silhouette_q.shape
    x0, y0 = chamfer.offset_xy
    mask[y0:y0 + rh, x0:x0 + rw] = np.where(chamfer.silhouette_q == 0, 255, 0).astype(np.uint8)
    return mask


class TrackerFitter:
    """The track worker's fitter around ``tracker.fitting.tracking.Tracker``:
    ``(frame_id, timestamp_ns, {camera: ChamferMessage}) -> pose record dict``."""

    def __init__(self, tracker) -> None:
        self.tracker = tracker

    @classmethod
    def from_session(cls, session, *, model: str = "knossow40", initial_params=None) -> "TrackerFitter":
        """A tracker on ``session``'s calibration with ``model`` sized by its subject (its subject file
        when session.toml names one for this model, else height and segment lengths).

        Parameters
        ----------
        session : capture.session.Session
        model : str
            Body model name or file.
        initial_params : ndarray, shape (n_params,), optional
            Start pose; else automatic initialisation on the first frame set.
        """
        from service.offline import session_model
        from tracker.fitting.tracking import Tracker

        return cls(Tracker(session_model(session, model), list(session.calibration), initial_params=initial_params))

    def __call__(self, frame_id: int, timestamp_ns: int, chamfer: dict) -> dict:
        """The pose record of one frame set (``chamfer``: camera name -> ChamferMessage)."""
        images = {name: message_to_chamfer(msg) for name, msg in chamfer.items()}
        silhouettes = {name: silhouette_mask(ci) for name, ci in images.items()}
        return self.tracker.step(frame_id, timestamp_ns, images, silhouettes=silhouettes)
