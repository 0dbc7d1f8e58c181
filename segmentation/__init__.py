"""Segmentation: background model, silhouettes, edges, distance-transform images (pure numpy/OpenCV).

Per camera frame: :class:`BackgroundModel` (per-pixel YUV Gaussian, shadow-relaxed Mahalanobis
distance) -> :func:`silhouette_from_distance` (hysteresis, morphology, components, holes) ->
:func:`silhouette_edges` (Canny inside the silhouette + its boundary) -> :func:`chamfer_images`
(truncated, quantised distance images with bilinear sampling and gradient).
:func:`segment_frame` runs the whole chain.
"""

from segmentation.background import BGR2YUV, BackgroundModel, bgr_to_yuv, evenly_spaced
from segmentation.distance import (ChamferImages, ChamferSample, chamfer_images, distance_to_mask,
                                   sample_bilinear)
from segmentation.edges import silhouette_boundary, silhouette_edges
from segmentation.pipeline import FrameSegmentation, SegmentationParams, segment_frame
from segmentation.silhouette import clean_silhouette, largest_components, silhouette_from_distance

__all__ = [
    "BGR2YUV", "BackgroundModel", "bgr_to_yuv", "evenly_spaced",
    "ChamferImages", "ChamferSample", "chamfer_images", "distance_to_mask", "sample_bilinear",
    "silhouette_boundary", "silhouette_edges",
    "FrameSegmentation", "SegmentationParams", "segment_frame",
    "clean_silhouette", "largest_components", "silhouette_from_distance",
]
