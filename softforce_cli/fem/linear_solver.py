"""Sparse LDL^T factorisation of the tangent stiffness, reused for many right-hand sides.

QDLDL (the OSQP project's solver) splits the work into a symbolic analysis with an AMD
ordering, done once per sparsity pattern, and a numeric factorisation, redone for every new
configuration of the same mesh: the pattern of K(x) never changes, so each update pays only
the numeric part.
"""

from __future__ import annotations

import numpy as np
import qdldl
import scipy.sparse as sp

from softforce_cli.errors import SolverError


class Factorization:
    """Factors of a sparse symmetric matrix (f, f); solve() takes (f,) or (f, k).

    refactor(matrix) reuses the symbolic analysis when the sparsity pattern is unchanged.
    """

    def __init__(self, matrix: sp.spmatrix) -> None:
        self._solver: qdldl.Solver | None = None
        self._pattern: tuple[np.ndarray, np.ndarray] | None = None
        self.refactor(matrix)

    def refactor(self, matrix: sp.spmatrix) -> Factorization:
        upper = sp.triu(matrix, format="csc")
        upper.sort_indices()
        same = self._pattern is not None and (
            np.array_equal(self._pattern[0], upper.indptr)
            and np.array_equal(self._pattern[1], upper.indices)
        )
        try:
            if same:
                self._solver.update(upper, upper=True)
            else:
                self._solver = qdldl.Solver(upper, upper=True)
                self._pattern = (upper.indptr.copy(), upper.indices.copy())
        except (ValueError, RuntimeError) as error:
            raise SolverError(
                "the stiffness matrix is singular: is the robot clamped (a [[fixed]] box that "
                f"catches nodes) and its mesh connected? ({error})"
            ) from error
        self.size = matrix.shape[0]
        return self

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        rhs = np.asarray(rhs, dtype=float)
        if rhs.ndim == 1:
            return self._checked(self._solver.solve(rhs))
        return np.column_stack([self._checked(self._solver.solve(col)) for col in rhs.T]
                               ) if rhs.shape[1] else np.zeros_like(rhs)

    @staticmethod
    def _checked(solution: np.ndarray) -> np.ndarray:
        if not np.all(np.isfinite(solution)):
            raise SolverError(
                "the stiffness matrix is singular: is the robot clamped (a [[fixed]] box that "
                "catches nodes) and its mesh connected?"
            )
        return solution
