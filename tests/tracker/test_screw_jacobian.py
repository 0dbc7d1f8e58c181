"""The chamfer cost's Jacobian kept as per-row screw motion (``tracker.fitting.screw_jacobian``): its
dense form is the (finite-difference tested) dense Jacobian, and its products are the dense ones."""

from __future__ import annotations

import numpy as np
import pytest

from segmentation.distance import chamfer_images
from tracker.body.kinematics import forward
from tracker.body.model import load_model
from tracker.fitting.cost import ChamferCost
from tracker.fitting.screw_jacobian import ScrewJacobian
from tracker.fitting.solver import levenberg_marquardt, robust_cost
from tracker.imaging.render import internal_edges, render_label_images
from tracker.synthetic.scene import ring_cameras


@pytest.fixture(scope="module")
def scene():
    return ring_cameras(4, size=(640, 480))


def _cost(model, scene, p):
    labels = render_label_images(model, forward(model, p), scene)
    chamfer = [chamfer_images(np.where(lab >= 0, 255, 0).astype(np.uint8), internal_edges(lab)) for lab in labels]
    return ChamferCost(model, scene, chamfer, n_samples=8, reverse_weight=1.0, reverse_samples=150,
                       reverse_min_px=2.0, reverse_cover_px=1.0)


def _moved(model, p, rng):
    q = p + rng.normal(0.0, 0.08, p.size) * (model.param_kind != 0)
    q[:3] += rng.normal(0.0, 0.03, 3)
    return model.clamp(q)


@pytest.mark.parametrize("name", ["knossow40", "knossow54"])
def test_products_equal_the_dense_jacobians(name, scene, rng):
    model = load_model(name)
    for trial in range(3):
        p = model.random_params(rng, fraction=0.3)
        p[:3] = rng.uniform(-0.2, 0.2, 3) * [1, 1, 0]
        cost = _cost(model, scene, p)
        q = _moved(model, p, rng)
        dense = cost.evaluate(q, jacobian=True, compact=True)
        J = dense.jacobian
        S = cost.evaluate(q, jacobian=True, compact=True, structured=True)
        np.testing.assert_array_equal(S.residuals, dense.residuals)
        Js = S.jacobian
        assert isinstance(Js, ScrewJacobian) and Js.shape == J.shape and J.shape[0] > 300
        np.testing.assert_allclose(Js.toarray(), J, rtol=0, atol=1e-12 * np.abs(J).max())
        w = rng.uniform(0.0, 1.0, J.shape[0]) * (rng.random(J.shape[0]) > 0.1)  # some zero weights
        r = dense.residuals
        A, g = Js.normal_equations(w, r)
        np.testing.assert_allclose(A, (J.T * w) @ J, rtol=1e-10, atol=1e-9 * np.abs(A).max())
        np.testing.assert_allclose(g, J.T @ (w * r), rtol=1e-10, atol=1e-9 * np.abs(g).max())
        assert np.array_equal(A, A.T)
        x = rng.normal(size=model.n_params)
        np.testing.assert_allclose(Js.matvec(x), J @ x, rtol=1e-10, atol=1e-10 * np.abs(J @ x).max())
        # dense rows stacked under (a penalty's)
        E = rng.normal(size=(5, model.n_params))
        Jx = Js.with_rows(E)
        w2, r2 = np.concatenate([w, np.full(5, 0.5)]), np.concatenate([r, rng.normal(size=5)])
        A2, g2 = Jx.normal_equations(w2, r2)
        D = np.vstack([J, E])
        np.testing.assert_allclose(A2, (D.T * w2) @ D, rtol=1e-10, atol=1e-9 * np.abs(A2).max())
        np.testing.assert_allclose(g2, D.T @ (w2 * r2), rtol=1e-10, atol=1e-9 * np.abs(g2).max())
        np.testing.assert_allclose(Jx.matvec(x), D @ x, rtol=1e-10, atol=1e-10 * np.abs(D @ x).max())
        assert Jx.shape == D.shape and Jx.all_finite()
        # a subset of the parameters (tracker.search.refine's stages)
        idx = np.sort(rng.choice(model.n_params, size=model.n_params // 2, replace=False))
        Jc = Jx.columns(idx)
        np.testing.assert_allclose(Jc.toarray(), D[:, idx], rtol=0, atol=1e-12 * np.abs(D).max())
        A3, g3 = Jc.normal_equations(w2, r2)
        np.testing.assert_allclose(A3, A2[np.ix_(idx, idx)], rtol=1e-10, atol=1e-9 * np.abs(A2).max())
        np.testing.assert_allclose(g3, g2[idx], rtol=1e-10, atol=1e-9 * np.abs(g2).max())
        np.testing.assert_allclose(Jc.matvec(x[idx]), D[:, idx] @ x[idx], rtol=1e-10,
                                   atol=1e-10 * np.abs(D[:, idx] @ x[idx]).max())
    bad = ScrewJacobian(Js.motion.copy(), Js.part, Js.screws, Js.affects)
    bad.motion[0, 0] = np.nan
    assert not bad.all_finite()


def test_lm_takes_the_same_steps_with_either_form(scene, rng):
    """The solver on the structured Jacobian converges to the point it reaches on the dense one."""
    model = load_model("knossow40")
    p = model.random_params(rng, fraction=0.3)
    cost = _cost(model, scene, p)
    q = _moved(model, p, rng)
    out = []
    for structured in (False, True):
        res = levenberg_marquardt(cost.residual_fn(compact=True, structured=structured), q, lower=model.lower,
                                  upper=model.upper, prior=q, prior_weight=1.0, loss="huber", f_scale=3.0,
                                  max_iterations=8, rtol=0.5)
        out.append(res)
    assert out[0].iterations == out[1].iterations and out[0].iterations >= 2
    np.testing.assert_allclose(out[1].params, out[0].params, atol=1e-8)
    assert abs(out[1].cost - out[0].cost) <= 1e-9 * out[0].cost
    start = robust_cost(cost.evaluate(q, compact=True).residuals, loss="huber", f_scale=3.0)
    assert out[1].cost < 0.5 * start, (out[1].cost, start)  # it did fit
