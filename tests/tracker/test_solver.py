"""Levenberg–Marquardt on generic bounded nonlinear least squares, and the scipy FD baseline."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tracker.fitting.solver import (
    CONVERGED_COST, CONVERGED_GRADIENT, CONVERGED_STEP, MAX_ITERATIONS, SolverResult, least_squares_fd,
    levenberg_marquardt, robust_cost, robust_weights,
)  # fmt: skip


def rosenbrock(x, jacobian):
    r = np.array([10.0 * (x[1] - x[0] ** 2), 1.0 - x[0]])
    J = np.array([[-20.0 * x[0], 10.0], [-1.0, 0.0]]) if jacobian else None
    return r, J


def exp_model(t, y):
    def fun(x, jacobian):
        e = np.exp(-x[1] * t)
        r = x[0] * e + x[2] - y
        J = np.stack([e, -x[0] * t * e, np.ones_like(t)], axis=1) if jacobian else None
        return r, J

    return fun


def test_rosenbrock_unbounded_reaches_minimum():
    res = levenberg_marquardt(rosenbrock, [-1.2, 1.0], loss="linear", max_iterations=100, ftol=1e-12, xtol=1e-12)
    assert res.status in (CONVERGED_COST, CONVERGED_STEP, CONVERGED_GRADIENT)
    np.testing.assert_allclose(res.params, [1.0, 1.0], atol=1e-6)
    assert res.cost < 1e-12


def test_rosenbrock_with_active_bound_stops_on_the_bound():
    # minimum of the bounded problem: x0 <= 0.5 is active; then x1 = x0² = 0.25
    res = levenberg_marquardt(rosenbrock, [-1.2, 1.0], lower=[-2, -2], upper=[0.5, 2], loss="linear",
                              max_iterations=100, ftol=1e-12, xtol=1e-12)
    np.testing.assert_allclose(res.params, [0.5, 0.25], atol=1e-6)
    assert np.all(res.params <= [0.5, 2])
    scipy_res = least_squares_fd(rosenbrock, [-1.2, 1.0], lower=[-2, -2], upper=[0.5, 2], loss="linear",
                                 max_iterations=200, ftol=1e-12, xtol=1e-12)
    np.testing.assert_allclose(scipy_res.params, res.params, atol=1e-4)


def test_curve_fit_recovers_parameters_in_few_iterations(rng):
    t = np.linspace(0, 4, 60)
    truth = np.array([2.5, 1.3, 0.4])
    y = truth[0] * np.exp(-truth[1] * t) + truth[2] + rng.normal(0, 1e-3, t.size)
    res = levenberg_marquardt(exp_model(t, y), [1.0, 0.5, 0.0], loss="linear", ftol=1e-10)
    np.testing.assert_allclose(res.params, truth, atol=5e-3)
    assert res.iterations <= 15
    assert res.rms_px == pytest.approx(1e-3, rel=0.3)


def test_robust_loss_resists_outliers(rng):
    t = np.linspace(0, 4, 80)
    truth = np.array([2.5, 1.3, 0.4])
    y = truth[0] * np.exp(-truth[1] * t) + truth[2] + rng.normal(0, 1e-3, t.size)
    y[::8] += 5.0  # 10 gross outliers
    plain = levenberg_marquardt(exp_model(t, y), [1.0, 0.5, 0.0], loss="linear", ftol=1e-10)
    for loss in ("huber", "cauchy"):
        res = levenberg_marquardt(exp_model(t, y), [1.0, 0.5, 0.0], loss=loss, f_scale=0.01, ftol=1e-12,
                                  max_iterations=100)
        err = np.abs(res.params - truth).max()
        assert err < 0.1, loss
        assert err < 0.2 * np.abs(plain.params - truth).max(), loss


def test_non_finite_trial_shrinks_the_step_never_nan():
    # residual undefined (NaN) for x > 1.5; the minimum of (x - 3)² restricted to the domain is at the rim
    def fun(x, jacobian):
        r = np.array([x[0] - 3.0]) if x[0] <= 1.5 else np.array([np.nan])
        return r, (np.array([[1.0]]) if jacobian else None)

    res = levenberg_marquardt(fun, [0.0], loss="linear", max_iterations=60)
    assert np.all(np.isfinite(res.params)) and np.isfinite(res.cost)
    assert 1.3 < res.params[0] <= 1.5


def test_prior_pulls_unobserved_parameters_and_weights_trade_off():
    # only x0 is observed (target 1); x1 unobserved, held at its prior by the prior term
    def fun(x, jacobian):
        return np.array([x[0] - 1.0]), (np.array([[1.0, 0.0]]) if jacobian else None)

    res = levenberg_marquardt(fun, [0.0, 0.3], prior=[0.0, 0.3], prior_weight=[1.0, 1.0], loss="linear",
                              ftol=1e-12)
    # minimiser of ½(x0-1)² + ½ x0²: x0 = 0.5
    np.testing.assert_allclose(res.params, [0.5, 0.3], atol=1e-6)


def test_max_iterations_and_frozen_result():
    res = levenberg_marquardt(rosenbrock, [-1.2, 1.0], loss="linear", max_iterations=2, ftol=0, xtol=0)
    assert res.status == MAX_ITERATIONS and res.iterations == 2
    assert isinstance(res, SolverResult)
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.cost = 0.0  # type: ignore[misc]
    assert not res.params.flags.writeable


def test_bad_arguments_named():
    with pytest.raises(ValueError, match="x0"):
        levenberg_marquardt(rosenbrock, [np.nan, 1.0])
    with pytest.raises(ValueError, match="lower"):
        levenberg_marquardt(rosenbrock, [0.0, 1.0], lower=[1, 1], upper=[0, 0])
    with pytest.raises(ValueError, match="loss"):
        levenberg_marquardt(rosenbrock, [0.0, 1.0], loss="tukey")


def test_robust_weights_match_loss_derivative(rng):
    r = rng.normal(0, 3, 50)
    h = 1e-6
    for loss in ("linear", "huber", "cauchy"):
        w = robust_weights(r, loss=loss, f_scale=2.0)
        # ρ'(r) by central differences of the per-residual cost
        d = np.array([(robust_cost(np.array([ri + h]), loss=loss, f_scale=2.0)
                       - robust_cost(np.array([ri - h]), loss=loss, f_scale=2.0)) / (2 * h) for ri in r])
        np.testing.assert_allclose(w * r, d, rtol=1e-5, atol=1e-7)
