"""Dense factorisation of a reduced tangent (r, r), with the interface of fem.linear_solver."""

from __future__ import annotations

import numpy as np
import scipy.linalg

from softforce_cli.errors import SolverError
from softforce_cli.fem.threads import on_one_blas_thread


class DenseFactorization:
    """LU factors of a small dense matrix (r, r); solve() takes (r,) or (r, k).

    LU rather than Cholesky: a reduced tangent with taut cables under compression can be
    indefinite, and at r ~ 100 the difference is microseconds.
    """

    def __init__(self, matrix: np.ndarray) -> None:
        self._factors: tuple[np.ndarray, np.ndarray] | None = None
        self.refactor(matrix)

    @on_one_blas_thread
    def refactor(self, matrix: np.ndarray) -> DenseFactorization:
        matrix = np.asarray(matrix, dtype=float)
        if not np.all(np.isfinite(matrix)):
            raise SolverError("the reduced stiffness matrix is not finite: the configuration "
                              "left the reduced model's range; check the loads")
        self._factors = scipy.linalg.lu_factor(matrix, check_finite=False)
        pivots = np.abs(np.diag(self._factors[0]))
        if pivots.min(initial=np.inf) <= 1e-13 * pivots.max(initial=0.0):
            raise SolverError("the reduced stiffness matrix is singular: is the robot clamped, "
                              "and was the reduced model trained on this robot?")
        return self

    @on_one_blas_thread
    def solve(self, rhs: np.ndarray) -> np.ndarray:
        return scipy.linalg.lu_solve(self._factors, np.asarray(rhs, dtype=float),
                                     check_finite=False)
