"""Dense factorisation of a reduced tangent (r, r), with the interface of fem.linear_solver."""

from __future__ import annotations

import numpy as np
import scipy.linalg
from threadpoolctl import ThreadpoolController

from softforce_cli.errors import SolverError

# numpy's and scipy's OpenBLAS each keep a pool of threads, which on two cores contend: a
# reduced model's matrices are small (r ~ 200), so its products and factorisations run on one
# BLAS thread (docs/reduced_model.md: an update took 24 ms with two, 16 ms with one; an LU
# 16 ms against 0.25 ms). Made after numpy and scipy.linalg are loaded, so it sees both.
_BLAS = ThreadpoolController()


def one_blas_thread():
    """A context in which BLAS runs on one thread (8 us to enter and leave)."""
    return _BLAS.limit(limits=1, user_api="blas")


class DenseFactorization:
    """LU factors of a small dense matrix (r, r); solve() takes (r,) or (r, k).

    LU rather than Cholesky: a reduced tangent with taut cables under compression can be
    indefinite, and at r ~ 100 the difference is microseconds.
    """

    def __init__(self, matrix: np.ndarray) -> None:
        self._factors: tuple[np.ndarray, np.ndarray] | None = None
        self.refactor(matrix)

    def refactor(self, matrix: np.ndarray) -> DenseFactorization:
        matrix = np.asarray(matrix, dtype=float)
        if not np.all(np.isfinite(matrix)):
            raise SolverError("the reduced stiffness matrix is not finite: the configuration "
                              "left the reduced model's range; check the loads")
        with one_blas_thread():
            self._factors = scipy.linalg.lu_factor(matrix, check_finite=False)
        pivots = np.abs(np.diag(self._factors[0]))
        if pivots.min(initial=np.inf) <= 1e-13 * pivots.max(initial=0.0):
            raise SolverError("the reduced stiffness matrix is singular: is the robot clamped, "
                              "and was the reduced model trained on this robot?")
        return self

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        with one_blas_thread():
            return scipy.linalg.lu_solve(self._factors, np.asarray(rhs, dtype=float),
                                         check_finite=False)
