"""Sparse factorisation of the tangent stiffness, reused for many right-hand sides.

CHOLMOD (SuiteSparse, through cvxopt's bundled build) splits the work into a symbolic
analysis with a fill-reducing ordering, done once per sparsity pattern, and a numeric
factorisation, redone for every new configuration of the same mesh: the pattern of K(x)
never changes, so each update pays only the numeric part.

The numeric part is a supernodal Cholesky L L^T (dense BLAS on blocks of columns), 5 to 10
times faster than a column-by-column L D L^T on the Diamond's stiffness matrices (P1 4.5k
to P2 26k dofs; docs/fem.md). It needs K positive definite, which a tangent is not always:
cables in compression, buckling, and the Diamond itself under gravity, whose tangent has
two tiny negative eigenvalues (about -3e-6 N/mm against a mean diagonal of 4.5 N/mm: the
apex tipping sideways, held only by the displacement-controlled cables that are
constraints, not springs, in K; docs/locking.md). Three ways, tried in turn:

1. L L^T of K.
2. Anchored: L L^T of K' = K + c E E^T, K with springs c to ground at a few dofs S
   (E = the identity's columns S), which stop the negative modes; then K^-1 exactly, by the
   Sherman-Morrison-Woodbury identity K^-1 b = y + Z (I/c - E^T Z)^-1 E^T y with
   y = K'^-1 b and Z = K'^-1 E (|S| extra columns per factorisation). S is found when
   needed (a few factorisations' worth): dofs that move most in the negative eigenvectors
   of K, computed by subspace iteration with a shifted Cholesky factor (K + sigma I).
3. CHOLMOD's simplicial L D L^T, which takes any pivot but zero, when no anchors do.

A Factorization keeps the way that worked for the refactors of the same pattern (the
tangents of one Newton solve, or of successive sensing frames, are alike), and searches
for new anchors when the old ones no longer hold (twice at most after L D L^T was needed).
Every Newton solve makes a new Factorization, and what a pattern fixes is shared by the
Factorizations of that pattern (`_Pattern`, the last few remembered): the triangle's
structure, the diagonal's positions, and the anchors that last held, with which a new
Factorization starts (not with K's own Cholesky, which failed for them). The Diamond's
negative modes are the same apex tipping at every state: the 28 states of a diagnosis had
searched 100 times, 36 s of a 142 s run. Any anchors that make K' positive definite give K^-1
exactly, so a hint that no longer holds costs one factorisation and a search, never
accuracy.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from cvxopt import cholmod, spmatrix
from cvxopt import matrix as dense

from softforce_cli.errors import SolverError
from softforce_cli.fem.cholmod_blocks import blocked_solver

SINGULAR = ("the stiffness matrix is singular: is the robot clamped (a [[fixed]] box that "
            "catches nodes) and its mesh connected?")
NON_FINITE = ("the stiffness matrix has non-finite entries: an element is inverted (the "
              "configuration left the material law's range)")
# cholmod.options["supernodal"]: 0 simplicial (L D L^T), 2 supernodal (L L^T only).
SIMPLICIAL, SUPERNODAL = 0, 2
# Shifts sigma tried for K + sigma I, as fractions of K's median diagonal entry: from just
# past the Diamond's negative eigenvalues (1e-6 to 4e-6 of it) up to a clear margin.
SHIFTS = 10.0 ** np.arange(-5.0, 0.0, 2.0)
# Subspace iteration for the negative modes: block sizes, tried until one holds more modes
# than are negative (the Diamond's tangents have 2 to 6), and iterations (each separates
# the modes by the ratio of their shifted eigenvalues, about 2x there).
MODES, ITERATIONS = (8, 16, 32), 8
# The capacitance matrix I/c - E^T K'^-1 E is singular with K: its smallest singular value
# below this fraction of 1/c means an eigenvalue of K at about that fraction of c, zero to
# working precision (the Diamond's negative ones give 1e-6).
SINGULAR_LEVEL = 1e-12
# Searches for anchors that may fail, per pattern, before L D L^T is kept for good (a
# Newton solve's first tangent can be far more indefinite than the following ones).
SEARCHES = 2
# Anchors per negative mode, tried in turn (the Diamond needs 1).
ANCHORS_PER_MODE = (1, 4, 16)
# Patterns remembered (the least recently used forgotten first): a coarse P2 Diamond's
# holds about 23 MB.
REMEMBERED_PATTERNS = 4


def _symbolic(lower: spmatrix, mode: int):
    """CHOLMOD's symbolic analysis of a lower triangle, simplicial or supernodal."""
    saved = dict(cholmod.options)
    cholmod.options["supernodal"] = mode
    try:
        return cholmod.symbolic(lower, uplo="L")
    finally:
        cholmod.options.clear()
        cholmod.options.update(saved)


class Factorization:
    """Factors of a sparse symmetric matrix (f, f); solve() takes (f,) or (f, k).

    refactor(matrix) reuses the symbolic analysis when the sparsity pattern is unchanged.
    `method` is how the last factorisation was made: "cholesky" (K positive definite),
    "anchored" (Cholesky of K with springs at a few dofs, corrected exactly) or "ldl".
    """

    def __init__(self, matrix: sp.spmatrix) -> None:
        self._pattern: _Pattern | None = None
        self.refactor(matrix)

    def refactor(self, matrix: sp.spmatrix) -> Factorization:
        csr = sp.csr_matrix(matrix)
        if not np.all(np.isfinite(csr.data)):
            raise SolverError(NON_FINITE)
        if not csr.has_sorted_indices:
            csr = csr.sorted_indices()
        if self._pattern is None or not self._pattern.holds(csr):
            self._analyse(csr)
        # The upper triangle of the symmetric K in CSR order is its lower triangle in CSC
        # order, which is how CHOLMOD (and cvxopt's spmatrix) store a matrix.
        values = csr.data[self._pattern.upper]
        self.size = csr.shape[0]
        if self.method == "cholesky" and self._numeric(values, self._cholesky):
            self._factor, self._correction = self._cholesky, None
            return self
        if self._failed_searches < SEARCHES and self._pattern.has_diagonal:
            if self._anchor_sets is not None and self._anchor(values):
                return self  # the anchors of the previous tangent still hold
            self._anchor_sets = self._negative_mode_dofs(csr, values)
            if self._anchor_sets is not None and self._anchor(values):
                return self
            self._anchor_sets, self._failed_searches = None, self._failed_searches + 1
        if self._ldl is None:
            self._ldl = _symbolic(self._lower, SIMPLICIAL)
        if not self._numeric(values, self._ldl):
            raise SolverError(f"{SINGULAR} (a zero pivot in L D L^T)")
        self._factor, self._correction, self.method = self._ldl, None, "ldl"
        return self

    def _analyse(self, csr: sp.csr_matrix) -> None:
        """Symbolic analysis of a new pattern; the L D L^T one waits until it is needed."""
        self._pattern = _Pattern.of(csr)
        self._lower = self._pattern.lower * 1.0  # its own values on the shared structure
        self._cholesky = _symbolic(self._lower, SUPERNODAL)
        self._ldl = self._factor = self._correction = None
        anchors = self._pattern.anchors
        self._anchor_sets = None if anchors is None else [anchors]
        # a pattern whose tangents needed anchors starts with them: K's own Cholesky would
        # fail again, at the cost of a whole numeric factorisation
        self.method = "cholesky" if anchors is None else "anchored"
        self._failed_searches = 0

    def _numeric(self, values: np.ndarray, symbolic) -> bool:
        """Factorise the lower triangle `values` into `symbolic`; False at a bad pivot."""
        self._lower.V = dense(values)
        try:
            cholmod.numeric(self._lower, symbolic)
        except ArithmeticError:
            return False
        return True

    def _negative_mode_dofs(self, csr: sp.csr_matrix, values: np.ndarray
                            ) -> list[np.ndarray] | None:
        """Candidate anchor sets, smallest first, that stop K's negative modes; None if no
        shift of K is positive definite.

        The modes: subspace iteration X <- (K + sigma I)^-1 X from a fixed start, then
        Rayleigh-Ritz with K, the Ritz vectors V (f, r) of negative value (or the lowest one).
        The anchors: the r dofs of a column-pivoted QR of V^T (the rows of V best
        conditioned together, so that no combination of the modes escapes them: the Diamond's
        symmetric pairs would slip past the largest entries alone) and each mode's largest
        entries, `count` of each per mode.
        """
        diagonal = self._pattern.diagonal
        scale = float(np.median(np.abs(values[diagonal])))
        for sigma in scale * SHIFTS:
            shifted = values.copy()
            shifted[diagonal] += sigma
            if self._numeric(shifted, self._cholesky):
                break
        else:
            return None
        rng = np.random.default_rng(0)  # a fixed start: the same matrix, the same anchors
        for modes in MODES:
            block = rng.standard_normal((self.size, min(modes, self.size)))
            for _ in range(ITERATIONS):
                block = np.linalg.qr(self._solve_with(self._cholesky, block))[0]
            ritz_values, ritz_vectors = np.linalg.eigh(block.T @ (csr @ block))
            negative = int(np.sum(ritz_values < 0))
            if negative < block.shape[1] - 1:  # the block holds them all, and a spare
                break
        vectors = block @ ritz_vectors[:, : max(1, negative)]
        pivots = scipy.linalg.qr(vectors.T, mode="r", pivoting=True)[1]
        largest = np.argsort(-np.abs(vectors), axis=0)
        return [np.unique(np.concatenate([pivots[: count * vectors.shape[1]],
                                          largest[:count].ravel()]))
                for count in ANCHORS_PER_MODE]

    def _anchor(self, values: np.ndarray) -> bool:
        """Cholesky of K + c E E^T and the Woodbury correction, with the first anchor set
        that makes it positive definite; False if none does."""
        diagonal = self._pattern.diagonal
        stiffness = float(np.median(np.abs(values[diagonal])))
        for anchors in self._anchor_sets:
            anchored = values.copy()
            anchored[diagonal[anchors]] += stiffness
            if self._numeric(anchored, self._cholesky):
                break
        else:
            return False
        self.method, self._anchors, self._anchor_sets = "anchored", anchors, [anchors]
        self._pattern.anchors = anchors
        columns = np.zeros((self.size, len(anchors)))
        columns[anchors, np.arange(len(anchors))] = 1.0
        responses = self._solve_with(self._cholesky, columns)  # Z = K'^-1 E
        capacitance = np.eye(len(anchors)) / stiffness - responses[anchors]
        if not stiffness * np.linalg.svd(capacitance, compute_uv=False)[-1] > SINGULAR_LEVEL:
            raise SolverError(f"{SINGULAR} (a zero eigenvalue)")
        self._correction = (responses, np.linalg.inv(capacitance))
        self._factor = self._cholesky
        return True

    @staticmethod
    def _solve_with(symbolic, rhs: np.ndarray) -> np.ndarray:
        """(f, k): the factor's solve of rhs (f, k), its columns together where CHOLMOD's
        own solve can be reached (fem.cholmod_blocks), else one by one through cvxopt."""
        blocked = blocked_solver()
        if blocked is not None:
            return blocked(symbolic, rhs)
        solution = dense(rhs)
        cholmod.solve(symbolic, solution)
        return np.array(solution)

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """K^-1 rhs for rhs (f,) or (f, k), all columns in one pass through the factors."""
        rhs = np.asarray(rhs, dtype=float)
        if rhs.ndim == 2 and rhs.shape[1] == 0:
            return np.zeros_like(rhs)
        solution = self._solve_with(self._factor, rhs.reshape(len(rhs), -1))
        if self._correction is not None:
            responses, inverse = self._correction
            solution += responses @ (inverse @ solution[self._anchors])
        solution = solution.reshape(rhs.shape)
        if not np.all(np.isfinite(solution)):
            raise SolverError(SINGULAR)
        return solution


@dataclass(eq=False)
class _Pattern:
    """What a sparsity pattern of K (f, f) fixes, shared by its Factorizations.

    indptr, indices : the CSR structure (sorted indices)
    upper           : (nnz,) bool, the CSR entries in the upper triangle
    lower           : those entries as the lower triangle in CSC order (cvxopt; its values
                      are a template, each Factorization copies it)
    diagonal        : (f,) position of each diagonal entry among `lower`'s values
    has_diagonal    : every diagonal entry is stored
    anchors         : the anchor dofs that last made a tangent of this pattern definite
    """

    indptr: np.ndarray
    indices: np.ndarray
    upper: np.ndarray
    lower: spmatrix
    diagonal: np.ndarray
    has_diagonal: bool
    anchors: np.ndarray | None = None

    @classmethod
    def of(cls, csr: sp.csr_matrix) -> _Pattern:
        """The remembered pattern of `csr`, or a new one (then remembered)."""
        key = hashlib.blake2b(np.int64(csr.shape[0]).tobytes() + csr.indptr.tobytes()
                              + csr.indices.tobytes(), digest_size=16).digest()
        pattern = _remembered.pop(key, None) or cls._analysed(csr)
        _remembered[key] = pattern
        while len(_remembered) > REMEMBERED_PATTERNS:
            del _remembered[next(iter(_remembered))]
        return pattern

    @classmethod
    def _analysed(cls, csr: sp.csr_matrix) -> _Pattern:
        size = csr.shape[0]
        rows = np.repeat(np.arange(size), np.diff(csr.indptr))
        upper = csr.indices >= rows
        lower = spmatrix(csr.data[upper], csr.indices[upper].astype(int),
                         rows[upper].astype(int), size=csr.shape)
        on_diagonal = np.flatnonzero(csr.indices == rows)
        return cls(csr.indptr.copy(), csr.indices.copy(), upper, lower,
                   (np.cumsum(upper) - 1)[on_diagonal], len(on_diagonal) == size)

    def holds(self, csr: sp.csr_matrix) -> bool:
        """Whether `csr` (sorted indices) has this pattern."""
        return (np.array_equal(self.indptr, csr.indptr)
                and np.array_equal(self.indices, csr.indices))


_remembered: dict[bytes, _Pattern] = {}
