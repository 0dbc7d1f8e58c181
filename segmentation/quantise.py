"""Quantisation of truncated distance images to unsigned integer codes (the chamfer images' storage)."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["quantise"]


def quantise(distance: np.ndarray, *, resolution_px: float, dtype) -> np.ndarray:
    """Round ``distance / resolution_px`` to an unsigned integer type (values must fit).

    Parameters
    ----------
    distance : ndarray, float32
        Pixels.
    resolution_px : float
        Pixels per step.
    dtype : numpy.uint8 or numpy.uint16

    Returns
    -------
    ndarray of ``dtype``, shape of ``distance``
    """
    if dtype == np.uint8:
        return cv2.convertScaleAbs(distance, alpha=1.0 / resolution_px)
    return (distance * np.float32(1.0 / resolution_px) + np.float32(0.5)).astype(np.uint16)
