"""Chamfer cost: residual Jacobian vs central differences, truncation, layout, real chamfer images."""

from __future__ import annotations

import numpy as np
import pytest

from segmentation.distance import chamfer_images
from tracker.fitting.cost import ChamferCost
from tracker.imaging.jacobian import contour_jacobian
from tracker.body.kinematics import forward
from tracker.body.model import load_model
from tracker.imaging.render import internal_edges, render_label_images
from tracker.synthetic.scene import ring_cameras


class SmoothField:
    """A smooth synthetic 'distance' pair over the image with analytic gradients (pixels)."""

    def __init__(self, centre, scale):
        self.c = np.asarray(centre, float)
        self.s = float(scale)

    def sample(self, uv):
        q = (uv - self.c) / self.s
        d_sil = 3.0 + 2.0 * np.sin(q[:, 0]) * np.cos(0.7 * q[:, 1])
        g_sil = np.stack([2.0 * np.cos(q[:, 0]) * np.cos(0.7 * q[:, 1]),
                          -1.4 * np.sin(q[:, 0]) * np.sin(0.7 * q[:, 1])], axis=1) / self.s
        d_edge = 0.5 * (q * q).sum(axis=1) + 1.0
        g_edge = q / self.s
        return d_sil, g_sil, d_edge, g_edge


@pytest.fixture(scope="module")
def scene():
    return ring_cameras(4, size=(800, 600))


@pytest.mark.parametrize("name", ["knossow40", "knossow54"])
def test_residual_jacobian_matches_central_differences(name, scene, rng):
    model = load_model(name)
    fields = [SmoothField((400 + 10 * i, 300 - 5 * i), 60.0 + 7 * i) for i in range(len(scene))]
    for trial in range(3):
        p = model.random_params(rng, fraction=0.4)
        p[:3] = rng.uniform(-0.3, 0.3, 3) * [1, 1, 0.1]
        cost = ChamferCost(model, scene, fields, sliding=True, n_samples=5, visibility="none", truncate_px=None)
        terms = cost.evaluate(p, jacobian=True)
        J = terms.jacobian
        h = 1e-6
        Jfd = np.empty_like(J)
        for k in range(model.n_params):
            dp = np.zeros(model.n_params)
            dp[k] = h
            rp = cost.evaluate(p + dp).residuals
            rm = cost.evaluate(p - dp).residuals
            Jfd[:, k] = (rp - rm) / (2 * h)
        used = np.repeat(terms.used, 2)
        assert used.sum() > 200
        scale = np.abs(Jfd[used]).max()
        err = np.abs(J[used] - Jfd[used]).max()
        assert err < 1e-5 * scale, (trial, err, scale)
        # rows not used are exactly zero
        assert not np.any(J[~used]) and not np.any(terms.residuals[~used])
    # without the sliding term the Jacobian is only an approximation of the true derivative
    cost_ns = ChamferCost(model, scene, fields, sliding=False, n_samples=5, visibility="none", truncate_px=None)
    Jns = cost_ns.evaluate(p, jacobian=True).jacobian
    assert np.abs(Jns[used] - Jfd[used]).max() > 1e-3 * scale


def test_truncation_zeroes_gradient_and_caps_residual(scene, rng):
    model = load_model("knossow40")
    fields = [SmoothField((400, 300), 20.0) for _ in scene]  # edge distance grows large off-centre
    cost = ChamferCost(model, scene, fields, n_samples=4, visibility="none", truncate_px=4.0)
    terms = cost.evaluate(model.zero(), jacobian=True)
    r = terms.residuals.reshape(-1, 2)
    J = terms.jacobian.reshape(-1, 2, model.n_params)
    assert r.max() <= 4.0 + 1e-12
    capped = r >= 4.0
    assert capped.any() and (~capped & terms.used[:, None]).any()
    assert not np.any(J[capped])


def test_compact_layout_and_bad_arguments(scene):
    model = load_model("knossow40")
    fields = [SmoothField((400, 300), 50.0) for _ in scene]
    cost = ChamferCost(model, scene, fields, n_samples=4)
    full = cost.evaluate(model.zero(), jacobian=True)
    comp = cost.evaluate(model.zero(), jacobian=True, compact=True)
    used = np.repeat(full.used, 2)
    np.testing.assert_array_equal(comp.residuals, full.residuals[used])
    np.testing.assert_array_equal(comp.jacobian, full.jacobian[used])
    assert full.residuals.shape == (2 * cost.n_rows,)
    with pytest.raises(ValueError, match="chamfer"):
        ChamferCost(model, scene, fields[:2])
    with pytest.raises(TypeError, match="cam0"):
        ChamferCost(model, scene, [object()] * len(scene))
    with pytest.raises(ValueError, match="visibility"):
        ChamferCost(model, scene, fields, visibility="sometimes")


def test_rendered_true_pose_has_subpixel_cost_and_perturbed_pose_does_not(scene, rng):
    """On chamfer images of a render, the true pose scores ~0 and a perturbed pose scores more."""
    model = load_model("knossow40")
    p = model.random_params(rng, fraction=0.3)
    p[:3] = [0.1, -0.1, 0.0]
    labels = render_label_images(model, forward(model, p), scene)
    chamfer = [chamfer_images(np.where(lab >= 0, 255, 0).astype(np.uint8), internal_edges(lab)) for lab in labels]
    cost = ChamferCost(model, scene, chamfer)
    true = cost.evaluate(p)
    assert true.n_used > 300
    assert true.rms_px() < 0.8
    assert true.inside_fraction() > 0.95
    q = p.copy()
    q[6:] += np.radians(8.0) * rng.choice([-1, 1], model.n_params - 6)
    off = ChamferCost(model, scene, chamfer).evaluate(model.clamp(q))
    assert off.rms_px() > 2 * true.rms_px()
    # inlier RMS and outlier fraction: the residuals up to / above a scale, counted directly
    r = np.concatenate([off.d_sil[off.used], off.d_edge[off.used]])
    assert off.outlier_fraction(max_px=3.0) == pytest.approx(np.mean(r > 3.0)) and 0 < np.mean(r > 3.0) < 1
    assert off.rms_px(max_px=3.0) == pytest.approx(np.sqrt(np.mean(r[r <= 3.0] ** 2)))
    assert off.rms_px(max_px=3.0) < off.rms_px() and off.rms_px(max_px=1e9) == pytest.approx(off.rms_px())


def test_reverse_term_jacobian_and_pull(scene, rng):
    """Reverse residuals (observed boundary → nearest predicted contour point): FD-checked Jacobian,
    and larger when a limb has left its silhouette.  At the truth they are all zero: boundary
    samples on the predicted silhouette count as explained.  Without that test they are not: the
    end caps of the cones (head top, hands, feet) are on the silhouette boundary but carry no
    contour generator samples, so boundary points there stay several pixels from the nearest one."""
    model = load_model("knossow40")
    p = model.random_params(rng, fraction=0.3)
    p[:3] = [0.1, -0.1, 0.0]
    labels = render_label_images(model, forward(model, p), scene)
    chamfer = [chamfer_images(np.where(lab >= 0, 255, 0).astype(np.uint8), internal_edges(lab)) for lab in labels]
    kw = dict(n_samples=8, visibility="none", reverse_weight=1.0, reverse_samples=150, reverse_min_px=2.0)
    cost = ChamferCost(model, scene, chamfer, reverse_cover_px=1.0, **kw)
    assert cost.n_reverse > 400
    q = p.copy()
    q[model.param_index("left_upper_arm.abduction")] += 0.5  # the arm swings out of its silhouette
    q = model.clamp(q)
    terms = cost.evaluate(q, jacobian=True)
    K = cost.n_reverse
    r, J = terms.residuals[-K:], terms.jacobian[-K:]
    h = 1e-7
    Jfd = np.empty_like(J)
    for k in range(model.n_params):
        dp = np.zeros(model.n_params)
        dp[k] = h
        Jfd[:, k] = (cost.evaluate(q + dp).residuals[-K:] - cost.evaluate(q - dp).residuals[-K:]) / (2 * h)
    active = r > 1e-3
    assert active.sum() > 20
    np.testing.assert_allclose(J[active], Jfd[active], atol=1e-4 * np.abs(Jfd[active]).max())
    at_truth = ChamferCost(model, scene, chamfer, reverse_cover_px=1.0, **kw).evaluate(p)
    assert not np.any(at_truth.residuals[-K:]) and at_truth.coverage() == 1.0
    uncovered = ChamferCost(model, scene, chamfer, **kw).evaluate(p).residuals[-K:]  # the test off
    assert np.count_nonzero(uncovered) > 20
    # the reverse term alone pulls the arm back: its gradient along the abduction is positive
    k = model.param_index("left_upper_arm.abduction")
    assert r @ J[:, k] > 0.0


def test_stacked_sampling_equals_per_camera_sampling(rng):
    """One ``sample`` call over the stacked images of all cameras reads what each camera's own
    ``ChamferImages.sample`` reads: inside, on and off the cropped arrays (truncation, zero
    gradient), at integer and fractional pixels, for an empty silhouette too."""
    from tracker.fitting.cost import _StackedChamfer

    masks = []
    for k, (cx, cy, r) in enumerate([(300, 200, 60), (500, 400, 90), (120, 500, 30)]):
        yy, xx = np.mgrid[0:600, 0:800]
        sil = (((xx - cx) / r) ** 2 + ((yy - cy) / (1.6 * r)) ** 2 <= 1.0).astype(np.uint8) * 255
        edges = np.zeros_like(sil)
        edges[cy, cx - r // 2:cx + r // 2] = 255
        masks.append((sil, edges))
    masks.append((np.zeros((600, 800), np.uint8), np.zeros((600, 800), np.uint8)))
    chamfer = [chamfer_images(s, e, max_distance_px=24.0) for s, e in masks]
    stacked = _StackedChamfer.build(chamfer)
    assert stacked is not None
    for c, ch in enumerate(chamfer):
        ox, oy = ch.offset_xy
        h, w = ch.silhouette_q.shape
        uv = np.column_stack([rng.uniform(ox - 30, ox + w + 30, 600), rng.uniform(oy - 30, oy + h + 30, 600)])
        uv[:100] = np.column_stack([ox + rng.integers(-3, w + 3, 100), oy + rng.integers(-3, h + 3, 100)])
        for a, b in zip(ch.sample(uv), stacked.sample(uv, np.full(len(uv), c))):
            np.testing.assert_allclose(b, a, rtol=0, atol=1e-9)
    assert _StackedChamfer.build([SmoothField((400, 300), 50.0)]) is None  # not ChamferImages: per camera


def test_compact_drops_only_rows_that_add_nothing(scene, rng):
    """On real chamfer images with the reverse term, the compact residuals leave out the zero
    residuals with a zero gradient (contour points inside their silhouette, boundary samples near
    the contour): robust cost, gradient and Gauss-Newton matrix equal the full layout's."""
    from tracker.fitting.solver import robust_cost, robust_weights

    model = load_model("knossow40")
    p = model.random_params(rng, fraction=0.3)
    p[:3] = [0.1, -0.1, 0.0]
    labels = render_label_images(model, forward(model, p), scene)
    chamfer = [chamfer_images(np.where(lab >= 0, 255, 0).astype(np.uint8), internal_edges(lab)) for lab in labels]
    q = p.copy()
    q[6:] += np.radians(5.0) * rng.choice([-1, 1], model.n_params - 6)
    q = model.clamp(q)
    kw = dict(n_samples=8, reverse_weight=1.0, reverse_samples=150, reverse_min_px=8.0)
    full = ChamferCost(model, scene, chamfer, **kw).evaluate(q, jacobian=True)
    comp = ChamferCost(model, scene, chamfer, **kw).evaluate(q, jacobian=True, compact=True)
    assert len(comp.residuals) < 0.8 * (2 * full.n_used + len(full.boundary_dist))
    np.testing.assert_allclose(robust_cost(comp.residuals, loss="huber", f_scale=3.0),
                               robust_cost(full.residuals, loss="huber", f_scale=3.0), rtol=1e-12)
    wc, wf = (robust_weights(t.residuals, loss="huber", f_scale=3.0) for t in (comp, full))
    Jc, Jf = comp.jacobian, full.jacobian
    np.testing.assert_allclose(Jc.T @ (wc * comp.residuals), Jf.T @ (wf * full.residuals), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(Jc.T @ (wc[:, None] * Jc), Jf.T @ (wf[:, None] * Jf), rtol=1e-9, atol=1e-6)


@pytest.mark.parametrize("name", ["knossow40", "knossow54"])
def test_covered_rays_agree_with_the_rendered_silhouette(name, rng):
    """A pixel's ray meets the body exactly where the renderer fills the pixel (pixel centre inside
    the projected outline), up to the renderer's polygonal outline on the silhouette's rim."""
    from tracker.imaging.visibility import covered_rays

    model = load_model(name)
    cams = ring_cameras(3, size=(400, 300), distortion=(-0.1, 0.02, 0.0, 0.0, 0.0))
    ys, xs = np.mgrid[0:300:2, 0:400:2]
    uv = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(float)
    for _ in range(2):
        p = model.random_params(rng, fraction=0.5)
        p[:2] *= 0.3
        pose = forward(model, p)
        for cam, lab in zip(cams, render_label_images(model, pose, cams)):
            dirs, index = cam.rays(uv), np.zeros(len(uv), dtype=np.intp)
            on = covered_rays(model, pose, [cam], index, dirs)
            sil = lab[ys.ravel(), xs.ravel()] >= 0
            assert sil.sum() > 300
            assert np.count_nonzero(on != sil) <= 0.05 * sil.sum(), (cam.name, np.count_nonzero(on != sil))
            # the disagreements are on the rim: a margin of 1.5 px covers every rendered pixel
            grown = covered_rays(model, pose, [cam], index, dirs, margin_m=1.5 * 4.0 / cam.matrix[0, 0])
            assert np.all(grown[sil])


def test_sliding_term_barely_changes_the_chamfer_jacobian(scene, rng):
    """Why dropping the sliding term B costs no iterations (hop: median 3 with and without).

    B moves a contour point along the image of its ruling (``tests/test_contour_jacobian``), and
    the chamfer residual sees a point's motion through the distance image's gradient, which on
    the observed outline is normal to it: at the truth ∇D · J_I B ≈ 0, and the share of B in the
    residual Jacobian is about half its share in the contour-point Jacobian.  Besides, B is a
    small part of dx/dΦ to begin with (measured, 4 poses × 0/3/8° off: 4–15 % of the contour
    Jacobian's norm, 2–12 % of the residual Jacobian's), so the LM steps hardly change.
    """
    model = load_model("knossow40")
    for trial in range(2):
        p = model.random_params(rng, fraction=0.3)
        p[:3] = [0.1, -0.1, 0.0]
        labels = render_label_images(model, forward(model, p), scene)
        chamfer = [chamfer_images(np.where(lab >= 0, 255, 0).astype(np.uint8), internal_edges(lab)) for lab in labels]
        for deg in (0.0, 3.0, 8.0):
            q = p.copy()
            q[6:] += np.radians(deg) * rng.uniform(-1, 1, model.n_params - 6)
            q = model.clamp(q)
            J = {}
            for sliding in (True, False):
                cost = ChamferCost(model, scene, chamfer, sliding=sliding, n_samples=8, visibility="frame")
                terms = cost.evaluate(q, jacobian=True)
                J[sliding] = terms.jacobian
            pose = terms.pose
            Jc = contour_jacobian(model, pose, scene, terms.contours, rows=terms.used)
            Jc_rigid = contour_jacobian(model, pose, scene, terms.contours, rows=terms.used, sliding=False)
            share_contour = np.linalg.norm(Jc - Jc_rigid) / np.linalg.norm(Jc)
            share_residual = np.linalg.norm(J[True] - J[False]) / np.linalg.norm(J[True])
            assert np.abs(Jc - Jc_rigid).max() > 1.0  # B is not negligible in pixels
            assert 0.0 < share_residual < 0.15 and share_contour < 0.2, (trial, deg, share_residual, share_contour)
            if deg == 0.0:
                assert share_residual < 0.75 * share_contour, (trial, share_residual, share_contour)
