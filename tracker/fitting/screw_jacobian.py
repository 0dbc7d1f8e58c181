"""The chamfer cost's Jacobian kept as per-row screw motion, for the LM solver's normal equations.

Every row of ``tracker.fitting.cost.ChamferCost``'s Jacobian is a 6-vector (the row's motion per unit
screw of its part) times the screws of the parameters that move that part.  ``ScrewJacobian`` keeps
the m × 6 rows and the parts instead of the m × n_params matrix, and forms ``JᵀWJ``, ``JᵀWr`` and
``J x`` part by part (``tracker.kernels.normal``); ``toarray`` gives the dense matrix, equal to what
``evaluate(jacobian=True)`` returns.  Dense rows (e.g. ``tracker.fitting.props.PropPenalty``'s) can
be stacked under it.
"""

from __future__ import annotations

import numpy as np

from tracker.kernels import screw_matvec, screw_normal_equations, screw_rows

__all__ = ["ScrewJacobian"]


class ScrewJacobian:
    """A Jacobian (m + k, n_params) whose first m rows are ``motion[i] · screws[:, j]`` where
    ``affects[part[i], j]`` (else 0; a row with ``part[i] < 0`` is zero) and whose last k rows are
    the dense ``extra``.

    Parameters
    ----------
    motion : ndarray, shape (m, 6)
    part : ndarray of int, shape (m,)
    screws : ndarray, shape (6, n_params)
    affects : ndarray of bool, shape (n_parts, n_params)
    extra : ndarray, shape (k, n_params), optional
    """

    def __init__(self, motion: np.ndarray, part: np.ndarray, screws: np.ndarray, affects: np.ndarray,
                 extra: np.ndarray | None = None) -> None:
        self.motion = motion
        self.part = part
        self.screws = screws
        self.affects = affects
        self.extra = np.zeros((0, screws.shape[1])) if extra is None else np.asarray(extra, dtype=float)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.motion.shape[0] + self.extra.shape[0], self.screws.shape[1])

    def with_rows(self, rows: np.ndarray) -> "ScrewJacobian":
        """This Jacobian with the dense ``rows`` (k, n_params) stacked under it."""
        return ScrewJacobian(self.motion, self.part, self.screws, self.affects,
                             np.concatenate([self.extra, np.asarray(rows, dtype=float).reshape(-1, self.shape[1])]))

    def columns(self, idx: np.ndarray) -> "ScrewJacobian":
        """The Jacobian of the parameters ``idx`` only (its columns ``idx``)."""
        idx = np.asarray(idx, dtype=np.intp)
        return ScrewJacobian(self.motion, self.part, np.ascontiguousarray(self.screws[:, idx]),
                             np.ascontiguousarray(self.affects[:, idx]), self.extra[:, idx])

    def all_finite(self) -> bool:
        return bool(np.isfinite(self.motion).all() and np.isfinite(self.screws).all()
                    and np.isfinite(self.extra).all())

    def normal_equations(self, w: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``JᵀWJ`` (n, n) and ``JᵀWr`` (n,) for row weights ``w`` and residuals ``r``, both (m + k,)."""
        m = self.motion.shape[0]
        A, g = screw_normal_equations(self.motion, self.part, w, r, self.screws, self.affects)
        if self.extra.shape[0]:
            E, we, re = self.extra, w[m:], r[m:]
            A += (E.T * we) @ E
            g += E.T @ (we * re)
        return A, g

    def matvec(self, x: np.ndarray) -> np.ndarray:
        """``J x`` (m + k,) for x (n_params,)."""
        out = screw_matvec(self.motion, self.part, self.screws, self.affects, np.asarray(x, dtype=float))
        return np.concatenate([out, self.extra @ x]) if self.extra.shape[0] else out

    def toarray(self) -> np.ndarray:
        """The dense matrix (m + k, n_params)."""
        J = screw_rows(self.motion, self.part, self.screws, self.affects)
        return np.vstack([J, self.extra]) if self.extra.shape[0] else J
