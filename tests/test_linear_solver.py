"""The sparse factorisation: Cholesky, anchored Cholesky for a few negative modes, L D L^T."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from softforce_cli.errors import SolverError
from softforce_cli.fem import cholmod_blocks, linear_solver
from softforce_cli.fem.linear_solver import Factorization

N = 10  # a 10 x 10 x 10 grid


@pytest.fixture(autouse=True)
def forget_patterns(monkeypatch):
    """Each test starts with no remembered pattern: the grid's matrices share one, and the
    anchors one test leaves would change how the next factorises."""
    monkeypatch.setattr(linear_solver, "_remembered", {})


def grid_laplacian(clamped: bool = True) -> sp.csr_matrix:
    """7-point Laplacian on the grid, Dirichlet (clamped, SPD) or Neumann (singular)."""
    path = sp.diags([-np.ones(N - 1), 2 * np.ones(N), -np.ones(N - 1)], [-1, 0, 1])
    if not clamped:
        path = path.tolil()
        path[0, 0] = path[-1, -1] = 1.0
    eye = sp.eye(N)
    return sp.csr_matrix(sp.kron(sp.kron(path, eye), eye) + sp.kron(sp.kron(eye, path), eye)
                         + sp.kron(sp.kron(eye, eye), path))


def lowest_eigenvalues(count: int) -> np.ndarray:
    """The Dirichlet grid Laplacian's eigenvalues sum_d 2 - 2 cos(pi k_d / (N + 1)), lowest."""
    one = 2 - 2 * np.cos(np.pi * np.arange(1, N + 1) / (N + 1))
    return np.sort((one[:, None, None] + one[None, :, None] + one[None, None, :]).ravel())[:count]


def check_solves(factor: Factorization, matrix: sp.spmatrix) -> None:
    rhs = np.random.default_rng(1).standard_normal((matrix.shape[0], 3))
    reference = sla.spsolve(sp.csc_matrix(matrix), rhs)
    scale = np.abs(reference).max()
    np.testing.assert_allclose(factor.solve(rhs), reference, atol=1e-9 * scale)
    np.testing.assert_allclose(factor.solve(rhs[:, 1]), reference[:, 1], atol=1e-9 * scale)
    assert factor.solve(rhs[:, :0]).shape == (matrix.shape[0], 0)


def test_positive_definite_matrices_use_cholesky():
    matrix = grid_laplacian()
    factor = Factorization(matrix)
    assert factor.method == "cholesky"
    check_solves(factor, matrix)


def test_a_few_negative_modes_are_anchored_and_solved_exactly():
    """Shifted just past its lowest eigenvalue, the Laplacian has one negative eigenvalue,
    tiny next to its diagonal (6), like the Diamond's two under gravity (1e-6 of it)."""
    first, second = lowest_eigenvalues(2)
    matrix = grid_laplacian() - sp.eye(N**3) * (first + 1e-4)
    factor = Factorization(matrix)
    assert factor.method == "anchored"
    check_solves(factor, matrix)
    # refactor with the same pattern keeps the anchors and solves the new matrix
    shifted = grid_laplacian() - sp.eye(N**3) * (first + 0.3 * (second - first))
    factor.refactor(shifted)
    assert factor.method == "anchored"
    check_solves(factor, shifted)


def test_a_new_factorization_of_the_pattern_starts_from_the_anchors_that_held(monkeypatch):
    """The anchors one factorisation searched for are tried first by the next of the same
    pattern (the next state's Newton solve), which then solves exactly without a search and
    without first failing K's own Cholesky; anchors that no longer hold are searched for
    again."""
    first, second = lowest_eigenvalues(2)
    matrix = grid_laplacian() - sp.eye(N**3) * (first + 1e-4)
    Factorization(matrix)
    searches, numerics = [], []
    search, numeric = Factorization._negative_mode_dofs, Factorization._numeric
    monkeypatch.setattr(Factorization, "_negative_mode_dofs",
                        lambda self, *args: searches.append(1) or search(self, *args))
    monkeypatch.setattr(Factorization, "_numeric",
                        lambda self, *args: numerics.append(1) or numeric(self, *args))
    nearby = grid_laplacian() - sp.eye(N**3) * (first + 3e-4)  # the same mode, deeper
    factor = Factorization(nearby)
    # one numeric factorisation: the anchored one, not K's own Cholesky first
    assert factor.method == "anchored" and not searches and len(numerics) == 1
    check_solves(factor, nearby)
    # a definite matrix of the pattern is solved exactly through the same anchors
    definite = grid_laplacian() + 0.1 * sp.eye(N**3)
    factor = Factorization(definite)
    assert factor.method == "anchored" and not searches
    check_solves(factor, definite)
    # four negative modes (the second eigenvalue is threefold): one mode's anchor no longer
    # stops them
    deeper = grid_laplacian() - sp.eye(N**3) * (second + 1e-3)
    factor = Factorization(deeper)
    assert factor.method == "anchored" and searches
    check_solves(factor, deeper)


def test_strongly_indefinite_matrices_fall_back_to_ldl():
    matrix = grid_laplacian() - 5.5 * sp.eye(N**3)  # half the spectrum negative
    factor = Factorization(matrix)
    assert factor.method == "ldl"
    check_solves(factor, matrix)


def test_a_new_pattern_is_analysed_again():
    matrix = grid_laplacian()
    factor = Factorization(matrix)
    coupled = sp.csr_matrix(matrix + 0.1 * sp.eye(N**3, k=5) + 0.1 * sp.eye(N**3, k=-5))
    factor.refactor(coupled)
    check_solves(factor, coupled)


def test_singular_matrices_raise_a_solver_error():
    """A Neumann Laplacian (constants in its kernel) is an unclamped body's stiffness."""
    with pytest.raises(SolverError, match="singular: is the robot clamped"):
        factor = Factorization(grid_laplacian(clamped=False))
        factor.solve(np.ones(N**3) + np.arange(N**3))


def test_non_finite_matrices_raise_a_solver_error():
    """An inverted element gives a hyperelastic law NaN stiffness: a SolverError (which
    sense turns into a skipped frame), not a failure deep in the factorisation."""
    matrix = grid_laplacian().tolil()
    matrix[5, 5] = np.nan
    with pytest.raises(SolverError, match="non-finite"):
        Factorization(matrix)
    factor = Factorization(grid_laplacian())
    with pytest.raises(SolverError, match="non-finite"):
        factor.refactor(matrix)


def test_many_right_hand_sides_are_solved_together_as_one_by_one(monkeypatch):
    """CHOLMOD's own solve of many columns at once (fem.cholmod_blocks, in blocks of 64:
    150 columns make three) gives scipy's answer and cvxopt's column-by-column one, for
    Cholesky and for the anchored factor with its correction."""
    assert cholmod_blocks.blocked_solver() is not None  # Linux, cvxopt's wheel
    rng = np.random.default_rng(2)
    for matrix in (grid_laplacian(), grid_laplacian() - 1.01 * lowest_eigenvalues(1)[0]
                   * sp.eye(N ** 3)):
        rhs = rng.standard_normal((matrix.shape[0], 150))
        reference = sla.spsolve(sp.csc_matrix(matrix), rhs)
        blocked = Factorization(matrix).solve(rhs)
        with monkeypatch.context() as patch:
            patch.setattr(linear_solver, "blocked_solver", lambda: None)
            one_by_one = Factorization(matrix).solve(rhs)
        scale = np.abs(reference).max()
        np.testing.assert_allclose(blocked, reference, atol=1e-9 * scale)
        np.testing.assert_allclose(blocked, one_by_one, atol=1e-12 * scale)


def test_the_blocked_solve_refuses_what_is_not_a_cholmod_factor():
    solve = cholmod_blocks.blocked_solver()
    with pytest.raises(ValueError):
        solve(object(), np.ones((3, 1)))
