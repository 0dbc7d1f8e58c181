"""Compiled (numba) kernels of the tracker's per-evaluation hot loops.

The cost of one frame is a few dozen evaluations of the chamfer cost, each made of many small
array operations over ~2000 contour points and ~900 silhouette boundary samples: the occlusion
tests of ``tracker.imaging.visibility`` (segment or ray against every other part's solid), the reverse
term's nearest contour point of every boundary sample (``tracker.fitting.cost``), the bilinear sampling
of the distance images and the forward kinematics.  Written as numpy, each is tens of calls whose
fixed overhead dominates; here each is one loop.  The maths is the one documented in the module
that calls the kernel (its docstring is the reference); these functions take plain arrays only.

Compiled on first use and cached on disk (``cache=True``): a process pays the compilation once per
installed version (a few seconds; ``tracker.fitting.warmup.warm_up`` triggers it, e.g. in a live worker before its first
frame), later processes load the cached machine code.
"""

from __future__ import annotations

import numpy as np

from tracker.kernels.kinematics import forward_kinematics
from tracker.kernels.normal import screw_matvec, screw_normal_equations
from tracker.kernels.occlusion import covered_mask, hidden_mask, part_boxes
from tracker.kernels.projection import contour_points, image_motion, projection_jacobians, ruling_angles
from tracker.kernels.residuals import assemble, nearest_rows, reverse_terms, sample_chamfer, screw_rows

__all__ = ["part_boxes", "hidden_mask", "covered_mask", "nearest_rows", "sample_chamfer", "forward_kinematics",
           "screw_rows", "image_motion", "contour_points", "ruling_angles", "projection_jacobians", "assemble",
           "reverse_terms", "screw_normal_equations", "screw_matvec"]

