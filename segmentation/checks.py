"""Argument checks shared by the segmentation functions (validate once at the boundary)."""

from __future__ import annotations

import numpy as np

__all__ = ["check_image_bgr", "check_mask", "check_roi", "check_finite_array"]


def check_image_bgr(image: np.ndarray, name: str = "image_bgr", *, size: tuple[int, int] | None = None) -> np.ndarray:
    """Validate a BGR image.

    Parameters
    ----------
    image : ndarray, shape (h, w, 3), uint8
    name : str
        Named in the error.
    size : (int, int), optional
        Required (w, h), pixels.

    Returns
    -------
    ndarray
        ``image`` itself.

    Raises
    ------
    TypeError, ValueError
        Not a uint8 array of that shape (the message names ``name``).
    """
    if not isinstance(image, np.ndarray):
        raise TypeError(f"{name}: expected a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise TypeError(f"{name}: expected dtype uint8, got {image.dtype}")
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"{name}: expected shape (h, w, 3), got {image.shape}")
    if size is not None and (image.shape[1], image.shape[0]) != tuple(size):
        raise ValueError(f"{name}: image size (w, h) = {(image.shape[1], image.shape[0])} does not match "
                         f"the background model's {tuple(size)}")
    return image


def check_mask(mask: np.ndarray, name: str, *, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Validate a mask and view it as uint8 (0 / non-zero); bool is accepted.

    Parameters
    ----------
    mask : ndarray, shape (h, w), uint8 or bool
    name : str
        Named in the error.
    shape : (int, int), optional
        Required (h, w).

    Returns
    -------
    ndarray, shape (h, w), uint8
    """
    if not isinstance(mask, np.ndarray):
        raise TypeError(f"{name}: expected a numpy array, got {type(mask).__name__}")
    if mask.dtype == bool:
        mask = mask.view(np.uint8)
    if mask.dtype != np.uint8:
        raise TypeError(f"{name}: expected dtype uint8 or bool, got {mask.dtype}")
    if mask.ndim != 2:
        raise ValueError(f"{name}: expected shape (h, w), got {mask.shape}")
    if shape is not None and mask.shape != tuple(shape):
        raise ValueError(f"{name}: shape {mask.shape} does not match {tuple(shape)}")
    return mask


def check_finite_array(a, name: str, *, ndim: int | None = None) -> np.ndarray:
    """Validate a real array without NaN or inf.

    Parameters
    ----------
    a : array_like
    name : str
        Named in the error.
    ndim : int, optional
        Required rank.

    Returns
    -------
    ndarray
    """
    arr = np.asarray(a)
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise TypeError(f"{name}: expected real numbers, got dtype {arr.dtype}")
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"{name}: expected {ndim}-D array, got shape {arr.shape}")
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise ValueError(f"{name}: contains NaN or inf")
    return arr


def check_roi(roi, size: tuple[int, int], name: str = "roi") -> tuple[int, int, int, int]:
    """Validate a region of interest inside an image.

    Parameters
    ----------
    roi : (int, int, int, int) or None
        ``(x0, y0, x1, y1)``, half-open, pixels; None: the whole image.
    size : (int, int)
        (w, h) of the image, pixels.
    name : str
        Named in the error.

    Returns
    -------
    (int, int, int, int)
        ``(x0, y0, x1, y1)`` as plain ints.
    """
    w, h = int(size[0]), int(size[1])
    if roi is None:
        return 0, 0, w, h
    try:
        vals = [float(v) for v in roi]
    except TypeError:
        raise TypeError(f"{name}: expected (x0, y0, x1, y1), got {roi!r}") from None
    if len(vals) != 4 or not all(np.isfinite(vals)) or any(v != int(v) for v in vals):
        raise ValueError(f"{name}: expected four finite integers (x0, y0, x1, y1), got {roi!r}")
    x0, y0, x1, y1 = (int(v) for v in vals)
    if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
        raise ValueError(f"{name}: {roi!r} is empty or outside the image of size (w, h) = {(w, h)}")
    return x0, y0, x1, y1
