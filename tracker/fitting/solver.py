"""Bounded, robust Levenberg–Marquardt for the tracker (IJCV 2008 §5), plus the scipy baseline.

The problem is ``min_x  Σ ρ(r_i(x)) + ½ ‖√w (x − x_prior)‖²`` subject to ``lower ≤ x ≤ upper``,
where ``r(x)`` ``(m,)`` are the data residuals (pixels), ``ρ`` a robust loss with scale ``f_scale``
and the second term a small temporal prior.

**Robust loss** by IRLS: at each iterate the weights ``w_i = ρ'(r_i) / r_i`` (Huber:
``min(1, s/|r|)``; Cauchy: ``1 / (1 + (r/s)²)``) scale the rows of the Gauss–Newton system; the
acceptance test uses the true robust cost.

**Damping**: Marquardt's diagonal scaling ``(JᵀWJ + P + μ D) δ = −g`` with ``D = diag(JᵀWJ + P)``
(floored, so a parameter that no residual sees is held by the damping) and Nielsen's update of
``μ`` (H. B. Nielsen, *Damping parameter in Marquardt's method*, IMM-REP-1999-05): on a gain
ratio ρ > 0 the step is taken and ``μ *= max(1/3, 1 − (2ρ − 1)³)``, else ``μ *= ν, ν *= 2``.

**Bounds** by projection: parameters at a bound whose gradient pushes them outward are frozen for
the step (removed from the linear system), and the trial point is projected onto the box.

A non-finite residual at a trial point counts as a rejected step (more damping), never a NaN result.

**Jacobians** are dense arrays, or objects that form the products themselves (``normal_equations(w, r)
-> (JᵀWJ, JᵀWr)``, ``matvec(x) -> J x``, ``all_finite()``; e.g. ``tracker.fitting.screw_jacobian``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

__all__ = ["SolverResult", "levenberg_marquardt", "least_squares_fd", "robust_cost", "robust_weights",
           "CONVERGED_COST", "CONVERGED_STEP", "CONVERGED_GRADIENT", "MAX_ITERATIONS", "STALLED"]

# status codes (≥ 1: converged; 0: iteration limit; < 0: failure)
CONVERGED_COST, CONVERGED_STEP, CONVERGED_GRADIENT = 1, 2, 3
MAX_ITERATIONS = 0
STALLED = -1

_MESSAGES = {
    CONVERGED_COST: "relative cost change below ftol (or residual change below rtol)",
    CONVERGED_STEP: "step size below xtol",
    CONVERGED_GRADIENT: "gradient below gtol",
    MAX_ITERATIONS: "iteration limit reached",
    STALLED: "no decreasing step found (damping at its limit)",
}

#: A residual function: ``fun(x (n,), jacobian: bool) -> (r (m,), J (m, n) or None)``.
ResidualFn = Callable[[np.ndarray, bool], tuple]


@dataclass(frozen=True)
class SolverResult:
    """Outcome of a solve.

    Attributes
    ----------
    params : ndarray, shape (n,)
        Within the bounds; read-only.
    cost : float
        Robust data cost + prior at ``params``.
    rms_px : float
        RMS of the data residuals ``r`` (unweighted), residual units (pixels).
    iterations : int
        Linear solves (trial steps) taken.
    status : int
        One of the module's status codes (``success``: converged or ran out of iterations).
    message : str
        Words for it.
    n_evaluations : int
        Residual evaluations.
    """

    params: np.ndarray
    cost: float
    rms_px: float
    iterations: int
    status: int
    message: str
    n_evaluations: int = 0

    @property
    def success(self) -> bool:
        return self.status >= MAX_ITERATIONS


def robust_weights(r: np.ndarray, *, loss: str, f_scale: float) -> np.ndarray:
    """IRLS weights ``ρ'(r)/r``.

    Parameters
    ----------
    r : ndarray, shape (m,)
    loss : {"linear", "huber", "cauchy"}
    f_scale : float
        Scale of the loss, residual units.

    Returns
    -------
    ndarray, shape (m,)
    """
    if loss == "linear":
        return np.ones_like(r)
    a = np.abs(r) / f_scale
    if loss == "huber":
        return 1.0 / np.maximum(a, 1.0)
    if loss == "cauchy":
        return 1.0 / (1.0 + a * a)
    raise ValueError(f"loss: expected 'linear', 'huber' or 'cauchy', got {loss!r}")


def robust_cost(r: np.ndarray, *, loss: str, f_scale: float) -> float:
    """``Σ ρ(r_i)`` with ``ρ(r) = r²/2`` near 0 (scipy's convention, scaled by ``f_scale²``).

    Parameters
    ----------
    r : ndarray, shape (m,)
    loss : {"linear", "huber", "cauchy"}
    f_scale : float
        Scale of the loss, residual units.

    Returns
    -------
    float
    """
    if loss == "linear":
        return 0.5 * float(r @ r)
    a = np.abs(r) / f_scale
    if loss == "huber":
        rho = np.where(a <= 1.0, 0.5 * a * a, a - 0.5)
    elif loss == "cauchy":
        rho = 0.5 * np.log1p(a * a)
    else:
        raise ValueError(f"loss: expected 'linear', 'huber' or 'cauchy', got {loss!r}")
    return float(f_scale * f_scale * rho.sum())


def _check_inputs(x0, lower, upper, prior, prior_weight):
    x0 = np.asarray(x0, dtype=float)
    if x0.ndim != 1 or not np.all(np.isfinite(x0)):
        raise ValueError(f"x0: expected a finite 1-D array, got shape {x0.shape}")
    n = x0.size
    lo = np.full(n, -np.inf) if lower is None else np.broadcast_to(np.asarray(lower, float), (n,))
    hi = np.full(n, np.inf) if upper is None else np.broadcast_to(np.asarray(upper, float), (n,))
    if np.any(lo > hi):
        raise ValueError("lower, upper: lower must be <= upper for every parameter")
    pw = np.zeros(n) if prior_weight is None else np.broadcast_to(np.asarray(prior_weight, float), (n,))
    if np.any(pw < 0) or not np.all(np.isfinite(pw)):
        raise ValueError("prior_weight: expected finite values >= 0")
    xp = x0 if prior is None else np.asarray(prior, dtype=float)
    if xp.shape != (n,) or not np.all(np.isfinite(xp)):
        raise ValueError(f"prior: expected a finite array of shape ({n},)")
    return np.clip(x0, lo, hi), lo, hi, xp, pw


def levenberg_marquardt(fun: ResidualFn, x0, *, lower=None, upper=None, prior=None, prior_weight=None,
                        loss: str = "huber", f_scale: float = 5.0, max_iterations: int = 20,
                        ftol: float = 1e-3, xtol: float = 1e-5, gtol: float = 1e-8, rtol: float = 0.0,
                        damping: float = 1e-3, min_diagonal: float = 1e-6,
                        diagonal_floor: float = 0.0) -> SolverResult:
    """Minimise the robust, bounded, prior-regularised least-squares problem of the module docstring.

    Parameters
    ----------
    fun : callable
        ``fun(x, jacobian) -> (r (m,), J (m, n) or None)``; ``m`` may change with ``x``; J an array or
        an object with the products (module docstring).
    x0 : ndarray, shape (n,)
        The start (projected onto the bounds).
    lower, upper : ndarray, shape (n,), or None
        Bounds; ±inf for unbounded.
    prior, prior_weight : ndarray, shape (n,), or None; ndarray or float
        Prior centre (None: ``x0``) and weights per unit² of x.
    loss, f_scale : str, float
        Robust loss and its scale in residual units (pixels).
    max_iterations, ftol, xtol, gtol : int, float, float, float
        Trial steps; stop when an accepted step lowers the cost by less than ``ftol`` × cost, when
        ``‖δ‖ ≤ xtol (‖x‖ + xtol)``, or when the gradient is below ``gtol``.
    rtol : float
        Stop after an accepted step that changes no residual by more than ``rtol`` (linearised,
        ``max |J δ|``, residual units: "no contour point moved rtol pixels").
    damping, min_diagonal, diagonal_floor : float
        Initial μ (relative to the diagonal); the damping diagonal is ``max(diag, min_diagonal,
        diagonal_floor × max(diag))``, so weakly observed parameters are damped too.

    Returns
    -------
    SolverResult
    """
    x, lo, hi, xp, pw = _check_inputs(x0, lower, upper, prior, prior_weight)
    robust_weights(np.zeros(1), loss=loss, f_scale=f_scale)  # validates loss
    n_eval = 0

    def total_cost(r, xx):
        d = xx - xp
        return robust_cost(r, loss=loss, f_scale=f_scale) + 0.5 * float(pw @ (d * d))

    r, J = fun(x, True)
    n_eval += 1
    if not np.all(np.isfinite(r)) or not _finite_jacobian(J):
        r = np.nan_to_num(r, nan=0.0, posinf=0.0, neginf=0.0)
        return _result(x, float("inf"), r, 0, STALLED, "non-finite residuals or Jacobian at the start", n_eval)
    cost = total_cost(r, x)
    mu, nu = float(damping), 2.0
    status = MAX_ITERATIONS
    it = 0
    while it < max_iterations:
        A, g = _normal_equations(J, robust_weights(r, loss=loss, f_scale=f_scale), r)  # IRLS weights >= 0
        A.flat[::x.size + 1] += pw
        g += pw * (x - xp)
        # freeze parameters at a bound that the gradient pushes outward
        free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
        all_free = bool(free.all())
        if np.max(np.abs(g if all_free else g[free]), initial=0.0) <= gtol:
            status = CONVERGED_GRADIENT
            break
        Af = A if all_free else A[np.ix_(free, free)]
        gf = g if all_free else g[free]
        diag = np.diag(Af)
        diag = np.maximum(diag, max(min_diagonal, diagonal_floor * float(diag.max(initial=0.0))))
        accepted = False
        while it < max_iterations:
            it += 1
            damped = Af.copy()
            damped.flat[::damped.shape[0] + 1] += mu * diag
            try:
                step_f = -np.linalg.solve(damped, gf)
            except np.linalg.LinAlgError:
                mu, nu = mu * nu, nu * 2.0
                continue
            if all_free:
                step = step_f
            else:
                step = np.zeros_like(x)
                step[free] = step_f
            x_new = np.clip(x + step, lo, hi)
            step = x_new - x
            small_step = np.linalg.norm(step) <= xtol * (np.linalg.norm(x) + xtol)
            r_new, _ = fun(x_new, False)
            n_eval += 1
            ok = np.all(np.isfinite(r_new))
            cost_new = total_cost(r_new, x_new) if ok else np.inf
            # predicted decrease of the (weighted) Gauss–Newton model along the projected step
            predicted = -(g @ step) - 0.5 * step @ (A @ step)
            gain = (cost - cost_new) / predicted if predicted > 0 else -1.0
            if ok and cost_new < cost:
                accepted = True
                rel = (cost - cost_new) / max(cost, 1e-300)
                moved = float(np.max(np.abs(_matvec(J, step)), initial=0.0)) if rtol > 0 else np.inf
                x, cost = x_new, cost_new
                mu *= max(1.0 / 3.0, 1.0 - (2.0 * max(gain, 0.0) - 1.0) ** 3)
                nu = 2.0
                break
            if small_step:
                status = CONVERGED_STEP
                break
            mu, nu = mu * nu, nu * 2.0
            if mu > 1e16:
                status = STALLED
                break
        if not accepted:
            break
        # stop before linearising again when converged (or out of iterations): saves a Jacobian
        if rel < ftol or moved < rtol or small_step or it >= max_iterations:
            r = r_new
            status = (CONVERGED_COST if rel < ftol or moved < rtol else
                      CONVERGED_STEP if small_step else MAX_ITERATIONS)
            break
        r_lin, J_lin = fun(x, True)
        n_eval += 1
        if not np.all(np.isfinite(r_lin)) or not _finite_jacobian(J_lin):
            r = r_new
            status = STALLED
            break
        r, J = r_lin, J_lin
        # the residual set may be refreshed at a new linearisation point (e.g. occlusion)
        cost = total_cost(r, x)
    else:
        status = MAX_ITERATIONS
    if status == STALLED and cost < np.inf:
        # damping exhausted at a point no step improves: a (possibly bound-constrained) minimum
        status = CONVERGED_STEP
    return _result(x, cost, r, it, status, _MESSAGES[status], n_eval)


def _finite_jacobian(J) -> bool:
    if J is None:
        return False
    return J.all_finite() if hasattr(J, "all_finite") else bool(np.all(np.isfinite(J)))


def _normal_equations(J, w, r):
    """``(JᵀWJ, JᵀWr)`` for the row weights ``w`` (m,) >= 0 of a dense or structured ``J``."""
    if hasattr(J, "normal_equations"):
        return J.normal_equations(w, r)
    sw = np.sqrt(w)
    Js = J * sw[:, None]
    return Js.T @ Js, Js.T @ (sw * r)  # a product with its own transpose: one symmetric rank-k update (syrk)


def _matvec(J, x):
    return J.matvec(x) if hasattr(J, "matvec") else J @ x


def _result(x, cost, r, it, status, message, n_eval) -> SolverResult:
    rms = float(np.sqrt(np.mean(r * r))) if r.size else 0.0
    x = np.array(x, dtype=float)
    x.setflags(write=False)
    return SolverResult(x, float(cost), rms, int(it), int(status), message, int(n_eval))


def least_squares_fd(fun: ResidualFn, x0, *, lower=None, upper=None, prior=None, prior_weight=None,
                     loss: str = "huber", f_scale: float = 5.0, max_iterations: int = 20,
                     ftol: float = 1e-3, xtol: float = 1e-5) -> SolverResult:
    """The speed baseline: ``scipy.optimize.least_squares`` (TRF) with a finite-difference Jacobian.

    The same problem as ``levenberg_marquardt`` (``fun``'s residual vector must keep its length);
    ``iterations`` counts scipy's Jacobian evaluations.

    Parameters
    ----------
    fun, x0, lower, upper, prior, prior_weight, loss, f_scale, max_iterations, ftol, xtol
        As ``levenberg_marquardt``.

    Returns
    -------
    SolverResult
    """
    from scipy.optimize import least_squares

    x, lo, hi, xp, pw = _check_inputs(x0, lower, upper, prior, prior_weight)
    n = x.size
    # TRF needs a start strictly inside finite bounds
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    x = np.clip(x, lo + 1e-9 * span, hi - 1e-9 * span)
    sw = np.sqrt(pw)
    m_data = [0]

    def stacked(xx):
        r, _ = fun(xx, False)
        m_data[0] = r.size
        # the prior rows are small: scale them so the robust loss (≤ f_scale) leaves them quadratic
        return np.concatenate([r, sw * (xx - xp)])

    res = least_squares(stacked, x, jac="2-point", bounds=(lo, hi), method="trf", loss=loss,
                        f_scale=f_scale, max_nfev=max_iterations * (n + 2), ftol=ftol, xtol=xtol)
    r, _ = fun(res.x, False)
    status = {0: MAX_ITERATIONS, 1: CONVERGED_GRADIENT, 2: CONVERGED_COST, 3: CONVERGED_STEP,
              4: CONVERGED_COST}.get(res.status, STALLED)
    d = res.x - xp
    cost = robust_cost(r, loss=loss, f_scale=f_scale) + 0.5 * float(pw @ (d * d))
    njev = int(res.njev) if res.njev is not None else int(res.nfev)
    return _result(res.x, cost, r, njev, status, str(res.message), int(res.nfev) + njev * n)
