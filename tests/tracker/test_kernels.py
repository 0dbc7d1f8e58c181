"""The compiled kernels against plain brute-force definitions (tracker.kernels)."""

import numpy as np

from tracker.kernels import nearest_rows


def _brute_nearest(samples, sample_cam, uv, used, per_cam):
    out = np.full(len(samples), -1)
    for j, (y, c) in enumerate(zip(samples, sample_cam)):
        rows = np.flatnonzero(used[c * per_cam:(c + 1) * per_cam]) + c * per_cam
        if rows.size:
            out[j] = rows[np.argmin(((uv[rows] - y) ** 2).sum(axis=1))]
    return out


def test_nearest_rows_is_the_exact_nearest_used_row_of_the_samples_camera():
    """Clustered and uniform contours, pixels on whole-pixel bin edges, far samples outside the
    contours' extent, a camera with no used row: the distance found equals the brute-force
    minimum for every sample (ties may pick another row at the same distance)."""
    rng = np.random.default_rng(11)
    per_cam, n_cams, k = 96, 4, 300
    for trial in range(25):
        if trial % 2:
            uv = np.column_stack([rng.normal(400, 30, per_cam * n_cams), rng.normal(300, 120, per_cam * n_cams)])
        else:
            uv = np.column_stack([rng.uniform(0, 800, per_cam * n_cams), rng.uniform(0, 600, per_cam * n_cams)])
        uv[::4] = np.round(uv[::4])
        used = rng.random(per_cam * n_cams) < 0.6
        used[2 * per_cam:3 * per_cam] = False  # camera 2 sees nothing
        samples = np.column_stack([rng.uniform(-100, 900, k), rng.uniform(-100, 700, k)])
        sample_cam = np.sort(rng.integers(0, n_cams, k))
        got = nearest_rows(samples, sample_cam, uv, used, per_cam)
        ref = _brute_nearest(samples, sample_cam, uv, used, per_cam)
        np.testing.assert_array_equal(got < 0, ref < 0)
        np.testing.assert_array_equal(got[sample_cam == 2], -1)
        ok = ref >= 0
        d_got = np.linalg.norm(samples[ok] - uv[got[ok]], axis=1)
        d_ref = np.linalg.norm(samples[ok] - uv[ref[ok]], axis=1)
        np.testing.assert_allclose(d_got, d_ref, rtol=0, atol=1e-9)
        assert np.all(used[got[ok]]) and np.all(got[ok] // per_cam == sample_cam[ok])
