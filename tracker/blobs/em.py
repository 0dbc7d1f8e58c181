"""Blobs matched to coloured voxels by EM (Caillette & Howard, BMVC'04 §4.1, eqs. 2–4).

A blob ``j`` is a Gaussian in position (mean ``mu_j``, covariance ``K_j``, metres) and in colour
(``mu'_j``, ``K'_j``, BGR levels).  A voxel ``v`` has a centre ``P_v``, an edge ``s_v`` and one
colour per view ``C_v,i``.

**Expectation** (eqs. 2–3): every voxel goes to the blob nearest in

    dst(v, B_j) = (P_v − mu_j)ᵀ K_j⁻¹ (P_v − mu_j) + min_i (C_v,i − mu'_j)ᵀ K'_j⁻¹ (C_v,i − mu'_j)

the colour term taking the view that fits the blob best (occlusion without a visibility test).
A voxel whose position term exceeds ``gate`` for every blob is left unassigned (clutter, phantom
volume between views).

**Maximisation** (eq. 4), weighted by voxel volume ``s_v³``: means and covariances of the voxels
each blob received, the position covariance including each cube's own spread ``s_v² / 12 · I``
(the paper's ``k_v = s_v⁵ / 12 · I``, volume times spread) and the colour statistics over the
colours chosen in the expectation.  Covariances are kept from collapsing: a floor ``sigma² · I``
is added, and a colour covariance whose determinant is below ``min_colour_det`` is scaled up to it
(the paper rescales ``K'`` when its determinant is too small, so colour does not outweigh
position).  The blob's *filling* is the volume it received over its prior volume.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracker.blobs.kernels import assign, weighted_moments

__all__ = ["Assignment", "BlobStats", "expectation", "maximisation"]


@dataclass(frozen=True, eq=False)
class Assignment:
    """Result of :func:`expectation`.

    labels : (n,) int, blob index of each voxel, -1 unassigned; colour : (n, 3) the view colour
    used for its blob; distance : (n,) its eq. 2 distance (inf when unassigned); shares : for a
    soft assignment, ``(voxel (m,), blob (m,), colour (m, 3), weight (m,))``: each voxel's share of
    its nearest blobs (weights summing to 1 per assigned voxel), else None.
    """

    labels: np.ndarray
    colour: np.ndarray
    distance: np.ndarray
    shares: tuple | None = None


@dataclass(frozen=True, eq=False)
class BlobStats:
    """Result of :func:`maximisation` for blobs ``(b,)``.

    mean : (b, 3) m; cov : (b, 3, 3) m²; colour : (b, 3) BGR; colour_cov : (b, 3, 3);
    volume : (b,) m³ received; count : (b,) voxels received.  Blobs that received nothing keep
    NaN statistics and zero volume.
    """

    mean: np.ndarray
    cov: np.ndarray
    colour: np.ndarray
    colour_cov: np.ndarray
    volume: np.ndarray
    count: np.ndarray


def expectation(centres: np.ndarray, colours: np.ndarray, mean: np.ndarray, cov: np.ndarray,
                colour_mean: np.ndarray, colour_cov: np.ndarray, *, colour_weight: float = 1.0,
                gate: float = 25.0, use: np.ndarray | None = None, log_det: bool = False,
                soft: int = 0) -> Assignment:
    """Eqs. 2–3: nearest blob of every voxel.

    Parameters
    ----------
    centres : (n, 3) voxel centres, m; colours : (n, v, 3) colour per view, BGR
    mean, cov : (b, 3), (b, 3, 3) blob positions, m, m²
    colour_mean, colour_cov : (b, 3), (b, 3, 3) blob colours, BGR, BGR²
    colour_weight : factor on the colour term (0: position only, as when colours are not learned yet)
    gate : largest position term (squared Mahalanobis) of an assigned voxel
    use : (b,) bool, blobs taking part (default all)
    log_det : add ``log det K_j + log det K'_j`` (the Gaussians' normalisation: the full negative
        log-likelihood; the paper's eq. 2 has none, which lets wide blobs take a narrow one's voxels)
    soft : 0 for the paper's hard assignment; ``k > 1`` shares each voxel among its ``k`` nearest
        blobs in proportion to ``exp(−dst / 2)`` (blobs beyond the gate get no share)
    """
    n, b = len(centres), len(mean)
    if n == 0 or b == 0:
        return Assignment(np.full(n, -1), np.zeros((n, 3), np.float32), np.full(n, np.inf))
    extra = np.zeros(b)
    if log_det:
        extra = np.linalg.slogdet(cov)[1] + (np.linalg.slogdet(colour_cov)[1] if colour_weight > 0 else 0.0)
    colours = np.ascontiguousarray(colours, dtype=np.float32)
    fallback = (np.zeros((n, 3), np.float32) if colour_weight > 0 else
                np.ascontiguousarray(np.median(colours, axis=1), dtype=np.float32))
    used = np.ones(b, bool) if use is None else np.asarray(use, bool)
    if colours.shape[0] != n or used.shape != (b,):
        raise ValueError(f"expectation: colours for {colours.shape[0]} voxels and use for {used.shape} blobs, "
                         f"expected {n} and ({b},)")
    # without the colour term its covariance is not read (a singular one is no error)
    colour_inv = np.linalg.inv(colour_cov) if colour_weight > 0 else np.zeros((b, 3, 3))
    labels, colour, dist, vox, blob, col, wgt = assign(
        np.ascontiguousarray(centres, dtype=float), colours, np.ascontiguousarray(mean, dtype=float),
        np.linalg.inv(cov), np.ascontiguousarray(colour_mean, dtype=float), colour_inv, extra, used,
        float(colour_weight), float(gate), int(soft), fallback)
    return Assignment(labels, colour, dist, (vox, blob, col, wgt) if soft > 1 else None)


def maximisation(assignment: Assignment, centres: np.ndarray, sizes: np.ndarray, n_blobs: int, *,
                 min_sigma_m: float = 0.01, min_colour_sigma: float = 4.0,
                 min_colour_det: float = 8.0**6) -> BlobStats:
    """Eq. 4 with the covariance floors (module docstring); ``sizes`` (n,) voxel edges, m.  A soft
    assignment's shares weight each voxel's volume (``count`` is then the summed shares)."""
    if assignment.shares is not None:
        vox, lab, C, share = assignment.shares
        P, s, C = centres[vox], sizes[vox], C.astype(float)
        w = s**3 * share
        count = np.bincount(lab, weights=share, minlength=n_blobs)
    else:
        lab = assignment.labels
        sel = lab >= 0
        lab, P, s, C = lab[sel], centres[sel], sizes[sel], assignment.colour[sel].astype(float)
        w = s**3
        count = np.bincount(lab, minlength=n_blobs)
    W = np.bincount(lab, weights=w, minlength=n_blobs)
    lab, w = np.ascontiguousarray(lab, dtype=np.int64), np.ascontiguousarray(w, dtype=float)
    mean, cov = weighted_moments(lab, np.ascontiguousarray(P, dtype=float), w, np.ascontiguousarray(s**2 / 12.0),
                                 n_blobs)
    colour, colour_cov = weighted_moments(lab, np.ascontiguousarray(C, dtype=float), w, np.zeros(len(w)), n_blobs)
    cov += min_sigma_m**2 * np.eye(3)
    colour_cov += min_colour_sigma**2 * np.eye(3)
    det = np.full(n_blobs, np.nan)
    finite = np.isfinite(colour_cov).all((1, 2))
    det[finite] = np.linalg.det(colour_cov[finite])
    small = finite & (det < min_colour_det)
    colour_cov[small] *= ((min_colour_det / np.maximum(det[small], 1e-12)) ** (1.0 / 3.0))[:, None, None]
    return BlobStats(mean, cov, colour, colour_cov, W, count)
