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


def _quadratic_features(X: np.ndarray) -> np.ndarray:
    """``[x_i x_j (i <= j), x_i, 1]`` of points (m, 3): shape (m, 10)."""
    x0, x1, x2 = X[:, 0], X[:, 1], X[:, 2]
    return np.column_stack([x0 * x0, x1 * x1, x2 * x2, x0 * x1, x0 * x2, x1 * x2, x0, x1, x2, np.ones(len(X))])


def _quadratic_coefficients(mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Coefficients (10, b) with ``features(X) @ coef = (X − mean_j)ᵀ cov_j⁻¹ (X − mean_j)`` for
    Gaussians ``mean`` (b, 3), ``cov`` (b, 3, 3): one matrix product gives every squared
    Mahalanobis distance (the expanded quadratic form)."""
    P = np.linalg.inv(cov)  # (b, 3, 3)
    Pm = np.einsum("bij,bj->bi", P, mean)
    return np.stack([P[:, 0, 0], P[:, 1, 1], P[:, 2, 2], 2 * P[:, 0, 1], 2 * P[:, 0, 2], 2 * P[:, 1, 2],
                     -2 * Pm[:, 0], -2 * Pm[:, 1], -2 * Pm[:, 2], np.einsum("bi,bi->b", Pm, mean)])


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
    # centred on the blobs' mean position / colour: the expanded form stays well conditioned
    c0 = mean.mean(0)
    dpos = np.maximum(_quadratic_features(centres - c0) @ _quadratic_coefficients(mean - c0, cov), 0.0)
    if use is not None:
        dpos[:, ~np.asarray(use, bool)] = np.inf
    total = dpos
    best_view = None
    if colour_weight > 0:
        v = colours.shape[1]
        k0 = colour_mean.mean(0)
        F = _quadratic_features(colours.reshape(-1, 3).astype(float) - k0)
        dcol = (F @ _quadratic_coefficients(colour_mean - k0, colour_cov)).reshape(n, v, b)
        best_view = dcol.argmin(1)  # (n, b)
        total = dpos + colour_weight * np.maximum(np.take_along_axis(dcol, best_view[:, None, :], 1)[:, 0], 0.0)
    if log_det:
        total = total + np.linalg.slogdet(cov)[1] + (np.linalg.slogdet(colour_cov)[1] if colour_weight > 0 else 0.0)
    labels = total.argmin(1)
    rows = np.arange(n)
    dist = total[rows, labels]
    out = dpos[rows, labels] > gate
    labels = np.where(out, -1, labels)
    dist = np.where(out, np.inf, dist)
    if best_view is None:
        colour = np.median(colours, axis=1).astype(np.float32)
    else:
        colour = colours[rows, best_view[rows, labels]].astype(np.float32)
    shares = None
    if soft > 1:
        k = min(int(soft), b)
        near = np.argpartition(total, k - 1, axis=1)[:, :k]  # (n, k)
        t = np.take_along_axis(total, near, 1)
        wgt = np.exp(-0.5 * (t - t.min(1, keepdims=True)))
        wgt[np.take_along_axis(dpos, near, 1) > gate] = 0.0
        wgt /= np.maximum(wgt.sum(1, keepdims=True), 1e-300)
        vox = np.repeat(rows, k)
        blob = near.ravel()
        keep = wgt.ravel() > 1e-3
        if best_view is None:
            col = np.repeat(colour, k, axis=0)
        else:
            col = colours[vox, best_view[vox, blob]].astype(np.float32)
        shares = (vox[keep], blob[keep], col[keep], wgt.ravel()[keep])
    return Assignment(labels, colour, dist, shares)


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
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.where(W > 0, 1.0 / W, np.nan)

    def moments(X: np.ndarray, extra: np.ndarray | None):
        mu = np.stack([np.bincount(lab, weights=w * X[:, i], minlength=n_blobs) for i in range(3)], 1) * inv[:, None]
        d = X - mu[lab]
        cov = np.empty((n_blobs, 3, 3))
        for i in range(3):
            for j in range(i, 3):
                cov[:, i, j] = cov[:, j, i] = np.bincount(lab, weights=w * d[:, i] * d[:, j], minlength=n_blobs) * inv
        if extra is not None:
            cov += (np.bincount(lab, weights=w * extra, minlength=n_blobs) * inv)[:, None, None] * np.eye(3)
        return mu, cov

    mean, cov = moments(P, s**2 / 12.0)
    colour, colour_cov = moments(C, None)
    cov += min_sigma_m**2 * np.eye(3)
    colour_cov += min_colour_sigma**2 * np.eye(3)
    det = np.full(n_blobs, np.nan)
    finite = np.isfinite(colour_cov).all((1, 2))
    det[finite] = np.linalg.det(colour_cov[finite])
    small = finite & (det < min_colour_det)
    colour_cov[small] *= ((min_colour_det / np.maximum(det[small], 1e-12)) ** (1.0 / 3.0))[:, None, None]
    return BlobStats(mean, cov, colour, colour_cov, W, count)
