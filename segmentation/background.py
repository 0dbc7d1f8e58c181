"""Per-pixel YUV background model with a Mahalanobis test (Caillette & Howard, BMVC'04 §3.2).

Each pixel of the empty scene is a Gaussian in centred YUV, ``p = (Y, U - 128, V - 128)``
(a linear map of BGR, see :func:`bgr_to_yuv`), with mean ``mu`` and covariance ``K`` learned
from ~50 background frames (:meth:`BackgroundModel.from_frames`) or, lacking those, from the
temporal median of session frames (:meth:`BackgroundModel.from_median`).  The test statistic
of a new pixel is the squared Mahalanobis distance ``(p - mu)^T K^-1 (p - mu)``.

Shadows.  The paper relaxes the luminance variance.  We do that (``luma_relax`` scales the Y
variance) and, because a cast shadow scales all of R, G, B by the same factor ``s`` and
therefore scales the *centred* YUV vector ``p`` by ``s`` too (chroma offsets shrink with the
brightness), we also relax along the pixel's own brightness axis: the distance is taken to
the nearest point of the segment ``{s * mu : s in shadow_range}``::

    A = mu^T K^-1 mu,   B = p^T K^-1 mu,   C = p^T K^-1 p
    s = clip(B / A, *shadow_range),   d = (C - 2 s B + s^2 A) / min(s, 1)^2        (d >= 0)

The division by ``s^2`` (as OpenCV's MOG2 shadow test) makes a darker "shadow" match the background's
colour more closely.  For grey backgrounds this axis is the paper's Y axis; for coloured ones (a
green floor) the physically right one; ``shadow_range = (1, 1)``: the plain Mahalanobis distance.

Camouflage (``window_px`` > 0).  A body part near the background's colour differs a little but by
one offset over its area; noise and shadows do not.  The relaxed residuals ``p - s mu`` are averaged
over a square window, their norm scaled by its effective sample count (area / ``WINDOW_CORRELATION``),
grey-eroded, and raise pixels already above ``WINDOW_GATE``.

Covariance ``"full"`` (3x3 per pixel) or ``"diag"`` (YUV variances only, the default); measurements
behind these choices: docs/tuning.md, "Segmentation".  ``BGR2YUV``: OpenCV's YUV coefficients without
the +128 offsets and without uint8 clipping.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Iterable, Sequence

import cv2
import numpy as np

from segmentation.checks import check_image_bgr, check_mask, check_roi
from segmentation.errors import SegmentationError

__all__ = ["BackgroundModel", "BackgroundFileError", "bgr_to_yuv", "BGR2YUV", "evenly_spaced"]


class BackgroundFileError(SegmentationError, ValueError):
    """A background model file that cannot be read; the message names it."""

# rows: Y, U - 128, V - 128 ; columns: B, G, R  (OpenCV's BGR2YUV without the +128 offsets)
BGR2YUV = np.array(
    [
        [0.114, 0.587, 0.299],
        [0.492 * (1 - 0.114), -0.492 * 0.587, -0.492 * 0.299],
        [-0.877 * 0.114, -0.877 * 0.587, 0.877 * (1 - 0.299)],
    ],
    dtype=np.float32,
)
# channel pairs of the off-diagonal terms, in the order (Y,U), (U,V), (V,Y)
_PERM = BGR2YUV[[1, 2, 0]].copy()
_ONES = np.ones((1, 3), np.float32)
_COV_INDEX = ((0, 0), (1, 1), (2, 2), (0, 1), (1, 2), (0, 2))  # layout of the 6 stored covariance terms
_FORMAT_VERSION = 1
WINDOW_CORRELATION = 3.0  # window area per effectively independent sample of the camouflage test
WINDOW_GATE = 4.0  # the camouflage test raises only pixels whose own distance exceeds this
BAND_PIXELS = 65536  # pixels per band of rows in the distance computation (measured ~20 % faster than whole-image)


def evenly_spaced(frames: Iterable[np.ndarray], count: int) -> list[np.ndarray]:
    """About ``count`` items spread evenly over an iterable of unknown length.

    Holds at most ``2 * count`` at a time (for a median background from a long session).

    Parameters
    ----------
    frames : iterable
    count : int
        At least 1.

    Returns
    -------
    list
    """
    if count < 1:
        raise ValueError(f"count: expected >= 1, got {count!r}")
    kept, stride = [], 1
    for i, frame in enumerate(frames):
        if i % stride == 0:
            kept.append(frame)
        if len(kept) >= 2 * count:
            kept, stride = kept[::2], stride * 2
    if len(kept) <= count:
        return kept
    pick = np.unique(np.linspace(0, len(kept) - 1, count).round().astype(int))
    return [kept[i] for i in pick]


def _downsample(image: np.ndarray) -> np.ndarray:
    """2x2 block means ``(ceil(h/2), ceil(w/2), c)``; odd sizes are padded by replication."""
    h, w = image.shape[:2]
    if h % 2 or w % 2:
        image = cv2.copyMakeBorder(image, 0, h % 2, 0, w % 2, cv2.BORDER_REPLICATE)
    return cv2.resize(image, (image.shape[1] // 2, image.shape[0] // 2), interpolation=cv2.INTER_AREA)


def bgr_to_yuv(image_bgr: np.ndarray) -> np.ndarray:
    """Centred YUV of a BGR image (Y in 0..255, U and V about 0).

    Parameters
    ----------
    image_bgr : ndarray, shape (h, w, 3), uint8

    Returns
    -------
    ndarray, shape (h, w, 3), float32
    """
    return cv2.transform(image_bgr.astype(np.float32), BGR2YUV)


class BackgroundModel:
    """Per-pixel Gaussian background in centred YUV; see the module docstring.

    ``update`` changes the mean in place (slow adaptation); everything else is fixed.  One model
    serves one camera stream: ``distance`` reuses scratch buffers, so do not call it from two
    threads at once.

    Parameters
    ----------
    mean_yuv : ndarray, shape (h, w, 3), float32
        Centred YUV mean.
    cov_yuv : ndarray, shape (h, w, 6), float32
        Covariance terms yy, uu, vv, yu, uv, yv (before regularisation; the off-diagonal terms
        are zeroed for ``covariance="diag"``).
    covariance : {"diag", "full"}
    luma_relax : float
        Factor on the Y variance (>= 1).
    shadow_range : (float, float)
        ``(s_lo, s_hi)`` brightness factors still explained as background.
    min_sigma : float
        Floor of the per-channel standard deviation, YUV levels.
    window_px : int
        Radius of the camouflage test's window, pixels (0: off, the default; 1 is what was measured).
    """

    def __init__(self, mean_yuv: np.ndarray, cov_yuv: np.ndarray, *, covariance: str = "diag",
                 luma_relax: float = 1.0, shadow_range: tuple[float, float] = (0.5, 1.1),
                 min_sigma: float = 2.5, window_px: int = 0) -> None:
        mean_yuv = np.asarray(mean_yuv, dtype=np.float32)
        cov_yuv = np.asarray(cov_yuv, dtype=np.float32)
        if mean_yuv.ndim != 3 or mean_yuv.shape[2] != 3 or min(mean_yuv.shape[:2]) < 1:
            raise ValueError(f"mean_yuv: expected shape (h, w, 3), got {mean_yuv.shape}")
        if cov_yuv.shape != mean_yuv.shape[:2] + (6,):
            raise ValueError(f"cov_yuv: expected shape {mean_yuv.shape[:2] + (6,)}, got {cov_yuv.shape}")
        if not (np.isfinite(mean_yuv).all() and np.isfinite(cov_yuv).all()):
            raise ValueError("mean_yuv / cov_yuv: contain NaN or inf")
        if covariance not in ("full", "diag"):
            raise ValueError(f"covariance: expected 'full' or 'diag', got {covariance!r}")
        lo, hi = (float(v) for v in shadow_range)
        if not (0.0 < lo <= 1.0 <= hi and np.isfinite(hi)):
            raise ValueError(f"shadow_range: expected 0 < lo <= 1 <= hi, got {shadow_range!r}")
        if not (np.isfinite(luma_relax) and luma_relax >= 1.0):
            raise ValueError(f"luma_relax: expected a finite number >= 1, got {luma_relax!r}")
        if not (np.isfinite(min_sigma) and min_sigma > 0):
            raise ValueError(f"min_sigma: expected a finite number > 0, got {min_sigma!r}")
        if not (isinstance(window_px, (int, np.integer)) and 0 <= window_px <= 8):
            raise ValueError(f"window_px: expected an integer in 0..8, got {window_px!r}")
        self.mean_yuv = np.ascontiguousarray(mean_yuv)
        self.cov_yuv = np.ascontiguousarray(cov_yuv)
        if covariance == "diag":
            self.cov_yuv[..., 3:] = 0.0
        self.covariance = covariance
        self.luma_relax = float(luma_relax)
        self.shadow_range = (lo, hi)
        self.min_sigma = float(min_sigma)
        self.window_px = int(window_px)
        self._window_disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * self.window_px + 1,) * 2)
        self._scratch: dict = {}
        self._coarse: BackgroundModel | None = None
        self._precision()
        self._derive_mean_terms()

    # ----------------------------------------------------------------- construction
    @classmethod
    def from_frames(cls, frames: Iterable[np.ndarray], **options) -> "BackgroundModel":
        """Learn mean and covariance from background frames.

        Parameters
        ----------
        frames : iterable of ndarray, each shape (h, w, 3), uint8
            At least 2 BGR frames of the empty scene.
        **options
            ``covariance``, ``luma_relax``, ``shadow_range``, ``min_sigma``, ``window_px`` (see the class).

        Returns
        -------
        BackgroundModel
        """
        n = 0
        s1 = s2 = None
        for i, frame in enumerate(frames):
            check_image_bgr(frame, f"frames[{i}]")
            if s1 is None:
                h, w = frame.shape[:2]
                s1 = np.zeros((h, w, 3), np.float64)
                s2 = np.zeros((h, w, 6), np.float64)
            elif frame.shape[:2] != s1.shape[:2]:
                raise ValueError(f"frames[{i}]: shape {frame.shape} differs from frames[0] {s1.shape[:2] + (3,)}")
            p = bgr_to_yuv(frame).astype(np.float64)
            s1 += p
            for k, (a, b) in enumerate(_COV_INDEX):
                s2[..., k] += p[..., a] * p[..., b]
            n += 1
        if n < 2:
            raise ValueError(f"frames: need at least 2 background frames, got {n}")
        mean = s1 / n
        cov = np.empty_like(s2)
        for k, (a, b) in enumerate(_COV_INDEX):
            cov[..., k] = (s2[..., k] - n * mean[..., a] * mean[..., b]) / (n - 1)
        return cls(mean, cov, **options)

    @classmethod
    def from_median(cls, frames: Sequence[np.ndarray], **options) -> "BackgroundModel":
        """Background from the temporal median of session frames (the person must move).

        Variances are robust: ``(1.4826 MAD)^2`` per channel; the covariance is diagonal.

        Parameters
        ----------
        frames : sequence of ndarray, each shape (h, w, 3), uint8
            At least 3 BGR frames.
        **options
            As :meth:`from_frames`.

        Returns
        -------
        BackgroundModel
        """
        frames = list(frames)
        if len(frames) < 3:
            raise ValueError(f"frames: need at least 3 frames for a median background, got {len(frames)}")
        for i, frame in enumerate(frames):
            check_image_bgr(frame, f"frames[{i}]")
            if frame.shape != frames[0].shape:
                raise ValueError(f"frames[{i}]: shape {frame.shape} differs from frames[0] {frames[0].shape}")
        stack = np.stack([bgr_to_yuv(f) for f in frames])  # (n, h, w, 3)
        med = np.median(stack, axis=0)
        mad = np.median(np.abs(stack - med), axis=0)
        cov = np.zeros(med.shape[:2] + (6,), np.float32)
        cov[..., :3] = (1.4826 * mad) ** 2
        options.setdefault("covariance", "diag")
        return cls(med, cov, **options)

    # ----------------------------------------------------------------- derived terms
    def _precision(self) -> None:
        """Regularised inverse covariance: diagonal (h, w, 3) and 2 x off-diagonal (h, w, 3) planes."""
        h, w = self.mean_yuv.shape[:2]
        cov = self.cov_yuv.astype(np.float64)
        full = np.empty((h, w, 3, 3))
        for k, (a, b) in enumerate(_COV_INDEX):
            full[..., a, b] = full[..., b, a] = cov[..., k]
        full[..., 0, :] *= np.sqrt(self.luma_relax)
        full[..., :, 0] *= np.sqrt(self.luma_relax)
        floor = self.min_sigma ** 2
        for c in range(3):
            full[..., c, c] = np.maximum(full[..., c, c], 0.0) + floor
        if self.covariance == "diag":
            inv = np.zeros_like(full)
            for c in range(3):
                inv[..., c, c] = 1.0 / full[..., c, c]
        else:
            inv = np.linalg.inv(full)
        self._inv = inv.astype(np.float32)  # (h, w, 3, 3)
        self._pdiag = np.ascontiguousarray(np.stack([inv[..., 0, 0], inv[..., 1, 1], inv[..., 2, 2]], -1),
                                           dtype=np.float32)
        self._pcross = np.ascontiguousarray(2 * np.stack([inv[..., 0, 1], inv[..., 1, 2], inv[..., 2, 0]], -1),
                                            dtype=np.float32)

    def _derive_mean_terms(self) -> None:
        a = np.einsum("hwij,hwj->hwi", self._inv, self.mean_yuv)  # K^-1 mu, (h, w, 3)
        big_a = np.einsum("hwi,hwi->hw", a, self.mean_yuv)
        self._a = np.ascontiguousarray(a, dtype=np.float32)
        self._big_a = np.ascontiguousarray(big_a, dtype=np.float32)
        self._inv_a = (1.0 / np.maximum(big_a, 1e-6)).astype(np.float32)

    # ----------------------------------------------------------------- per frame
    @property
    def size(self) -> tuple[int, int]:
        """Image size ``(w, h)`` the model was learned at."""
        return int(self.mean_yuv.shape[1]), int(self.mean_yuv.shape[0])

    def distance(self, image_bgr: np.ndarray, *, roi=None) -> np.ndarray:
        """Squared Mahalanobis distance (shadow-relaxed) of each pixel.

        Parameters
        ----------
        image_bgr : ndarray, shape (h, w, 3), uint8
            The full image.
        roi : (int, int, int, int), optional
            ``(x0, y0, x1, y1)``: limit the work (and the result) to that box.

        Returns
        -------
        ndarray, shape (y1 - y0, x1 - x0), float32
        """
        check_image_bgr(image_bgr, "image_bgr", size=self.size)
        x0, y0, x1, y1 = check_roi(roi, self.size)
        return self._distance_in(image_bgr[y0:y1, x0:x1], (slice(y0, y1), slice(x0, x1)))

    def _distance_in(self, region: np.ndarray, sl, terms: bool = False):
        """Distance ``(h, w)`` of a BGR uint8 ``region`` ``(h, w, 3)`` against the model pixels
        ``sl = (slice(y0, y1), slice(x0, x1))``, computed in bands of rows that stay in cache;
        ``terms``: also the plain distance and the brightness ratio (``distance_terms``)."""
        h, w = region.shape[:2]
        d = np.empty((h, w), np.float32)
        plain = np.empty((h, w), np.float32) if terms else None
        ratio = np.empty((h, w), np.float32) if terms else None
        rows = max(1, min(h, BAND_PIXELS // max(w, 1)))
        ws = self._workspace((rows, w))
        y0 = sl[0].start
        q = np.empty((h, w, 3), np.float32) if self.window_px else None
        for r0 in range(0, h, rows):  # a loop over ~10-30 bands, not over pixels
            r1 = min(r0 + rows, h)
            extra = (plain[r0:r1], ratio[r0:r1]) if terms else None
            self._distance_band(region[r0:r1], (slice(y0 + r0, y0 + r1), sl[1]), ws, r1 - r0, d[r0:r1], extra,
                                None if q is None else q[r0:r1])
        if q is not None:
            self._camouflage(q, sl, d)
        return (d, plain, ratio) if terms else d

    def _camouflage(self, q: np.ndarray, sl, d: np.ndarray) -> None:
        """The window test of the module docstring, in place on ``d`` (h, w); ``q`` (h, w, 3) the relaxed
        residual vectors of the pixels ``sl``."""
        k = 2 * self.window_px + 1
        cv2.boxFilter(q, -1, (k, k), dst=q, borderType=cv2.BORDER_REFLECT)
        if self.covariance == "full":
            window = np.einsum("hwi,hwij,hwj->hw", q, self._inv[sl], q).astype(np.float32)
        else:
            cv2.multiply(q, q, dst=q)
            cv2.multiply(q, self._pdiag[sl], dst=q)
            window = cv2.transform(q, _ONES)
        window *= np.float32(k * k / WINDOW_CORRELATION)
        window = cv2.erode(window, self._window_disk, borderType=cv2.BORDER_REFLECT)
        # raise only pixels above the gate: window zeroed elsewhere (d >= 0), OpenCV not a masked ufunc
        cv2.subtract(window, window, dst=window, mask=cv2.compare(d, WINDOW_GATE, cv2.CMP_LE))
        cv2.max(d, window, dst=d)

    def _distance_band(self, region, sl, ws: dict, n: int, out: np.ndarray, extra=None, resid=None) -> None:
        bgr, p, t3, big_c, big_b, s, t = (ws[k][:n] for k in ("bgr", "p", "t3", "c", "b", "s", "t"))
        np.copyto(bgr, region, casting="unsafe")  # uint8 -> float32 into a reused buffer
        cv2.transform(bgr, BGR2YUV, dst=p)
        cv2.multiply(p, p, dst=t3)
        cv2.multiply(t3, self._pdiag[sl], dst=t3)
        if self.covariance == "full":
            q = ws["q"][:n]
            cv2.transform(bgr, _PERM, dst=q)  # (U, V, Y): pairs (Y,U), (U,V), (V,Y) with p
            cv2.multiply(p, q, dst=q)
            cv2.multiply(q, self._pcross[sl], dst=q)
            cv2.add(t3, q, dst=t3)
        cv2.transform(t3, _ONES, dst=big_c)
        cv2.multiply(p, self._a[sl], dst=t3)
        cv2.transform(t3, _ONES, dst=big_b)
        cv2.multiply(big_b, self._inv_a[sl], dst=s)
        if extra is not None:  # C - 2 B + A: the distance without the shadow relaxation; B / A
            cv2.scaleAdd(big_b, -2.0, big_c, dst=extra[0])
            cv2.add(extra[0], self._big_a[sl], dst=extra[0])
            cv2.max(extra[0], 0.0, dst=extra[0])
            np.copyto(extra[1], s)
        lo, hi = self.shadow_range
        cv2.max(s, lo, dst=s)
        cv2.min(s, hi, dst=s)
        if resid is not None:  # the relaxed residual p - s mu (t3 is free here; OpenCV, not a broadcast)
            cv2.merge((s, s, s), dst=t3)
            cv2.multiply(self.mean_yuv[sl], t3, dst=t3)
            cv2.subtract(p, t3, dst=resid)
        cv2.multiply(s, self._big_a[sl], dst=t)
        cv2.scaleAdd(big_b, -2.0, t, dst=t)  # s A - 2 B
        cv2.multiply(s, t, dst=t)
        cv2.add(big_c, t, dst=out)  # C - 2 s B + s^2 A
        cv2.max(out, 0.0, dst=out)
        cv2.min(s, 1.0, dst=t)  # a darker "shadow" must match the background colour more closely:
        cv2.multiply(t, t, dst=t)  # divide by min(s, 1)^2, as OpenCV's MOG2 shadow test does
        cv2.divide(out, t, dst=out)

    def _workspace(self, shape: tuple[int, int]) -> dict:
        """Float32 scratch arrays of ``shape`` (a band), views of flat buffers reused for every shape
        (ROIs change every frame: fresh arrays would page-fault on each)."""
        h, w = shape
        n = h * w
        if self._scratch.get("n", 0) < n:
            self._scratch = {"n": n, **{k: np.empty(3 * n, np.float32) for k in ("bgr", "p", "t3", "q")},
                             **{k: np.empty(n, np.float32) for k in ("c", "b", "s", "t")}}
        ws = self._scratch
        return {**{k: ws[k][:3 * n].reshape(h, w, 3) for k in ("bgr", "p", "t3", "q")},
                **{k: ws[k][:n].reshape(h, w) for k in ("c", "b", "s", "t")}}

    def distance_terms(self, image_bgr: np.ndarray, *, roi=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`distance`, the plain Mahalanobis distance (no shadow relaxation) and the
        brightness ratio ``B / A`` of each pixel (the shadow factor before clipping).

        Parameters
        ----------
        image_bgr : ndarray, shape (h, w, 3), uint8
        roi : (int, int, int, int), optional
            ``(x0, y0, x1, y1)``, as :meth:`distance`.

        Returns
        -------
        distance, plain, ratio : ndarray, each shape (y1 - y0, x1 - x0), float32
        """
        check_image_bgr(image_bgr, "image_bgr", size=self.size)
        x0, y0, x1, y1 = check_roi(roi, self.size)
        return self._distance_in(image_bgr[y0:y1, x0:x1], (slice(y0, y1), slice(x0, x1)), terms=True)

    def distance_at(self, image_bgr: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                    scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Plain squared distances of single pixels to the background and to the background
        darkened by ``scale`` (``s * mu``: a shadow of that depth), without relaxation.

        Parameters
        ----------
        image_bgr : ndarray, shape (h, w, 3), uint8
        rows, cols : ndarray of int, shape (n,)
            Pixel coordinates inside the image.
        scale : ndarray, shape (n,)
            Brightness factor per pixel.

        Returns
        -------
        unchanged, darkened : ndarray, each shape (n,), float32
        """
        check_image_bgr(image_bgr, "image_bgr", size=self.size)
        rows, cols = np.asarray(rows, np.intp), np.asarray(cols, np.intp)
        p = image_bgr[rows, cols].astype(np.float32) @ BGR2YUV.T  # (n, 3) centred YUV
        big_a = self._big_a[rows, cols]
        big_b = np.einsum("ni,ni->n", self._a[rows, cols], p)  # p^T K^-1 mu
        if self.covariance == "full":
            big_c = np.einsum("ni,nij,nj->n", p, self._inv[rows, cols], p)
        else:
            big_c = np.einsum("ni,ni->n", p * p, self._pdiag[rows, cols])
        s = np.asarray(scale, np.float32)
        unchanged = np.maximum(big_c - 2 * big_b + big_a, 0)
        darkened = np.maximum(big_c - 2 * s * big_b + s * s * big_a, 0)
        return unchanged.astype(np.float32), darkened.astype(np.float32)

    def coarse_distance(self, image_bgr: np.ndarray, *, plain: bool = False) -> np.ndarray:
        """The distance at half resolution: 2x2 block means of the image against those of the model.

        About four times cheaper; a first pass that finds where the person is (e.g. for an automatic
        ROI).  Pixel (i, j) covers full pixels 2i..2i+1, 2j..2j+1.

        Parameters
        ----------
        image_bgr : ndarray, shape (h, w, 3), uint8
        plain : bool
            The distance without the shadow relaxation (finds shadows and shadow-like body parts too).

        Returns
        -------
        ndarray, shape (ceil(h/2), ceil(w/2)), float32
        """
        check_image_bgr(image_bgr, "image_bgr", size=self.size)
        coarse = self._coarse_model()
        small = _downsample(image_bgr)
        sl = (slice(0, small.shape[0]), slice(0, small.shape[1]))
        return coarse._distance_in(small, sl, terms=True)[1] if plain else coarse._distance_in(small, sl)

    def _coarse_model(self) -> "BackgroundModel":
        if self._coarse is None:
            self._coarse = BackgroundModel(_downsample(self.mean_yuv), _downsample(self.cov_yuv),
                                           covariance=self.covariance, luma_relax=self.luma_relax,
                                           shadow_range=self.shadow_range, min_sigma=self.min_sigma,
                                           window_px=self.window_px)
        return self._coarse

    def update(self, image_bgr: np.ndarray, foreground: np.ndarray, *, rate: float = 0.01) -> None:
        """Slow adaptation in place: ``mu += rate (p - mu)`` where ``foreground`` is 0.

        Parameters
        ----------
        image_bgr : ndarray, shape (h, w, 3), uint8
        foreground : ndarray, shape (h, w), uint8 or bool
            Non-zero = person (not learned there).
        rate : float
            In (0, 1].
        """
        check_image_bgr(image_bgr, "image_bgr", size=self.size)
        fg = check_mask(foreground, "foreground", shape=self.mean_yuv.shape[:2])
        if not (np.isfinite(rate) and 0.0 < rate <= 1.0):
            raise ValueError(f"rate: expected 0 < rate <= 1, got {rate!r}")
        background = cv2.compare(fg, 0, cv2.CMP_EQ)
        cv2.accumulateWeighted(bgr_to_yuv(image_bgr), self.mean_yuv, float(rate), mask=background)
        self._derive_mean_terms()
        if self._coarse is not None:  # a coarse pixel learns only where its whole 2x2 block is background
            coarse_bg = cv2.compare(_downsample(background), 255, cv2.CMP_EQ)
            cv2.accumulateWeighted(bgr_to_yuv(_downsample(image_bgr)), self._coarse.mean_yuv, float(rate),
                                   mask=coarse_bg)
            self._coarse._derive_mean_terms()

    # ----------------------------------------------------------------- persistence
    def save(self, path) -> Path:
        """Write the model as ``.npz`` (no pickles).

        Parameters
        ----------
        path : str or Path

        Returns
        -------
        Path
        """
        path = Path(path)
        np.savez_compressed(
            path, format_version=np.int64(_FORMAT_VERSION), mean_yuv=self.mean_yuv, cov_yuv=self.cov_yuv,
            covariance=np.array(self.covariance), luma_relax=np.float64(self.luma_relax),
            shadow_range=np.array(self.shadow_range, np.float64), min_sigma=np.float64(self.min_sigma),
            window_px=np.int64(self.window_px))
        return path

    @classmethod
    def load(cls, path) -> "BackgroundModel":
        """Read a model written by :meth:`save`.

        Parameters
        ----------
        path : str or Path

        Returns
        -------
        BackgroundModel

        Raises
        ------
        BackgroundFileError
            A malformed file (named); a ``ValueError`` and a ``SegmentationError``.
        """
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                version = int(z["format_version"])
                if version != _FORMAT_VERSION:
                    raise ValueError(f"format_version {version} (expected {_FORMAT_VERSION})")
                return cls(z["mean_yuv"], z["cov_yuv"], covariance=str(z["covariance"]),
                           luma_relax=float(z["luma_relax"]),
                           shadow_range=tuple(float(v) for v in z["shadow_range"]),
                           min_sigma=float(z["min_sigma"]),
                           window_px=int(z["window_px"]) if "window_px" in z.files else 0)
        except (KeyError, ValueError, TypeError, OSError, EOFError, zipfile.BadZipFile) as exc:
            raise BackgroundFileError(f"{path}: not a background model file ({exc})") from exc
