"""Segmentation: background model, silhouettes, edges, distance-transform images (pure numpy/OpenCV)."""
