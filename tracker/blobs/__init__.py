"""The BMVC'04 tracker (Caillette & Howard): coloured voxels, EM blobs and inverse kinematics.

A second tracking method beside the contour tracker (``tracker.fitting.tracking``), on the same inputs
(calibrated cameras, background models, frame sets) and with the same pose records::

    tracker = BlobTracker(model, cameras, backgrounds, initial_params=p0)
    record = tracker.step(frame_id, timestamp_ns, {"cam0": image_bgr, ...})   # "method": "blobs"

- ``colour_hull``: the hierarchical coloured visual hull from sampled background statistics;
- ``em``: expectation–maximisation of position/colour blobs on the voxels (eqs. 2–4);
- ``blobset``: blobs attached to the body model's parts, learned at initialisation;
- ``ik``: the root by least squares, the limbs by cyclic coordinate descent, the floor contact;
- ``static_voxels``: hull cubes that stay away from the body (furniture), left out of the fit;
- ``props``: the operator's prop boxes carved from the hull and kept out of by the IK;
- ``tracking``: the per-frame loop.
"""

from tracker.blobs.blobset import BlobLayout, BlobSet, blob_layout, learn_blobs
from tracker.blobs.colour_hull import ColourHull, HullOptions, coloured_hull, zone_of_interest
from tracker.blobs.em import Assignment, BlobStats, expectation, maximisation
from tracker.blobs.ik import ccd, damped_least_squares, fit_root, floor_contact
from tracker.blobs.tracking import BlobOptions, BlobTracker, initialise_from_images

__all__ = [
    "BlobLayout", "BlobSet", "blob_layout", "learn_blobs",
    "ColourHull", "HullOptions", "coloured_hull", "zone_of_interest",
    "Assignment", "BlobStats", "expectation", "maximisation",
    "ccd", "damped_least_squares", "fit_root", "floor_contact",
    "BlobOptions", "BlobTracker", "initialise_from_images",
]
